"""An independent continuous-time planar rigid-body plant that writes recordings in the measured-data format.

Test data for ``coload diagnose`` and the batch fit made by a program that shares no code with them:
numpy, scipy and the csv module only (no import of simulator/, ident/, agents/, coload/). The load is
a rigid body (mass m, inertia J about its centre of mass C) pushed by n agents at contact points r_i
fixed in the body frame (relative to C). State: C's position c, heading theta, C's velocity v, omega:

    m dv/dt     = sum_i f_i(t) + F_effects(v, t)
    J domega/dt = sum_i (tau_i(t) + cross(R(theta) r_i, f_i(t))) + T_effects(omega)

integrated by ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-10) with the inputs evaluated
continuously (nothing is held over a sample interval), then sampled: contact-point velocities
v_i = v + omega perp(R r_i) and/or positions p_i = c + R r_i, plus Gaussian noise.

Effects (vocabulary names of the diagnosis; values in SI units):
    viscous_friction    c_v     F -= c_v v
    coulomb_friction    F_c     F -= F_c tanh(|v|/v_s) v/|v|        (v_s = ``coulomb_speed``)
    rotational_damping  c_r     T -= c_r omega
    force_bias          (bx,by) F += b (world frame)
    torque_bias         T_0     T += T_0
    measurement_delay   d       every measurement at t is the true value at t - d
    velocity_bias       (bx,by) every measured velocity is offset by b (world frame)
and outside the vocabulary:
    periodic_force      {"amplitude", "freq", "angle"}      F += A sin(2 pi f t) (cos a, sin a)
    load_change         {"t", "m", "J", "shift"}           at t, m and J (about the new CoM) change and the
                        CoM moves by ``shift`` (body frame); body points keep their positions and velocities.

Deterministic for a seed: one ``numpy.random.SeedSequence(seed)`` spawns independent streams for the
geometry, the inputs, the initial state, the time stamps and the noise, so changing the noise level
or the sample rate leaves the trajectory unchanged.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

VOCABULARY = (
    "viscous_friction", "coulomb_friction", "rotational_damping", "measurement_delay", "force_bias", "velocity_bias",
    "torque_bias",
)  # fmt: skip
OUTSIDE = ("periodic_force", "load_change")
GEOMETRIES = ("random", "perimeter", "axis")
RTOL, ATOL = 1e-10, 1e-12


# --- the load and its inputs ---------------------------------------------------------------------
@dataclass(frozen=True)
class Load:
    """Rigid load: mass (kg), inertia about the CoM (kg m^2), contact points (n, 2) in the body frame
    relative to the CoM (m), and the rectangle outline (width, height) it was drawn from."""

    m: float
    J: float
    r: np.ndarray
    outline: tuple[float, float]
    com_offset: tuple[float, float]  # CoM relative to the outline's centroid, body frame

    @property
    def n(self) -> int:
        return self.r.shape[0]


def perimeter_points(width: float, height: float, s: np.ndarray) -> np.ndarray:
    """Points at fractions ``s`` of the outline of a width x height rectangle centred on the origin."""
    per = 2.0 * (width + height)
    corners = np.array([[-width, -height], [width, -height], [width, height], [-width, height]]) / 2
    lengths = np.array([width, height, width, height])
    ends = np.cumsum(lengths)
    out = []
    for d in (np.asarray(s, dtype=float) % 1.0) * per:
        e = int(min(np.searchsorted(ends, d, side="right"), 3))
        a, b = corners[e], corners[(e + 1) % 4]
        out.append(a + (b - a) * (d - (ends[e] - lengths[e])) / lengths[e])
    return np.array(out).reshape(-1, 2)


def make_load(n: int, geometry: str, rng: np.random.Generator, m: float | None = None) -> Load:
    """A rectangular load of uniform density with a displaced CoM (a payload), contacts on its outline.

    ``random``: contacts at random places on the outline; ``perimeter``: evenly spaced from a random
    start; ``axis``: every contact behind the CoM on the body x axis (pushing along x through the CoM
    makes no torque: one translational degree of freedom).
    """
    if geometry not in GEOMETRIES:
        raise ValueError(f"geometry {geometry!r}: expected one of {GEOMETRIES}")
    w, h = rng.uniform(1.5, 4.0), rng.uniform(1.0, 3.0)
    mass = float(m) if m is not None else float(rng.uniform(20.0, 120.0))
    if geometry == "axis":
        off = np.zeros(2)
        r = np.tile([-w / 2, 0.0], (n, 1))
    else:
        off = rng.uniform(-0.15, 0.15, size=2) * (w, h)
        s = rng.uniform(0, 1, size=n) if geometry == "random" else (rng.uniform() + np.arange(n) / n)
        r = perimeter_points(w, h, s) - off
    J = mass * (w * w + h * h) / 12.0 + mass * float(off @ off)  # about the displaced CoM
    return Load(mass, float(J), r, (float(w), float(h)), (float(off[0]), float(off[1])))


@dataclass(frozen=True)
class Inputs:
    """Each agent's wrench as a linear combination of smooth basis functions of time.

    wrench(t)[i, c] = coef[i, c] @ basis(t), c in (fx, fy, tau); the basis is sinusoids
    sin(2 pi freq t + phase) followed by smooth pulses (quintic smooth-step up at t0, down at t1,
    both over a rise time ``rise``): continuous with continuous first and second derivatives.
    """

    coef: np.ndarray  # (n, 3, K)
    freq: np.ndarray  # (Ks,)
    phase: np.ndarray  # (Ks,)
    pulse: np.ndarray  # (Kp, 3): t0, t1, rise

    def basis(self, t: np.ndarray | float) -> np.ndarray:
        """(K,) or (T, K) basis values at t."""
        t = np.asarray(t, dtype=float)
        sin = np.sin(2 * np.pi * self.freq * t[..., None] + self.phase)
        if len(self.pulse) == 0:
            return sin
        t0, t1, rise = self.pulse.T
        pul = _smoothstep((t[..., None] - t0) / rise) - _smoothstep((t[..., None] - t1) / rise)
        return np.concatenate((sin, pul), axis=-1)

    def wrench(self, t: np.ndarray | float) -> np.ndarray:
        """(n, 3) or (T, n, 3): each agent's [fx, fy, tau] at t (world frame)."""
        return np.einsum("...k,ick->...ic", self.basis(t), self.coef)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


