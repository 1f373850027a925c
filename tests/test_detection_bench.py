"""rt2 bench detector runs and writes its JSON rows (no timing assertions: speed is the bench's job)."""

from __future__ import annotations

import json

from harness.cli import main
from tracker.detection.synthetic import hand_made_model


def test_bench_json_rows(tmp_path, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    out = tmp_path / "bench.json"
    assert main(["bench", "detector", "--model", str(model), "--repeats", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert {(r["mode"], r["backend"]) for r in rows} == {("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch")}
    assert all(set(r) == {"mode", "backend", "median_ms"} and r["median_ms"] > 0 for r in rows)
    assert "torch / cv2" in capsys.readouterr().out


def test_bench_bad_repeats(tmp_path, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    assert main(["bench", "detector", "--model", str(model), "--repeats", "0"]) == 2
    assert "--repeats must be >= 1" in capsys.readouterr().err
