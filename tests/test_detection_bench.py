"""rt2 bench detector runs and writes its JSON rows (no timing assertions: speed is the bench's job)."""

from __future__ import annotations

import json

from harness.cli import main
from tracker.detection.synthetic import hand_made_model

ROWS = {("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch")}


def test_bench_json_rows_rendered_frame(tmp_path, capsys):
    out = tmp_path / "bench.json"  # default: the shipped model on a rendered lab4_vga frame
    assert main(["bench", "detector", "--repeats", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert {(r["mode"], r["backend"]) for r in rows} == ROWS
    assert all(set(r) == {"mode", "backend", "median_ms"} and r["median_ms"] > 0 for r in rows)
    text = capsys.readouterr().out
    assert "torch / cv2" in text and "rendered lab4_vga" in text


def test_bench_frame_from_a_coco_set(tmp_path, synthetic_ball_coco, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    out = tmp_path / "bench.json"
    assert main(["bench", "detector", "--model", str(model), "--data", str(synthetic_ball_coco(30, 0)), "--repeats", "2", "--json", str(out)]) == 0
    assert {(r["mode"], r["backend"]) for r in json.loads(out.read_text())} == ROWS


def test_bench_bad_input(tmp_path, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    assert main(["bench", "detector", "--model", str(model), "--repeats", "0"]) == 2
    assert "--repeats must be >= 1" in capsys.readouterr().err
