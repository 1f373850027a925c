"""Re-tracking a recorded ``rt2 track`` session with the images decoded ahead by threads: the same figures,
byte for byte, as decoding in the tracker's thread (``rt2 reevaluate``), the replay source's frames in the
same order, and ``rt2 bench replay`` from the command line. Speed is ``rt2 bench replay``'s to measure."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import main as rt2
from harness.live.reevaluate_track import reevaluate_track
from harness.experiments.studies.bench_replay import make_track_log
from harness.logs import SessionLogReader


@pytest.fixture(scope="module")
def track_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "track.mcap"
    summary = make_track_log(path, framesets=40, distinct=12, seed=0)
    assert summary["frame_sets"] == 40 and not summary["log"]["dropped"]
    return path


def test_retracking_with_decoding_threads_gives_the_same_figures_byte_for_byte(track_log):
    out = {}
    with SessionLogReader(track_log) as reader:
        for workers in (0, 1, 3):
            out[workers] = json.dumps(reevaluate_track(reader, source="images", decode_workers=workers), sort_keys=True,
                                      default=str)
    assert out[0] == out[1] == out[3]
    doc = json.loads(out[0])
    assert doc["frame_sets"] == 40 and doc["source"] == "images" and doc["with_position_rerun"] > 0


def test_the_replay_source_keeps_the_order_with_decoding_threads(track_log):
    from harness.live.sources.replay import open_replay
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    frames = {}
    for workers in (0, 2):
        sources, feed = open_replay(track_log, rig, speed=None, queue_len=64, decode_workers=workers)
        got = [[] for _ in sources]
        try:
            for s in sources:
                s.start()
            for j, s in enumerate(sources):
                while not s.exhausted:
                    f = s.read(1.0)
                    if f is not None:
                        got[j].append(f)
        finally:
            for s in sources:
                s.close()
        frames[workers] = got
    for a, b in zip(frames[0], frames[2]):
        assert [f.frame_id for f in a] == [f.frame_id for f in b] == list(range(40))
        assert all(np.array_equal(x.image, y.image) and x.t_device_s == y.t_device_s for x, y in zip(a, b))


def test_rt2_bench_replay_on_a_given_log(track_log, tmp_path, capsys):
    out = tmp_path / "b.json"
    assert rt2(["bench", "replay", "--log", str(track_log), "--workers", "0,2", "--repeats", "1", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "re-track fs/s" in printed and "goal: re-tracking >= 200 frame sets/s" in printed
    doc = json.loads(out.read_text())
    assert [r["decode_workers"] for r in doc["rows"]] == [0, 2]
    assert all(r["same_figures"] and r["frame_sets"] == 40 and r["images"] == 160 for r in doc["rows"])
    assert doc["rows"][0]["retrack_speed_up"] == 1.0


@pytest.mark.parametrize("argv, message", [
    (["--workers", "0,-1"], "--workers must be a comma list of whole numbers in [0, 64]"),
    (["--workers", "two"], "--workers must be a comma list"),
    (["--repeats", "0"], "need --repeats >= 1"),
    (["--distinct", "0"], "--distinct in [1, 2000]"),
    (["--log", "/no/such/log.mcap"], "--log '/no/such/log.mcap': no such file"),
])
def test_rt2_bench_replay_bad_input_is_one_line(argv, message, capsys):
    assert rt2(["bench", "replay", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.parametrize("bad", ["-1", "65"])
def test_rt2_reevaluate_bad_decode_workers_is_one_line(track_log, bad, capsys):
    assert rt2(["reevaluate", str(track_log), "--decode-workers", bad]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--decode-workers" in err, err
