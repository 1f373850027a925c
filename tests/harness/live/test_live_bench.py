"""The live service's builder (``harness.live.run``) and ``rt2 bench live``'s measurement
(``harness.live.bench``): from Python and from the command line, short runs on the simulated lab,
bad input as one line and exit 2. Figures are not asserted here (the machine is shared): the
measurement is ``rt2 bench live`` itself."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import pytest

from harness.cli import main as rt2
from harness.cli.bench_live import add_arguments as bench_arguments
from harness.cli.track import add_arguments as track_arguments
from harness.cli.track import track_config
from harness.live.bench import MODES, acquisition, bench_live, check_options
from harness.live.config import ConfigError, TrackConfig
from harness.live.run import open_service, stream_addresses


def _parse(add_arguments, *argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(list(argv))


def _track_args(*argv: str) -> argparse.Namespace:
    return _parse(track_arguments, *argv)


def _config(*argv: str) -> TrackConfig:
    return track_config(_track_args(*argv))


def _run_until(live, n_sets: int, *, cap_s: float = 300.0) -> dict:
    """``live``'s service run until it has tracked ``n_sets`` frame sets (a generous cap: a loaded machine, a cold
    kernel cache, any speed of the first call; the figures are ``rt2 bench live``'s business)."""
    stop = threading.Event()

    def watch():
        t_end = time.monotonic() + cap_s
        while live.service.stats.n < n_sets and time.monotonic() < t_end and not stop.is_set():
            time.sleep(0.01)
        stop.set()

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    live.assembler.start()
    try:
        return live.service.run(live.assembler, stop=stop)
    finally:
        stop.set()
        watcher.join()


def _kernel_versions() -> dict:
    """Compiled versions of every numba kernel of ours loaded so far, by name."""
    from numba.core.registry import CPUDispatcher

    return {f"{name}.{k}": len(v.signatures) for name, mod in list(sys.modules.items())
            if name.split(".")[0] in ("tracker", "harness", "policies", "checks")
            for k, v in list(vars(mod).items()) if isinstance(v, CPUDispatcher)}


# -- smoke -------------------------------------------------------------------------------------------
def test_open_service_from_python_tracks_the_simulated_lab(first_serve_only):
    config = TrackConfig(publish=None, prerender_s=0.1, status_period_s=0, duration_s=1.0)
    assert config == _config("--publish", "none", "--prerender", "0.1", "--status-period", "0", "--duration", "1")
    with open_service(config, status=None) as live:
        service = live.service
        assert service.publisher is None and service.log is None and service.view is None
        summary = _run_until(live, 20)
    assert summary["frame_sets"] >= 20 and summary["tracker"] == "rt2"


@pytest.mark.parametrize("rig", ["lab4_vga", "lab8_vga"])
def test_the_warm_up_leaves_no_kernel_to_compile_while_tracking(rig, first_serve_only):
    """open_service warms the tracker up on a made-up ball it confirms and then predicts, so that no compiled
    kernel is built (or loaded from numba's cache) while the clock runs: on a fresh clone's first run that took
    seconds, and the first frame sets waited for it."""
    with open_service(TrackConfig(rig=rig, publish=None, prerender_s=0.1, status_period_s=0), status=None) as live:
        before = _kernel_versions()
        summary = _run_until(live, 40)
        after = _kernel_versions()
    assert summary["frame_sets"] >= 40 and summary["status"].get("ok", 0) > 0
    assert {k: (before.get(k), n) for k, n in after.items() if n != before.get(k)} == {}


def test_the_warm_up_runs_the_windows_at_the_ball_its_deferred_search_found(monkeypatch):
    """With the full frames searched after the frame set, the warm-up waits for each search, so its next frame set
    takes up the ball and searches windows there: the first real ball's frame sets pay no first-call costs (without
    the wait a run's slowest frame set was its second, 14-27 ms of tracker time, once 484 ms)."""
    from harness.live.service import warm_up
    from tracker import Status, Tracker
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    with Tracker(rig, "rt2", workers=2, defer_full_frame=True) as tr:
        seen = []
        process = tr.process_with_info

        def spy(frameset, **kw):
            out = process(frameset, **kw)
            seen.append(out[0])
            return out

        monkeypatch.setattr(tr, "process_with_info", spy)
        warm_up(tr, rig)
    notes = [n for o in seen for n in o.notes]
    assert any(o.status is Status.OK and any("found the ball" in n and "windows at it" in n for n in o.notes) for o in seen), notes
    assert not [n for n in notes if n.startswith("not searched")]
    assert sum("searched after this frame set was reported" in n for n in notes) >= 2  # the ball's, the blank sets' fallback


