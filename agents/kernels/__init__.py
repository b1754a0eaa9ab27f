"""The agent's compiled core: numba kernels over a leading agent axis (docs/fast-core-plan.md).

Every kernel is a scalar loop over its rows (``for b in range(B)``, no operation mixes rows), so a
daemon's batch of one and the in-process engine's whole team run the same code and give the same bits.
Kernels are compiled with :data:`jit` only: no fastmath (it reorders sums), no parallel (it reorders
reductions), Python's error model (a division by zero raises). ``NUMBA_DISABLE_JIT=1`` runs the same
source interpreted, for debugging. tests/test_kernel_rules.py holds the kernel modules to these rules.
"""

from __future__ import annotations

from collections.abc import Callable

import numba

jit = numba.njit(cache=True)
"""The one decorator of the compiled core: compiled on first call, the machine code cached on disk."""

_WARMERS: list[Callable[[], None]] = []


def register_warm(fn: Callable[[], None]) -> Callable[[], None]:
    """Registers a function that calls its module's kernels once on small inputs of the production
    types (so :func:`warm` compiles, or loads from the cache, everything a run will call)."""
    _WARMERS.append(fn)
    return fn


def warm() -> None:
    """Compiles (or loads from the cache) every kernel; called once by a parent process before it
    starts agents, workers or test workers, so that they only load the cache."""
    import importlib
    import pkgutil

    for mod in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{mod.name}")
    for fn in _WARMERS:
        fn()
