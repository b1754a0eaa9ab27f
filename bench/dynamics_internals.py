"""Inside the dynamical phase of one run: every agent's filter and torque model against the plant's truth.

    python bench/dynamics_internals.py [--scenario paper-fig4] [--seed 3] [--duration 90] [--set KEY=VALUE]

Runs the scenario in process (fault-free lockstep links only) and prints, per stage and agent, the mean
error of the filter's q_i angle and length, omega and v_C (the filter's state after tick k is its prediction
for tick k + 1 and is compared with the plant after the step), the error of the torque the agent feeds its
filter (against sum_i q_i x f_i + tau_i with the true q_i and the wrenches applied), and each agent's own m and
J when its excitation stage ends. This is how the J-stage torque transients and the bad filter starts were
found (docs/dynamics.md, "Diagnosis").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents import dynamic_phase as D  # noqa: E402
from agents.factory import build_team  # noqa: E402
from agents.rigid_filter import RigidEKF  # noqa: E402
from coload.runs.team import team_ticks  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from simulator.plant import Plant  # noqa: E402


def run(sc) -> dict[str, np.ndarray]:
    """Steps plant and agents like coload.runs.engine.run_inproc (one-tick links) and records internals."""
    n, T = sc.n, sc.ticks
    plant = Plant(sc)
    team = build_team([sc.agent_view(i) for i in range(n)])
    agents = [team.agent(i) for i in range(n)]
    seen: dict[int, float] = {}
    predict = RigidEKF.predict

    def spy(self, force, torque, dt):  # the torque each filter is given
        seen[id(self)] = torque
        return predict(self, force, torque, dt)

    RigidEKF.predict = spy
    rec = {"s": np.full((T, n, 7), np.nan), "stage": np.zeros((T, n), int), "tq": np.full((T, n), np.nan),
           "true_tq": np.zeros(T), "q": np.zeros((T + 1, n, 2)), "om": np.zeros(T + 1), "vc": np.zeros((T + 1, 2))}

    def truth(k):
        t = plant.truth()
        rec["q"][k] = np.asarray(t.zi) + np.asarray(t.zc)
        rec["om"][k], rec["vc"][k] = t.omega, t.vc

    try:
        for k, wr in team_ticks(sc, plant, team):
            truth(k)
            for i, a in enumerate(agents):
                dyn = a._dyn
                rec["stage"][k, i] = dyn.stage
                if dyn.kf.ready:
                    rec["s"][k, i] = dyn.kf.s[:7]  # the rigid-body states (not the effects, nor b)
                rec["tq"][k, i] = seen.pop(id(dyn.kf), np.nan)
            w = np.asarray(wr)
            q = rec["q"][k]
            rec["true_tq"][k] = float(np.sum(q[:, 0] * w[:, 1] - q[:, 1] * w[:, 0] + w[:, 2]))
        truth(T)
    finally:
        RigidEKF.predict = predict
    rec["mass"], rec["inertia"] = np.array(plant.mass), np.array(plant.inertia)
    return rec


def report(rec: dict[str, np.ndarray]) -> None:
    s, stage = rec["s"], rec["stage"][:, 0]
    n = s.shape[1]
    qe = s[:, :, 2] + 1j * s[:, :, 3]
    qt = rec["q"][1:, :, 0] + 1j * rec["q"][1:, :, 1]
    vt = rec["vc"][1:, 0] + 1j * rec["vc"][1:, 1]
    rows = {
        "q angle (mrad)": 1e3 * np.angle(qe / qt),
        "|q| rel (1e-3)": 1e3 * (np.abs(qe) / np.abs(qt) - 1),
        "omega (mrad/s)": 1e3 * (s[:, :, 5] - rec["om"][1:, None]),
        "|v_C| (mm/s)": 1e3 * np.abs(s[:, :, 0] + 1j * s[:, :, 1] - vt[:, None]),
        "torque (N m)": rec["tq"] - rec["true_tq"][:, None],
    }
    print("mean error per agent, last 3/4 of each stage (the torque: mean / RMS over the whole stage)")
    for st in (D.M_EXCITE, D.M_AVERAGE, D.J_EXCITE, D.J_AVERAGE, D.BACKGROUND):
        idx = np.flatnonzero(stage == st)
        if not len(idx):
            continue
        late = idx[len(idx) // 4:]
        print(f"-- {D.STAGE_NAMES[st]}: t = {idx[0] * 0.01:.2f} .. {idx[-1] * 0.01:.2f} s (ticks {idx[0]}..{idx[-1]})")
        for name, v in rows.items():
            if name.startswith("torque"):
                cells = [f"{np.nanmean(v[idx, i]):+.2f}/{np.sqrt(np.nanmean(v[idx, i] ** 2)):.2f}" for i in range(n)]
            else:
                cells = [f"{np.nanmean(v[late, i]):+7.2f}" for i in range(n)]
            print(f"  {name:15s} " + " ".join(cells))
        if st == D.J_EXCITE:
            print(f"  |true torque| RMS {np.sqrt(np.mean(rec['true_tq'][idx] ** 2)):.2f} N m")
    for st, col, key, name in ((D.M_EXCITE, 4, "mass", "m"), (D.J_EXCITE, 6, "inertia", "J")):
        idx = np.flatnonzero(stage == st)
        if len(idx):
            rel = 100 * (1 / s[idx[-1], :, col] / float(rec[key]) - 1)
            print(f"own {name} at the end of {D.STAGE_NAMES[st]} (%): " + " ".join(f"{x:+.2f}" for x in rel)
                  + f"   mean {rel.mean():+.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-fig4", help="bundled scenario name")
    ap.add_argument("--seed", type=int, default=3, help="run seed")
    ap.add_argument("--duration", type=float, default=85.0, help="simulated time (s)")
    ap.add_argument("--set", action="append", default=[], help="scenario override key=value (repeatable)")
    a = ap.parse_args()
    sc = load_scenario(ROOT / "config" / "scenarios" / f"{a.scenario}.toml",
                       [f"seed={a.seed}", f"duration={a.duration}", *a.set])
    if sc.link.model_dump() != type(sc.link)().model_dump():
        sys.exit("dynamics_internals: fault-free links only (this loop delivers every message after one tick)")
    report(run(sc))


if __name__ == "__main__":
    main()