def test_bench_live_from_python_gives_one_row_per_mode(first_serve_only):
    args = _parse(bench_arguments, "--prerender", "0.1", "--duration", "2", "--warmup", "0.5", "--modes", "roi")
    lines = []
    doc = bench_live(args, check_options(args), track_config(args), progress=lines.append)
    assert [r["mode"] for r in doc["modes"]] == ["roi"] and len(lines) == 1 and "mode roi" in lines[0]
    row = doc["modes"][0]
    assert row["defer_full_frame"] is True  # the shipped filter alone: its full frames after the frame set
    assert row["frame_sets_published"] > 0 and row["frame_sets_measured"] > 0
    assert row["dropped_by_rt2_total"] >= 0 and set(row["latency_ms"]) == {"p50", "p90", "p99", "max"}
    assert set(doc["goals_met"]) == {"rate", "p99", "max", "no_drops_by_rt2"} and doc["prerender_s"] == 0.1
    # the skipped sets are what the assembler counted, within the bound of the default backlog
    assert row["max_backlog"] == 1 and 0 <= row["skipped_framesets"] <= row["dropped_by_rt2_total"]
    budget = row["latency_budget_ms"]
    # the clip's loop brings a new ball, whose frame sets search full frames: those sets' own rows come last
    assert list(budget)[:6] == ["assembly", "backlog", "tracker", "publish", "after", "total"]
    assert all(budget[k]["n"] == budget["total"]["n"] > 0 for k in list(budget)[:6])
    if len(budget) > 6:
        assert list(budget)[6:] == ["tracker_full", "total_full"]
        assert 0 < budget["tracker_full"]["n"] == budget["total_full"]["n"] < budget["total"]["n"]
    assert budget["tracker"]["p50"] <= budget["total"]["p50"] and set(row["backlog_wait_periods"]) == {"p50", "p99", "max"}
    assert row["process_per_set"]["cpu_ms"] > 0 and row["process_per_set"]["page_faults"] >= 0
    # the tracker's counters over the run: every frame set the tracker took counted (not the warm-up's before it)
    st = row["tracker_stats"]
    assert st["frames"] == sum(row["status"].values()) and st["ok"] == row["status"].get("ok", 0)
    assert st["deferred_searches"] >= st["deferred_found"] >= 0 and st["not_searched"] >= 0


def test_acquisition_counts_frame_sets_from_a_new_ball_to_its_first_right_ok_position():
    """Two flights and a jump (the prerendered clip's loop): acquired at once, after 4 frame sets (no consensus, a
    skipped set, a wrong ok position, a low-support one before it), never (no right ok position while it flew)."""
    import numpy as np

    def truth_at(k):  # flight A frames 10-19, flight B 30-39, a jump at 35 (a new ball elsewhere), nothing else
        if 10 <= k < 20:
            return np.array([0.0, 0.01 * k, 1.0])
        if 30 <= k < 35:
            return np.array([1.0, 0.01 * k, 1.0])
        if 35 <= k < 40:
            return np.array([2.0, 0.01 * k, 1.0])
        return None

    rec = {"frame_id": [], "status": [], "position_m": []}

    def msg(k, status, pos):
        rec["frame_id"].append(k)
        rec["status"].append(status)
        rec["position_m"].append(None if pos is None else list(pos))

    for k in range(5, 45):
        if k == 31:
            continue  # skipped by the tracker
        t = truth_at(k)
        if t is None:
            msg(k, "too_few_observations", None)
        elif k == 30:
            msg(k, "no_consensus", None)
        elif k == 32:
            msg(k, "ok", t + [0.3, 0.0, 0.0])  # ok but 30 cm off: not the ball
        elif k == 33:
            msg(k, "low_support", t)
        elif 35 <= k:
            msg(k, "ok", t + [0.0, 0.05, 0.0])  # 5 cm off: never within 4 cm
        else:
            msg(k, "ok", t)
    acq = acquisition(truth_at, rec, first_frame=5)
    assert acq["new_balls"] == 3 and acq["acquired"] == 2
    assert acq["frame_sets_p50"] == 2.0 and acq["frame_sets_max"] == 4.0 and acq["within_3"] == 1 / 3
    assert acquisition(truth_at, rec, first_frame=12)["new_balls"] == 2  # flight A began before the measured part
    # a ball that appears in the record's last 3 frame sets (here 43 of 5-44) is not counted: the run ended first
    late = lambda k: np.array([3.0, 0.0, 1.0]) if k >= 43 else truth_at(k)  # noqa: E731
    assert acquisition(late, rec, first_frame=5)["new_balls"] == 3
    assert acquisition(lambda k: np.array([3.0, 0.0, 1.0]) if k >= 41 else truth_at(k), rec, first_frame=5)["new_balls"] == 4
    assert acquisition(truth_at, {"frame_id": [], "status": [], "position_m": []}, 0)["new_balls"] == 0


