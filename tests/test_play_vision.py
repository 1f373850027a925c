"""Playing sessions with the vision source: rendered cameras through the real trackers (slow: a handful of balls)."""

from __future__ import annotations

import json

import pytest

from harness.cli import main


def _vision(tmp_path, *argv):
    out = tmp_path / "v"
    code = main(["play", "--source", "vision", "--seed", "1", "--out", str(out), "--json", str(out / "r.json"),
                 "--quiet", "--no-figure", *argv])
    assert code == 0
    return json.loads((out / "r.json").read_text())


def test_tiny_vision_session_runs(tmp_path):
    (row,) = _vision(tmp_path, "--balls", "1", "--tracker", "rtblob", "--filter", "ransac_kalman", "--log-images", "30")
    assert row["source"] == "vision" and row["balls"] == 1 and row["rate_hz"] == 60.0
    assert sum(row["outcomes"].values()) == 1
    from harness.logs import SessionLogReader

    with SessionLogReader(row["log"]) as log:
        assert "/camera/cam0/image" in log.topics() and "/tracker/rtblob/ball" in log.topics()


@pytest.mark.slow
def test_vision_session_rt2_handful_of_balls(tmp_path):
    (row,) = _vision(tmp_path, "--balls", "4", "--tracker", "rt2", "--filter", "raw", "--no-log")
    assert row["balls"] == 4 and row["attempted"] >= 1
