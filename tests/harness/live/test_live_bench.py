"""The live service's builder (``harness.live.run``) and ``rt2 bench live``'s measurement
(``harness.live.bench``): from Python and from the command line, short runs on the simulated lab,
bad input as one line and exit 2. Figures are not asserted here (the machine is shared): the
measurement is ``rt2 bench live`` itself."""

from __future__ import annotations

import argparse
import json

import pytest

from harness.cli import main as rt2
from harness.cli.bench_live import add_arguments as bench_arguments
from harness.cli.track import add_arguments as track_arguments
from harness.live.bench import MODES, bench_live, check_options
from harness.live.run import open_service, stream_addresses


def _parse(add_arguments, *argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(list(argv))


def _track_args(*argv: str) -> argparse.Namespace:
    return _parse(track_arguments, *argv)


# -- smoke -------------------------------------------------------------------------------------------
def test_open_service_from_python_tracks_the_simulated_lab():
    args = _track_args("--publish", "none", "--prerender", "0.1", "--status-period", "0", "--duration", "1")
    service, assembler, closers = open_service(args, status=None)
    try:
        assert service.publisher is None and service.log is None and service.view is None
        assembler.start()
        summary = service.run(assembler, duration_s=args.duration)
    finally:
        service.finish()
        for close in reversed(closers):
            close()
    assert summary["frame_sets"] > 0 and summary["tracker"] == "rt2"


def test_bench_live_from_python_gives_one_row_per_mode():
    args = _parse(bench_arguments, "--prerender", "0.1", "--duration", "2", "--warmup", "0.5", "--modes", "roi")
    lines = []
    doc = bench_live(args, check_options(args), progress=lines.append)
    assert [r["mode"] for r in doc["modes"]] == ["roi"] and len(lines) == 1 and "mode roi" in lines[0]
    row = doc["modes"][0]
    assert row["frame_sets_published"] > 0 and row["frame_sets_measured"] > 0
    assert row["dropped_by_rt2_total"] >= 0 and set(row["latency_ms"]) == {"p50", "p90", "p99", "max"}
    assert set(doc["goals_met"]) == {"rate", "p99", "max", "no_drops_by_rt2"} and doc["prerender_s"] == 0.1
    # the skipped sets are what the assembler counted, within the bound of the default backlog
    assert row["max_backlog"] == 1 and 0 <= row["skipped_framesets"] <= row["dropped_by_rt2_total"]
    budget = row["latency_budget_ms"]
    assert list(budget) == ["assembly", "backlog", "tracker", "publish", "after", "total"]
    assert all(b["n"] == budget["total"]["n"] > 0 for b in budget.values())
    assert budget["tracker"]["p50"] <= budget["total"]["p50"] and set(row["backlog_wait_periods"]) == {"p50", "p99", "max"}


def test_rt2_bench_live_writes_its_figures(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert rt2(["bench", "live", "--duration", "2", "--warmup", "0.5", "--modes", "full", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "rt2 bench live: mode full" in printed and "end-to-end latency" in printed and f"wrote {out}" in printed
    assert "goals (roi" not in printed  # the goals are the roi mode's
    doc = json.loads(out.read_text())
    assert doc["prerender_s"] == 0.5 and doc["goals_met"] is None  # the sim source's default pre-render
    assert [r["mode"] for r in doc["modes"]] == ["full"] and doc["modes"][0]["frame_sets_published"] > 0


def test_stream_addresses_follow_the_tennicam_port():
    assert stream_addresses(_track_args("--publish", "tcp://127.0.0.1:7000")) == ("tcp://127.0.0.1:7000", "tcp://127.0.0.1:7001")
    assert stream_addresses(_track_args("--publish", "tcp://127.0.0.1:0")) == ("tcp://127.0.0.1:0", "tcp://127.0.0.1:0")
    assert stream_addresses(_track_args("--publish", "none")) == (None, None)
    assert stream_addresses(_track_args("--publish-rt2", "none"))[1] is None


# -- bad input ---------------------------------------------------------------------------------------
def test_truth_stream_without_a_scene_builder_is_refused():
    args = _track_args("--publish", "none", "--truth-stream", "tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match="--truth-stream needs a lab truth scene"):
        open_service(args, status=None)


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
])
def test_rt2_bench_live_bad_input_is_one_line(argv, message, capsys):
    assert rt2(["bench", "live", "--duration", "1", "--warmup", "0", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("rt2 bench live: error: ") and message in err, err


def test_rt2_bench_live_json_folder_is_one_line(tmp_path, capsys):
    assert rt2(["bench", "live", "--json", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