def make_inputs(load: Load, rng: np.random.Generator, *, force_rms: float, band: tuple[float, float],
                duration: float, pulses: bool = True, torque_share: float = 0.1,
                axis: bool = False) -> Inputs:  # fmt: skip
    """Random smooth inputs: per agent and channel three sinusoids (frequencies log-uniform in ``band``,
    random phases) and, with ``pulses``, one smooth pulse of random sign and length. The total applied
    force has an RMS of about ``force_rms`` per axis; agents' torques are ``torque_share`` of the torque
    their forces make. ``axis``: forces along x only and no torques (one degree of freedom)."""
    n = load.n
    k_sin = 3
    ks = n * 3 * k_sin
    freq = np.exp(rng.uniform(math.log(band[0]), math.log(band[1]), size=ks))
    phase = rng.uniform(0, 2 * np.pi, size=ks)
    per_agent = force_rms / math.sqrt(n)
    lever = float(np.sqrt(np.mean(np.sum(load.r**2, axis=1)))) if n else 1.0
    coef_s = np.zeros((n, 3, ks))
    amp = rng.uniform(0.5, 1.0, size=(n, 3, k_sin))
    amp *= math.sqrt(2.0 / k_sin) / np.sqrt(np.mean(amp**2, axis=2, keepdims=True))  # channel RMS 1
    scale = np.array([per_agent, per_agent, torque_share * per_agent * lever])
    for i in range(n):
        for c in range(3):
            j = (i * 3 + c) * k_sin
            coef_s[i, c, j : j + k_sin] = amp[i, c] * scale[c]
    if pulses:
        t0 = rng.uniform(0.1, 0.6, size=(n, 3)) * duration
        t1 = t0 + rng.uniform(0.05, 0.15, size=(n, 3)) * duration
        rise = rng.uniform(0.5, 2.0, size=(n, 3))
        level = rng.choice([-1.0, 1.0], size=(n, 3)) * rng.uniform(0.2, 0.4, size=(n, 3)) * scale
        pulse = np.stack((t0.ravel(), t1.ravel(), rise.ravel()), axis=1)
        coef_p = np.zeros((n, 3, n * 3))
        for i in range(n):
            for c in range(3):
                coef_p[i, c, i * 3 + c] = level[i, c]
    else:
        pulse = np.zeros((0, 3))
        coef_p = np.zeros((n, 3, 0))
    coef = np.concatenate((coef_s, coef_p), axis=2)
    if axis:
        coef[:, 1:, :] = 0.0
    return Inputs(coef, freq, phase, pulse)


