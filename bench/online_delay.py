"""The velocity-sensor delay and the online team: what detection does with it, and whether a state for it is practical.

    python bench/online_delay.py runs [--delays 0.02,0.05,0.1] [--seeds 1-2] [--keep DIR]
    python bench/online_delay.py cost [--delays 0.02,0.05,0.1] [--reps 20000]
    python bench/online_delay.py separability [--stage m|J] RUN_DIR [RUN_DIR ...]

``runs``: in-process lockstep (equal to a Zenoh run bit for bit), friction-online.toml with nothing declared
(``dynamics.estimate_effects = []``), a clean floor (``plant.friction = {}``) and ``sensor.delay`` set,
``dynamics.online_detection = true``, run to 110 s; for each run the switches the team agreed and withdrew
(summary.json ``effects``), the ``unexplained`` windows, m and J relative errors at the end, and the same
plant and seed with detection off (the nominal twin). ``--keep DIR`` keeps each run directory (for
``separability``).

``cost``: one EKF predict + update with numpy as agents/rigid_filter.py does it (dense A P A^T, gain from
the innovation covariance), of the filter's dimension (10 with detection) and of the exact delay model that
carries the last d contact velocities too (2 d more states, d = 1 .. round(max delay / dt)), and the bank of
those filters over d that an unknown delay needs.

``separability [--stage m|J]``: over a stage of a kept run, from its truth, the cosine between the
first-order delay signature (the contact acceleration a_i: v_meas ~ v - tau a_i) and each column the filter
fits to the same own-velocity innovations (1/m, omega, q's angle and scale); the part of a_i that the
filter's v_C walk and those columns leave; the pooled score a delay candidate would reach per window from
it; and the cosine of that part with what the viscous and rotational candidates leave. docs/online-delay.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.rundir import format as fmt  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from net.vocabulary import J_EXCITE, M_EXCITE  # noqa: E402
from seed_list import parse_seeds  # noqa: E402  (bench/ is the script's own directory)

SCENARIO = ROOT / "config" / "scenarios" / "friction-online.toml"
BASE = ["dynamics.estimate_effects=[]", "plant.friction={}", "duration=110"]


def one(delay: float, seed: int, detect: bool, keep: str | None) -> dict:
    sc = load_scenario(SCENARIO, [*BASE, f"plant.sensor={{delay={delay}}}", f"seed={seed}",
                                  f"dynamics.online_detection={'true' if detect else 'false'}"])
    with tempfile.TemporaryDirectory() as d:
        run = Path(keep) / f"delay{delay:g}-s{seed}-{'det' if detect else 'nom'}" if keep else Path(d) / "run"
        s = run_inproc(sc, run)
        c = fmt.read_run(run).estimates.columns
    t = np.arange(len(c["phase"])) * sc.record.every_ticks * sc.dt
    m_start = t[np.flatnonzero(c["phase"][:, 0] >= M_EXCITE)[0]]
    eff = s.get("effects", {})
    return {"delay": delay, "seed": seed, "detect": detect, "m_rel": s["errors"].get("m_rel"),
            "J_rel": s["errors"].get("J_rel"), "effects": eff, "m_start": float(m_start), "dt": sc.dt,
            "step_us": s.get("agent_step_us"),
            "b": float(c["b"][-1, 0]) if "b" in c else float("nan"),
            "c": float(c["c"][-1, 0]) if "c" in c else float("nan")}


def runs(a: argparse.Namespace) -> None:
    delays = a.delays
    seeds = parse_seeds(a.seeds)
    if a.keep:
        Path(a.keep).mkdir(parents=True, exist_ok=True)
    out = []
    for dl in delays:
        for sd in seeds:
            for det in (True, False):
                r = one(dl, sd, det, a.keep)
                out.append(r)
                print("run", json.dumps(r), flush=True)
    table(out)


def table(out: list[dict]) -> None:
    """The markdown table of the runs: one row per detection run, its nominal twin's errors beside it."""
    nominal = {(r["delay"], r["seed"]): r for r in out if not r["detect"]}
    f = lambda v: "-" if v is None or v != v else f"{100 * v:.2f} %"  # noqa: E731
    g = lambda v: "-" if v != v else f"{v:.3f}"  # noqa: E731
    print("| delay (s) | seed | switched (tick: effect, z) | first switch from the m stage start (s) | withdrawn "
          "| unexplained windows "
          "| m err | J err | nominal m err | nominal J err | b | c | agent step (us) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in (r for r in out if r["detect"]):
        eff = r["effects"]
        ev = eff.get("events", [])
        sw = "; ".join(f"{e['tick']}: {e['effect']}, {e['statistic']:.2f}" for e in ev) or "none"
        dt0 = f"{ev[0]['tick'] * r['dt'] - r['m_start']:.1f}" if ev else "-"
        # a withdrawal, where the decision code reports one (summary.json effects.withdrawn)
        wd = "; ".join(f"{e.get('tick')}: {e.get('effect')}" if isinstance(e, dict) else str(e)
                       for e in eff.get("withdrawn", [])) or "-"
        nom = nominal.get((r["delay"], r["seed"]), {})
        print(f"| {r['delay']:g} | {r['seed']} | {sw} | {dt0} | {wd} | {eff.get('unexplained_windows')} "
              f"| {f(r['m_rel'])} | {f(r['J_rel'])} | {f(nom.get('m_rel'))} | {f(nom.get('J_rel'))} "
              f"| {g(r['b'])} | {g(r['c'])} | {r.get('step_us') or 0:.0f} |")


def _ekf_step(s: np.ndarray, P: np.ndarray, A: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray,
              y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One predict + update as the filter does it: P <- A P A^T + Q, then the gain from P H^T and the
    innovation covariance (3 measurements: the own contact velocity and the pooled rate)."""
    s = A @ s
    P = A @ P @ A.T + Q
    C = P @ H.T
    S = H @ C + R
    K = C @ np.linalg.inv(S)
    s = s + K @ (y - H @ s)
    P = P - K @ C.T
    return s, 0.5 * (P + P.T)


def cost(a: argparse.Namespace) -> None:
    """Time (least of 7) of one predict + update, the filter's dimension against the exact delay model's."""
    dt = 0.01
    dmax = max(int(round(x / dt)) for x in a.delays)
    dims = [("nominal filter (7 + rate bias)", 8), ("with detection (+ beta, gamma)", 10)]
    dims += [(f"exact delay {d * dt:g} s: + last {d} contact velocities", 10 + 2 * d) for d in range(1, dmax + 1)]
    rng = np.random.default_rng(0)  # the test matrices only; the timing does not depend on their values
    out = []
    print("| model | states | us per predict + update | x detection filter |")
    print("|---|---|---|---|")
    for name, n in dims:
        A = np.eye(n) + 0.01 * rng.standard_normal((n, n))
        P = np.eye(n)
        Q = 1e-4 * np.eye(n)
        H = np.zeros((3, n))
        H[0, 0] = H[1, 1] = H[2, 5] = 1.0
        R = 0.09 * np.eye(3)
        s = np.zeros(n)
        y = np.zeros(3)
        ts = []
        for _ in range(7):
            t0 = time.perf_counter()
            for _ in range(a.reps):
                s, P = _ekf_step(s, P, A, Q, H, R, y)
            ts.append((time.perf_counter() - t0) / a.reps * 1e6)
        out.append((name, n, min(ts)))  # the least disturbed timing on a shared machine
    base = next(us for _, n, us in out if n == 10)
    for name, n, us in out:
        print(f"| {name} | {n} | {us:.1f} | {us / base:.2f} |")
    # the delay is unknown: a bank of exact filters over d = 0..dmax, one per hypothesis
    bank = base + sum(us for _, n, us in out if n > 10)
    print(f"| bank over d = 0..{dmax} ({dmax + 1} filters) | {sum(10 + 2 * d for d in range(dmax + 1))} | {bank:.1f} "
          f"| {bank / base:.2f} |")


def _signatures(run: Path, agent: int, dt: float, phase: int) -> dict[str, np.ndarray]:
    """The stage ``phase`` (M_EXCITE: the m stage) of ``run``, agent ``agent``, from truth (kept every record
    tick, interpolated to the tick ``dt``): the delay signature (the true contact acceleration a_i;
    v_meas = v_i - tau a_i to first order), the columns the filter fits to the same own-velocity innovations
    and the other candidates' signatures, complex (x + i y)."""
    r = fmt.read_run(run)
    tr = r.truth
    ph = r.estimates.columns["phase"][:, 0]
    m = r.estimates.t[ph == phase]
    t = np.arange(m[0], m[-1], dt)
    c = tr.columns
    vc = c["vc_x"] + 1j * c["vc_y"]
    om = c["omega"]
    z = tr.zi[:, agent, 0] + 1j * tr.zi[:, agent, 1]
    v = vc + 1j * om * z
    ip = lambda x: np.interp(t, tr.t, x.real) + 1j * np.interp(t, tr.t, x.imag)  # noqa: E731
    # the other candidates' signatures in the own velocity: viscous friction -beta dt sum v_C, rotational
    # damping -gamma dt sum omega through omega's column q^perp
    ivc = np.concatenate(([0.0], np.cumsum(0.5 * (vc[1:] + vc[:-1]) * np.diff(tr.t))))
    iom = np.concatenate(([0.0], np.cumsum(0.5 * (om[1:] + om[:-1]) * np.diff(tr.t))))
    return {"delay": ip(np.gradient(v, tr.t)), "a_C": ip(np.gradient(vc, tr.t)), "viscous": ip(ivc),
            "rotational": ip(1j * iom * z),
            "1/m (dt sum F / m = v_C)": ip(vc), "omega (q^perp)": ip(1j * z + 0j),
            "q angle (omega q)": ip(om * z), "q scale (omega q^perp)": ip(1j * om * z)}


def _walk_highpass(x: np.ndarray, q: float, r: float, dt: float) -> np.ndarray:
    """The innovations a steady-state random-walk filter (walk intensity q per s, noise variance r per sample)
    leaves of a noise-free input x: what the filter's v_C state does not absorb of it."""
    p = q * dt / 2 + np.sqrt((q * dt) ** 2 / 4 + q * dt * r)  # the prior variance's fixed point
    k = p / (p + r)
    e = np.empty_like(x)
    est = x[0]
    for i, xi in enumerate(x):
        e[i] = xi - est
        est += k * e[i]
    return e


def separability(a: argparse.Namespace) -> None:
    """Cosines of the delay signature with each column the filter fits over the m stage; the part of it left
    after the v_C walk and a least-squares fit of the other columns; the score a first-order candidate would
    reach per window with it, per agent and pooled over the team."""
    for run in a.runs:
        run = Path(run)
        cfg = fmt.read_run(run).config
        dt = float(cfg["dt"])
        n = int(cfg["n"])
        sigma = a.sigma
        w = int(round(a.window / dt))
        print(f"\n{run.name}: {a.stage} stage; v_C walk {a.v_walk} m/s/sqrt(s), sigma {sigma} m/s, "
              f"windows {a.window:g} s")
        hdr = None
        zs = []
        for ag in range(n):
            sg = _signatures(run, ag, dt, J_EXCITE if a.stage == "J" else M_EXCITE)
            y = sg.pop("delay")
            ac = sg.pop("a_C")
            cands = {k: sg.pop(k) for k in ("viscous", "rotational")}
            cos = {k: float(abs(np.vdot(x, y)) / (np.linalg.norm(x) * np.linalg.norm(y))) for k, x in sg.items()}
            hp = lambda x: _walk_highpass(x.real, a.v_walk**2, sigma**2, dt) + 1j * _walk_highpass(  # noqa: E731
                x.imag, a.v_walk**2, sigma**2, dt)
            yh = hp(y)
            X = np.column_stack([hp(x) for x in sg.values()])
            Xr = np.vstack((X.real, X.imag))
            yr = np.concatenate((yh.real, yh.imag))
            beta, *_ = np.linalg.lstsq(Xr, yr, rcond=None)
            res = yr - Xr @ beta
            # the other candidates' signatures as the filter leaves them, against the delay's
            ccos = {}
            for k, x in cands.items():
                xh = hp(x)
                xr = np.concatenate((xh.real, xh.imag))
                bx, *_ = np.linalg.lstsq(Xr, xr, rcond=None)
                xl = xr - Xr @ bx
                ccos[k] = float(abs(xl @ res) / (np.linalg.norm(xl) * np.linalg.norm(res)))
            left_walk = float(np.linalg.norm(yh) / np.linalg.norm(y))
            left = float(np.linalg.norm(res) / np.linalg.norm(y))
            # the one-window score of a candidate column at tau = 1 s: |left signature| / sigma over the window
            nw = len(y) // w
            rr = res.reshape(2, -1)[:, : nw * w].reshape(2, nw, w)
            z1 = np.sqrt(np.sum(rr**2, axis=(0, 2))) / sigma
            zs.append(z1)
            if hdr is None:
                hdr = list(cos)
                print("| agent | cos " + " | cos ".join(hdr) + " | left after the v_C walk | left after all "
                      "| RMS a_C (m/s^2) | RMS a_i (m/s^2) | median window score per 0.01 s of delay "
                      "| cos left: viscous | cos left: rotational |")
                print("|" + "---|" * (len(hdr) + 8))
            print(f"| {ag} | " + " | ".join(f"{cos[k]:.2f}" for k in hdr) + f" | {left_walk:.2f} | {left:.2f} "
                  f"| {np.sqrt(np.mean(np.abs(ac) ** 2)):.3f} | {np.sqrt(np.mean(np.abs(y) ** 2)):.3f} "
                  f"| {0.01 * np.median(z1):.2f} | {ccos['viscous']:.2f} | {ccos['rotational']:.2f} |")
        # (agent, window): the pooled statistic sum s_i / sqrt(sum v_i) has the mean tau sqrt(sum_i |g_i|^2) / sigma
        pooled = np.sqrt(np.sum(np.array(zs) ** 2, axis=0))
        for tau in a.taus:
            print(f"tau {tau:g} s: pooled window score (team of {n}) median {tau * np.median(pooled):.2f}, "
                  f"min {tau * pooled.min():.2f}, max {tau * pooled.max():.2f} over {len(pooled)} windows")


def _floats(text: str) -> list[float]:
    """A comma list of positive numbers (argparse type: a bad one is one line and exit status 2)."""
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma list of numbers, got {text!r}") from None
    if not all(v > 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected positive numbers, got {text!r}")
    return vals


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("runs", help="the team on a clean plant with a sensor delay, and the nominal twins")
    p.add_argument("--delays", default="0.02,0.05,0.1", type=_floats,
                   help="sensor delays (s), comma list (default 0.02,0.05,0.1)")
    p.add_argument("--seeds", default="1-2", help="seeds, a range A-B or a comma list (default 1-2)")
    p.add_argument("--keep", help="keep each run directory under this directory")
    p.set_defaults(fn=runs)
    p = sub.add_parser("cost", help="time one EKF predict + update: the filter's dimension and the exact delay model's")
    p.add_argument("--delays", default="0.02,0.05,0.1", type=_floats,
                   help="sensor delays (s), comma list (default 0.02,0.05,0.1)")
    p.add_argument("--reps", type=int, default=20000, help="steps per timing (default 20000)")
    p.set_defaults(fn=cost)
    p = sub.add_parser("separability", help="the delay signature against the filter's columns over a run's m stage")
    p.add_argument("runs", nargs="+", help="run directories (runs --keep DIR keeps them)")
    p.add_argument("--stage", choices=("m", "J"), default="m", help="the stage to take (default m)")
    p.add_argument("--v-walk", type=float, default=0.01, help="the filter's v_C walk (kf_v_walk, default 0.01)")
    p.add_argument("--sigma", type=float, default=0.3, help="velocity noise std (noise.sigma_v, default 0.3)")
    p.add_argument("--window", type=float, default=5.0, help="the tests' window (monitor_window_s, default 5)")
    p.add_argument("--taus", default="0.02,0.05,0.1", type=_floats,
                   help="delays (s) to state the pooled score for (default 0.02,0.05,0.1)")
    p.set_defaults(fn=separability)
    a = ap.parse_args()
    for run in getattr(a, "runs", None) or []:
        if a.fn is separability and not (Path(run) / "truth.csv").is_file():
            ap.error(f"{run}: not a run directory with a truth.csv (runs --keep DIR keeps them)")
    a.fn(a)


if __name__ == "__main__":
    main()
