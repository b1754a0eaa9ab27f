"""``coload diagnose`` on recordings shaped as another lab's program writes them: a table, one row per case.

The plant here is written for this bench and shares no code with ident/, simulator/ or tests/ctplant.py:
a planar rigid body integrated by scipy (``solve_ivp``, rtol 1e-10), n agents at random contacts pushing
with sums of sines, the wrench either smooth or held by a controller at its own rate; viscous friction,
Coulomb friction smoothed as v / sqrt(|v|^2 + v_s^2), rotational damping, a sensor delay, sensor glitches
(a share of samples off by many sigma); velocities or positions logged (velocities in each robot's own
frame: odometry); the wrench in rows of its own at another rate; an agent's logger that drops out; the same
offset on every force sensor (world or robot frame); a logged force clipped at a limit; a mass that drifts;
velocity noise low-passed (a filtered estimate); force sensors that low-pass or log late; friction fixed to the
load's axes (a cart); run.toml says n, edges and dt and
nothing about how the wrench varies. Each case is diagnosed through the public CLI and judged against the
plant's truth (docs/diagnose.md, "Measured: recordings as other loggers write them"):

    python bench/foreign_recordings.py                      # every case (~10-20 min on two cores)
    python bench/foreign_recordings.py --cases held_100 coulomb_wide
    python bench/foreign_recordings.py --list
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]

CASES: dict[str, dict] = {
    "smooth_viscous": {"b": 8.0},
    "held_100": {"b": 8.0, "hold_hz": 100.0},
    "held_25_logged_100": {"b": 8.0, "hold_hz": 25.0},
    "held_20": {"b": 8.0, "rate": 20.0, "hold_hz": 20.0, "dur": 40.0},
    "smooth_delay_20ms": {"b": 8.0, "delay": 0.02},
    "held_delay_20ms": {"b": 8.0, "hold_hz": 100.0, "delay": 0.02},
    "coulomb_wide": {"fc": 10.0, "vs": 0.01},
    "viscous_and_coulomb": {"b": 8.0, "fc": 10.0, "vs": 0.01},
    "viscous_and_rotational": {"b": 8.0, "c": 30.0},
    "glitches_1pct": {"b": 8.0, "glitches": 0.01},
    "positions_held": {"b": 8.0, "hold_hz": 100.0, "pos": 0.001},
    "wrench_rows_33hz": {"b": 8.0, "wrench_hz": 33.0},
    "logger_dropout": {"b": 8.0, "dropout": (2, 5.0, 15.0)},
    "payload_added": {"b": 8.0, "change": (11.0, 1.5)},
    "one_noisy_agent": {"b": 8.0, "sigma": (0.01, 0.01, 0.01, 0.1)},
    "force_sensor_noise": {"fnoise": 0.05},
    "force_sensor_noise_viscous": {"b": 8.0, "fnoise": 0.05},
    "velocity_offset_viscous": {"b": 8.0, "vbias": (0.03, -0.02)},
    "one_actuator_80pct": {"b": 8.0, "gain": (2, 0.8)},
    "one_clock_50ms": {"b": 8.0, "clock": (1, 0.05)},
    "robot_frame_forces": {"b": 8.0, "robot_frame": True},
    "spin_10rad_s": {"b": 8.0, "spin": 10.0},
    "sensor_offset": {"soffset": (0.4, -0.3)},
    "sensor_offset_viscous": {"b": 8.0, "soffset": (0.4, -0.3)},
    "clipped_forces": {"b": 8.0, "fclip": 10.0},
    "sensor_offset_robot_frames": {"b": 8.0, "soffset": (0.4, -0.3), "soffset_robot": True},
    "mass_drift": {"drift": 0.8},
    "robot_frame_velocities": {"b": 8.0, "vel_robot": True},
    "colored_velocity": {"vcolor": 0.1},
    "colored_velocity_viscous": {"b": 8.0, "vcolor": 0.1},
    "butterworth_velocity_viscous": {"b": 8.0, "vfilter": ("butter2", 0.1)},
    "boxcar_velocity_viscous": {"b": 8.0, "vfilter": ("boxcar", 0.15)},
    "cart_2_20": {"aniso": (2.0, 20.0)},
    "force_lowpass_30ms": {"b": 8.0, "flp": 0.03},
    "force_late_30ms": {"b": 8.0, "flate": 0.03},
    "force_spikes": {"b": 8.0, "fspikes": (0.005, 2.0)},
    "one_velocity_scale_90pct": {"b": 8.0, "vscale": (1, 0.9)},
}
"""case -> plant: n 4, 100 Hz, 20 s, sigma 0.01 m/s, seed 1 unless the case says."""


def record(out: Path, *, n: int = 4, rate: float = 100.0, dur: float = 20.0, sigma: float | tuple = 0.01, seed: int = 1,
           b: float = 0.0, fc: float = 0.0, vs: float = 0.01, c: float = 0.0, delay: float = 0.0,
           hold_hz: float | None = None, glitches: float = 0.0, pos: float = 0.0, wrench_hz: float | None = None,
           dropout: tuple[int, float, float] | None = None, change: tuple[float, float] | None = None,
           fnoise: float = 0.0, vbias: tuple[float, float] = (0.0, 0.0), gain: tuple[int, float] | None = None,
           clock: tuple[int, float] | None = None, robot_frame: bool = False, spin: float = 0.0,
           soffset: tuple[float, float] | None = None, fclip: float | None = None, fs: float = 0.0,
           vst: float = 0.02, famp: float = 1.0, soffset_robot: bool = False, drift: float | None = None,
           vel_robot: bool = False, vcolor: float = 0.0, aniso: tuple[float, float] | None = None, flp: float = 0.0,
           flate: float = 0.0, fspikes: tuple[float, float] | None = None, fspikes_applied: bool = False,
           vscale: tuple[int, float] | None = None, soffsets: float | None = None,
           vfilter: tuple[str, float] | None = None,
           sdrift: tuple[int, float, float, float] | None = None,
           own_clock: tuple[float, float] | None = None,
           fclip_agents: tuple[int, ...] | None = None) -> dict:  # fmt: skip
    """Write one recording to ``out``; return the truth. ``wrench_hz``: the wrench in rows of its own at
    that rate (a topic per row), ``dropout`` (agent, from, to): that agent's logger writes nothing then;
    ``change`` (t, factor): m and J are multiplied by factor from t on (a payload on the load's CoM);
    ``sigma`` one velocity noise for all agents or one per agent; ``fnoise``: the logged force's own noise,
    as a share of the force's RMS (the plant gets the true force); ``vbias``: every velocity sensor's offset;
    ``gain`` (agent, k): that agent's actuator delivers k x the force it logs; ``clock`` (agent, s): that agent's
    logger stamps its rows s late (the row at stamp t holds what happened at t - s); ``robot_frame``: each
    robot logs its force in its own frame, fixed to the load and facing the load's centre (logged
    f_i = R(theta + phi_i)^T f_i, phi_i the contact's polar angle + pi); ``spin``: the load's rate (rad/s) at
    the start of the integration, 1 s before the recording; ``soffset``: every agent's force sensor reads this
    much more (N, world frame, or with ``soffset_robot`` each robot's own frame as ``robot_frame`` has it;
    the plant gets the true force); ``drift``: m and J change linearly from their values at t = 0 to ``drift``
    times them at the recording's end; ``vel_robot``: each robot logs its velocity in its own frame (as
    ``robot_frame`` the force: wheel odometry); ``fclip``: the logged force saturates at
    +-fclip per axis (the plant gets the true force), every agent's or ``fclip_agents``' only; ``vcolor``: the velocity noise is a first-order low-pass
    of white noise with this correlation time (s; a filtered velocity estimate), of standard deviation
    ``sigma``; ``aniso`` (b_x, b_y): viscous friction b_x along the load's own x axis and b_y along its y axis
    (a cart on wheels; the axes as at the integration's start); ``fs``: static friction (Stribeck: the Coulomb
    level rises from ``fc`` to ``fs`` as the speed falls below ``vst``); ``famp``: the pushes' amplitude scaled;
    ``flp``: every force sensor low-passes (first order, this time constant, s; steady state, smooth pushes
    only); ``flate``: the force rows are stamped this late (s; the row at t holds the force of t - flate);
    ``fspikes`` (share, k): that share of the force samples is off by k x the force's RMS per axis (normal; a
    dropped byte in the F/T log), in the log only or, with ``fspikes_applied``, applied too (a one-sample knock:
    a triangle of one sample's half-width); ``vscale`` (agent, k): that agent logs k x its contact's velocity (a
    wheel radius off); ``soffsets``: each agent's force sensor its own offset (world frame), normal with this sd
    per axis (drawn apart from the plant's stream); ``vfilter`` (kind, tau): the velocity noise is white noise
    filtered otherwise than ``vcolor``, rescaled to ``sigma``: ``"butter2"`` a digital second-order Butterworth
    low-pass of cutoff 1 / (2 pi tau) (the commonest filter on a lab's velocity estimate), ``"boxcar"`` the mean
    over the last tau (a moving average); stationary from the first sample (run in on draws apart from the
    plant's stream); ``sdrift`` (agent, x, y, tau): that agent's force sensor's
    offset warms up from 0 to (x, y) N (world frame) as 1 - exp(-t / tau) (a thermal drift); ``own_clock`` (phase,
    jitter): each robot samples and stamps on its own clock, agent i's k-th
    row at k/rate + i phase + U(-jitter, jitter) (s; drawn apart from the plant's stream), the stamps exact."""
    if flp and hold_hz:
        raise ValueError("flp: the low-pass of a held wrench is not written here (smooth pushes only)")
    sig = np.broadcast_to(np.asarray(sigma, float), (n,))
    rng = np.random.default_rng(seed)
    m = rng.uniform(20, 80)
    J = m * rng.uniform(0.3, 1.5)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = rng.uniform(0.4, 1.0, n)
    r = np.c_[rad * np.cos(ang), rad * np.sin(ang)]
    freq = rng.uniform(0.15, 1.5, (n, 2, 3))
    amp = rng.uniform(2, 8, (n, 2, 3)) * m / 40 * famp
    ph = rng.uniform(0, 2 * np.pi, (n, 2, 3))

    kg = np.ones((n, 1))
    if gain:
        kg[gain[0]] = gain[1]
    lag = np.zeros(n)
    if clock:
        lag[clock[0]] = clock[1]
    phi = ang + np.pi
    keep = np.exp(-1 / (rate * vcolor)) if vcolor else 0.0  # the low-pass's share of the previous noise
    vnoise: list = [None] * n
    if vfilter:  # y_k = sum b_j w_(k-j) - sum a_j y_(k-j), per agent and axis, on the plant's own draws
        if vfilter[0] == "butter2":
            from scipy.signal import butter

            fb, fa = butter(2, 1 / (2 * np.pi * vfilter[1]), fs=rate)
        else:
            fb, fa = np.ones(max(1, round(vfilter[1] * rate))), np.ones(1)
        fb, fa = fb / fa[0], fa / fa[0]
        imp = np.zeros(int(50 * vfilter[1] * rate) + fb.size)  # the impulse response: the output's variance
        for k in range(imp.size):
            imp[k] = (fb[k] if k < fb.size else 0.0) - sum(fa[j] * imp[k - j] for j in range(1, min(k, fa.size - 1) + 1))
        fb = fb / np.sqrt((imp**2).sum())
        rw = np.random.default_rng(seed + 104729)
        whist = [rw.normal(0, sig[i], (fb.size, 2)) for i in range(n)]  # newest first
        yhist = [np.zeros((max(fa.size - 1, 1), 2)) for i in range(n)]
        for i in range(n):  # run in: the filter's state stationary before the first row
            for _ in range(imp.size):
                whist[i] = np.vstack((rw.normal(0, sig[i], (1, 2)), whist[i][:-1]))
                y_ = fb @ whist[i] - (fa[1:] @ yhist[i][: fa.size - 1] if fa.size > 1 else 0.0)
                yhist[i] = np.vstack((y_[None], yhist[i][:-1]))
    t = np.arange(0, dur, 1 / rate)
    frms = float(np.sqrt((amp**2 / 2).sum(-1).mean()))  # RMS of one agent's force component
    spikes = np.zeros((t.size, n, 2))
    if fspikes:  # drawn apart from the plant's stream: the other cases' recordings stay as they were
        rs = np.random.default_rng(seed + 7919)
        spikes[rs.random((t.size, n)) < fspikes[0]] = 1.0
        spikes *= rs.normal(0, fspikes[1] * frms, spikes.shape)

    own = np.random.default_rng(seed + 104729).normal(0, soffsets, (n, 2)) if soffsets else np.zeros((n, 2))

    def knocks(tq: float) -> np.ndarray:  # (n, 2): the applied spikes, triangles one sample wide either side
        k = int(np.floor(tq * rate))
        out = np.zeros((n, 2))
        for j in (k, k + 1):
            if 0 <= j < t.size:
                out += spikes[j] * max(0.0, 1.0 - abs(tq * rate - j))
        return out

    def force(t: float) -> np.ndarray:  # (n, 2), world frame, as logged
        if hold_hz:
            t = np.floor(t * hold_hz + 1e-9) / hold_hz
        return (amp * np.sin(2 * np.pi * freq * t + ph)).sum(-1)

    def logged(t: float) -> np.ndarray:  # (n, 2): what the force sensors log at t
        if not flp:
            return force(t - flate)
        w = 2 * np.pi * freq  # each sine through T f' + f = its force: gain 1/sqrt(1 + (w T)^2), phase -atan(w T)
        return (amp / np.sqrt(1 + (w * flp) ** 2) * np.sin(w * (t - flate) + ph - np.arctan(w * flp))).sum(-1)

    def arms(th: float) -> np.ndarray:
        ct, st = np.cos(th), np.sin(th)
        return r @ np.array([[ct, st], [-st, ct]])

    def rhs(t, y):
        _, _, th, vx, vy, om = y
        rw, f = arms(th), kg * (force(t) + (knocks(t) if fspikes_applied else 0.0))
        torque = float((rw[:, 0] * f[:, 1] - rw[:, 1] * f[:, 0]).sum())
        v = np.array([vx, vy])
        k = change[1] if change and t >= change[0] else 1.0
        if drift:
            k = 1.0 + (drift - 1.0) * min(max(t, 0.0), dur) / dur
        fric = fc + (fs - fc) * np.exp(-(v @ v) / vst**2) if fs else fc
        acc = (f.sum(0) - b * v - fric * v / np.sqrt(v @ v + vs * vs)) / (k * m)
        if aniso:
            R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
            acc -= R @ (np.asarray(aniso) * (R.T @ v)) / (k * m)
        return [vx, vy, om, acc[0], acc[1], (torque - c * om) / (k * J)]

    y0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, spin])  # x, y, theta, vx, vy, omega
    sol = solve_ivp(rhs, (-1.0, dur + 0.1), y0, dense_output=True, rtol=1e-10, atol=1e-12,
                    max_step=0.5 / hold_hz if hold_hz else 0.25 / rate if fspikes_applied else 0.01)  # fmt: skip
    at = np.repeat(t[:, None], n, axis=1)  # each agent's sample instants
    if own_clock:
        at = at + np.arange(n) * own_clock[0] + np.random.default_rng(seed + 15485863).uniform(
            -own_clock[1], own_clock[1], at.shape)
    rows = []
    for k_row in range(t.size):
        for i in range(n):
            tk = at[k_row, i]
            px, py, th, vx, vy, om = sol.sol(max(tk - lag[i] - delay, -1.0))
            rw = arms(th)
            f = logged(tk - lag[i])
            if robot_frame:
                thf = sol.sol(tk)[2] + phi[i]
                c_, s_ = np.cos(thf), np.sin(thf)
                f[i] = [c_ * f[i, 0] + s_ * f[i, 1], -s_ * f[i, 0] + c_ * f[i, 1]]
            if pos:
                y = np.array([px + rw[i, 0], py + rw[i, 1]]) + rng.normal(0, pos, 2)
            else:
                draw = rng.normal(0, sig[i], 2)
                if vcolor:  # stationary from the first sample: the same draws, low-passed
                    draw = draw if vnoise[i] is None else keep * vnoise[i] + np.sqrt(1 - keep * keep) * draw
                    vnoise[i] = draw
                elif vfilter:
                    whist[i] = np.vstack((draw[None], whist[i][:-1]))
                    draw = fb @ whist[i] - (fa[1:] @ yhist[i][: fa.size - 1] if fa.size > 1 else 0.0)
                    yhist[i] = np.vstack((draw[None], yhist[i][:-1]))
                y = np.array([vx - om * rw[i, 1], vy + om * rw[i, 0]]) + draw + vbias
                if vscale and i == vscale[0]:
                    y = vscale[1] * y
                if glitches and rng.random() < glitches:
                    y += rng.normal(0, 20 * sig[i], 2)
                if vel_robot:
                    thf = th + phi[i]
                    y = np.array([np.cos(thf) * y[0] + np.sin(thf) * y[1], -np.sin(thf) * y[0] + np.cos(thf) * y[1]])
            fl = f[i] + (rng.normal(0, fnoise * frms, 2) if fnoise else 0.0) + spikes[k_row, i]
            if soffset and soffset_robot:  # the offset in the robot's frame, turning with the load
                thf = sol.sol(tk)[2] + phi[i]
                fl = fl + [np.cos(thf) * soffset[0] - np.sin(thf) * soffset[1],
                           np.sin(thf) * soffset[0] + np.cos(thf) * soffset[1]]
            elif soffset:
                fl = fl + soffset
            fl = fl + own[i]
            if sdrift and i == sdrift[0]:
                fl = fl + np.asarray(sdrift[1:3]) * (1.0 - np.exp(-tk / sdrift[3]))
            if fclip and (fclip_agents is None or i in fclip_agents):
                fl = np.clip(fl, -fclip, fclip)
            w = ",," if wrench_hz else f"{fl[0]:.9g},{fl[1]:.9g},0"
            rows.append((tk, i, f"{tk:.6f},{i},{y[0]:.9g},{y[1]:.9g},{w}"))
    for tk in np.arange(0, dur, 1 / wrench_hz) if wrench_hz else ():
        f = logged(tk)
        rows += [(tk, i, f"{tk:.6f},{i},,,{f[i, 0]:.9g},{f[i, 1]:.9g},0") for i in range(n)]
    rows.sort(key=lambda r: r[:2])
    rows = [r for tk, i, r in rows if not (dropout and i == dropout[0] and dropout[1] <= tk < dropout[2])]
    out.mkdir(parents=True, exist_ok=True)
    (out / "samples.csv").write_text(("t,agent,x,y,fx,fy,tau\n" if pos else "t,agent,vx,vy,fx,fy,tau\n")
                                     + "\n".join(rows) + "\n")  # fmt: skip
    edges = [[i, (i + 1) % n] for i in range(n)] if n > 1 else []
    (out / "run.toml").write_text(f"n = {n}\nedges = {json.dumps(edges)}\ndt = {1 / rate}\n")
    effects = {"viscous_friction": b, "coulomb_friction": fc, "rotational_damping": c, "measurement_delay": delay,
               "agent_actuator_gain": gain and gain[1], "agent_clock_offset": clock and clock[1],
               "robot_frame_forces": robot_frame, "robot_frame_velocities": vel_robot,
               "velocity_scale": vscale and vscale[1],
               "force_sensor_offset": soffset and not soffset_robot and list(soffset),
               "force_sensor_lowpass": flp, "force_sensor_lag": flate}
    if aniso:  # the isotropic part is viscous friction; the rest D = (b_x - b_y) / 2 diag(1, -1) in the start's axes
        effects["viscous_friction"] = b + (aniso[0] + aniso[1]) / 2
        effects["anisotropic_friction"] = [aniso[0] + b, aniso[1] + b]  # the friction along x and along y
    if soffset and soffset_robot:  # the team's offset: a force fixed in the load's frame and a constant torque
        turned = [np.array([[np.cos(p_), -np.sin(p_)], [np.sin(p_), np.cos(p_)]]) @ soffset for p_ in phi]
        torque = sum(r[i, 0] * turned[i][1] - r[i, 1] * turned[i][0] for i in range(n))
        effects["sensor_offset_body"] = [float(np.hypot(*sum(turned))), float(torque)]  # |B| (its frame's zero is the model's), T
    if soffsets:
        effects["force_offsets_sum"] = own.sum(axis=0).tolist()
    if sdrift:
        effects["force_offset_drift"] = sdrift[0]
    return {"m": m, "J": J, "effects": {k: v for k, v in effects.items() if v}, "change": change, "drift": drift,
            "fclip": fclip,
            "force_noise": fnoise * frms * np.sqrt(n), "mounting_deg": np.degrees(phi).tolist()}


def _named(k: str, e: dict) -> str:
    """An effect as named: a scalar +- its ci95, or a per-agent effect's agents off the reference."""
    if e.get("agents") is not None:
        return f"{k} " + ", ".join(f"agent {i}: {e['value'][i]:.4g}"
                                   + ("" if e["ci95"][i] is None else f" +- {e['ci95'][i]:.2g}") for i in e["agents"])
    if e["value"] is None:
        return k
    if isinstance(e["value"], list):  # a vector effect: (x, y)
        return f"{k} ({', '.join(f'{v:.4g}' for v in e['value'])}) +- ({', '.join(f'{c:.2g}' for c in e['ci95'])})"
    return f"{k} {e['value']:.4g} +- {e['ci95']:.2g}"


def _truth(v) -> str:
    if isinstance(v, list):
        return f" (truth ({', '.join(f'{x:g}' for x in v)}))"
    return " (truth: the robots' frames)" if v is True else f" (truth {v:g})"


def row(name: str, truth: dict, d: dict, wall: float) -> str:
    ch = d.get("change") or {}
    if truth["change"]:  # the change must be found and each side must name the truth's effects
        tc, k = truth["change"]
        named = {e["name"]: e for e in ch.get("after", {}).get("effects", [])}
        right = ch.get("found", False) and ch["window"][0] <= tc <= ch["window"][1] and all(
            {e["name"] for e in ch[s]["effects"]} == set(truth["effects"]) for s in ("before", "after"))
        sides = "; ".join(f"{s} m {100 * (ch[s]['m'] / (truth['m'] * (k if s == 'after' else 1)) - 1):+.2f} %, J "
                          f"{100 * (ch[s]['J'] / (truth['J'] * (k if s == 'after' else 1)) - 1):+.2f} %"
                          for s in ("before", "after")) if ch.get("found") else "no change found"  # fmt: skip
        return (f"| {name} | {', '.join(truth['effects'])}, m and J x{k:g} at {tc:g} s | {'yes' if right else 'NO'} | "
                f"change in [{ch['window'][0]:g}, {ch['window'][1]:g}] s; after: "
                + "; ".join(f"{n} {e['value']:.4g} +- {e['ci95']:.2g}" for n, e in named.items())
                + f" | {sides} | | | | {d['model']['hold']} ({d['model'].get('hold_source', '-')}) | {wall:.0f} |")
    named = {e["name"]: e for e in d["effects"]}
    right = set(named) == set(truth["effects"]) and not d["unexplained"]
    if truth.get("drift"):  # no effect of the vocabulary: unexplained, no change kept, the drift named
        right = d["unexplained"] and not (d.get("change") or {}).get("found") and any(
            w.startswith("m drifts: ") for w in d["warnings"])
    elif truth.get("fclip"):  # the log, not the plant: the saturation named, no effect named that is not there
        right = bool(d.get("saturation")) and set(named) <= set(truth["effects"])
    vals = "; ".join(_named(k, e) + (_truth(truth["effects"][k]) if k in truth["effects"] else "")
                     for k, e in named.items())  # fmt: skip
    rf = d.get("random_force")
    if rf:
        vals += ("; " if vals else "") + f"random force {rf['force_x_N']:.3g}, {rf['force_y_N']:.3g} N" + (
            f" (truth {truth['force_noise']:.3g})" if truth.get("force_noise") else "")
    nom, aug = d["nominal"], d["augmented"]

    def err(rep, key):
        return f"{100 * (rep[key] / truth[key] - 1):+.2f}" if rep[key] is not None else "-"

    return (f"| {name} | {', '.join(truth['effects']) or 'none'} | {'yes' if right else 'NO'} | {vals or '-'}"
            f"{' (unexplained)' if d['unexplained'] else ''} | {err(nom, 'm')} -> {err(aug, 'm')} | "
            f"{err(nom, 'J')} -> {err(aug, 'J')} | {aug['residual_over_floor']:.2f} | {aug['whiteness_p']:.2g} | "
            f"{d['model']['hold']} ({d['model'].get('hold_source', '-')}) | {wall:.0f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES), metavar="CASE")
    ap.add_argument("--list", action="store_true", help="print the cases and their plants, then exit")
    args = ap.parse_args(argv)
    if args.list:
        for k, v in CASES.items():
            print(f"{k}: {v}")
        return 0
    print("| case | truth's effects | named right | named (value +- ci95) | m error % before -> after | "
          "J error % before -> after | residual / floor | whiteness p | hold (why) | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.cases:
            out = Path(tmp) / name
            truth = record(out, **CASES[name])
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "coload", "diagnose", str(out), "--quiet", "--json",
                            str(out / "d.json")], check=True, stdout=subprocess.DEVNULL, cwd=ROOT)  # fmt: skip
            print(row(name, truth, json.loads((out / "d.json").read_text()), time.perf_counter() - t0), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