# --- effects -------------------------------------------------------------------------------------
def realistic_effects(names: Sequence[str], load: Load, force_rms: float, band: tuple[float, float],
                      duration: float) -> dict[str, Any]:  # fmt: skip
    """Magnitudes at which each effect matters next to the inertial and applied forces (docstring of the
    module; the choices are in :data:`MAGNITUDES`)."""
    m, J = load.m, load.J
    w_mid = 2 * np.pi * math.sqrt(band[0] * band[1])
    out: dict[str, Any] = {}
    for name in names:
        if name == "viscous_friction":  # c_v v about 20 % of m dv/dt at the band's middle frequency
            out[name] = 0.2 * m * w_mid
        elif name == "coulomb_friction":  # 10 % of the applied force's RMS
            out[name] = 0.1 * force_rms
        elif name == "rotational_damping":  # c_r omega about 20 % of J domega/dt
            out[name] = 0.2 * J * w_mid
        elif name == "force_bias":  # 5 % of the applied force's RMS, a fixed direction
            out[name] = [0.05 * force_rms * math.cos(0.6), 0.05 * force_rms * math.sin(0.6)]
        elif name == "torque_bias":  # 5 % of the applied force's RMS at the load's radius of gyration
            out[name] = 0.05 * force_rms * math.sqrt(J / m)
        elif name == "measurement_delay":  # 30 ms: a sensor pipeline's latency
            out[name] = 0.03
        elif name == "velocity_bias":  # 3 cm/s: an encoder calibration offset
            out[name] = [0.03, -0.02]
        elif name == "periodic_force":  # 30 % of the applied force's RMS at 2.7 band-middles
            out[name] = {"amplitude": 0.3 * force_rms, "freq": 2.7 * w_mid / (2 * np.pi), "angle": 0.4}
        elif name == "load_change":  # a payload added at 60 % of the recording
            out[name] = {"t": 0.6 * duration, "m": 1.3 * m, "J": 1.25 * J, "shift": [0.1, -0.05]}
        else:
            raise ValueError(f"unknown effect {name!r}: expected one of {VOCABULARY + OUTSIDE}")
    return out


MAGNITUDES = {
    "viscous_friction": "0.2 m w_mid (N s/m): about 20 % of the inertial force at the inputs' middle frequency",
    "coulomb_friction": "0.1 force_rms (N), smoothing speed 0.01 m/s",
    "rotational_damping": "0.2 J w_mid (N m s)",
    "force_bias": "0.05 force_rms (N), direction 0.6 rad",
    "torque_bias": "0.05 force_rms sqrt(J / m) (N m)",
    "measurement_delay": "0.03 s",
    "velocity_bias": "(0.03, -0.02) m/s",
    "periodic_force": "0.3 force_rms at 2.7 w_mid / 2 pi Hz, direction 0.4 rad",
    "load_change": "at 0.6 duration: m x 1.3, J x 1.25, CoM shift (0.1, -0.05) m body frame",
}


