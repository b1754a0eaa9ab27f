"""What produced a run: coload's version and git commit, and the versions of the libraries its numbers
depend on, for summary.json's ``versions`` block (docs/run-directory.md)."""

from __future__ import annotations

import functools
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

LIBRARIES = ("numpy", "scipy", "pymunk", "eclipse-zenoh")
SOURCE = Path(__file__).resolve().parent.parent


def version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


@functools.cache
def commit() -> str | None:
    """The git commit of the source tree coload runs from (``+dirty`` with uncommitted changes to tracked
    files); None when it is not a git checkout (an installed wheel, the Docker image) or git is absent."""
    if not (SOURCE / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(SOURCE), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(SOURCE), "diff", "--quiet", "HEAD", "--"], capture_output=True,
                               timeout=10).returncode == 1
    except (OSError, subprocess.TimeoutExpired):
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


@functools.cache
def versions() -> dict[str, Any]:
    """``{"coload": ..., "commit": ..., "numpy": ..., ...}``; a library that is not installed is None."""
    return {"coload": version("coload"), "commit": commit(), **{lib: version(lib) for lib in LIBRARIES}}
