"""Robot CLI commands: `rt2 sim wam`, `rt2 sim reach`, `rt2 bench robot` run, are seeded, and fail cleanly."""

from __future__ import annotations

import json

import pytest

from harness.cli import main


def _json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_sim_wam_same_seed_same_figures(capsys):
    a = _json(capsys, ["sim", "wam", "--seed", "1", "--n-via", "3", "--json"])
    b = _json(capsys, ["sim", "wam", "--seed", "1", "--n-via", "3", "--json"])
    c = _json(capsys, ["sim", "wam", "--seed", "2", "--n-via", "3", "--json"])
    assert a == b and a != c
    assert a["ball_tracking_mm"]["max"] < 5.0  # a slow trajectory is tracked to millimetres
    assert 0.1 < a["ball_reported_vs_true_mm"]["median"] < 50.0  # the zero offsets move the reported ball


def test_sim_reach_small_grid_is_seeded(capsys):
    argv = ["sim", "reach", "--grid", "2", "2", "2", "--grow-m", "0", "--seed", "3", "--json"]
    a = _json(capsys, argv)
    assert a == _json(capsys, argv)
    region = a["results"]["hitting region"]
    assert region["reached"] == region["points"] == 8


def test_bench_robot_rows_are_consistent_measurements(capsys):
    r = _json(capsys, ["bench", "robot", "--n", "50", "--ticks", "40", "--repeats", "1", "--json"])
    assert (r["n"], r["ticks"], r["repeats"]) == (50, 40, 1)
    rows = {row["what"]: row for row in r["rows"]}
    # every row, each timed per its own unit: a batch of --n configurations, one call, --ticks ticks
    per_unit = {"fk_batch pinocchio loop": ("config", 50), "fk_batch numpy": ("config", 50), "fk_batch numba": ("config", 50),
                "link_points (9 frames)": ("config", 50), "jacobian (one q)": ("call", 1),
                "ik racket position+normal": ("solve", 1), "simulated ticks numpy": ("tick", 40),
                "simulated ticks numba": ("tick", 40)}
    assert list(rows) == list(per_unit)
    for what, (per, count) in per_unit.items():
        row = rows[what]
        assert row["per"] == per and 0 < row["median_s"] < 60, row
        assert row["per_item_us"] == pytest.approx(row["median_s"] / count * 1e6, rel=1e-12), row
    # speed-ups are the baseline row's median over this row's, against rows that exist
    for what, baseline in (("fk_batch numpy", "fk_batch pinocchio loop"), ("fk_batch numba", "fk_batch pinocchio loop"),
                           ("simulated ticks numba", "simulated ticks numpy")):
        assert rows[what]["speedup_vs"] == baseline
        assert rows[what]["speedup"] == pytest.approx(rows[baseline]["median_s"] / rows[what]["median_s"], rel=1e-12)
    assert all(rows[w]["speedup"] is None for w in ("fk_batch pinocchio loop", "jacobian (one q)", "simulated ticks numpy"))


def test_bad_config_is_one_line_error(capsys, tmp_path):
    path = tmp_path / "robot.yaml"
    path.write_text("format: rt2.robot\nversion: 1\nmount: {xyz_m: [1, 2]}\n")
    assert main(["sim", "wam", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "robot.yaml" in err and "mount_xyz_m must have 3 values" in err and "Traceback" not in err
    assert main(["bench", "robot", "--n", "0"]) == 2
