"""Plain message types of the paper-003 runtime (coload hinf run); the codec is in :mod:`net.schema`.

Vectors are tuples of floats (a few entries each). Key expressions: :func:`net.keys.hinf`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class HinfMeas:
    """Simulator -> estimator ``agent``: its relative measurements z^(k) at ``tick``, neighbours in spec order."""

    tick: int
    agent: int
    z: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class HinfState:
    """Estimator -> its out-neighbours, sent during ``tick``: values for time ``tick + 1``.

    ``xhat`` is the sender's estimate of its own state, ``u`` the input it applies over the next tick
    (so that neighbours can predict it, Remark 2), ``zeta`` its internal-model state (10).
    """

    tick: int
    sender: int
    xhat: tuple[float, ...]
    u: tuple[float, ...]
    zeta: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class HinfInput:
    """Estimator -> simulator at ``tick``: u_k to apply, and the whole local estimate x^(k) and zeta_k
    (recorded, never used by the plant)."""

    tick: int
    agent: int
    u: tuple[float, ...]
    xhat: tuple[float, ...]
    zeta: tuple[float, ...]
