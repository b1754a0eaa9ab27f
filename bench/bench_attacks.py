"""The attacks of docs/security.md, each against an insecure and a secure team: what it does to the run.

    python bench/bench_attacks.py [--scenario quick] [--window 1200 1299] [--duration S] [--only NAME ...]
                                  [--insecure-only] [--json FILE]

For each attack: a router, the simulator and five agents (scenario quick, lockstep) as separate
processes on loopback, and an attacker in this process (plain zenoh + msgpack, the documented wire
format). On the insecure team (plain TCP) the attacker needs no key; on the secure team
(``--tls-dir``: mutual TLS, default-deny access control) it holds agent 1's certificate, a
compromised robot. Each run is compared with the in-process run of the same scenario and seed:
whether the tables are bit-identical, the rows of ``estimates.csv`` that differ, the estimates'
errors against the run's own truth from the attack on, the load's final position and the drops the
daemons counted. quick ends in the kinematic phase: J and m are not estimated in it;
``--scenario quick-dynamics`` runs the whole of Algorithm 1 in 34 s, and its J and m (the last
recorded, relative to the truth) are reported too.

The attacker times its forgeries on what it hears: a measurement of agent 0 and a state of agent 2
for tick t + 1 once every wrench of tick t is out (the simulator is about to send tick t + 1), a
wrench or an estimate of tick t once agent 1's measurement of tick t is out (the simulator is at
t). An attacker that cannot hear the wrenches (the secure team's) times everything on agent 1's
measurements. Each forgery is the victim's last genuine message (eavesdropped where the attacker
may hear it) with a plausible bias, on the ticks of ``--window FIRST LAST``; ``done`` and the
far-future ticks once, at tick FIRST; the flood from FIRST for FLOOD_TICKS ticks. Prints a markdown table; see docs/security.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.certificates import init_team  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from net import access_policy as ap  # noqa: E402
from net import keys  # noqa: E402
from net.messages import Control, Estimate, Measurement, StateMsg, Wrench  # noqa: E402
from net.schema import DecodeError, decode, encode  # noqa: E402
from net.zenoh_transport import client_session, free_tcp_port  # noqa: E402

SCENARIOS = ROOT / "config" / "scenarios"
BIAS = 0.5  # m/s, added to a forged velocity (measurement, state); 20 N to a forged wrench
FLOOD_RATE = 50_000  # forged states per second, the flood
FLOOD_TICKS = 500  # it lasts from the window's first tick for 500; the run's pace is timed over as many ticks before
FAR = 5_000  # ticks ahead (50 s at quick's 10 ms)
PER_TICK = ("meas", "state", "wrench", "estimate", "wide")
"""The attacks forged on every tick of the window; the others once, at its first tick."""
DEFAULT_WINDOW = (1200, 1299)  # 1 s of quick, once the kinematic estimates settle
TABLES = ("samples.csv", "estimates.csv", "pairs.csv", "truth.csv")


def _decode(sample, cls):
    try:
        return decode(sample.payload.to_bytes(), cls)
    except DecodeError:
        return None


class Attacker:
    """One attack on one run: ``arm`` declares its subscriptions (and starts its timing), ``stop``
    ends it; ``seen`` is what it observed (samples heard, forgeries sent, ...)."""

    def __init__(self, name: str, run: str, n: int, ticks: int, window: tuple[int, int]) -> None:
        self.name, self.run, self.n, self.ticks = name, run, n, ticks
        self.once = window[0]  # the tick of the one-shot attacks (done, far-future) and the flood's start
        self.window = range(window[0], window[1] + 1)  # the ticks each per-tick forgery is made on
        self.wrenches: dict[int, set[int]] = {}  # tick -> the agents whose wrench is out
        self.heard_wrench = False  # a secure team's attacker never does: it times on agent 1's measurements
        self.clock: dict[int, float] = {}  # tick -> wall time agent 1's measurement of it was heard
        self.seen: Counter = Counter()
        self.heard_keys: set[str] = set()
        self.last: dict[str, Any] = {}  # the victims' last genuine messages, by key
        self.forged: set[bytes] = set()  # our own puts come back to our own subscribers: not genuine
        self.lock = threading.Lock()
        self.stopped = threading.Event()
        self.threads: list[threading.Thread] = []

    # -- timing and eavesdropping -------------------------------------------------------------
    def arm(self, s: zenoh.Session) -> None:
        self.s = s
        r = self.run
        if self.name == "eavesdrop":
            s.declare_subscriber(keys.run_all(r), self._on_any)
            return
        s.declare_subscriber(keys.meas(r, 1), self._on_meas)
        s.declare_subscriber(keys.agent_all(r, "wrench"), self._on_wrench)
        for key, cls in ((keys.meas(r, 0), Measurement), (keys.state(r, 2), StateMsg),
                         (keys.wrench(r, 2), Wrench), (keys.estimate(r, 3), Estimate)):
            s.declare_subscriber(key, lambda smp, key=key, cls=cls: self._remember(key, cls, smp))

    def stop(self) -> None:
        self.stopped.set()
        for t in self.threads:
            t.join(10)

    def _on_any(self, sample) -> None:
        with self.lock:
            self.seen["heard"] += 1
            self.heard_keys.add(str(sample.key_expr))

    def _remember(self, key: str, cls, sample) -> None:
        b = sample.payload.to_bytes()
        if b in self.forged:
            return
        msg = _decode(sample, cls)
        if msg is not None:
            self.last[key] = msg

    def _put(self, key: str, msg) -> None:
        b = encode(msg)
        self.forged.add(b)
        self.s.put(key, b)
        self.seen["forged"] += 1

    def _on_meas(self, sample) -> None:
        """Agent 1's measurement of tick t: a tick is on, its states, wrenches and estimates to come."""
        m = _decode(sample, Measurement)
        if m is None or encode(m) in self.forged or self.stopped.is_set():
            return
        if m.tick in (self.once - FLOOD_TICKS, self.once, self.once + FLOOD_TICKS):
            self.clock[m.tick] = time.perf_counter()
        if self.name == "flood" and m.tick == self.once:
            t = threading.Thread(target=self._flood, daemon=True)
            t.start()
            self.threads.append(t)
        self._forge("meas", m.tick)

    def _on_wrench(self, sample) -> None:
        """Every agent's wrench of tick t is out: the simulator's measurements of t + 1 are about to
        come (the simulator hears them at the same time as the attacker)."""
        w = _decode(sample, Wrench)
        if w is None or encode(w) in self.forged or self.stopped.is_set():
            return
        with self.lock:
            self.heard_wrench = True
            got = self.wrenches.setdefault(w.tick, set())
            got.add(w.agent)
            complete = len(got) == self.n
            if complete:
                self.wrenches = {k: v for k, v in self.wrenches.items() if k > w.tick}
        if complete:
            self._forge("wrenches", w.tick)

    # -- the forgeries ------------------------------------------------------------------------
    def _forge(self, trigger: str, t: int) -> None:
        """``trigger`` "wrenches": every wrench of tick t is out, the next tick's measurements and
        states are about to come; "meas": agent 1's measurement of tick t, the simulator is at t.
        An attacker that cannot hear the wrenches (the secure team's) times everything on "meas"."""
        r, name = self.run, self.name
        ahead = trigger == "wrenches" or (trigger == "meas" and not self.heard_wrench)
        nxt = t + 1 if ahead else t
        if name in PER_TICK:
            if not (ahead if name in ("meas", "state", "wide") else trigger == "meas") or nxt not in self.window:
                return
        if name == "meas":
            m = self.last.get(keys.meas(r, 0), Measurement(t, 0, 0.0, 0.0))
            self._put(keys.meas(r, 0), Measurement(nxt, 0, m.vx + BIAS, m.vy))
        elif name == "state":
            st = self.last.get(keys.state(r, 2), StateMsg(t, 2, 0.0, 0.0))
            self._put(keys.state(r, 2), dataclasses.replace(st, tick=nxt, vx=st.vx + BIAS))
        elif name == "wrench":
            w = self.last.get(keys.wrench(r, 2), Wrench(t, 2, 0.0, 0.0, 0.0))
            self._put(keys.wrench(r, 2), Wrench(t, 2, w.fx + 20.0, w.fy, w.tau))
        elif name == "estimate":
            e = self.last.get(keys.estimate(r, 3), Estimate(t, 3, {"omega": 0.0, "zi_x": 0.0}, {}))
            values = {k: v + (1.0 if k in ("omega", "zi_x", "zi_y") else 0.0) for k, v in e.values.items()}
            values.update({k: 1.2 * values[k] for k in ("J", "m") if k in values})  # once estimated
            self._put(keys.estimate(r, 3), Estimate(t, 3, values, e.pairs))
        elif name == "wide":
            m = self.last.get(keys.meas(r, 0), Measurement(t, 0, 0.0, 0.0))
            st = self.last.get(keys.state(r, 2), StateMsg(t, 2, 0.0, 0.0))
            self._put(keys.agent_all(r, "meas"), Measurement(nxt, 0, m.vx + BIAS, m.vy))
            self._put(keys.agent_all(r, "state"), dataclasses.replace(st, tick=nxt, vx=st.vx + BIAS))
            self._put(f"{keys.ROOT}/{r}/**", Control("done", self.ticks, self.ticks))
        elif name == "done" and trigger == "meas" and t == self.once:
            self._put(keys.sim_control(r), Control("done", self.ticks, self.ticks))
        elif name == "far" and trigger == "meas" and t == self.once:
            self._put(keys.meas(r, 2), Measurement(t + FAR, 2, 0.0, 0.0))
            self._put(keys.state(r, 2), StateMsg(t + FAR, 2, 0.0, 0.0))
            self._put(keys.state(r, 1), StateMsg(t + FAR, 1, 0.0, 0.0))  # agent 1's own key: its certificate may

    def _flood(self) -> None:
        """Well-formed states of agent 2, stale at once (tick 0), at FLOOD_RATE until agent 1's
        measurement of tick first + FLOOD_TICKS is heard."""
        pub = self.s.declare_publisher(keys.state(self.run, 2))
        payload = encode(StateMsg(0, 2, 0.0, 0.0))
        t0 = time.perf_counter()
        n = 0
        while not self.stopped.is_set() and self.once + FLOOD_TICKS not in self.clock:
            pub.put(payload)
            n += 1
            if n % 500 == 0:
                ahead = n / FLOOD_RATE - (time.perf_counter() - t0)
                if ahead > 0:
                    time.sleep(ahead)
        self.seen["forged"] += n
        self.seen["flood_rate"] = round(n / (time.perf_counter() - t0))


