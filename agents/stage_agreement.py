"""Stage agreement: the tick at which the whole team leaves a stage, with no clock and no coordinator.

Each agent floods a bitmask of the agents known to be ready and the latest ready tick; once the mask
is full the switch tick is that latest ready tick plus a horizon, the same number at every agent (the
mask and the max are exact once complete). A lost message only delays the flood (states are re-sent
every tick). Wire form: ``B0, B1, ...`` (50 agents per float, exact in a double), ``Bt``, ``Bs``.
The maths is agents/kernels/agreement.py's ``barrier_*``; :class:`StageBarrier` is a view of one row.
See docs/dynamics.md ("Stage agreement").
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from agents.kernels.agreement import (
    HORIZON,
    MASK_BITS,
    ME,
    SBITS,
    SWITCH,
    TMAX,
    N,
    barrier_bank,
    barrier_complete,
    barrier_merge,
    barrier_reset,
    barrier_set_ready,
)

__all__ = ["MASK_BITS", "StageBarrier", "decode", "encode", "mask_keys"]


def mask_keys(n: int) -> tuple[str, ...]:
    """The wire names of the mask's chunks for a team of ``n``."""
    return tuple(f"B{c}" for c in range((n + MASK_BITS - 1) // MASK_BITS))


def encode(mask: int, tmax: int, switch: int, keys: tuple[str, ...]) -> dict[str, float]:
    """The barrier state (mask, latest ready tick, switch tick) as StateMsg.shared entries."""
    out = {key: float((mask >> (c * MASK_BITS)) & ((1 << MASK_BITS) - 1)) for c, key in enumerate(keys)}
    out["Bt"] = float(tmax)
    out["Bs"] = float(switch)
    return out


def decode(sh: Mapping[str, float], keys: tuple[str, ...]) -> tuple[int, int, int]:
    """(mask, tmax, switch) from a neighbour's shared states; KeyError or ValueError if malformed."""
    m = 0
    for c, key in enumerate(keys):
        v = sh[key]
        if not (0.0 <= v < 2.0**MASK_BITS) or v != int(v):
            raise ValueError("bad mask chunk")
        m |= int(v) << (c * MASK_BITS)
    return m, int(sh["Bt"]), int(sh["Bs"])


class StageBarrier:
    """One agent's view of the agreement on leaving the current stage (module docstring): row ``b`` of a
    barrier bank (:mod:`agents.kernels.agreement`, whose kernels it calls), its own bank of one unless given.
    ``mask``, ``tmax`` and ``switch`` read and write the row."""

    __slots__ = ("me", "n", "horizon", "mask_keys", "_S", "_b")

    def __init__(self, me: int, n: int, horizon_ticks: int, bank: np.ndarray | None = None, b: int = 0) -> None:
        self.me = me
        self.n = n
        self.mask_keys = mask_keys(n)
        self.horizon = horizon_ticks
        self._S = S = barrier_bank(1, len(self.mask_keys)) if bank is None else bank
        self._b = b
        S[b, ME], S[b, N], S[b, HORIZON] = me, n, horizon_ticks
        if bank is None:
            self.reset()

    @property
    def mask(self) -> int:
        """The agents known to be ready (bit i: agent i)."""
        return sum(int(c) << (k * MASK_BITS) for k, c in enumerate(self._S[self._b, SBITS:].tolist()))

    @mask.setter
    def mask(self, mask: int) -> None:
        self._S[self._b, SBITS:] = _chunks(mask, len(self.mask_keys))

    @property
    def tmax(self) -> int:
        """The latest ready tick known (-1: none)."""
        return int(self._S[self._b, TMAX])

    @tmax.setter
    def tmax(self, tick: int) -> None:
        self._S[self._b, TMAX] = tick

    @property
    def switch(self) -> int:
        """The agreed switch tick (-1: not yet)."""
        return int(self._S[self._b, SWITCH])

    @switch.setter
    def switch(self, tick: int) -> None:
        self._S[self._b, SWITCH] = tick

    def reset(self) -> None:
        barrier_reset(self._b, self._S)

    def set_ready(self, tick: int) -> None:
        barrier_set_ready(self._b, self._S, tick)

    def merge(self, mask: int, tmax: int, switch: int) -> None:
        barrier_merge(self._b, self._S, _chunks(mask, len(self.mask_keys)), tmax, switch)

    @property
    def complete(self) -> bool:
        """Every agent is known to be ready."""
        return bool(barrier_complete(self._b, self._S))

    def encode(self) -> dict[str, float]:
        return encode(self.mask, self.tmax, self.switch, self.mask_keys)

    def decode(self, sh: Mapping[str, float]) -> tuple[int, int, int]:
        return decode(sh, self.mask_keys)


def _chunks(mask: int, nbk: int) -> np.ndarray:
    """A mask as its ``nbk`` chunks of MASK_BITS bits (int64)."""
    return np.array([(mask >> (c * MASK_BITS)) & ((1 << MASK_BITS) - 1) for c in range(nbk)], np.int64)