def test_rt2_bench_live_writes_its_figures(tmp_path, capsys, first_serve_only):
    out = tmp_path / "bench.json"
    assert rt2(["bench", "live", "--duration", "2", "--warmup", "0.5", "--modes", "full", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "rt2 bench live: mode full" in printed and "end-to-end latency" in printed and f"wrote {out}" in printed
    assert "goals (roi" not in printed  # the ROI goals are the roi mode's
    assert "cpu ms/set" in printed and "faults/set" in printed
    doc = json.loads(out.read_text())
    assert doc["prerender_s"] == 0.5 and doc["goals_met"] is None  # the sim source's default pre-render
    # the full frame's own goals (the shipped model has no learned stage): judged from the row, and printed so
    row, full = doc["modes"][0], doc["full_goals_met"]
    assert full == {"rate": row["rate_hz"] >= 199.0, "wait": row["backlog_wait_periods"]["max"] <= 1.0}
    said = [line for line in printed.splitlines() if line.startswith("goals (lab4_vga, full frame, the 5x5 filter alone)")]
    assert len(said) == 1 and said[0].endswith(f"longest wait <= 1 period {'met' if full['wait'] else 'NOT met'}")
    assert [r["mode"] for r in doc["modes"]] == ["full"] and doc["modes"][0]["frame_sets_published"] > 0
    assert doc["modes"][0]["defer_full_frame"] is False  # every frame set in full: nothing to defer


def test_rt2_bench_live_rigs_gives_a_row_per_rig_on_the_same_scene(tmp_path, capsys, first_serve_only):
    out = tmp_path / "rigs.json"
    assert rt2(["bench", "live", "--rigs", "lab4_vga", "lab4_vga_v1", "--duration", "2", "--warmup", "0.5", "--modes", "roi",
                "--prerender", "0.1", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    rows = [line.split() for line in printed.splitlines() if line.startswith(("lab4_vga ", "lab4_vga_v1 "))]
    assert [r[:3] for r in rows] == [["lab4_vga", "4", "roi"], ["lab4_vga_v1", "4", "roi"]]
    assert "goals (lab4_vga, roi at 200 Hz)" in printed and "goals (lab4_vga_v1, roi at 200 Hz)" in printed
    docs = json.loads(out.read_text())["rigs"]
    assert [d["rig"] for d in docs] == ["lab4_vga", "lab4_vga_v1"] and [d["cameras"] for d in docs] == [4, 4]
    for d in docs:
        row = d["modes"][0]
        assert 0 <= row["ok_share"] <= 1 and row["frame_sets_measured"] > 0
        assert row["error_3d_mm"]["n"] >= 0 and d["image_size"] == [640, 480]
        assert set(row["acquisition"]) == {"new_balls", "acquired", "frame_sets_p50", "frame_sets_max", "within_3"}
        assert (d["model"], d["full_frame_pyramid"], d["motion_cue"], d["sim_ball"]) == (None, True, False, "orange")  # how it ran


def test_goals_are_the_rigs_own():
    from harness.live.bench import GOALS, goals_for

    assert goals_for("lab8_vga") == GOALS and goals_for("data/rigs/lab4_vga.yaml") == GOALS
    assert goals_for("lab9_ace")["p99_ms"] == 8.0 and goals_for("lab9_ace")["max_ms"] is None


def test_stream_addresses_follow_the_tennicam_port():
    assert stream_addresses(_config("--publish", "tcp://127.0.0.1:7000")) == ("tcp://127.0.0.1:7000", "tcp://127.0.0.1:7001")
    assert stream_addresses(_config("--publish", "tcp://127.0.0.1:0")) == ("tcp://127.0.0.1:0", "tcp://127.0.0.1:0")
    assert stream_addresses(_config("--publish", "none")) == (None, None)
    assert stream_addresses(_config("--publish-rt2", "none"))[1] is None
    assert stream_addresses(_config("--publish-rt2", "tcp://127.0.0.1:9"))[1] == "tcp://127.0.0.1:9"


# -- bad input ---------------------------------------------------------------------------------------
def test_truth_stream_without_a_scene_builder_is_refused():
    config = _config("--publish", "none", "--truth-stream", "tcp://127.0.0.1:1")
    with pytest.raises(ConfigError, match="^truth_stream needs a lab truth scene") as err:
        open_service(config, status=None)
    assert err.value.field == "truth_stream"


@pytest.mark.parametrize("fields, field, message", [
    (dict(rate_hz=0), "rate_hz", "rate_hz must be a positive number, got 0"),
    (dict(rate_hz=float("nan")), "rate_hz", "rate_hz must be a positive number, got nan"),
    (dict(rate_hz="200"), "rate_hz", "rate_hz must be a positive number, got 200"),
    (dict(seed=1.5), "seed", "seed must be a whole number"),
    (dict(seed=-1), "seed", "seed must be a whole number >= 0, got -1"),
    (dict(log_images="-1"), "log_images", "log_images must be 'all', 'none' or a positive integer N (every N-th frame set), got '-1'"),
    (dict(log_images="0"), "log_images", "log_images must be 'all', 'none' or a positive integer N"),
    (dict(log_images="often"), "log_images", "log_images must be 'all', 'none' or a positive integer N"),
    (dict(queue_s=0), "queue_s", "queue_s must be in (0, 10] seconds"),
    (dict(max_backlog=True), "max_backlog", "max_backlog must be a whole number of frame sets in [1, 50] (queue_s x rate_hz)"),
    (dict(max_backlog=51), "max_backlog", "in [1, 50]"),
    (dict(prerender_s=0.1, source=("replay", "x.mcap")), "prerender_s", "prerender_s applies to the sim source only, got source replay x.mcap"),
    (dict(prerender_s=11), "prerender_s", "prerender_s must be in (0, 10] seconds"),
    (dict(sim_rig="lab4_vga", source=("video", "d")), "sim_rig", "truth_stream and sim_rig apply to the sim source only"),
    (dict(truth_stream="tcp://127.0.0.1:1", prerender_s=0.1), "prerender_s", "prerender_s cannot go with truth_stream"),
    (dict(truth_stream="tcp://127.0.0.1:1", max_behind_s=0), "max_behind_s", "max_behind_s must be in (0, 3600]"),
    (dict(sim_render="gpu"), "sim_render", "sim_render must be one of"),
    (dict(sim_render="process", prerender_s=0.1), "sim_render", "sim_render process cannot go with prerender_s"),
    (dict(sim_render_nice=20), "sim_render_nice", "sim_render_nice must be a whole number in [0, 19]"),
    (dict(sim_render_nice=True), "sim_render_nice", "sim_render_nice must be a whole number"),
    (dict(sim_render_nice=3, source=("replay", "x.mcap")), "sim_render_nice", "sim_render_nice applies to the sim source only"),
    (dict(tracker="rt3"), "tracker", "unknown tracker 'rt3'; valid: rt2, rt2-paper, rtblob"),
    (dict(workers=0), "workers", "workers must be a whole number in [1, 64], got 0"),
    (dict(workers=65), "workers", "workers must be a whole number in [1, 64], got 65"),
    (dict(workers=1.5), "workers", "workers must be a whole number in [1, 64], got 1.5"),
    (dict(workers="2"), "workers", "workers must be a whole number in [1, 64], got '2'"),
    (dict(tracker="rtblob", model_path="m.npz"), "model_path", "model_path applies to the rt2 kinds only"),
    (dict(roi="yes"), "roi", "roi must be True, False or None"),
    (dict(duration_s=-3), "duration_s", "duration_s must be a positive number of seconds"),
    (dict(status_period_s=-1), "status_period_s", "status_period_s must be >= 0 seconds"),
    (dict(foxglove_port=70000), "foxglove_port", "foxglove_port must be a port number"),
    (dict(log_overwrite="yes"), "log_overwrite", "log_overwrite must be True or False"),
])
def test_track_config_names_the_field(fields, field, message):
    """Hostile values, each refused when the config is made, naming its field (never a CLI flag)."""
    with pytest.raises(ConfigError) as err:
        TrackConfig(**fields)
    assert err.value.field == field and message in str(err.value) and "--" not in str(err.value), str(err.value)


def test_default_workers_are_two_for_the_rt2_kinds_and_one_for_rtblob():
    from harness.live.config import DEFAULT_WORKERS

    assert DEFAULT_WORKERS == 2
    assert TrackConfig().tracker_workers == 2 and TrackConfig(tracker="rt2-paper").tracker_workers == 2
    assert TrackConfig(tracker="rtblob").tracker_workers == 1  # runs its cameras in its own loop
    assert TrackConfig(workers=1).tracker_workers == 1 and TrackConfig(workers=3).tracker_workers == 3
    assert track_config(_parse(track_arguments)).tracker_workers == 2  # rt2 track without --workers
    assert track_config(_parse(track_arguments, "--tracker", "rtblob")).tracker_workers == 1
    assert track_config(_parse(track_arguments, "--workers", "1")).tracker_workers == 1


def test_track_config_paths_are_checked_before_anything_opens(tmp_path):
    (tmp_path / "there.mcap").write_bytes(b"keep me")
    for fields, message in ((dict(model_path=str(tmp_path / "none.npz")), "model_path '"),
                            (dict(log_path=str(tmp_path / "there.mcap")), "exists; pass log_overwrite to replace it"),
                            (dict(log_path=str(tmp_path)), "is a folder"),
                            (dict(log_path=str(tmp_path / "there.mcap" / "x.mcap")), "is a file, not a folder")):
        with pytest.raises(ConfigError, match=message):
            open_service(TrackConfig(publish=None, **fields), status=None)
    assert (tmp_path / "there.mcap").read_bytes() == b"keep me"


def test_rt2_track_unknown_tracker_lists_the_kinds(capsys):
    assert rt2(["track", "--tracker", "rt3", "--publish", "none"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "unknown --tracker 'rt3'; valid: rt2, rt2-paper, rtblob" in err, err


def test_rt2_track_hands_the_builder_the_lab_truth_scene(capsys):
    """The command passes the accuracy experiment's LabTruthScene: its own check of --scene answers."""
    argv = ["track", "--publish", "none", "--truth-stream", "tcp://127.0.0.1:1", "--scene", "nowhere"]
    assert rt2(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "unknown lab truth scene 'nowhere'" in err, err


def test_check_options_names_the_option():
    base = dict(duration=5.0, warmup=1.0, modes="roi,full")
    assert check_options(argparse.Namespace(**base)) == list(MODES)
    with pytest.raises(ValueError, match="--modes must list some of"):
        check_options(argparse.Namespace(**{**base, "modes": "roi,fast"}))
    with pytest.raises(ValueError, match="need --duration > --warmup"):
        check_options(argparse.Namespace(**{**base, "warmup": 5.0}))


@pytest.mark.parametrize("argv, message", [
    (["--modes", ","], "--modes must list some of"),
    (["--duration", "1", "--warmup", "2"], "need --duration > --warmup"),
    (["--rate-hz", "0"], "--rate-hz must be a positive number"),
    (["--max-backlog", "0"], "--max-backlog must be a whole number of frame sets in [1, 50]"),
    (["--max-backlog", "51"], "--max-backlog must be a whole number of frame sets in [1, 50]"),
    (["--max-backlog", "9", "--queue-s", "0.01"], "--max-backlog must be a whole number of frame sets in [1, 8]"),
    (["--rigs", "lab4_vga", "lab5_nope"], "unknown rig 'lab5_nope'"),  # every rig checked before the first runs
    (["--rigs", ""], "--rig must name a rig"),
    (["--rigs", "lab8_vga", "--max-backlog", "0"], "--max-backlog must be a whole number of frame sets in [1, 50]"),
])
def test_rt2_bench_live_bad_input_is_one_line(argv, message, capsys):
    assert rt2(["bench", "live", "--duration", "1", "--warmup", "0", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("rt2 bench live: error: ") and message in err, err


def test_rt2_bench_live_json_folder_is_one_line(tmp_path, capsys):
    assert rt2(["bench", "live", "--json", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
