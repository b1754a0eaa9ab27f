"""Interleaved A/B of the agent step: another source tree against this one, same inputs, same outputs?

    mkdir -p OTHER && git archive HEAD~1 agents coload config net simulator hinf | tar -x -C OTHER
    OPENBLAS_NUM_THREADS=1 python bench/agent_step_ab.py OTHER [--n 20] [--agent 10] [--duration S] [--reps 2]

Runs the campaign scenario (paper-fig4 resized to ``n``, sigma 0.3, seed 12345) once on the in-process
engine of the OTHER tree, recording every input (tick, measurement, inbox) and output (state, wrench,
estimate) of one agent (the in-process engine steps a ``TeamCore``; its messages are read back as the wire's
``StateMsg``s). Then a fresh ``AgentCore`` (the daemon's core, a team of one) of each tree steps those inputs, tick by
tick alternately (the order swapped every tick), each side's time summed separately: both see the same
machine load, which on a shared machine is the only fair comparison (run-to-run noise there is +-10 %,
the interleaved ratio moves by ~1 %). Prints both costs in us per tick, the ratio, and the number of
ticks whose outputs differ from the recorded ones (compared by repr: bit for bit, NaN included) -- it
must be 0 for a pure speed change. The better of ``--reps`` replays counts. With the compiled core the ratio
is biased: a tree replayed against an archive of itself reads 0.57 (n = 10, agent 5, 3000 ticks; with the
Python core 0.93), so the speed of the team core is measured by bench/core_speed.py, and this bench is the
daemon core's bit-for-bit check.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path
from typing import Any

_PKGS = ("agents", "coload", "net", "config", "simulator", "hinf")


def _load_tree(root: str) -> dict[str, Any]:
    """Import the project's packages from ``root`` and unregister them, so another tree can load too."""
    sys.path.insert(0, root)
    try:
        import agents.agent
        import agents.factory
        import coload.analysis.campaign
        import coload.runs.engine
        import config.loader
        import net.messages

        mods = {
            "agent": agents.agent, "campaign": coload.analysis.campaign, "engine": coload.runs.engine,
            "world": agents.factory, "loader": config.loader, "messages": net.messages,
        }
        try:  # a tree with the team core (agents/team.py, net/rows.py)
            import agents.team
            import net.rows

            mods.update(team=agents.team, rows=net.rows)
        except ImportError:
            pass
    finally:
        for k in [k for k in sys.modules if k.split(".")[0] in _PKGS]:
            del sys.modules[k]
        sys.path.remove(root)
    return mods


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("other", help="the other source tree (holds agents/, coload/, config/, net/, simulator/, hinf/)")
    ap.add_argument("--n", type=int, default=20, help="team size")
    ap.add_argument("--agent", type=int, default=None, help="the agent replayed (default n // 2)")
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    ap.add_argument("--reps", type=int, default=2, help="replays; the fastest counts")
    a = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    other = _load_tree(str(Path(a.other).resolve()))
    mine = _load_tree(here)
    who = a.n // 2 if a.agent is None else a.agent

    def scenario(mods: dict[str, Any]) -> Any:
        base = mods["loader"].load_scenario(mods["loader"].resolve_scenario_path("paper-fig4"))
        scn = mods["campaign"].campaign_scenario(base, a.n, 0.3, 12345)
        return scn if a.duration is None else scn.model_copy(update={"duration": a.duration})

    # record one agent's inputs and outputs with the other tree's engine: trees with a team core step the whole
    # team in one call (``TeamCore.step``: the agent's inbox is read from the team's OUT ring before the step,
    # its outputs after); older trees call ``AgentCore.advance`` (the estimate built only on recorded ticks) or
    # ``step`` per agent
    rows: list[tuple] = []
    team_mod = other.get("team")
    if team_mod is not None and hasattr(team_mod.TeamCore, "message"):
        cls, entry = team_mod.TeamCore, "step"
        plain = cls.step
        state_from_row, wrench_cls = other["rows"].state_from_row, other["messages"].Wrench

        def recording(self, tick, meas, inbox):  # noqa: ANN001, ANN202
            b = self.ids.index(who)
            ref = inbox.ref[inbox.ptr[b]:inbox.ptr[b + 1]].tolist()
            msgs = [state_from_row(self.out[slot, s], self._lay, self.nbr_ids[s]) for slot, s, _ in ref]
            vx, vy = (float(x) for x in meas[b])
            w = plain(self, tick, meas, inbox)
            fx, fy, tau = w[b].tolist()
            rows.append((tick, vx, vy, msgs, repr(self.message(tick, b)), repr(wrench_cls(tick, who, fx, fy, tau)),
                         repr(self.estimates()[b])))
            return w
    else:
        cls = other["agent"].AgentCore
        entry = "advance" if hasattr(cls, "advance") else "step"
        plain = getattr(cls, entry)

        def recording(self, tick, vx, vy, inbox):  # noqa: ANN001, ANN202
            out = plain(self, tick, vx, vy, inbox)
            if self.id == who:
                state, wrench, est = (*out, self.estimate()) if entry == "advance" else out
                rows.append((tick, vx, vy, list(inbox), repr(state), repr(wrench), repr(est)))
            return out

    setattr(cls, entry, recording)
    try:
        other["engine"].run_inproc(scenario(other), None)  # no run directory: nothing imported late
    finally:
        setattr(cls, entry, plain)
    if not rows:
        sys.exit(f"agent {who} was never stepped: is it one of the team's (n = {a.n})?")

    clock = time.perf_counter
    best_o = best_m = float("inf")
    bad = 0
    for _ in range(a.reps):
        ao = other["world"].build_agent(scenario(other).agent_view(who)).step
        am = mine["world"].build_agent(scenario(mine).agent_view(who)).step
        to = tm = 0.0
        bad = 0
        gc.disable()
        try:
            for t, vx, vy, inbox, st, wr, est in rows:
                if t & 1:
                    c0 = clock(); ao(t, vx, vy, inbox); c1 = clock(); rm = am(t, vx, vy, inbox); c2 = clock()  # noqa: E702
                    to += c1 - c0
                    tm += c2 - c1
                else:
                    c0 = clock(); rm = am(t, vx, vy, inbox); c1 = clock(); ao(t, vx, vy, inbox); c2 = clock()  # noqa: E702
                    tm += c1 - c0
                    to += c2 - c1
                if repr(rm.state) != st or repr(rm.wrench) != wr or repr(rm.estimate) != est:
                    bad += 1
        finally:
            gc.enable()
        best_o = min(best_o, to)
        best_m = min(best_m, tm)
    k = len(rows)
    print(f"n={a.n} agent {who}, {k} ticks: other {1e6 * best_o / k:.1f} us/tick, this tree {1e6 * best_m / k:.1f} "
          f"us/tick, speed-up {best_o / best_m:.3f}; ticks with different outputs: {bad}")


if __name__ == "__main__":
    main()
