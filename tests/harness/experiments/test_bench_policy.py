"""``rt2 bench policy``: planning steps of the hitting policy timed for both planners (smoke, figures' shape, bad input)."""

from __future__ import annotations

import json

from harness.cli import main
from harness.experiments.play.bench import GOAL_P95_MS, bench_policy, summarise


def test_bench_policy_times_first_plans_and_replans_of_both_planners(capsys, tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "policy", "--balls", "3", "--seed", "0", "--no-progress", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| fast | re-plans |" in text and "| reference | a ball's first plan |" in text
    assert f"goal: a planning step's p95 <= {GOAL_P95_MS:g} ms" in text and "successes: fast" in text
    doc = json.loads(out.read_text())
    assert doc["balls"] == 3 and doc["goal_p95_ms"] == GOAL_P95_MS
    for planner in ("fast", "reference"):
        rows = doc["planners"][planner]
        assert rows["replan"]["n"] > 10 and rows["first"]["n"] >= 2  # two balls after the first, each planned
        assert 0 < rows["replan"]["median_ms"] <= rows["replan"]["p90_ms"] <= rows["replan"]["max_ms"]
        assert rows["all"]["n"] == rows["first"]["n"] + rows["replan"]["n"]
    assert doc["planners"]["fast"]["all"]["speedup_median"] > 0


def test_both_planners_play_the_same_balls():
    raw = bench_policy(2, 4, progress=False)
    rows = summarise(raw)
    assert rows["fast"]["successes"] == rows["reference"]["successes"]


def test_bench_policy_bad_input_is_one_line(capsys):
    for argv, needle in ((["--balls", "1"], "--balls must be >= 2"), (["--filter", "kalman"], "unknown --filter 'kalman'")):
        assert main(["bench", "policy", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and len(err.splitlines()) == 1
