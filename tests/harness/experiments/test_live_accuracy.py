"""The accuracy experiment on live streams (harness/experiments/accuracy/live.py, live_stream.py): three processes -- the simulated bridge with
its lab truth stream, `rt2 track --source sim --truth-stream`, and the experiment -- against the in-process run of
the same seed.

Tolerance (docs/accuracy.md, "Live"): mean and median within 1 mm, p90 within 2 mm of the in-process figures. What
differs between the two runs is timing only: the live cameras expose on their own grid (frame 0 lands within a
robot tick of the in-process instant), their clock is their own (the in-process run models a 2 ms camera clock
error), the tracker runs continuously instead of in reset segments, and the sensor noise of camera frame j0 + k is
not that of frame k.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from harness.experiments.accuracy import AccuracyConfig
from harness.experiments.accuracy.live import run_live_accuracy
from harness.experiments.accuracy.live_stream import StreamSilent, observation_from_message
from harness.cli import main

SEED = 4
TOL_MM = {"mean_cm": 1.0, "median_cm": 1.0, "p90_cm": 2.0}


# -- bad input: one line, exit 2 -----------------------------------------------------------------------------------
def test_a_silent_tracker_stream_is_named(tmp_path, capsys):
    config = AccuracyConfig(seed=SEED, n_frames=40, rate_hz=100.0, trackers=("rt2",))
    with pytest.raises(StreamSilent, match=r"tracker stream at tcp://127.0.0.1:9 sent nothing in 0.3 s"):
        run_live_accuracy(config, tmp_path / "out", robot="tcp://127.0.0.1:9", tracker_stream="tcp://127.0.0.1:9",
                          stream_timeout_s=0.3)
    assert main(["accuracy", "--live", "--robot", "tcp://127.0.0.1:9", "--tracker-stream", "tcp://127.0.0.1:9",
                 "--stream-timeout", "0.3", "--trackers", "rt2", "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sent nothing in 0.3 s" in err[0]


def test_a_tracker_process_that_stopped_is_reported_at_once(tmp_path):
    config = AccuracyConfig(seed=SEED, n_frames=40, rate_hz=100.0, trackers=("rt2",))
    t0 = time.monotonic()
    with pytest.raises(ValueError, match=r"rt2 track stopped \(exit code 2\): no camera delivered"):
        run_live_accuracy(config, tmp_path / "out", robot="tcp://127.0.0.1:9", tracker_stream="tcp://127.0.0.1:9",
                          stream_timeout_s=600.0,
                          tracker_alive=lambda: "rt2 track stopped (exit code 2): no camera delivered a frame")
    assert time.monotonic() - t0 < 60  # not the 600 s stream timeout


@pytest.mark.parametrize("argv, match", [
    (["--tracker-stream", "tcp://127.0.0.1:9"], "--tracker-stream goes with --live"),
    (["--live", "--robot", "tcp://127.0.0.1:9"], "both --robot ADDR and --tracker-stream ADDR"),
    (["--live", "--tracker-stream", "tcp://127.0.0.1:9"], "both --robot ADDR and --tracker-stream ADDR"),
    (["--live", "--robot", "tcp://127.0.0.1:9", "--tracker-stream", "localhost:7661"], "--tracker-stream must be"),
    (["--live", "--trackers", "rt2", "rtblob"], "scores the one rt2 tracker"),
])
def test_bad_live_options_are_one_line(tmp_path, capsys, argv, match):
    base = ["accuracy", "--out", str(tmp_path / "o"), "--stream-timeout", "0.3"]
    if "--trackers" not in argv:
        base += ["--trackers", "rt2"]
    if "--live" in argv and "--trackers" in argv:  # checked before anything starts
        argv = argv + ["--robot", "tcp://127.0.0.1:9", "--tracker-stream", "tcp://127.0.0.1:9"]
    assert main(base + argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err


def test_observation_from_message_reads_the_rich_stream():
    m = {"num": 3, "frame_id": 7, "tracker": "rt2", "status": "ok", "position_m": [0.1, 0.2, 1.0],
         "covariance_m2": np.eye(3).tolist(), "support": 3, "inliers": [True, True, False, True],
         "cameras": ["cam0", "cam1", "cam2", "cam3"], "uv_px": [[1.0, 2.0], [3.0, 4.0], [None, None], [5.0, 6.0]],
         "t_s": 12.5, "tracker_latency_s": 0.001, "notes": ["camera cam2: no frame in time"], "candidates": [[], [], [], []]}
    obs = observation_from_message(json.loads(json.dumps(m)))
    assert obs.status.value == "ok" and obs.support == 3 and obs.t_s == 12.5
    assert np.allclose(obs.position_m, [0.1, 0.2, 1.0]) and np.isnan(obs.uv_px[2]).all()
    assert obs.notes == ("camera cam2: no frame in time",)


# -- live vs in process (real processes and sockets on 127.0.0.1) ---------------------------------------------------
@pytest.fixture(scope="module")
def in_process(tmp_path_factory):
    from harness.experiments.accuracy.experiment import run_accuracy

    config = AccuracyConfig(seed=SEED, n_frames=100, rate_hz=100.0, trackers=("rt2",))
    return run_accuracy(config, tmp_path_factory.mktemp("ip"), log=False, progress=False)


def _rows(res):
    return {k: res.rows[0][k] for k in TOL_MM}


def _diagnosis(live) -> dict:
    """What a failed comparison needs to be understood after its files are gone (pytest keeps three basetemps):
    the clocks, the registration, the error against the true ball, the error over the run's course."""
    m = live.motion_info
    info = m.get("live", {})
    err = np.asarray(live.errors.get("rt2", []), float) * 1e3
    quarters = [round(float(np.nanmedian(q)), 3) for q in np.array_split(err, 4)] if err.size >= 4 else []
    reg = live.figures.get("registration", {})
    return {"robot_clock_error_ms": m.get("robot_clock_error_ms"), "gt_vs_true_mm": m.get("gt_vs_true_mm"),
            "first_frame_id": info.get("first_frame_id"),
            "camera_clock_offsets": info.get("camera_clock_offsets"),
            "registration": {k: reg.get(k) for k in ("pairs", "inliers", "rms_cm", "max_cm", "spread_cm", "vs_true_mount")},
            "median_mm_by_quarter": quarters, "missing": int(np.isnan(err).sum()), "scene_events": live.scene_events,
            "truth": live.truth, "ball_speed_mps": m.get("ball_speed_mps"),
            "command_to_motion": info.get("latency_budget", {}).get("command_to_motion")}