@dataclass(frozen=True)
class Effects:
    viscous: float = 0.0
    coulomb: float = 0.0
    coulomb_speed: float = 0.01
    rotational: float = 0.0
    fbias: tuple[float, float] = (0.0, 0.0)
    tbias: float = 0.0
    delay: float = 0.0
    vbias: tuple[float, float] = (0.0, 0.0)
    periodic: tuple[float, float, float] = (0.0, 0.0, 0.0)  # amplitude, freq, angle
    change: Mapping[str, Any] | None = None

    @classmethod
    def from_dict(cls, eff: Mapping[str, Any]) -> Effects:
        unknown = set(eff) - set(VOCABULARY + OUTSIDE + ("coulomb_speed",))
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}: expected names from {VOCABULARY + OUTSIDE}")
        p = eff.get("periodic_force")
        return cls(
            viscous=float(eff.get("viscous_friction", 0.0)), coulomb=float(eff.get("coulomb_friction", 0.0)),
            coulomb_speed=float(eff.get("coulomb_speed", 0.01)), rotational=float(eff.get("rotational_damping", 0.0)),
            fbias=tuple(map(float, eff.get("force_bias", (0.0, 0.0)))), delay=float(eff.get("measurement_delay", 0.0)),
            tbias=float(eff.get("torque_bias", 0.0)),
            vbias=tuple(map(float, eff.get("velocity_bias", (0.0, 0.0)))),
            periodic=(float(p["amplitude"]), float(p["freq"]), float(p["angle"])) if p else (0.0, 0.0, 0.0),
            change=eff.get("load_change"),
        )  # fmt: skip


# --- dynamics ------------------------------------------------------------------------------------
class _Segment:
    """The ODE of one constant-parameter stretch of the motion (between load changes)."""

    def __init__(self, m: float, J: float, r: np.ndarray, inputs: Inputs, eff: Effects) -> None:
        self.m, self.J, self.r, self.eff = m, J, r, eff
        self.inputs = inputs
        c = inputs.coef  # (n, 3, K)
        # aggregate channels over agents: Fx, Fy, sum tau, P = sum(rx fy - ry fx), Q = sum(rx fx + ry fy)
        rx, ry = r[:, 0:1], r[:, 1:2]
        self.agg = np.stack((c[:, 0].sum(0), c[:, 1].sum(0), c[:, 2].sum(0),
                             (rx * c[:, 1] - ry * c[:, 0]).sum(0), (rx * c[:, 0] + ry * c[:, 1]).sum(0)))  # fmt: skip
        # the same inputs, flattened for a cheap right-hand side: sinusoids, then each pulse as a rising
        # and a falling smooth step
        ks = inputs.freq.size
        self.agg_s = self.agg[:, :ks].copy()
        self.agg_p = np.concatenate((self.agg[:, ks:], -self.agg[:, ks:]), axis=1)
        self.pulsed = self.agg_p.shape[1] > 0
        self.omega_in, self.phase = 2 * np.pi * inputs.freq, inputs.phase
        p = inputs.pulse
        self.edge = np.concatenate((p[:, 0], p[:, 1]))
        self.inv_rise = 1.0 / np.concatenate((p[:, 2], p[:, 2]))
        a, f, ang = eff.periodic
        self.per = (a * math.cos(ang), a * math.sin(ang), 2 * math.pi * f)

    def rhs(self, t: float, s: np.ndarray) -> np.ndarray:
        u = self.agg_s @ np.sin(self.omega_in * t + self.phase)
        if self.pulsed:
            x = np.minimum(np.maximum((t - self.edge) * self.inv_rise, 0.0), 1.0)
            u += self.agg_p @ (x * x * x * (10.0 + x * (-15.0 + 6.0 * x)))
        fx, fy, tq, P, Q = u
        _, _, th, vx, vy, w = s
        e = self.eff
        fx += e.fbias[0]
        fy += e.fbias[1]
        if self.per[0] or self.per[1]:
            sw = math.sin(self.per[2] * t)
            fx += self.per[0] * sw
            fy += self.per[1] * sw
        if e.viscous:
            fx -= e.viscous * vx
            fy -= e.viscous * vy
        if e.coulomb:
            sp = math.hypot(vx, vy)
            if sp > 0.0:
                k = e.coulomb * math.tanh(sp / e.coulomb_speed) / sp
                fx -= k * vx
                fy -= k * vy
        # cross(R r_i, f_i) summed = cos(th) P - sin(th) Q
        tq += math.cos(th) * P - math.sin(th) * Q - e.rotational * w + e.tbias
        return np.array([vx, vy, w, fx / self.m, fy / self.m, tq / self.J])


