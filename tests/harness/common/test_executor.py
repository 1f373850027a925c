"""harness.common.executor: the same figures whatever the backend (this process, local workers, Ray) and the number
of workers; bad options; ``--ray`` without Ray; seeds required where random numbers are drawn."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.common.executor import Executor, SweepOptions, WorkerLost, in_task_order
from harness.experiments.studies import eval_framesets
from harness.experiments.studies.table1 import run_table1

SMALL = {"cameras": [4, 8], "rates": [0.25], "trials": 1000, "seed": 3, "progress": False}  # 4 chunks of 500


def _table1(sweep):
    return run_table1(SMALL["cameras"], SMALL["rates"], trials=SMALL["trials"], seed=SMALL["seed"],
                      progress=False, sweep=sweep)


def _framesets(sweep, monkeypatch):
    from tracker.rig_files import resolve_rig

    monkeypatch.setattr(eval_framesets, "CHUNK", 2)  # 3 tasks of 2 frame sets
    scores = eval_framesets.evaluate(resolve_rig("lab4_vga_v1"), 6, 2, progress=False, sweep=sweep)
    return [s.as_json() | {"errors_cm": s.errors_cm} for s in scores]


@pytest.fixture(scope="module")
def table1_here():
    return _table1(SweepOptions(workers=1))


# -- smoke and order ----------------------------------------------------------------------------------------
def test_map_here_yields_every_task_with_its_index():
    with Executor() as ex:
        got = dict(ex.map(abs, [-3, 1, -2]))
    assert got == {0: 3, 1: 1, 2: 2}


def test_in_task_order_reorders():
    assert list(in_task_order([(2, "c"), (0, "a"), (1, "b"), (3, "d")])) == [(0, "a"), (1, "b"), (2, "c"), (3, "d")]


# -- same figures whatever the backend ----------------------------------------------------------------------
def test_table1_local_workers_equal_this_process(table1_here):
    assert json.dumps(_table1(SweepOptions(workers=2))) == json.dumps(table1_here)


@pytest.mark.slow  # ~1 min: every worker builds a renderer and three trackers (table1 covers the backend fast)
def test_framesets_local_workers_equal_this_process(monkeypatch):
    assert _framesets(SweepOptions(workers=2), monkeypatch) == _framesets(SweepOptions(workers=1), monkeypatch)


def test_task_error_reaches_the_caller_unchanged():
    with Executor(SweepOptions(workers=2)) as ex, pytest.raises(ValueError, match="math domain error"):
        list(ex.map(_sqrt, [4.0, -1.0, 9.0]))


def test_a_dead_worker_stops_the_sweep_with_the_finished_count():
    with Executor(SweepOptions(workers=2)) as ex, pytest.raises(WorkerLost, match="a worker process died or its start-up failed") as info:
        for _ in ex.map(_exit_on_negative, [1.0, 2.0, -1.0, 3.0, 4.0, 5.0]):
            pass
    assert info.value.total == 6 and info.value.done < 6 and info.value.exit_code == 1


def _exit_on_negative(x):
    import os
    import time

    if x < 0:
        time.sleep(0.5)  # let the first tasks come back
        os._exit(3)  # as if killed: no exception, no result
    return x


def _sqrt(x):
    import math

    return math.sqrt(x)


@pytest.fixture(scope="module")
def ray_local():
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'rt2[cluster]')")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    yield ray
    ray.shutdown()


def test_table1_on_ray_equals_local_bit_for_bit(ray_local, table1_here):
    assert json.dumps(_table1(SweepOptions(ray_address="auto"))) == json.dumps(table1_here)


@pytest.mark.slow  # ~30 s, as above
def test_framesets_on_ray_equal_local(ray_local, monkeypatch):
    # the initializer (renderer and trackers built once per Ray worker) runs there too
    assert _framesets(SweepOptions(ray_address="auto"), monkeypatch) == _framesets(SweepOptions(workers=1), monkeypatch)


@pytest.mark.slow  # a Ray worker builds a playing session (~20 s on a loaded machine)
def test_play_on_ray_writes_the_same_bytes_as_this_process(ray_local, tmp_path, capsys):
    from harness.cli import main

    def play(name, *extra):
        out = tmp_path / name
        assert main(["play", "--balls", "2", "--seed", "4", "--out", str(out), "--json", str(out / "play.json"),
                     "--quiet", "--no-figure", "--no-log", *extra]) == 0
        return (out / "play.json").read_bytes()

    assert play("ray", "--ray", "auto") == play("here", "--workers", "1")


def test_ray_task_error_reaches_the_caller(ray_local):
    with Executor(SweepOptions(ray_address="auto")) as ex, pytest.raises(ValueError, match="math domain error"):
        list(ex.map(_sqrt, [4.0, -1.0]))


def _blas_threads(_task) -> list[int]:
    from threadpoolctl import threadpool_info

    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.mark.parametrize("workers", [1, 2])
def test_tasks_run_with_one_blas_thread_in_every_backend(workers, monkeypatch):
    from threadpoolctl import threadpool_limits

    # the parallel suite runs its workers with one BLAS thread (tests/conftest.py): as a user's process, two here
    # (and no thread variables for the sweep's workers to inherit), or one thread seen in the tasks proves nothing
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    with threadpool_limits(2, user_api="blas"):
        before = _blas_threads(None)
        with Executor(SweepOptions(workers=workers)) as ex:
            seen = [threads for _, threads in ex.map(_blas_threads, range(3))]
        assert seen and all(t == [1] * len(before) for t in seen)  # the same summation order everywhere
        assert _blas_threads(None) == before  # this process gets its own limits back after the sweep
    if (os.cpu_count() or 1) >= 2:
        assert 2 in before  # the check above could fail


# -- bad input ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kw, match", [
    ({"workers": 0}, r"--workers must be >= 1 \(an integer\), got 0"),
    ({"workers": 1.5}, r"--workers must be >= 1 \(an integer\), got 1.5"),
    ({"ray_address": " "}, r"--ray: address must be 'local', 'auto' or host:port, got ' '"),
])
def test_bad_options(kw, match):
    with pytest.raises(ValueError, match=match):
        SweepOptions(**kw)


def test_ray_flag_without_ray_is_one_line_exit_2(monkeypatch, capsys, tmp_path):
    from harness.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError, as without the extra
    code = main(["sim", "table1", "--trials", "10", "--cameras", "4", "--outlier-rates", "5", "--ray",
                 "--json", str(tmp_path / "t.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err == ["rt2 sim table1: error: --ray needs Ray, which is not installed: pip install 'rt2[cluster]'"]
    assert not (tmp_path / "t.json").exists()


# -- randomness is passed in --------------------------------------------------------------------------------
def test_launcher_and_trajectories_need_a_seed():
    from harness.sim.launcher import BallLauncher
    from harness.sim.trajectories import random_via_trajectory
    from robot_models import WamKinematics

    with pytest.raises(ValueError, match=r"BallLauncher: a seed or an rng \(numpy.random.Generator\) is required"):
        BallLauncher()
    with pytest.raises(ValueError, match="BallLauncher: give either seed or rng, not both"):
        BallLauncher(seed=1, rng=np.random.default_rng(1))
    with pytest.raises(ValueError, match="random_via_trajectory: a seed or an rng"):
        random_via_trajectory(WamKinematics.default())
    a = BallLauncher(seed=np.random.SeedSequence(4)).serve().state
    b = BallLauncher(rng=np.random.default_rng(np.random.SeedSequence(4))).serve().state
    np.testing.assert_array_equal(a, b)


def _die_in_the_middle_of_a_result(x):
    """In a worker: write the start of a result message into the pool's result pipe, then die (as a worker
    killed while it hands back a large result)."""
    import gc
    import os
    import struct
    import time
    from multiprocessing.queues import SimpleQueue

    if x >= 0:
        time.sleep(0.05)
        return x
    results = next(q for q in gc.get_objects() if isinstance(q, SimpleQueue))  # the pool's result queue
    os.write(results._writer.fileno(), struct.pack("!i", 100_000) + b"x" * 10)  # 10 of 100,000 bytes
    os._exit(9)


def test_a_worker_dying_in_the_middle_of_a_result_is_a_lost_worker_not_a_hang():
    """The pool's manager thread then waits for the rest of the message forever: the sweep used to hang in its
    wait loop (and the process at exit)."""
    code = ("import sys\nfrom tests.harness.common.test_executor import _die_in_the_middle_of_a_result as f\n"
            "from harness.common.executor import Executor, SweepOptions, WorkerLost\n"
            "try:\n    with Executor(SweepOptions(workers=2)) as ex:\n"
            "        for _ in ex.map(f, [1.0, 2.0, -1.0] + [3.0] * 20):\n            pass\n"
            "except WorkerLost as exc:\n    print('LOST', exc.done, exc.total, flush=True)\n")
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=90)
    assert proc.returncode == 0 and proc.stdout.startswith("LOST"), proc.stdout + proc.stderr[-2000:]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_signal_while_the_caller_writes_a_result_waits_for_the_whole_record(workers):
    """A stop that comes while the caller handles a finished result (hold_stop: rt2 accuracy writes a frame set to
    its session log, rt2 play hands a ball on) is raised once that record is whole, not in its middle (a torn
    record left `session.mcap` not finished cleanly, once in 14 stops of rt2 accuracy under load)."""
    import os
    import signal

    from harness.common.executor import SweepInterrupted

    records = []
    with pytest.raises(SweepInterrupted) as info:
        with Executor(SweepOptions(workers=workers)) as ex:
            for _, x in ex.map(_sqrt, [4.0, 9.0, 16.0]):
                with ex.hold_stop():
                    os.kill(os.getpid(), signal.SIGTERM)  # the handler runs at once, here
                    records.append(("begin", x))
                    records.append(("end", x))
    assert len(records) == 2 and records[0] == ("begin", records[1][1]) and records[1][0] == "end"  # one, whole
    assert info.value.exit_code == 128 + signal.SIGTERM
