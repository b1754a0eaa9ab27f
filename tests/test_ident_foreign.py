"""Recordings as another lab's program writes them (docs/diagnose.md, "Measured: recordings as other
loggers write them"): the wrench's hold when run.toml does not say, a Coulomb friction smoothed
otherwise than ident's, two effects at once.

The recordings come from a small plant written here: a digital controller's wrench held between its
ticks, the rigid body integrated by scipy from tick to tick, every sample logged; it shares no code with
ident/ or simulator/.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ident.diagnose import diagnose_dir
from ident.recording import held_share, read_recording

M, J, B, C = 42.0, 12.0, 8.0, 6.0
CONTACTS = np.array([[0.7, 0.1], [-0.4, 0.6], [-0.3, -0.65]])


def _held_plant(out: Path, *, log_hz: float, control_hz: float, seconds: float, b: float = 0.0, c: float = 0.0,
                fc: float = 0.0, vs: float = 0.01, sigma: float = 0.01, seed: int = 3) -> Path:
    """A controller at ``control_hz`` holds each wrench until its next tick; the logger samples the body's
    contact velocities and the wrench in force at ``log_hz``; run.toml does not say how the wrench varies.
    Friction: viscous ``b``, Coulomb ``fc`` smoothed as v / sqrt(|v|^2 + vs^2), rotational damping ``c``."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(0.2, 1.4, (3, 2, 3))
    amp = rng.uniform(3.0, 9.0, (3, 2, 3))
    phase = rng.uniform(0.0, 2 * np.pi, (3, 2, 3))
    ticks = np.arange(0.0, seconds, 1.0 / control_hz)
    forces = (amp * np.sin(2 * np.pi * freq * ticks[:, None, None, None] + phase)).sum(-1)  # (K, 3, 2)

    def rhs(_t, s, f):
        th, vx, vy, om = s[2], s[3], s[4], s[5]
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        arm = CONTACTS @ rot.T
        torque = float((arm[:, 0] * f[:, 1] - arm[:, 1] * f[:, 0]).sum())
        fx, fy = f.sum(axis=0) - (b + fc / np.sqrt(vx * vx + vy * vy + vs * vs)) * np.array([vx, vy])
        return [vx, vy, om, fx / M, fy / M, (torque - c * om) / J]

    logs = np.arange(0.0, seconds - 1.0 / control_hz, 1.0 / log_hz)
    state = np.zeros(6)
    rows = []
    for k, t0 in enumerate(ticks[:-1]):
        mine = logs[(logs >= t0 - 1e-12) & (logs < ticks[k + 1] - 1e-12)]
        sol = solve_ivp(rhs, (t0, ticks[k + 1]), state, args=(forces[k],), rtol=1e-10, atol=1e-12,
                        dense_output=True)  # fmt: skip
        for t in mine:
            th, vx, vy, om = sol.sol(t)[2:]
            rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
            arm = CONTACTS @ rot.T
            for i in range(3):
                v = np.array([vx - om * arm[i, 1], vy + om * arm[i, 0]]) + rng.normal(0.0, sigma, 2)
                rows.append(f"{t:.6f},{i},{v[0]:.9g},{v[1]:.9g},{forces[k, i, 0]:.9g},{forces[k, i, 1]:.9g},0")
        state = sol.y[:, -1]
    out.mkdir(parents=True, exist_ok=True)
    (out / "samples.csv").write_text("t,agent,vx,vy,fx,fy,tau\n" + "\n".join(rows) + "\n")
    (out / "run.toml").write_text(f"n = 3\nedges = [[0, 1], [1, 2], [2, 0]]\ndt = {1.0 / log_hz}\n")
    return out


def test_a_wrench_held_at_the_logging_rate_is_not_read_as_a_sensor_delay(tmp_path):
    """Held at the logging rate the wrench's samples look like a smooth force's; taken as smooth, the data
    show half a sample of delay, which a user would chase in the sensor. Read as held: no delay, friction
    alone, m and J within 1 % (their 95 % half-widths here are ~0.3 % and ~3 %)."""
    d = diagnose_dir(_held_plant(tmp_path, log_hz=100.0, control_hz=100.0, seconds=12.0, b=B))
    assert [e["name"] for e in d.effects] == ["viscous_friction"]
    assert d.effects[0]["value"] == pytest.approx(B, rel=0.05)
    assert d.model["hold"] == "zoh" and d.model["hold_source"].startswith("inferred")
    assert any("half the sample period" in w for w in d.warnings)
    assert d.augmented.m == pytest.approx(M, rel=0.01)
    assert d.augmented.J == pytest.approx(J, rel=0.05)


def test_a_wrench_held_slower_than_it_is_logged_is_read_as_held(tmp_path):
    """A 25 Hz controller logged at 100 Hz repeats each wrench four times: the reader sees it (3/4 repeats)."""
    path = _held_plant(tmp_path, log_hz=100.0, control_hz=25.0, seconds=12.0, b=B)
    rec = read_recording(path)
    assert rec.hold == "zoh" and rec.hold_source.startswith("inferred")
    assert held_share(rec.wrench) == pytest.approx(0.75, abs=0.01)
    d = diagnose_dir(path)
    assert [e["name"] for e in d.effects] == ["viscous_friction"]
    assert d.effects[0]["value"] == pytest.approx(B, rel=0.05)


def test_a_declared_hold_is_kept(tmp_path):
    path = _held_plant(tmp_path, log_hz=100.0, control_hz=25.0, seconds=3.0)
    with (path / "run.toml").open("a") as fh:
        fh.write('input_hold = "foh"\n')
    rec = read_recording(path)
    assert (rec.hold, rec.hold_source) == ("foh", "declared")


@pytest.mark.long
def test_viscous_friction_and_rotational_damping_together_are_both_named(tmp_path):
    """Named first, viscous friction leaves J ten times too large, where the score test is blind to the
    damping that J absorbed; a structured residual no score points at makes every candidate left be
    fitted (docs/diagnose.md, "Method" 5)."""
    d = diagnose_dir(_held_plant(tmp_path, log_hz=50.0, control_hz=50.0, seconds=30.0, b=B, c=C))
    assert sorted(e["name"] for e in d.effects) == ["rotational_damping", "viscous_friction"]
    got = {e["name"]: e for e in d.effects}
    assert abs(got["viscous_friction"]["value"] - B) < got["viscous_friction"]["ci95"] * 1.5
    assert abs(got["rotational_damping"]["value"] - C) < got["rotational_damping"]["ci95"] * 1.5


@pytest.mark.slow
def test_a_coulomb_friction_smoothed_otherwise_is_named_alone_with_its_value(tmp_path):
    """A Coulomb term smoothed as v / sqrt(|v|^2 + vs^2) with vs = 2 cm/s is wider near rest than ident's
    default (0.5 % of the RMS speed, ~0.9 mm/s here): with that smoothing kept, F_c reads 8.0 N and viscous
    friction (11.6 N s/m) and a delay (3.8 ms) are named beside it to make up the ramp. With the smoothing
    fitted: Coulomb friction alone, within 3 %."""
    path = _held_plant(tmp_path, log_hz=100.0, control_hz=100.0, seconds=12.0, fc=10.0, vs=0.02)
    with (path / "run.toml").open("a") as fh:
        fh.write('input_hold = "zoh"\n')  # the hold is the other tests' subject: one diagnosis here, not two
    d = diagnose_dir(path)
    assert [e["name"] for e in d.effects] == ["coulomb_friction"]
    assert d.effects[0]["value"] == pytest.approx(10.0, rel=0.03)
    assert 0.005 < d.model["coulomb_speed"] < 0.05
