"""``rt2 bench estimator``: the naive OpenCV baseline is the same algorithm; the command's output."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import main
from harness.sim.study_rigs import load_sim_rig
from tracker.synthetic import simulate_observations
from harness.experiments.studies.bench_estimator import bench, naive_estimate
from tracker import RobustTriangulator


def test_naive_baseline_is_algorithm_2():
    """Same sets as our method="paper" (the candidates differ by solver only: homogeneous SVD in
    OpenCV, inhomogeneous least squares in ours), same positions where the sets agree."""
    rig = load_sim_rig(8)
    _, uv, _ = simulate_observations(rig, 120, 0.2, np.random.default_rng(0))
    uv[3, 2] = np.nan  # a camera without an observation
    est = RobustTriangulator(rig, method="paper")
    agree, dist = 0, []
    for f in range(len(uv)):
        pos, info = est.estimate(uv[f])
        X, best = naive_estimate(uv[f], rig, est.options.eps_px)
        if sorted(best) == np.flatnonzero(info.inliers).tolist() or (X is None and pos is None):
            agree += 1
            if X is not None:
                dist.append(np.linalg.norm(X - pos))
    assert agree >= 118
    assert max(dist) < 0.003 and np.median(dist) < 0.001  # pixel-space SVD vs normalised least squares: different weights


def test_bench_rows():
    rows = bench((4,), repeats=10, naive_budget_s=0.2, progress=False)
    assert [r["method"] for r in rows] == ["paper", "ours", "naive"]
    assert all(r["cameras"] == 4 and r["median_ms"] > 0 and r["calls"] >= 5 for r in rows)


def test_cli_json(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "estimator", "--cameras", "4", "8", "--repeats", "10", "--naive-budget-s", "0.1",
                 "--json", str(out), "--no-progress"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "| cameras | paper's C++ (Table 2) ms |" in text and "load average" in text
    rows = json.loads(out.read_text())
    assert len(rows) == 6
    assert all(set(r) == {"cameras", "method", "median_ms"} for r in rows)
    assert {r["method"] for r in rows} == {"paper", "ours", "naive"}


def test_bad_arguments(capsys):
    with pytest.raises(ValueError, match=r"--repeats must be >= 5, got 2"):
        bench((4,), repeats=2, progress=False)
    assert main(["bench", "estimator", "--cameras", "1", "--no-progress"]) == 2
    assert "every count must be >= 2, got 1" in capsys.readouterr().err
