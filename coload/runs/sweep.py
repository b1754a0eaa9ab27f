"""Where a campaign's runs execute: this process, a local process pool, or a Dask cluster.

:func:`open_pool` turns ``--executor local`` or ``--executor dask://HOST:PORT`` into a :class:`Pool`, a
``concurrent.futures`` executor with what the progress line says about it; :func:`sweep` runs one task per
item on any pool, at most a few per worker in flight (the driver's memory does not grow with the
grid), and hands each result to the driver as it arrives. Workers share no filesystem with the
driver: a task returns its files as data (:func:`pack_dir`) and the driver writes them
(:func:`unpack_dir`). A Dask worker lost mid-task costs only its tasks: the scheduler runs them again
elsewhere. See docs/campaign.md (Running on a cluster).
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from pathlib import Path, PurePosixPath
from typing import Any, TypeVar

T = TypeVar("T")

LOCAL = "local"
DASK_SCHEME = "dask://"
CLUSTER_EXTRA = "coload[cluster]"
IN_FLIGHT_PER_SLOT = 2
"""Tasks handed to the executor per worker thread: one running, one waiting, so no worker idles
while the driver writes a result, and the driver holds a few results at a time, not the grid's."""
POLL_S = 2.0
"""How often the loop looks at the pool when no task finishes: workers that join get work, and the
progress line shows the workers there are."""


class ExecutorError(ValueError):
    """``--executor`` names a pool that cannot be used (bad form, dask missing, scheduler unreachable)."""


def parse_executor(text: str) -> str | None:
    """``"local"`` -> None (the local process pool); ``"dask://HOST:PORT"`` -> ``"tcp://HOST:PORT"``,
    the Dask scheduler's address, once dask.distributed is known to be installed. Raises
    :class:`ExecutorError` naming what was expected."""
    if text == LOCAL:
        return None
    if text.startswith(DASK_SCHEME):
        host, sep, port = text[len(DASK_SCHEME):].rpartition(":")
        if sep and host and port.isdigit() and 0 < int(port) < 65536:
            try:
                import distributed  # noqa: F401
            except ImportError:
                raise ExecutorError(f"--executor {text}: needs dask.distributed, which is not installed "
                                    f"(pip install '{CLUSTER_EXTRA}')") from None
            return f"tcp://{host}:{port}"
    raise ExecutorError(f"--executor: expected 'local' or dask://HOST:PORT (a Dask scheduler), got {text!r}")


class Pool:
    """Runs tasks. This base runs them in the calling process, one at a time (``executor`` None)."""

    executor: Executor | None = None

    def status(self) -> tuple[int, str]:
        """(tasks it runs at once now, a note for the progress line)."""
        return 1, ""

    def abort(self) -> None:
        """Drops the tasks under way (Ctrl-C, SIGTERM): their results are not awaited."""

    def close(self) -> None:
        """Releases the workers (after every task finished)."""


class LocalPool(Pool):
    """``jobs`` spawned worker processes on this machine."""

    def __init__(self, jobs: int) -> None:
        from agents.kernels import warm

        warm()  # compiled once here: the workers only load the cache
        ctx = multiprocessing.get_context("spawn")  # no fork of a possibly threaded parent
        self.jobs = jobs
        self.executor = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)

    def status(self) -> tuple[int, str]:
        return self.jobs, f"{self.jobs} processes"

    def abort(self) -> None:
        workers = list(getattr(self.executor, "_processes", {}).values())
        self.executor.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            proc.terminate()

    def close(self) -> None:
        self.executor.shutdown(wait=True)


