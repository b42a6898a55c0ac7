"""Executors (issue 16): the same arrays whatever runs the per-layer tasks -- in this process in order or on
threads, a local Dask cluster, or a real ``dask scheduler`` + ``dask worker`` pair one of which is killed mid-run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curvslice.cli import main
from curvslice.errors import CurvsliceError
from curvslice.executors import InProcess, Threads, open_executor
from curvslice.toolpaths.passes import uncross

ROOT = Path(__file__).resolve().parents[1]
TEE = ROOT / "models" / "tee.stl"
ARGS = ["--voxel", "2", "--stages", "toolpaths", "--quiet"]
#: Task-name prefixes of the per-layer work (working surfaces, tool-paths under either start rule).
LAYER_TASKS = ("_contour_layer", "_layer_toolpaths", "_prepare_layer", "_fold_layer", "_orient_layer")


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    out = {}
    for name in ("field.npz", "toolpaths.npz"):
        with np.load(folder / name) as z:
            out.update({f"{name}:{k}": z[k] for k in z.files})
    return out


def _assert_same(a: Path, b: Path) -> None:
    x, y = _arrays(a), _arrays(b)
    assert x.keys() == y.keys()
    for k in x:
        assert x[k].shape == y[k].shape and np.array_equal(x[k], y[k]), k
    assert len(x["toolpaths.npz:positions"]) > 100  # a real tool-path, not two empty ones


@pytest.fixture(scope="module")
def in_process(tmp_path_factory) -> Path:
    """The tee sliced in a fresh interpreter, in-process and in order (``--threads 1``); that run must not import
    Dask at all."""
    out = tmp_path_factory.mktemp("inproc") / "tee"
    code = ("import sys; from curvslice.cli import main; rc = main(sys.argv[1:]); "
            "assert 'distributed' not in sys.modules and 'dask' not in sys.modules, 'in-process run imported Dask'; "
            "sys.exit(rc)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-c", code, "slice", str(TEE), *ARGS, "--out", str(out), "--threads", "1"], check=True,
                   env=env)
    return out


def test_local_cluster_gives_the_in_process_arrays(in_process, tmp_path):
    out = tmp_path / "tee2"
    assert main(["slice", str(TEE), *ARGS, "--out", str(out), "--workers", "2"]) == 0
    _assert_same(in_process, out)
    # the per-layer report rows (counts, lengths) are the same too; only the timings differ
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]
    reports = [json.loads((f / "report.json").read_text()) for f in (in_process, out)]
    assert strip(reports[0]["toolpaths"]["per_layer"]) == strip(reports[1]["toolpaths"]["per_layer"])


def test_threads_give_the_in_order_arrays(in_process, tmp_path):
    """Two threads (the command line's default on two cores and more) give the arrays of one, under the
    ``chain`` rule, whose folds wait for each other and for their layer's rings on the other thread."""
    out = tmp_path / "tee2"
    assert main(["slice", str(TEE), *ARGS, "--out", str(out), "--threads", "2"]) == 0
    _assert_same(in_process, out)


def test_thread_tasks_wait_for_the_futures_they_take():
    """``submit`` with futures among the arguments: each task gets their results (a chain of 40 links, each
    added to the last, on two threads), ``map`` keeps the order, and ``gather`` counts each task done once."""
    class Count:
        n = 0

        def update(self, k: int) -> None:
            self.n += k

    with open_executor(threads=2) as ex:
        assert isinstance(ex, Threads) and ex.workers == 2
        link = ex.submit(lambda x: x, 0)
        links = [link]
        for i in range(1, 40):
            link = ex.submit(lambda previous, i: (time.sleep(0.001 * (i % 3)), previous + i)[1], link, i=i)
            links.append(link)
        bar = Count()
        assert ex.gather(links, bar) == [i * (i + 1) // 2 for i in range(40)] and bar.n == 40
        assert ex.map(lambda x, k: x * k, range(10), k=3) == [3 * x for x in range(10)]
    with open_executor(threads=1) as ex:
        assert isinstance(ex, InProcess)
    with pytest.raises(CurvsliceError, match="at least 1"):
        with open_executor(threads=0):
            pass
    with pytest.raises(CurvsliceError, match="without Dask"):
        with open_executor(workers=2, threads=2):
            pass


def test_an_error_in_the_caller_drops_the_queued_thread_tasks():
    """An exception (an interrupt) in the ``with`` block cancels the tasks not yet started instead of running
    them all first: the running one ends, the other 20 never start."""
    started = []
    with pytest.raises(KeyboardInterrupt):
        with open_executor(threads=2) as ex:
            for i in range(22):
                ex.submit(lambda i: (started.append(i), time.sleep(0.2)), i)
            time.sleep(0.05)
            raise KeyboardInterrupt
    time.sleep(0.5)
    assert len(started) == 2


def test_seam_start_rule_on_a_local_cluster_gives_the_in_process_arrays(in_process, tmp_path):
    """The ``seam`` rule (one independent task per layer: rings, pieces and orientations) gives the
    in-process arrays on two workers too, and not the default ``chain`` rule's."""
    seam = [*ARGS, "--start-rule", "seam"]
    assert main(["slice", str(TEE), *seam, "--out", str(tmp_path / "a")]) == 0
    assert main(["slice", str(TEE), *seam, "--out", str(tmp_path / "b"), "--workers", "2"]) == 0
    _assert_same(tmp_path / "a", tmp_path / "b")
    chain, seam = (_arrays(f)["toolpaths.npz:positions"] for f in (in_process, tmp_path / "a"))
    assert seam.shape != chain.shape or not np.array_equal(seam, chain)


@pytest.mark.dask_cluster
def test_killing_a_worker_mid_run_still_gives_the_same_arrays(in_process, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes (no nanny: a killed worker stays dead) on
    127.0.0.1; the slice runs through ``--scheduler``; once a worker is busy with a per-layer task it is
    killed (SIGKILL), with whatever shared inputs and results it held. The lost tasks are re-run on the
    survivor and the arrays are the in-process ones."""
    from dask.distributed import Client

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    info = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], env=env, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.time() + 30
        while not info.exists() and time.time() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        workers = [subprocess.Popen([*dask, "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                     "--no-nanny", "--no-dashboard", "--name", f"w{i}"], env=env,
                                    stderr=subprocess.DEVNULL) for i in range(2)]
        procs += workers
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=30)
            out = tmp_path / "tee"
            run = subprocess.Popen([sys.executable, "-m", "curvslice", "slice", str(TEE), *ARGS, "--out", str(out),
                                    "--scheduler", address], env=env)
            procs.append(run)
            victim = None
            while victim is None and run.poll() is None:
                busy = [a for a, tasks in client.processing().items()
                        if any(str(t).startswith(LAYER_TASKS) for t in tasks)]
                if busy:
                    victim = client.scheduler_info()["workers"][busy[0]]["name"]
                time.sleep(0.02)
            assert victim is not None, "the slice ended before any per-layer task reached a worker"
            workers[int(victim[1:])].send_signal(signal.SIGKILL)
            assert run.wait(timeout=120) == 0
            assert len(client.scheduler_info()["workers"]) == 1  # the killed worker did not come back
        _assert_same(in_process, out)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(4, 60))
def test_uncrossing_keeps_a_pieces_ends(seed, n):
    """The chain's fold orders a layer's pieces and finds where the layer ends before they are uncrossed
    (that runs in the parallel orient task): valid because ``uncross`` only reverses inner stretches.
    Random walks cross themselves often; every order keeps the first and last point, visits each once,
    and leaves the piece no longer."""
    p = np.c_[np.random.default_rng(seed).normal(size=(n, 2)).cumsum(axis=0), np.zeros(n)]
    order = uncross(p, 1.0)
    assert order[0] == 0 and order[-1] == n - 1 and sorted(order) == list(range(n))
    length = lambda q: np.linalg.norm(np.diff(q, axis=0), axis=1).sum()
    assert length(p[order]) <= length(p) + 1e-9


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 40), st.booleans(), st.integers(0, 3))
def test_a_layers_end_read_off_its_last_piece_is_its_last_sample(seed, n, reverse, repeats):
    """The chain's fold reads where a layer ends off its last piece, without uncrossing and re-sampling
    it (that runs in the parallel orient task, with the final bead widths): whenever ``_printed_end``
    answers, it is exactly the last sample the orient task makes of that piece -- with the fitted widths
    or any others. Random walks cross themselves; ``repeats`` copies of the end point (or points within
    1e-9 of it) sit next to it, where re-sampling merges points."""
    from curvslice.toolpaths.plan import LayerPaths, ToolpathSettings, _piece_samples, _printed_end

    rng = np.random.default_rng(seed)
    p = np.c_[rng.normal(size=(n, 2)).cumsum(axis=0), rng.normal(size=n) * 0.1]
    end = p[0] if reverse else p[-1]
    near = end + rng.choice([0.0, 5e-10, 3e-9], size=(repeats, 1)) * rng.normal(size=(repeats, 3))
    p = np.vstack([p[:1], near, p[1:]]) if reverse else np.vstack([p, near])[np.r_[0:n - 1, n:n + repeats, n - 1]]
    paths = LayerPaths(pieces=[p], widths=[np.full(len(p), 1.0)])
    found = _printed_end(p, reverse)
    for widths in ([np.full(len(p), 1.0)], [rng.uniform(0.5, 2.0, len(p))]):
        samples = _piece_samples(paths, widths, (0, reverse), ToolpathSettings())
        if found is not None:
            assert len(samples) >= 2 and np.array_equal(found, samples[-1, :3])
    if repeats == 0:
        assert found is not None  # the usual case: no point of a random walk repeats its end


def test_local_cluster_workers_run_without_profiler_and_dask_malloc_setting():
    """The settings of :data:`LOCAL_CLUSTER_CONFIG` reach the workers' processes (from their nannies),
    not only the client's."""
    import dask

    with open_executor(workers=1) as ex:
        seen = ex.client.run(lambda: (dask.config.get("distributed.worker.profile.enabled"),
                                      "MALLOC_TRIM_THRESHOLD_" in os.environ,
                                      dask.config.get("distributed.admin.tick.interval")))
    assert list(seen.values()) == [(False, False, "1s")]
    assert dask.config.get("distributed.worker.profile.enabled")  # the client's own config is left as it was


def test_kd_queries_take_one_thread_per_worker_and_every_core_in_process(monkeypatch):
    """A worker process (one task thread, ``OMP_NUM_THREADS=1`` from its nanny) queries KD trees on one thread,
    not on every core beside the other workers; in-process without the variable, on every core."""
    from curvslice.executors import THREADED_QUERY, query_threads

    with open_executor(workers=1) as ex:
        assert list(ex.client.run(query_threads, THREADED_QUERY).values()) == [1]
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert query_threads(THREADED_QUERY) == -1
    assert query_threads(THREADED_QUERY - 1) == 1  # a small query is not worth starting threads
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert query_threads(THREADED_QUERY) == 3
