"""Is a campaign's accuracy the same as another grid's, within the seed spread? Cell by cell.

    python bench/grid_compare.py CAMPAIGN_CSV TABLES_MD [--section HEADING] [--min-runs 10]

CAMPAIGN_CSV is a grid's ``campaign.csv``; TABLES_MD holds the other grid's sigma x n tables as
``coload campaign --out DIR --table`` prints them (a markdown file; ``--section`` starts the search at a
heading, e.g. docs/campaign.md's "Before the compiled core"). For each table found (the median and 90th
percentile of J and m, the median finish time) and each cell, the other grid's value is compared with the
CSV's distribution-free 95 % interval of the same statistic (binomial order statistics over the cell's
runs), widened by half a unit of the table's last printed digit. Prints how many cells lie inside and
names the others. The two grids' runs need not be the same code or seeds: this asks whether their
statistics differ by more than the runs' spread.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

import numpy as np
from scipy.stats import binom

VIEWS = (  # (table title as --table prints it, column, quantile, scale, digits)
    ("RE of J (%), median:", "J_rel", 0.5, 100.0, 2),
    ("RE of J (%), 90th percentile:", "J_rel", 0.9, 100.0, 2),
    ("RE of m (%), median:", "m_rel", 0.5, 100.0, 2),
    ("RE of m (%), 90th percentile:", "m_rel", 0.9, 100.0, 2),
    ("(s of simulated time), median:", "finished_s", 0.5, 1.0, 0),
)


def read_table(text: str, title: str) -> dict[tuple[int, float], float]:
    """The first sigma x n table after ``title``: {(n, sigma): value}; a cell "0.21 (2 n/a)" reads 0.21."""
    at = text.find(title)
    if at < 0:
        return {}
    lines = [line for line in text[at:].splitlines()[1:40] if line.startswith("|")]
    ns = [int(x) for x in lines[0].strip().strip("|").split("|")[1:]]
    out: dict[tuple[int, float], float] = {}
    for line in lines[2:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        try:
            sigma = float(cells[0])
        except ValueError:
            break
        for n, cell in zip(ns, cells[1:], strict=True):
            m = re.match(r"[0-9.]+", cell)
            if m:
                out[(n, sigma)] = float(m.group(0))
    return out


def interval(values: np.ndarray, q: float, conf: float = 0.95) -> tuple[float, float]:
    """Distribution-free ``conf`` interval of the q-quantile: order statistics at binomial ranks."""
    v = np.sort(values)
    k = len(v)
    lo = int(binom.ppf((1 - conf) / 2, k, q))
    hi = int(binom.ppf(1 - (1 - conf) / 2, k, q))
    return float(v[max(lo - 1, 0)]), float(v[min(hi, k - 1)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("campaign_csv", type=Path)
    ap.add_argument("tables_md", type=Path)
    ap.add_argument("--section", help="start at the first line containing this text")
    ap.add_argument("--min-runs", type=int, default=10, help="skip cells with fewer runs (default 10)")
    a = ap.parse_args(argv)
    text = a.tables_md.read_text(encoding="utf-8")
    if a.section:
        at = text.find(a.section)
        if at < 0:
            print(f"{a.tables_md}: no line contains {a.section!r}", file=sys.stderr)
            return 2
        text = text[at:]
    with a.campaign_csv.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    inside = total = 0
    for title, col, q, scale, digits in VIEWS:
        other = read_table(text, title)
        if not other:
            continue
        half = 0.5 * 10.0**-digits
        ins, outside = 0, []
        for (n, sigma), value in sorted(other.items()):
            v = np.array([float(r[col]) * scale for r in rows
                          if int(r["n"]) == n and float(r["sigma"]) == sigma and r.get(col)])
            if len(v) < a.min_runs:
                continue
            lo, hi = interval(v, q)
            if lo - half <= value <= hi + half:
                ins += 1
            else:
                outside.append(f"  n = {n}, sigma = {sigma:g}: {value:.{digits}f} there, "
                               f"{np.quantile(v, q):.{digits}f} here, 95 % interval [{lo:.{digits}f}, {hi:.{digits}f}]")
        total += ins + len(outside)
        inside += ins
        print(f"{title} inside in {ins} of {ins + len(outside)} cells")
        for line in outside:
            print(line)
    print(f"all: {inside} of {total} cell statistics inside")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