class DaskPool(Pool):
    """The workers of a running Dask scheduler, through ``Client.get_executor()``."""

    def __init__(self, address: str, timeout_s: float = 10.0) -> None:
        from distributed import Client

        try:
            self.client = Client(address, timeout=timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ExecutorError(f"--executor: cannot reach the Dask scheduler at {address} ({exc})") from None
        from agents.kernels import warm

        # each worker compiles the kernels (or loads a cache it shares with others on its node) before
        # its first run, not inside it
        self.client.run(warm)
        # pure=False: every submission is a run of its own, never merged with an equal-looking one
        self.executor = self.client.get_executor(pure=False)

    def status(self) -> tuple[int, str]:
        threads = self.client.nthreads()
        n = len(threads)
        return sum(threads.values()), f"{n} worker{'' if n == 1 else 's'}"

    def abort(self) -> None:
        self.executor.shutdown(wait=False)  # cancels what the scheduler has not finished
        self.client.close()

    def close(self) -> None:
        self.client.close()


@contextmanager
def open_pool(executor: str, jobs: int, tasks: int) -> Iterator[Pool]:
    """The pool for ``--executor`` (see :func:`parse_executor`): a Dask cluster, or ``jobs`` local
    processes (this process alone when ``jobs`` is 1 or there is at most one task; no pool at all for
    no task). Raises :class:`ExecutorError` if the pool cannot be opened."""
    address = parse_executor(executor)
    if address is not None and tasks > 0:
        pool: Pool = DaskPool(address)
    elif address is not None or jobs <= 1 or tasks <= 1:
        pool = Pool()
    else:
        pool = LocalPool(min(jobs, tasks))
    try:
        yield pool
    except BaseException:
        pool.abort()
        raise
    pool.close()


_END: Any = object()


def sweep(
    pool: Pool,
    task: Callable[..., Any],
    items: Iterable[T],
    args: Callable[[T], tuple[Any, ...]],
    done: Callable[[T, Callable[[], Any]], None],
    note: Callable[[str], None] | None = None,
) -> None:
    """``task(*args(item))`` for every item on ``pool``, submitted in order; ``done(item, result)`` in the
    calling thread as each one finishes (``result()`` returns the task's value or raises its error).

    At most :data:`IN_FLIGHT_PER_SLOT` tasks per worker thread are submitted at once; ``note`` gets the
    pool's note (workers) whenever the loop looks at the pool."""
    if pool.executor is None:
        for item in items:
            done(item, lambda item=item: task(*args(item)))
        return
    queue = iter(items)
    pending: dict[Future, T] = {}
    more = True
    while True:
        slots, text = pool.status()
        while more and len(pending) < max(1, IN_FLIGHT_PER_SLOT * slots):
            item = next(queue, _END)
            if item is _END:
                more = False
            else:
                pending[pool.executor.submit(task, *args(item))] = item  # type: ignore[index]
        if not pending:
            return
        if note is not None:
            note(text)
        finished, _ = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
        for fut in finished:
            done(pending.pop(fut), fut.result)


# --- a directory as data ------------------------------------------------------------------------


def pack_dir(path: Path, skip: Iterable[str] = ()) -> dict[str, bytes]:
    """Every file under ``path`` as {relative POSIX path: bytes}, and every directory as
    {relative path + "/": b""} (so empty ones come back too); top-level names in ``skip`` left out."""
    skipped = set(skip)
    out: dict[str, bytes] = {}
    for root, dirs, files in os.walk(path):
        rel = PurePosixPath(Path(root).relative_to(path).as_posix())
        top = rel == PurePosixPath(".")
        dirs.sort()
        for d in dirs:
            out[f"{rel / d}/"] = b""
        for name in sorted(files):
            if not (top and name in skipped):
                out[str(rel / name)] = (Path(root) / name).read_bytes()
    return out


def unpack_dir(files: dict[str, bytes], dest: Path) -> None:
    """Writes :func:`pack_dir`'s data as directory ``dest``, replacing whatever was there: first in a
    hidden sibling, then renamed into place, so ``dest`` never holds half of it."""
    for rel in files:
        p = PurePosixPath(rel)
        if p.is_absolute() or ".." in p.parts:
            raise ValueError(f"a task returned the path {rel!r}, outside its run directory")
    dest = Path(dest)
    part = dest.with_name(f".{dest.name}.part")
    shutil.rmtree(part, ignore_errors=True)
    part.mkdir(parents=True)
    for rel, data in files.items():
        target = part.joinpath(*PurePosixPath(rel).parts)
        if rel.endswith("/"):
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
    if dest.exists():
        shutil.rmtree(dest)
    os.replace(part, dest)
