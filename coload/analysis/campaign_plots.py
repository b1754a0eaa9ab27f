"""Fig. 7- and Fig. 8-like box plots of a campaign's rows (``coload campaign``, docs/campaign.md#plots).

:func:`plot_campaign` draws what the rows have: one panel per error column of :data:`FIG7_PANELS`, and
the errors before and after the averaging consensus (:data:`FIG8_PANELS`) when the runs carry the
agents' local estimates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

PLOT_NAME = "campaign.png"
CONSENSUS_PLOT_NAME = "campaign-consensus.png"

# Panels of the Fig. 7-like plot: (column, label); drawn when some run has the column.
FIG7_PANELS = (
    ("eerd_ratio", "EERD final / initial"),
    ("zi_rel", "z_i RMS / RMS |z_i|"),
    ("omega_rms", "omega RMS (rad/s)"),
    ("vC_rms", "v_C RMS (m/s)"),
    ("zC_rms", "z_C RMS (m)"),
    ("J_rel", "RE of J"),
    ("m_rel", "RE of m"),
    ("finished_s", "finished (s)"),
)
LINEAR_COLUMNS = frozenset({"finished_s"})
"""Panels on a linear axis (times); errors spanning decades get a log axis when all are positive."""
# Fig. 8: relative errors before (local least squares) and after the averaging consensus.
FIG8_PANELS = (("J_local_rel", "J_rel", "J"), ("m_local_rel", "m_rel", "m"))


def cell_values(rows: Sequence[dict[str, Any]], col: str, n: int, sigma: float) -> list[float]:
    """The finite values of column ``col`` over the rows of cell (n, sigma)."""
    return [r[col] for r in rows if r["n"] == n and r["sigma"] == sigma and r.get(col) is not None
            and math.isfinite(r[col])]


def _box_panel(ax: Any, rows: Sequence[dict[str, Any]], col: str, label: str, ns: list[int],
               sigmas: list[float]) -> None:
    """One panel: a group of boxes per sigma, one box per n (coloured), over the runs of the cell."""
    import matplotlib.pyplot as plt

    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, max(1, len(ns))))
    width = 0.8 / len(ns)
    positive = True
    for a, n in enumerate(ns):
        data, pos = [], []
        for b, sigma in enumerate(sigmas):
            v = cell_values(rows, col, n, sigma)
            if v:
                data.append(v)
                pos.append(b + (a - (len(ns) - 1) / 2) * width)
                positive = positive and min(v) > 0
        if data:
            bp = ax.boxplot(data, positions=pos, widths=0.9 * width, patch_artist=True, manage_ticks=False,
                            flierprops={"markersize": 2})
            for patch in bp["boxes"]:
                patch.set_facecolor(colours[a])
            for med in bp["medians"]:
                med.set_color("black")
    if positive and col not in LINEAR_COLUMNS:
        ax.set_yscale("log")
    ax.set_xticks(range(len(sigmas)), [f"{s:g}" for s in sigmas])
    ax.set_ylabel(label)
    ax.grid(True, axis="y", alpha=0.3)


def _legend(ax: Any, ns: list[int]) -> None:
    """Colour key of the team sizes, above the top panel."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, max(1, len(ns))))
    ax.legend(handles=[Patch(facecolor=colours[a], label=f"n = {n}") for a, n in enumerate(ns)],
              loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(ns), frameon=False, fontsize=8)


def _save(fig: Any, legend_axes: Sequence[Any], ns: list[int], path: Path) -> Path:
    """The colour key above the top panels, then the file."""
    import matplotlib.pyplot as plt

    for ax in legend_axes:
        _legend(ax, ns)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_campaign(rows: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """campaign.png (Fig. 7-like) and, when local estimates exist, campaign-consensus.png (Fig. 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = sorted({int(r["n"]) for r in rows})
    sigmas = sorted({float(r["sigma"]) for r in rows})
    has = {c for r in rows for c, v in r.items() if v is not None}
    written: list[Path] = []
    panels = [(c, lab) for c, lab in FIG7_PANELS if c in has]
    if panels:
        fig, axes = plt.subplots(len(panels), 1, figsize=(min(20.0, max(7.0, 0.25 * len(sigmas) * len(ns) + 4)),
                                                          2.2 * len(panels) + 0.8), squeeze=False, sharex=True)
        for ax, (col, lab) in zip(axes[:, 0], panels, strict=True):
            _box_panel(ax, rows, col, lab, ns, sigmas)
        axes[-1, 0].set_xlabel("velocity noise sigma (m/s)")
        fig.suptitle(f"campaign: {len(rows)} runs, line graph, m = 5n (a box = the runs of one (n, sigma))",
                     fontsize=10)
        written.append(_save(fig, [axes[0, 0]], ns, out / PLOT_NAME))
    pairs = [(lo, hi, q) for lo, hi, q in FIG8_PANELS if lo in has and hi in has]
    if pairs:
        wide = min(12.0, max(5.0, 0.2 * len(sigmas) * len(ns) + 2))
        fig, axes = plt.subplots(len(pairs), 2, figsize=(2 * wide, 2.6 * len(pairs) + 0.8), squeeze=False,
                                 sharey="row")
        for row_axes, (lo, hi, q) in zip(axes, pairs, strict=True):
            _box_panel(row_axes[0], rows, lo, f"RE of {q}, before consensus", ns, sigmas)
            _box_panel(row_axes[1], rows, hi, f"RE of {q}, after consensus", ns, sigmas)
        for ax in axes[-1]:
            ax.set_xlabel("velocity noise sigma (m/s)")
        fig.suptitle("relative errors before and after the averaging consensus (Fig. 8)", fontsize=10)
        written.append(_save(fig, list(axes[0]), ns, out / CONSENSUS_PLOT_NAME))
    return written
