"""Optional dependencies: the extras of ``pip install 'coload[...]'`` and the one line that names a missing one.

``viz`` (``coload export --mcap``, ``coload run --view``, ``coload view``): mcap, foxglove-sdk.
``hinf`` (``coload hinf design|run``): cvxpy. docs/viewers.md, README "Install".
"""

from __future__ import annotations

import importlib.util


class ExtraMissing(RuntimeError):
    """An optional dependency is not installed; the message is the one line that says what to install."""


def require(extra: str, *modules: str) -> None:
    """Raise :class:`ExtraMissing` naming ``coload[extra]`` unless every module can be imported."""
    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise ExtraMissing(f"needs the Python package(s) {', '.join(missing)}: pip install 'coload[{extra}]'")
