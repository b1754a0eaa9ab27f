"""The cost of security, measured in one run: ratios, not thresholds.

    python bench/bench_security.py [--duration 10] [--repeats 2] [--pings 1000]

1. Lockstep speed on paper-fig4 (router, simulator and 10 agents as separate processes): simulated
   seconds per wall second of ``coload run`` with mutual TLS and the default-deny access-control list
   (``--secure``) over without, runs alternated (plain, secure, plain, secure, ...), each side's median.
2. Real-time tick latency: a tick's critical path is the simulator's measurement to an agent and the
   agent's wrench back. With the team's own certificates and access-control list (or none), a
   simulator session puts a measurement every 10 ms (the paper's tick) on agent 0's key and an agent-0
   session answers each on its wrench key; the round trip is timed on the simulator side. Median and
   99th percentile, secure over plain, in one process, alternating blocks of 100. ``--breakdown``
   adds mutual TLS without access control, and with the access-control list but default allow.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.certificates import init_team  # noqa: E402
from coload.runs.orchestrate import prepare_run_dir, run_processes  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from net import access_policy as ap  # noqa: E402
from net import keys  # noqa: E402
from net.zenoh_transport import close_session, free_tcp_port, open_session, zenoh_config  # noqa: E402

FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"
KIN = 'dynamics.algorithm="none"'  # engine speed of the kinematic phase, as bench_engines.py


def lockstep(duration: float, repeats: int) -> dict[str, list[float]]:
    sc = load_scenario(FIG4, [f"duration={duration}", KIN, "record.batch_fit=false"])
    speed: dict[str, list[float]] = {"plain": [], "secure": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for side in ("plain", "secure"):
                run_dir = Path(tmp) / f"{side}{r}"
                prepare_run_dir(run_dir)
                summary = run_processes(sc, run_dir, quiet=True, secure=side == "secure")
                assert summary is not None and summary["timeouts"] == {"wrench": 0, "neighbour": 0}, side
                speed[side].append(summary["sim_s"] / summary["wall_s"])
                print(f"  lockstep {side}: {speed[side][-1]:.2f} sim s / wall s", flush=True)
    return speed


SIDES = {"plain": (False, None), "secure": (True, "deny"), "tls-no-acl": (True, None),
         "tls-acl-default-allow": (True, "allow")}
"""side -> (mutual TLS, the access-control list's default permission or None for no list)."""


def _sessions(side: str, tmp: Path):
    run = "bench"
    secure, acl = SIDES[side]
    endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{free_tcp_port()}"
    team = None
    if secure:
        team = init_team(tmp / "keys", [[1], [0]], run=run, endpoint=endpoint, now=dt.datetime.now(dt.timezone.utc))

    def conf(role: str):
        c = zenoh_config("router" if role == ap.ROUTER else "client",
                         listen=[endpoint] if role == ap.ROUTER else [],
                         connect=[] if role == ap.ROUTER else [endpoint])
        if secure:
            c.insert_json5("transport/link/tls", json.dumps(ap.tls_block(tmp / "keys", role)))
            if role == ap.ROUTER and acl is not None:
                policy = ap.access_control(run, team.neighbours, team.common_names())
                c.insert_json5("access_control", json.dumps({**policy, "default_permission": acl}))
        return c

    router = open_session(conf(ap.ROUTER))
    return run, router, open_session(conf(ap.SIM)), open_session(conf(ap.agent_role(0)))


def latency(pings: int, sides: list[str], period: float = 0.01) -> dict[str, list[float]]:
    rtt: dict[str, list[float]] = {side: [] for side in sides}
    lost = dict.fromkeys(sides, 0)
    with tempfile.TemporaryDirectory() as tmp:
        teams = {side: _sessions(side, Path(tmp) / side) for side in rtt}
        got = threading.Event()
        subs = []
        try:
            for side, (run, _, sim, agent) in teams.items():
                reply = agent.declare_publisher(keys.wrench(run, 0))
                subs.append(agent.declare_subscriber(keys.meas(run, 0), lambda s, reply=reply: reply.put(b"w")))
                subs.append(sim.declare_subscriber(keys.agent_all(run, "wrench"), lambda s: got.set()))
            pubs = {side: t[2].declare_publisher(keys.meas(t[0], 0)) for side, t in teams.items()}
            for side, pub in pubs.items():  # warm-up: the first put races the declarations
                for _ in range(50):
                    got.clear()
                    pub.put(b"m")
                    got.wait(1.0)
            for block in range(pings // 100):
                for side, pub in pubs.items():
                    for _ in range(100):
                        got.clear()
                        t0 = time.perf_counter()
                        pub.put(b"m")
                        if not got.wait(5.0):
                            lost[side] += 1  # counted, not timed: a reply later than 5 s
                            continue
                        rtt[side].append(time.perf_counter() - t0)
                        time.sleep(max(0.0, period - (time.perf_counter() - t0)))
        finally:
            for s in subs:
                s.undeclare()
            for _, router, sim, agent in teams.values():
                for s in (agent, sim, router):
                    close_session(s)
    for side, n in lost.items():
        if n:
            print(f"  {side}: {n} round trips took longer than 5 s (not timed)")
    return rtt


def main() -> None:
    ap_ = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap_.add_argument("--duration", type=float, default=10.0, help="simulated seconds per lockstep run")
    ap_.add_argument("--repeats", type=int, default=2, help="lockstep runs per side")
    ap_.add_argument("--pings", type=int, default=1000, help="round trips per side (multiple of 100)")
    ap_.add_argument("--breakdown", action="store_true",
                     help="round trips also with TLS but no access control, and access control with default allow")
    ap_.add_argument("--skip-lockstep", action="store_true", help="the round trips only")
    args = ap_.parse_args()
    if not args.skip_lockstep:
        print(f"lockstep paper-fig4, {args.duration:g} s simulated, {args.repeats} runs per side:")
        speed = lockstep(args.duration, args.repeats)
        plain, secure = statistics.median(speed["plain"]), statistics.median(speed["secure"])
        print(f"lockstep speed: plain {plain:.2f}, secure {secure:.2f} sim s / wall s; "
              f"secure/plain {secure / plain:.3f}")
    print(f"real-time tick round trip (meas -> wrench), {args.pings} per side, one every 10 ms:")
    rtt = latency(args.pings, list(SIDES) if args.breakdown else ["plain", "secure"])
    for side, xs in rtt.items():
        xs.sort()
        print(f"  {side}: median {1e6 * statistics.median(xs):.0f} us, p99 {1e6 * xs[int(0.99 * len(xs))]:.0f} us")
    med = {s: statistics.median(x) for s, x in rtt.items()}
    p99 = {s: x[int(0.99 * len(x))] for s, x in rtt.items()}
    print(f"real-time round trip secure/plain: median {med['secure'] / med['plain']:.3f}, "
          f"p99 {p99['secure'] / p99['plain']:.3f}")


if __name__ == "__main__":
    main()
