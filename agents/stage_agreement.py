"""Stage agreement: the tick at which the whole team leaves a stage, with no clock and no coordinator.

Each agent floods a bitmask of the agents known to be ready and the latest ready tick; once the mask
is full the switch tick is that latest ready tick plus a horizon, the same number at every agent (the
mask and the max are exact once complete). A lost message only delays the flood (states are re-sent
every tick). Wire form: ``B0, B1, ...`` (50 agents per float, exact in a double), ``Bt``, ``Bs``.
See docs/dynamics.md ("Stage agreement").
"""

from __future__ import annotations

from collections.abc import Mapping

MASK_BITS = 50  # agents per float in the flooded ready mask (exact in a double)


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
    """One agent's view of the agreement on leaving the current stage (module docstring)."""

    __slots__ = ("me", "n", "full", "horizon", "mask", "tmax", "switch", "mask_keys")

    def __init__(self, me: int, n: int, horizon_ticks: int) -> None:
        self.me = me
        self.n = n
        self.full = (1 << n) - 1
        self.mask_keys = mask_keys(n)
        self.horizon = horizon_ticks
        self.reset()

    def reset(self) -> None:
        self.mask = 0
        self.tmax = -1
        self.switch = -1

    def set_ready(self, tick: int) -> None:
        if not (self.mask >> self.me) & 1:
            self.mask |= 1 << self.me
            self.tmax = max(self.tmax, tick)
            self._check()

    def merge(self, mask: int, tmax: int, switch: int) -> None:
        if switch >= 0 and self.switch < 0:
            self.switch = switch
        if mask & ~self.mask:
            self.mask |= mask & self.full
            self.tmax = max(self.tmax, tmax)
            self._check()

    def _check(self) -> None:
        if self.switch < 0 and self.mask == self.full:
            self.switch = self.tmax + self.horizon

    @property
    def complete(self) -> bool:
        """Every agent is known to be ready."""
        return self.mask == self.full

    def encode(self) -> dict[str, float]:
        return encode(self.mask, self.tmax, self.switch, self.mask_keys)

    def decode(self, sh: Mapping[str, float]) -> tuple[int, int, int]:
        return decode(sh, self.mask_keys)