def _assert_close(live, ref):
    a, b = _rows(live), _rows(ref)
    for key, tol_mm in TOL_MM.items():
        assert abs(a[key] - b[key]) * 10 <= tol_mm, (key, a, b, _diagnosis(live))


@pytest.mark.realtime
@pytest.mark.parametrize("skew_ms", [0.0, 5.0])
def test_live_figures_match_the_in_process_run(tmp_path, in_process, skew_ms):
    from harness.experiments.accuracy.live import run_live_local
    from harness.experiments.accuracy.reevaluate_accuracy import reevaluate_accuracy
    from harness.logs import SessionLogReader

    config = AccuracyConfig(seed=SEED, n_frames=100, rate_hz=100.0, trackers=("rt2",))
    live = run_live_local(config, tmp_path / "live", clock_skew_ms=skew_ms, status=lambda line: None)
    info = live.motion_info["live"]
    assert info["frames_received"] == 100
    assert abs(live.motion_info["robot_clock_error_ms"]) < 0.5  # the 5 ms skew is found
    _assert_close(live, in_process)
    budget = info["latency_budget"]
    assert budget["exposure_to_observation_ms"]["p50"] > 0 and budget["command_to_motion"]["command_ack_ms"] > 0
    with SessionLogReader(live.paths["log"]) as log:  # rt2 reevaluate on the live log: the same figures
        r = reevaluate_accuracy(log, source="detections")
        assert log.metadata("live")["robot_clock_estimate"]["uncertainty_ms"] >= 0
    assert r.rows[0]["median_cm"] == pytest.approx(live.rows[0]["median_cm"], abs=0.01)


@pytest.mark.slow
def test_sigint_stops_the_child_processes(tmp_path):
    """`rt2 accuracy --live` alone: SIGINT once both children run -> exit 130, the bridge and rt2 track gone."""
    import os
    import re
    import select
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "harness.cli", "accuracy", "--live", "--frames", "40", "--rate-hz", "100",
                             "--trackers", "rt2", "--out", str(tmp_path / "out")], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    pids, seen = [], ""
    t_end = time.monotonic() + 600
    while not pids and time.monotonic() < t_end and proc.poll() is None:
        if select.select([proc.stdout], [], [], 1.0)[0]:
            line = proc.stdout.readline()
            seen += line
            if line.startswith("bridge "):
                pids = [int(p) for p in re.findall(r"pid (\d+)", line)]
    assert len(pids) == 2, seen
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=60) == 130
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            for _ in range(50):  # stopped by the parent on its way out (reaped: no such process)
                os.kill(pid, 0)
                time.sleep(0.1)
