"""``coload campaign --executor dask://``: a real Dask LocalCluster (worker processes on loopback) gives
the local pool's table bit for bit, and a worker killed mid-grid loses no run; the sweep loop's bound on
the tasks in flight; a run directory as data (coload.runs.sweep)."""

from __future__ import annotations

import csv
import json
import os
import signal
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coload.analysis import campaign as cp
from coload.runs import sweep
from coload.cli import main as cli_main
from config.loader import load_scenario

TIMINGS = ("wall_s", "agent_step_us")  # wall-clock columns: the only ones that may differ


def _base():
    """paper-fig4's kinematic phase alone, 30 s: ~0.5 s of work per run at n = 4."""
    return load_scenario(cp.DEFAULT_BASE, ["duration=30", 'dynamics.algorithm="none"'])


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMINGS} for r in csv.DictReader(f)]


@pytest.mark.slow
def test_a_dask_cluster_gives_the_local_table_and_survives_a_lost_worker(tmp_path):
    distributed = pytest.importorskip("distributed")
    sigmas = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]
    grid = {"ns": [4], "sigmas": sigmas, "runs_per_cell": 1, "seed0": 3}
    local = cp.run_campaign(cp.plan(_base(), tmp_path / "local", **grid), tmp_path / "local", jobs=2, plots=False)
    assert (local.ran, local.failed) == (len(sigmas), [])

    out = tmp_path / "dask"
    runs = cp.plan(_base(), out, **grid)
    killed: list[tuple[int, list[str]]] = []  # (pid, the tasks it was running)
    notes: list[str] = []
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:

        def progress(done: int, total: int, note: str = "") -> None:
            notes.append(note)
            if killed or done < 1:
                return
            # the first worker seen running a run after one finished: killed in the middle of it
            busy = {addr: keys for addr, keys in client.processing().items() if keys}
            if busy:
                addr, keys = next(iter(busy.items()))
                pid = client.run(os.getpid, workers=[addr])[addr]
                os.kill(pid, signal.SIGKILL)
                killed.append((pid, list(keys)))

        executor = cluster.scheduler_address.replace("tcp://", "dask://")
        res = cp.run_campaign(runs, out, executor=executor, progress=progress, plots=False)
    assert killed, "no worker was busy to be killed: the grid ended too soon"
    assert (res.ran, res.failed) == (len(sigmas), [])
    assert "2 workers" in notes
    # the same rows, bit for bit, as the local pool's, and each run logged once: the lost runs redone
    assert _rows(out / cp.CSV_NAME) == _rows(tmp_path / "local" / cp.CSV_NAME)
    logged = [json.loads(line)["run"] for line in (out / cp.LOG_NAME).read_text().splitlines()]
    assert sorted(logged) == sorted(r.run_dir.name for r in runs)
    # the driver wrote each run directory as the worker left it: run.toml, summary.json, logs/
    for r in runs:
        mine, theirs = r.run_dir, tmp_path / "local" / cp.RUNS_DIR / r.run_dir.name
        assert sorted(p.name for p in mine.iterdir()) == ["logs", "run.toml", "summary.json"]
        assert (mine / "run.toml").read_bytes() == (theirs / "run.toml").read_bytes()
        assert cp.finished_summary(r) is not None
    # resume with the cluster gone: nothing is left to run, so no scheduler is asked
    again = cp.run_campaign(runs, out, executor=executor, plots=False)
    assert (again.reused, again.ran) == (len(sigmas), 0)