@dataclass
class Trajectory:
    """Piecewise dense solution: state(t) = [cx, cy, theta, vx, vy, omega] and the CoM-relative contacts."""

    breaks: list[float]  # segment start times (first = start of the integration)
    sols: list[Any]
    r: list[np.ndarray]  # contact points (body frame, relative to the segment's CoM)
    m: list[float]
    J: list[float]
    nfev: int

    def _seg(self, t: np.ndarray) -> np.ndarray:
        return np.searchsorted(np.asarray(self.breaks[1:]), t, side="right")

    def state(self, t: np.ndarray) -> np.ndarray:
        """(T, 6) states at times t (within the integrated span)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty((t.size, 6))
        seg = self._seg(t)
        for k, sol in enumerate(self.sols):
            sel = seg == k
            if sel.any():
                out[sel] = sol(t[sel]).T
        return out

    def contacts(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (T, n, 2), velocities (T, n, 2)) of the contact points at times t, noise-free."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s = self.state(t)
        seg = self._seg(t)
        r = np.stack([self.r[k] for k in seg])  # (T, n, 2)
        c, sn = np.cos(s[:, 2])[:, None], np.sin(s[:, 2])[:, None]
        Rx = c * r[..., 0] - sn * r[..., 1]
        Ry = sn * r[..., 0] + c * r[..., 1]
        pos = np.stack((s[:, 0:1] + Rx, s[:, 1:2] + Ry), axis=-1)
        w = s[:, 5:6]
        vel = np.stack((s[:, 3:4] - w * Ry, s[:, 4:5] + w * Rx), axis=-1)
        return pos, vel


def simulate(load: Load, inputs: Inputs, eff: Effects, x0: np.ndarray, t0: float, t1: float,
             max_step: float) -> Trajectory:  # fmt: skip
    """Integrate from state x0 at t0 to t1 (DOP853, rtol 1e-10, atol 1e-12, steps <= max_step)."""
    m, J, r = load.m, load.J, load.r
    x = np.asarray(x0, dtype=float)
    pieces = [(t0, t1)]
    ch = eff.change
    if ch is not None and t0 < float(ch["t"]) < t1:
        pieces = [(t0, float(ch["t"])), (float(ch["t"]), t1)]
    traj = Trajectory([], [], [], [], [], 0)
    for k, (a, b) in enumerate(pieces):
        if k == 1:  # load change: the CoM moves by `shift` in the body frame, body points keep their velocities
            d = np.asarray(ch["shift"], dtype=float)
            c, s = math.cos(x[2]), math.sin(x[2])
            dw = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
            x = x.copy()
            x[0:2] += dw
            x[3:5] += x[5] * np.array([-dw[1], dw[0]])
            m, J, r = float(ch["m"]), float(ch["J"]), r - d
        seg = _Segment(m, J, r, inputs, eff)
        sol = solve_ivp(seg.rhs, (a, b), x, method="DOP853", rtol=RTOL, atol=ATOL, max_step=max_step,
                        dense_output=True)  # fmt: skip
        if not sol.success:
            raise RuntimeError(f"integration failed: {sol.message}")
        traj.breaks.append(a)
        traj.sols.append(sol.sol)
        traj.r.append(r)
        traj.m.append(m)
        traj.J.append(J)
        traj.nfev += sol.nfev
        x = sol.y[:, -1]
    return traj


# --- sampling and writing ----------------------------------------------------------------------------
def stamps(rate_hz: float, duration_s: float, rng: np.random.Generator, jitter: float = 0.0,
           gaps: Sequence[tuple[float, float]] = ()) -> np.ndarray:  # fmt: skip
    """Sample times k/rate in [0, duration), each moved by U(-jitter/2, jitter/2)/rate (jitter < 1 keeps
    them increasing), none inside a gap [a, b)."""
    k = np.arange(int(round(duration_s * rate_hz)))
    t = k / rate_hz
    if jitter:
        if not 0 <= jitter < 1:
            raise ValueError(f"jitter {jitter}: expected a fraction of the period in [0, 1)")
        t = t + rng.uniform(-jitter / 2, jitter / 2, size=t.size) / rate_hz
        t[0] = max(t[0], 0.0)
    keep = np.ones(t.size, bool)
    for a, b in gaps:
        keep &= ~((t >= a) & (t < b))
    return t[keep]


def write_recording(out_dir: Path, t: np.ndarray, wrench: np.ndarray, vel: np.ndarray | None,
                    pos: np.ndarray | None, dt: float, edges: Sequence[tuple[int, int]],
                    comment: str = "") -> None:  # fmt: skip
    """samples.csv (long format, one row per agent per stamp; NaN written as an empty cell) and run.toml."""
    out_dir.mkdir(parents=True, exist_ok=True)
    n = wrench.shape[1]
    header = ["t", "agent"]
    if vel is not None:
        header += ["vx", "vy"]
    if pos is not None:
        header += ["x", "y"]
    header += ["fx", "fy", "tau"]

    def cell(x: float) -> str:
        return "" if math.isnan(x) else repr(float(x))

    with open(out_dir / "samples.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for k, tk in enumerate(t.tolist()):
            for i in range(n):
                row = [repr(tk), str(i)]
                if vel is not None:
                    row += [cell(vel[k, i, 0]), cell(vel[k, i, 1])]
                if pos is not None:
                    row += [cell(pos[k, i, 0]), cell(pos[k, i, 1])]
                row += [repr(float(x)) for x in wrench[k, i]]
                w.writerow(row)
    edge_text = ", ".join(f"[{i}, {j}]" for i, j in edges)
    lines = [f"# {comment}", f"n = {n}", f"dt = {dt!r}", f"edges = [{edge_text}]", 'name = "ctplant"', "",
             "[recording]", 'source = "tests/ctplant.py (independent continuous-time plant)"']  # fmt: skip
    (out_dir / "run.toml").write_text("\n".join(lines) + "\n")


def make_recording(out_dir: str | Path | None, *, n: int, rate_hz: float, duration_s: float, sigma_v: float,
                   effects: Mapping[str, Any] | Sequence[str] = (), seed: int, velocities: bool = True,
                   positions: bool = False, sigma_p: float = 0.0, jitter: float = 0.0,
                   gaps: Sequence[tuple[float, float]] = (), missing: float = 0.0, geometry: str = "random",
                   m: float | None = None, force_rms: float | None = None, band: tuple[float, float] = (0.2, 2.0),
                   pulses: bool = True, max_step: float | None = None, inputs: bool = True,
                   x0: Sequence[float] | None = None, sigma_f: float = 0.0) -> dict[str, Any]:  # fmt: skip
    """Generate one recording into ``out_dir`` (None: only return the truth) and return the truth.

    ``effects``: names (realistic magnitudes, :func:`realistic_effects`) or a mapping name -> value
    (None = realistic). ``force_rms`` defaults to 0.4 m (an RMS acceleration of 0.4 m/s^2 per axis).
    ``missing``: probability that an agent's measurement at a stamp is absent (empty cells).
    ``sigma_f``: noise on the logged force (N, each agent's fx and fy at each stamp; the plant gets the
    true force): a force sensor's own noise, or what a logged command misses of the force delivered.
    ``max_step`` defaults to 0.02 s or 1/25 of the fastest input period if shorter (the error control
    at rtol 1e-10 sets the accuracy; tests/test_ctplant.py checks a tenth of the sample period agrees).
    ``inputs=False``: no applied wrench (free motion from ``x0``, the state at the start of the motion,
    t = -delay). The returned dict (also written as truth.json) holds m, J, the contact points
    (body frame and world frame at t = 0, relative to the CoM), the initial state, the effects and the
    recording's settings; arrays ``t``, ``wrench``, ``vel_true``, ``pos_true`` are returned but not written.
    """
    if not 1 <= n <= 12:
        raise ValueError(f"n = {n}: expected 1..12 agents")
    if not velocities and not positions:
        raise ValueError("a recording needs velocities, positions or both")
    ss = np.random.SeedSequence(seed)
    r_geom, r_in, r_x0, r_t, r_noise = (np.random.default_rng(s) for s in ss.spawn(5))
    load = make_load(n, geometry, r_geom, m)
    axis = geometry == "axis"
    frms = 0.4 * load.m if force_rms is None else float(force_rms)
    given = dict(effects) if isinstance(effects, Mapping) else dict.fromkeys(effects)
    eff_dict = realistic_effects([k for k, v in given.items() if v is None], load, frms, band, duration_s)
    eff_dict.update({k: v for k, v in given.items() if v is not None})
    eff = Effects.from_dict(eff_dict)
    inp = make_inputs(load, r_in, force_rms=frms if inputs else 0.0, band=band, duration=duration_s, pulses=pulses,
                      axis=axis)  # fmt: skip
    if x0 is None:
        x0 = np.concatenate((r_x0.uniform(-1, 1, 2), [r_x0.uniform(-np.pi, np.pi)],
                             r_x0.normal(0, 0.1, 2), [r_x0.normal(0, 0.1)]))  # fmt: skip
        if axis:
            x0[[1, 2, 4, 5]] = 0.0
    x0 = np.asarray(x0, dtype=float)
    dt = 1.0 / rate_hz
    t = stamps(rate_hz, duration_s, r_t, jitter, gaps)
    t_start = min(0.0, float(t[0])) - eff.delay  # the motion starts before the first delayed measurement
    if max_step is None:  # the inputs' and the periodic force's time scale bound the step; rtol bounds the error
        max_step = min(0.02, 1 / (25 * band[1]), 1 / (25 * eff.periodic[1]) if eff.periodic[1] else math.inf)
    traj = simulate(load, inp, eff, x0, t_start, duration_s + dt, max_step)
    pos_true, vel_true = traj.contacts(t - eff.delay)
    T = t.size
    vel = pos = None
    if velocities:
        vel = vel_true + np.asarray(eff.vbias) + r_noise.normal(0.0, sigma_v, size=(T, n, 2))
    if positions:
        pos = pos_true + r_noise.normal(0.0, sigma_p, size=(T, n, 2))
    if missing:
        gone = r_noise.uniform(size=(T, n)) < missing
        for a in (vel, pos):
            if a is not None:
                a[gone] = np.nan
    wrench = inp.wrench(t)
    if sigma_f:
        r_force = np.random.default_rng(ss.spawn(1)[0])  # a stream of its own: the others stay as they were
        wrench[..., :2] += r_force.normal(0.0, sigma_f, size=(T, n, 2))
    s0 = traj.state(np.array([0.0]))[0]
    th0 = s0[2]
    rot = np.array([[math.cos(th0), -math.sin(th0)], [math.sin(th0), math.cos(th0)]])
    r0 = load.r @ rot.T
    edges = [(i, i + 1) for i in range(n - 1)]
    truth: dict[str, Any] = {
        "generator": "tests/ctplant.py", "seed": seed, "n": n, "geometry": geometry,
        "m": load.m, "J": load.J, "r_body": load.r.tolist(), "r0": r0.tolist(), "zc0": r0.mean(axis=0).tolist(),
        "outline": list(load.outline), "com_offset": list(load.com_offset),
        "c0": s0[0:2].tolist(), "theta0": float(th0), "v0": s0[3:5].tolist(), "omega0": float(s0[5]),
        "effects": eff_dict, "coulomb_speed": eff.coulomb_speed,
        "rate_hz": rate_hz, "dt": dt, "duration_s": duration_s, "samples": int(T),
        "sigma_v": sigma_v if velocities else None, "sigma_p": sigma_p if positions else None, "jitter": jitter,
        "gaps": [list(g) for g in gaps], "missing": missing, "sigma_f": sigma_f,
        "force_rms": frms, "band": list(band), "edges": [list(e) for e in edges], "nfev": traj.nfev,
        "identifiable": {"m": True, "J": not axis, "geometry": not axis},
    }  # fmt: skip
    if out_dir is not None:
        out = Path(out_dir)
        write_recording(out, t, wrench, vel, pos, dt, edges, comment=f"ctplant seed {seed}")
        (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    truth.update(t=t, wrench=wrench, vel_true=vel_true, pos_true=pos_true, trajectory=traj, load=load, inputs=inp)
    return truth


__all__ = [
    "GEOMETRIES", "MAGNITUDES", "OUTSIDE", "VOCABULARY", "Effects", "Inputs", "Load", "Trajectory", "make_inputs",
    "make_load", "make_recording", "perimeter_points", "realistic_effects", "simulate", "stamps", "write_recording",
]  # fmt: skip
