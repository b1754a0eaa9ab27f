"""Logged forces that saturate: many rows of one agent and axis at exactly its extreme value (docs/diagnose.md,
"Saturated forces").

A continuous force meets any one value at one instant, held at most over one run of equal samples (a
controller slower than the logger repeats each value a few rows in a row). A force that saturates meets its
limit at every excursion beyond it: the extreme value recurs in many separate runs, which no other value
does. A force of a few levels (a switching law) or a quantised log repeats its values across runs: a limit
is looked for only where most runs between the extremes hold a value of their own, and the extreme must
recur in more runs than any value between. A force of exactly 0 is an idle actuator, not a limit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ident.recording import Recording

AXES = ("fx", "fy", "tau")
MIN_RUNS = 3  # a value met in one or two runs is a coincidence of a held or quantised log, not a limit


def _runs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The value of each maximal run of equal consecutive samples and each run's length."""
    start = np.r_[True, x[1:] != x[:-1]]
    idx = np.flatnonzero(start)
    return x[idx], np.diff(np.r_[idx, x.size])


def saturated(rec: Recording) -> list[dict]:
    """Per agent and wrench axis whose largest or smallest logged value recurs in more separate runs than any
    other value (and in at least ``MIN_RUNS``): the agent, axis, value, its share of the agent's rows and the
    number of runs, largest share first."""
    out = []
    for i in range(rec.n):
        for c, axis in enumerate(AXES):
            x = rec.wrench[:, i, c]
            x = x[np.isfinite(x)]
            if x.size < 10:
                continue
            vals, _ = _runs(x)
            uniq, runs = np.unique(vals, return_counts=True)
            ends = (uniq == x.max()) | (uniq == x.min())  # a force clipped both ways has two limits
            others = runs[~ends]
            if others.sum() == 0 or uniq.size - ends.sum() < 0.5 * others.sum():
                continue  # a force of a few levels (a switching law, a quantised log): no continuum to clip
            for ext in sorted({float(x.max()), float(x.min())}):
                if ext == 0.0:
                    continue
                k = int(np.flatnonzero(uniq == ext)[0])
                most = int(others.max()) if others.size else 0
                if runs[k] >= MIN_RUNS and runs[k] > most:
                    out.append({"agent": i, "axis": axis, "value": ext, "share": float((x == ext).mean()),
                                "runs": int(runs[k]), "most_runs_of_another_value": most})  # fmt: skip
    return sorted(out, key=lambda d: -d["share"])


def at_limit(rec: Recording, found: list[dict]) -> np.ndarray:
    """(T,) True at each stamp where some agent's logged force sits at one of its found limits."""
    hit = np.zeros(rec.T, bool)
    for d in found:
        hit |= rec.wrench[:, d["agent"], AXES.index(d["axis"])] == d["value"]
    return hit


# the share of stamps a cut must leave: a limit hit by most stamps leaves fragments of a few samples between
# its hits, each a window of its own whose free start takes what little motion it holds (the bench's
# clipped_forces, every agent clipped: 89 % of the stamps hit, fragments of 6 stamps; cut, J read -39 %)
MIN_KEPT_SHARE = 0.5


def without_limits(rec: Recording, hit: np.ndarray) -> tuple[Recording, int]:
    """``rec`` without the stamps ``hit`` where a found limit is hit (:func:`at_limit`), and how many were left
    out. A sensor at its limit logs less than the load felt: the team's force is unknown there, as where an
    agent's wrench is missing (ident/recording.py leaves those stamps out too). Left as it is when less than
    ``MIN_KEPT_SHARE`` of the stamps would remain."""
    if not hit.any() or (~hit).mean() < MIN_KEPT_SHARE:
        return rec, 0
    keep = ~hit
    cut = {k: getattr(rec, k)[keep] for k in ("t", "wrench", "vel", "pos", "wrench_logged")
           if getattr(rec, k) is not None}
    return replace(rec, **cut), int(hit.sum())


def saturation_warning(found: list[dict], left_out: int = 0, hit_share: float = 0.0) -> str:
    """One warning naming each saturated agent and axis with its value and share of rows, and how many stamps
    the fit leaves out for it (``left_out``) or, with none left out, the share of stamps that hit a limit."""
    by: dict[tuple[int, str], list[dict]] = {}
    for d in found:
        by.setdefault((d["agent"], d["axis"]), []).append(d)
    each = "; ".join(f"agent {i} {axis} at {' and '.join(format(d['value'], '.6g') for d in ds)} "
                     f"({100 * sum(d['share'] for d in ds):.1f} % of its rows)" for (i, axis), ds in by.items())
    return (f"saturated forces: {each}. A logged force that recurs at one extreme value is at a limit: a force "
            "sensor's range (the applied force went beyond it: the log is wrong there) or an actuator's (the log "
            "is what was applied where it records the limited force, or wrong where it records the command). "
            + (f"Read as a sensor's limit: the team's force is unknown at a stamp where one is hit, and the fit "
               f"leaves those {left_out} stamps out (as for a missing wrench; were it an actuator's limit logged "
               "as applied, this costs only their information)" if left_out else
               f"The fit takes the log as the applied force (the rows are kept: a limit is hit at "
               f"{100 * hit_share:.0f} % of the stamps, and the fragments between would be too short to fit); m, "
               "J and the effects hold only as far as it is"))


__all__ = ["at_limit", "saturated", "saturation_warning", "without_limits"]
