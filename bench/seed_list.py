"""The benches' --seeds argument: a comma list of seeds and ranges A-B."""

from __future__ import annotations


def parse_seeds(text: str) -> list[int]:
    """``"1-5"`` -> [1, 2, 3, 4, 5]; ``"3,7"`` -> [3, 7]; ``"1-2,7"`` -> [1, 2, 7]."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += range(int(lo), int(hi or lo) + 1)
    return out
