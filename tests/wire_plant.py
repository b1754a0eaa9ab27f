"""A simulator for `coload agent` daemons written from docs/wire.md and docs/security.md alone: plain
zenoh + msgpack + numpy, no import of coload. Its own rigid body (its own integrator, its own load: not
the scenario's), the lockstep protocol, the liveliness token, a monitor of the agents' estimates scored
against its own truth. Used by tests/test_net_foreign_plant.py.
"""

from __future__ import annotations

import math
import threading

import msgpack
import numpy as np
import zenoh


def _rot(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


class Body:
    """A planar rigid body under per-contact world-frame forces and torques held over a tick: translation
    integrated exactly, rotation with the lever arms at the tick's mid angle."""

    def __init__(self, m: float, J: float, r_body: np.ndarray) -> None:
        self.m, self.J, self.r = m, J, np.asarray(r_body, float)  # contacts about the CoM, body frame
        self.p, self.a, self.v, self.w = np.zeros(2), 0.0, np.zeros(2), 0.0

    def contacts(self) -> np.ndarray:
        return self.p + self.r @ _rot(self.a).T

    def contact_velocities(self) -> np.ndarray:
        rw = self.r @ _rot(self.a).T
        return self.v + self.w * np.stack([-rw[:, 1], rw[:, 0]], axis=1)

    def step(self, f: np.ndarray, tau: np.ndarray, dt: float) -> None:
        rw = self.r @ _rot(self.a + 0.5 * self.w * dt).T
        acc = f.sum(axis=0) / self.m
        alpha = (float(np.sum(rw[:, 0] * f[:, 1] - rw[:, 1] * f[:, 0])) + float(tau.sum())) / self.J
        self.p = self.p + self.v * dt + 0.5 * acc * dt * dt
        self.v = self.v + acc * dt
        self.a = self.a + self.w * dt + 0.5 * alpha * dt * dt
        self.w = self.w + alpha * dt


def pentagon(n: int) -> np.ndarray:
    """n <= 5 contacts, counter-clockwise, irregular, about a CoM off their centroid."""
    ang = np.array([-2.6, -1.2, 0.15, 1.3, 2.35])[:n]
    rad = np.array([1.9, 1.6, 2.1, 1.4, 1.8])[:n]
    return np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1) + np.array([0.25, -0.15])


def run_plant(conf: zenoh.Config, run: str, n: int, ticks: int, *, dt: float = 0.01, sigma: float = 0.1,
              mass: float = 38.0, inertia: float = 61.0, every: int = 10, seed: int = 11,
              startup_s: float = 60.0, wrench_timeout_s: float = 10.0) -> dict:
    """Play the simulator's role for a lockstep run of ``ticks``; return the agents' last estimates scored
    against this plant's truth, their reports and the wrench timeouts."""
    body = Body(mass, inertia, pentagon(n))
    rng = np.random.default_rng(seed)
    cv = threading.Condition()
    wrenches: dict[tuple[int, int], tuple[float, float, float]] = {}
    alive: set[int] = set()
    last_estimate: dict[int, tuple[int, dict]] = {}
    reports: dict[int, dict] = {}

    def agent_of(sample) -> int:
        return int(str(sample.key_expr).split("/")[3])

    def body_of(sample) -> dict:
        return msgpack.unpackb(sample.payload.to_bytes(), strict_map_key=False)[2]

    def on_wrench(sample) -> None:
        b = body_of(sample)
        with cv:
            wrenches[(b["tick"], agent_of(sample))] = (b["fx"], b["fy"], b["tau"])
            cv.notify_all()

    def on_estimate(sample) -> None:
        b = body_of(sample)
        with cv:
            last_estimate[agent_of(sample)] = (b["tick"], b["values"])

    def on_report(sample) -> None:
        with cv:
            reports[agent_of(sample)] = body_of(sample)
            cv.notify_all()

    def on_alive(sample) -> None:
        i = int(str(sample.key_expr).rsplit("/", 1)[1])
        with cv:
            (alive.add if sample.kind == zenoh.SampleKind.PUT else alive.discard)(i)
            cv.notify_all()

    truth: dict[int, dict] = {}
    timeouts = 0
    with zenoh.open(conf) as s:
        subs = [s.declare_subscriber(f"coload/{run}/agent/*/wrench", on_wrench),
                s.declare_subscriber(f"coload/{run}/agent/*/estimate", on_estimate),
                s.declare_subscriber(f"coload/{run}/agent/*/report", on_report),
                s.liveliness().declare_subscriber(f"coload/{run}/alive/agent/*", on_alive, history=True)]
        token = s.liveliness().declare_token(f"coload/{run}/alive/sim/0")
        meas = [s.declare_publisher(f"coload/{run}/agent/{i}/meas") for i in range(n)]
        control = s.declare_publisher(f"coload/{run}/sim/control")
        pose = s.declare_publisher(f"coload/{run}/sim/pose")

        def notice(kind: str, tick: int) -> None:
            control.put(msgpack.packb(["control", 1, {"kind": kind, "tick": tick, "ticks": ticks}]))

        with cv:
            assert cv.wait_for(lambda: len(alive) == n, startup_s), f"agents alive: {sorted(alive)}"
        notice("start", 0)
        for k in range(ticks):
            pc = body.contacts()
            pg = pc.mean(axis=0)
            if k % every == 0:
                truth[k] = {"omega": body.w, "z": pc - pg, "zc": pg - body.p}
                pose.put(msgpack.packb(["pose", 1, {
                    "tick": k, "x": float(body.p[0]), "y": float(body.p[1]), "angle": float(body.a),
                    "pg_x": float(pg[0]), "pg_y": float(pg[1]), "z": [float(c) for c in (pc - pg).ravel()]}]))
            v = body.contact_velocities() + rng.normal(0.0, sigma, (n, 2))
            for i in range(n):
                meas[i].put(msgpack.packb(["meas", 1, {"tick": k, "agent": i, "vx": float(v[i, 0]),
                                                       "vy": float(v[i, 1])}]))
            f, tau = np.zeros((n, 2)), np.zeros(n)
            with cv:
                if not cv.wait_for(lambda k=k: all((k, i) in wrenches for i in alive), wrench_timeout_s):
                    timeouts += 1
                for i in range(n):
                    w = wrenches.pop((k, i), None)
                    if w is not None:
                        f[i], tau[i] = w[:2], w[2]
            body.step(f, tau, dt)
            if k % 100 == 0:
                notice("progress", k)
        notice("done", ticks)
        with cv:
            cv.wait_for(lambda: len(reports) == n, 30)
        del token, subs

    scored = {}
    for i, (tick, v) in last_estimate.items():
        t = truth[tick]
        scored[i] = {
            "tick": tick, "phase": v.get("phase"),
            "J_rel": (v["J"] - inertia) / inertia, "m_rel": (v["m"] - mass) / mass,
            "zi_err": math.hypot(v["zi_x"] - t["z"][i, 0], v["zi_y"] - t["z"][i, 1]),
            "zc_err": math.hypot(v["zc_x"] - t["zc"][0], v["zc_y"] - t["zc"][1]),
            "omega_err": v["omega"] - t["omega"],
        }
    return {"estimates": scored, "reports": reports, "wrench_timeouts": timeouts}