ATTACKS = {
    "eavesdrop": "eavesdrop on `coload/R/**`",
    "meas": "forged measurement of agent 0 (+0.5 m/s; ticks {a}-{b}, before the simulator's)",
    "state": "forged state \"from agent 2\" (+0.5 m/s; ticks {a}-{b}, before agent 2's)",
    "wrench": "forged wrench of agent 2 (+20 N; ticks {a}-{b})",
    "estimate": "forged estimate of agent 3 (omega, z_i +1, J and m x 1.2; ticks {a}-{b})",
    "done": "forged `done` (once, tick {a})",
    "wide": "forged measurement, state and `done` on wider key expressions (`agent/*/meas`, `agent/*/state`, "
            "`coload/R/**`; ticks {a}-{b})",
    "far": "far-future tick (+5000) on agent 2's measurement and state, agent 1's state (once, tick {a})",
    "flood": f"flood of well-formed states of agent 2 ({FLOOD_RATE} a second asked; ticks {{a}}-{{f}})",
}


def _sorted_rows(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    return [lines[0], *sorted(lines[1:])]


def _estimates(d: Path) -> dict[tuple[str, str], dict[str, str]]:
    """estimates.csv by (t, agent)."""
    if not (d / "estimates.csv").exists():
        return {}
    head, *lines = (d / "estimates.csv").read_text().splitlines()
    cols = head.split(",")
    return {tuple(x.split(",")[:2]): dict(zip(cols, x.split(","), strict=True)) for x in lines}


def _table(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    head, *lines = path.read_text().splitlines()
    return [dict(zip(head.split(","), x.split(","), strict=True)) for x in lines]


def estimate_errors(d: Path, t0: float) -> dict[str, float | None]:
    """The estimates' errors against the run's own truth (the load it really moved) from ``t0`` on:
    the largest |z_i - z_i true| (m) and |omega - omega true| (rad/s) over every agent and recorded
    tick, and their largest at the last recorded tick. With the dynamical phase: each agent's last
    recorded J and m against the truth at its tick, relative, the one of largest magnitude over the
    agents (signed, ``J_final``, ``m_final``), and when Algorithm 1 was done at every agent."""
    truth = {round(float(r["t"]), 6): r for r in _table(d / "truth.csv")}
    dz: list[tuple[float, float]] = []
    dw: list[tuple[float, float]] = []
    last: dict[str, dict[int, float]] = {"J": {}, "m": {}}
    done: dict[int, float] = {}
    for r in _table(d / "estimates.csv"):
        t, i = round(float(r["t"]), 6), int(float(r["agent"]))
        tr = truth.get(t)
        if tr is None:
            continue
        for col, tcol in (("J", "inertia"), ("m", "mass")):
            if r.get(col) and tr.get(tcol) and math.isfinite(float(r[col])):
                last[col][i] = float(r[col]) / float(tr[tcol]) - 1.0
        if r.get("phase") and float(r["phase"]) == 6.0:  # net.vocabulary.DONE
            done.setdefault(i, t)
        if t < t0 or not r["zi_x"] or not r["omega"]:
            continue
        dz.append((t, math.hypot(float(r["zi_x"]) - float(tr[f"z{i}_x"]), float(r["zi_y"]) - float(tr[f"z{i}_y"]))))
        dw.append((t, abs(float(r["omega"]) - float(tr["omega"]))))
    out: dict[str, float | None] = {
        f"{col}_final": max(v.values(), key=abs) if v else None for col, v in last.items()}
    out["done_s"] = max(done.values()) if done and len(done) == len({i for v in last.values() for i in v}) else None
    if not dz:
        return {**out, "dz_max": None, "dz_final": None, "dw_max": None, "dw_final": None}
    end = max(t for t, _ in dz)
    return {**out, "dz_max": max(e for _, e in dz), "dz_final": max(e for t, e in dz if t == end),
            "dw_max": max(e for _, e in dw), "dw_final": max(e for t, e in dw if t == end), "t_end": end}


def compare(out: Path, ref: Path) -> dict[str, Any]:
    """Bit-identical tables, and the estimate rows (t, agent) that differ from the in-process run's
    or are missing."""
    same = {name: (out / name).exists() and _sorted_rows(out / name) == _sorted_rows(ref / name) for name in TABLES}
    got, want = _estimates(out), _estimates(ref)
    diff = Counter(int(float(k[1])) for k, v in want.items() if got.get(k) != v)
    return {"identical": all(same.values()), "rows_differ": dict(sorted(diff.items())), "rows": len(want),
            "missing": sum(k not in got for k in want), "last_t": max((float(k[0]) for k in got), default=None)}


def _final_xy(run_dir: Path) -> tuple[float, float] | None:
    p = run_dir / "truth.csv"
    if not p.exists():
        return None
    head, *_, last = p.read_text().splitlines()
    cols = dict(zip(head.split(","), last.split(","), strict=True))
    return float(cols["x"]), float(cols["y"])


def run_team(tmp: Path, tag: str, attack: str | None, secure: bool, scenario: Path, overrides: list[str],
             window: tuple[int, int]) -> dict[str, Any]:
    """One team (router, simulator, agents as processes) under one attack; its summary and what the
    attacker saw."""
    run = f"att-{tag}"
    sc = load_scenario(scenario, overrides)
    d = tmp / tag
    d.mkdir()
    endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{free_tcp_port()}"
    tls_dir = d / "keys"
    if secure:
        init_team(tls_dir, sc.neighbours(), run=run, endpoint=endpoint, now=dt.datetime.now(dt.timezone.utc))
    net = ["--tls-dir", str(tls_dir)] if secure else ["--connect", endpoint]
    sets = [x for o in overrides for x in ("--set", o)]
    common = [str(scenario), *sets, "--run", run, *net]
    cmd = [sys.executable, "-m", "coload"]
    logs, procs = [], []

    def start(name: str, argv: list[str], **kw) -> subprocess.Popen:
        log = (d / f"{name}.log").open("w")
        logs.append(log)
        kw.setdefault("stdout", log)
        p = subprocess.Popen(argv, stderr=log, stdin=subprocess.DEVNULL, **kw)
        procs.append(p)
        return p

    out = d / "run"
    att = Attacker(attack or "", run, sc.n, sc.ticks, window)
    res: dict[str, Any] = {"attack": attack, "secure": secure}
    try:
        router = start("router", [*cmd, "router", *(net if secure else ["--listen", endpoint])], stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready"), "the router did not start"
        if secure:  # a session without a certificate, and plain TCP: the handshake must fail
            for ep, tls in ((endpoint, {"root_ca_certificate": str(tls_dir / ap.CA_CERT)}),
                            (endpoint.replace("tls/", "tcp/"), None)):
                try:
                    client_session(ep, tls, 1500).close()
                    res["no_cert_connected"] = True
                except zenoh.ZError:
                    res.setdefault("no_cert_refused", 0)
                    res["no_cert_refused"] += 1
        session = client_session(endpoint, ap.tls_block(tls_dir, ap.agent_role(1)) if secure else None) if attack else None
        if session is not None:
            att.arm(session)
        t0 = time.perf_counter()
        sim = start("sim", [*cmd, "sim", *common, "--out", str(out)])
        agents = [start(f"agent{i}", [*cmd, "agent", "--id", str(i), *common]) for i in range(sc.n)]
        try:
            res["sim_rc"] = sim.wait(240)
        except subprocess.TimeoutExpired:
            res["sim_rc"] = "stalled (killed after 240 s)"
        res["wall_s"] = time.perf_counter() - t0
        att.stop()
        if session is not None:
            session.close()
        res["agent_rc"] = []
        for a in agents:
            try:
                res["agent_rc"].append(a.wait(30))
            except subprocess.TimeoutExpired:
                res["agent_rc"].append("hung")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        for f in logs:
            f.close()
    res["seen"] = dict(att.seen)
    res["clock"] = att.clock
    res["dt"] = sc.dt
    res["heard_keys"] = len(att.heard_keys)
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    res["summary"] = {k: summary.get(k) for k in ("agents_reported", "drops", "timeouts", "sim_s", "wall_s")}
    res["final_xy"] = _final_xy(out)
    res["out"] = str(out)
    return res


def _f(x: float | None, fmt: str = "{:.3f}") -> str:
    return "-" if x is None else fmt.format(x)


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:+.2f} %"


def effect(r: dict[str, Any], ref: dict[str, Any], once: int) -> str:
    """One cell: what the attack did to this run (``once``: the window's first tick)."""
    s, c = r["summary"], r["cmp"]
    parts = []
    if r["attack"] == "eavesdrop":
        parts.append(f"heard {r['seen'].get('heard', 0)} samples on {r['heard_keys']} keys")
    if r.get("no_cert_refused"):
        parts.append(f"no certificate / plain TCP: {r['no_cert_refused']} of 2 handshakes refused")
    if r["attack"] == "flood":
        parts.append(f"{r['seen'].get('flood_rate', 0)} puts/s sent (the attacker's process takes one of the 2 cores)")
        c0, c1, c2 = (r["clock"].get(t) for t in (once - FLOOD_TICKS, once, once + FLOOD_TICKS))
        if None not in (c0, c1, c2):
            sim_s = FLOOD_TICKS * r["dt"]
            parts.append(f"lockstep pace {sim_s / (c1 - c0):.2f} sim s / wall s before, {sim_s / (c2 - c1):.2f} "
                         f"during the flood ({(c2 - c1) / (c1 - c0):.1f}x slower)")
    if r["sim_rc"] != 0:
        parts.append(f"simulator exit {r['sim_rc']}")
    if s.get("agents_reported") is not None and s["agents_reported"] != list(range(len(r["agent_rc"]))):
        parts.append(f"agents reported: {s['agents_reported']}")
    drops = s.get("drops") or {}
    parts.append("drops " + (", ".join(f"{k} {v}" for k, v in sorted(drops.items())) if drops else "none"))
    if any(v for v in (s.get("timeouts") or {}).values()):
        parts.append(f"timeouts {s['timeouts']}")
    if c["identical"]:
        parts.append("tables bit-identical to the in-process run")
    else:
        rows = sum(c["rows_differ"].values())
        end = _f(c["last_t"], "{:.1f}")
        parts.append(f"{rows} of {c['rows']} estimate rows differ (agents {sorted(c['rows_differ'])})"
                     + (f", {c['missing']} missing (the estimates end at t = {end} s)"
                        if c["missing"] else ""))
        a, b = ref["err"], r["err"]
        parts.append(f"estimate errors against the truth from tick {once} on, largest (at the end), in-process -> "
                     f"attacked: z_i "
                     f"{_f(a['dz_max'])} ({_f(a['dz_final'])}) -> {_f(b['dz_max'])} ({_f(b['dz_final'])}) m, omega "
                     f"{_f(a['dw_max'])} ({_f(a['dw_final'])}) -> {_f(b['dw_max'])} ({_f(b['dw_final'])}) rad/s")
        if a.get("J_final") is not None or b.get("J_final") is not None:
            parts.append(f"last J, m against the truth, in-process -> attacked: J {_pct(a.get('J_final'))} -> "
                         f"{_pct(b.get('J_final'))}, m {_pct(a.get('m_final'))} -> {_pct(b.get('m_final'))}; "
                         f"done at every agent at {_f(a.get('done_s'), '{:.1f}')} -> {_f(b.get('done_s'), '{:.1f}')} s")
        if r["final_xy"] and ref["final_xy"]:
            (x, y), (x0, y0) = r["final_xy"], ref["final_xy"]
            if (x, y) != (x0, y0):
                parts.append(f"load ends at ({x:.2f}, {y:.2f}) m instead of ({x0:.2f}, {y0:.2f})")
    return "; ".join(parts)


def _scenario(arg: str) -> Path:
    path = Path(arg) if arg.endswith(".toml") else SCENARIOS / f"{arg}.toml"
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{arg}: no such scenario file or bundled scenario")
    return path


def _errors_row(name: str, r: dict[str, Any], secure: dict[str, Any] | None) -> str:
    """One row of the errors table: the insecure run's final errors, the secure run's verdict."""
    e, s = r["err"], r["summary"]
    xy = r["final_xy"]
    verdict = "-" if secure is None else (
        ("bit-identical" if secure["cmp"]["identical"] else "differs") + ", drops "
        + (", ".join(f"{k} {v}" for k, v in sorted((secure["summary"].get("drops") or {}).items())) or "none"))
    drops = ", ".join(f"{k} {v}" for k, v in sorted((s.get("drops") or {}).items())) or "none"
    if any((s.get("timeouts") or {}).values()):
        drops += "; timeouts " + ", ".join(f"{k} {v}" for k, v in sorted(s["timeouts"].items()) if v)
    return (f"| {name} | {'yes' if r['cmp']['identical'] else sum(r['cmp']['rows_differ'].values())} | "
            f"{_f(e['dz_max'])} ({_f(e['dz_final'])}) | {_f(e['dw_max'])} ({_f(e['dw_final'])}) | "
            f"{_pct(e.get('J_final'))} | {_pct(e.get('m_final'))} | {_f(e.get('done_s'), '{:.1f}')} | "
            f"{'-' if xy is None else f'({xy[0]:.2f}, {xy[1]:.2f})'} | {drops} | {verdict} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", type=_scenario, default=SCENARIOS / "quick.toml", metavar="NAME|FILE",
                   help="a bundled scenario's name or a scenario file (default quick; quick-dynamics reaches J and m)")
    p.add_argument("--window", type=int, nargs=2, default=DEFAULT_WINDOW, metavar=("FIRST", "LAST"),
                   help="the ticks of the per-tick forgeries; the one-shot ones and the flood start at FIRST "
                        "(default %(default)s)")
    p.add_argument("--duration", type=float, help="simulated seconds per run (default: the scenario's)")
    p.add_argument("--only", nargs="+", choices=list(ATTACKS), help="these attacks only")
    p.add_argument("--insecure-only", action="store_true", help="skip the secure runs")
    p.add_argument("--json", type=Path, help="write every run's numbers here")
    args = p.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a stopped bench kills its teams (run_team's finally)
    overrides = [] if args.duration is None else [f"duration={args.duration}"]
    sc = load_scenario(args.scenario, overrides)
    first, last = window = tuple(args.window)
    if not 0 < first <= last < sc.ticks - FLOOD_TICKS * (args.only is None or "flood" in args.only):
        p.error(f"--window: expected 0 < FIRST <= LAST within the run's {sc.ticks} ticks (and the flood's "
                f"{FLOOD_TICKS} after FIRST)")
    names = args.only or list(ATTACKS)
    results: list[dict[str, Any]] = []
    fmt = {"a": first, "b": last, "f": first + FLOOD_TICKS - 1}
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        ref_dir = tmp / "inproc"
        run_inproc(sc, ref_dir)
        t0 = first * sc.dt
        ref = {"final_xy": _final_xy(ref_dir), "err": estimate_errors(ref_dir, t0)}
        print(f"in-process {sc.name}, {sc.ticks * sc.dt:g} s: {ref}", flush=True)
        base = run_team(tmp, "plain", None, False, args.scenario, overrides, window)
        base["cmp"] = compare(Path(base["out"]), ref_dir)
        base["err"] = estimate_errors(Path(base["out"]), t0)
        print(f"no attack, insecure team: {effect(base, ref, first)}", flush=True)
        rows, err_rows = [], []
        for name in names:
            cells, runs = [], []
            for secure in (False,) if args.insecure_only else (False, True):
                r = run_team(tmp, f"{name}-{'sec' if secure else 'ins'}", name, secure, args.scenario, overrides,
                             window)
                r["cmp"] = compare(Path(r["out"]), ref_dir)
                r["err"] = estimate_errors(Path(r["out"]), t0)
                cells.append(effect(r, ref, first))
                runs.append(r)
                results.append(r)
                print(f"{name} {'secure' if secure else 'insecure'} ({r['wall_s']:.0f} s): {cells[-1]}", flush=True)
            rows.append((ATTACKS[name].format(**fmt), *cells))
            err_rows.append(_errors_row(name, runs[0], runs[1] if len(runs) > 1 else None))
    print()
    print("| attack | insecure team (no key) | secure team (attacker holds agent 1's certificate) |")
    print("|---|---|---|")
    for row in rows:
        print("| " + " | ".join([*row, *(["-"] * (3 - len(row)))]) + " |")
    print()
    print(f"Insecure team, {sc.name}, ticks {first}-{last}: errors against the truth (z_i m, omega rad/s: largest from "
          f"tick {first} on (at the end); J, m: the last recorded, relative, largest over the agents)")
    print()
    print("| attack | bit-identical (or rows differing) | z_i | omega | J | m | done at (s) | load ends at (m) "
          "| drops | secure team |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(_errors_row("in-process reference", {**ref, "cmp": {"identical": True}, "summary": {}}, None))
    print(_errors_row("none (insecure team)", base, None))
    for row in err_rows:
        print(row)
    if args.json:
        args.json.write_text(json.dumps({"ref": ref, "base": base, "runs": results}, indent=1, default=str))


if __name__ == "__main__":
    main()
