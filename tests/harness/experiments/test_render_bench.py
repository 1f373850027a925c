"""``rt2 bench renderer``: the benchmark runs, its table and JSON have the promised fields."""

from __future__ import annotations

import json

import pytest

from harness.cli import main
from harness.sim.lab import preview_rig
from harness.experiments.studies.bench_renderer import bench, format_table


def test_bench_rows_table_and_json(tmp_path, capsys):
    rig_file = tmp_path / "preview.yaml"
    preview_rig(120, 90).save(rig_file)
    rows = bench(str(rig_file), frames=10, progress=False)
    assert [(r["scene"], r["method"]) for r in rows] == [
        ("empty", "numba"), ("ball", "numba"), ("dataset", "numba"), ("crowded", "numba"), ("dataset", "numpy"),
    ]  # fmt: skip
    for r in rows:
        assert r["frames_per_s"] > 0 and r["median_ms"] == pytest.approx(1000 / r["frames_per_s"])
    assert "| dataset | numba |" in format_table(rows)
    out = tmp_path / "bench.json"
    assert main(["bench", "renderer", "--rig", str(rig_file), "--frames", "10", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"scene", "frames_per_s", "median_ms"} <= set(data[0])
    assert "images/s" in capsys.readouterr().out


def test_bench_refuses_too_few_frames():
    with pytest.raises(ValueError, match="--frames must be an integer >= 10, got 3"):
        bench(frames=3)