def test_cli_names_the_extra_when_dask_is_missing(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    out = tmp_path / "camp"
    assert cli_main(["campaign", "--out", str(out), "--n", "4", "--sigma", "0.1", "--runs-per-cell", "1",
                     "--executor", "dask://127.0.0.1:8786"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "coload[cluster]" in err[0] and "dask.distributed" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("bad", ["dask", "dask://", "dask://host", "dask://host:port", "dask://:8786",
                                 "tcp://host:8786", "dask://host:70000"])
def test_cli_rejects_a_bad_executor(tmp_path, capsys, bad):
    out = tmp_path / "camp"
    assert cli_main(["campaign", "--out", str(out), "--executor", bad]) == 2
    assert "--executor: expected 'local' or dask://HOST:PORT" in capsys.readouterr().err
    assert not out.exists()


def test_executor_addresses():
    assert sweep.parse_executor("local") is None
    pytest.importorskip("distributed")
    assert sweep.parse_executor("dask://10.0.0.7:8786") == "tcp://10.0.0.7:8786"
    assert sweep.parse_executor("dask://node-3.cluster:8786") == "tcp://node-3.cluster:8786"


# --- the sweep loop -----------------------------------------------------------------------------


class _ThreadPool(sweep.Pool):
    """A pool of ``slots`` threads that counts the tasks handed to it and not yet seen finished."""

    def __init__(self, slots: int) -> None:
        self.slots, self.outstanding, self.most = slots, 0, 0
        self._threads = ThreadPoolExecutor(max(1, slots))
        self.executor = self  # type: ignore[assignment]

    def submit(self, fn, *args):
        self.outstanding += 1
        self.most = max(self.most, self.outstanding)
        return self._threads.submit(fn, *args)

    def status(self) -> tuple[int, str]:
        return self.slots, f"{self.slots} threads"

    def close(self) -> None:
        self._threads.shutdown()


def _half(x: int) -> int:
    if x % 7 == 3:
        raise ValueError(f"odd {x}")
    return x // 2


@settings(max_examples=30, deadline=None)
@given(items=st.lists(st.integers(0, 1000), max_size=40), slots=st.integers(0, 3))
def test_sweep_bounds_the_tasks_in_flight_and_delivers_each_once(items, slots):
    pool = _ThreadPool(slots)
    got: list[tuple[int, object]] = []

    def done(item, result):
        pool.outstanding -= 1
        try:
            got.append((item, result()))
        except ValueError as exc:  # a task's error reaches the driver, the sweep goes on
            got.append((item, str(exc)))

    notes: list[str] = []
    sweep.sweep(pool, _half, items, lambda x: (x,), done, notes.append)
    pool.close()
    assert sorted(got) == sorted((x, f"odd {x}" if x % 7 == 3 else x // 2) for x in items)
    assert pool.most <= max(1, sweep.IN_FLIGHT_PER_SLOT * slots)  # 0 workers yet: one task waits
    assert set(notes) <= {f"{slots} threads"} and (notes or not items)


# --- a run directory as data ---------------------------------------------------------------------

DIRS = st.lists(st.sampled_from(["d0", "d1", "d.x"]), max_size=2).map(tuple)  # never a file's name
FILES = st.text(alphabet="abc_-.0", max_size=6).map(lambda s: "f" + s)


@settings(max_examples=40, deadline=None)
@given(tree=st.dictionaries(st.tuples(DIRS, FILES), st.binary(max_size=64), max_size=8),
       empty=st.lists(DIRS, max_size=2))
def test_pack_then_unpack_gives_the_same_directory(tmp_path_factory, tree, empty):
    src = tmp_path_factory.mktemp("src")
    for (dirs, name), data in tree.items():
        src.joinpath(*dirs).mkdir(parents=True, exist_ok=True)
        src.joinpath(*dirs, name).write_bytes(data)
    for dirs in empty:
        src.joinpath(*dirs).mkdir(parents=True, exist_ok=True)
    packed = sweep.pack_dir(src)
    assert len([k for k in packed if not k.endswith("/")]) == len(tree)
    dest = tmp_path_factory.mktemp("dest") / "run"
    dest.mkdir()
    (dest / "stale.csv").write_text("from an earlier run")  # replaced, not merged
    sweep.unpack_dir(packed, dest)
    assert sweep.pack_dir(dest) == packed
    assert [p.name for p in dest.parent.iterdir()] == ["run"]  # no temporary sibling left


def test_pack_skips_top_level_names_and_unpack_refuses_paths_outside(tmp_path):
    (tmp_path / "src" / "logs").mkdir(parents=True)
    (tmp_path / "src" / "samples.csv").write_text("t\n")
    (tmp_path / "src" / "logs" / "samples.csv").write_text("kept: not top level\n")
    assert sweep.pack_dir(tmp_path / "src", skip=["samples.csv"]) == {"logs/": b"", "logs/samples.csv":
                                                                      b"kept: not top level\n"}
    for rel in ("../escape", "/abs", "a/../../b"):
        with pytest.raises(ValueError, match="outside its run directory"):
            sweep.unpack_dir({rel: b"x"}, tmp_path / "run")
        assert not (tmp_path / "run").exists() and not (tmp_path / "escape").exists()
