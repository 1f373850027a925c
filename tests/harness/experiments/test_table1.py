"""``rt2 sim table1``, the simulation rigs determinism, JSON, goals, bad input."""

from __future__ import annotations

import json
from math import comb

import numpy as np
import pytest

from harness.cli import main
from harness.sim.study_rigs import SIM_CAMERA_COUNTS, load_sim_rig, make_sim_rig
from tracker.synthetic import simulate_observations
from harness.experiments.studies.paper_tables import PAPER_TABLE1, failure_floor
from harness.experiments.studies.table1 import check_goals, format_table, run_table1

KEYS = {"cameras", "outlier_rate", "method", "mean_error_cm", "median_error_cm", "gross_error_rate", "failure_rate", "failure_floor"}


# -- smoke: the command line ----------------------------------------------------------------------------
def test_cli_prints_the_table_and_writes_json(tmp_path, capsys):
    out = tmp_path / "t1.json"
    code = main(["sim", "table1", "--trials", "60", "--cameras", "4", "8", "--outlier-rates", "10", "50",
                 "--json", str(out), "--no-progress"])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "| c | p_o | paper E cm | paper F |" in text and "| 4 | 10% | 0.84 | 2.00% |" in text
    assert "F <= floor + 0.5 percentage points" in text
    rows = json.loads(out.read_text())
    assert len(rows) == 2 * 2 * 2
    for r in rows:
        assert KEYS <= set(r) and r["method"] in ("paper", "ours") and r["trials"] == 60
        assert 0 <= r["failure_rate"] <= 1 and 0 <= r["gross_error_rate"] <= 1
    assert {(r["cameras"], r["outlier_rate"]) for r in rows} == {(4, 0.1), (4, 0.5), (8, 0.1), (8, 0.5)}


# -- determinism: seed, not workers --------------------------------------------------------------------
def test_same_seed_same_rows_whatever_the_workers():
    kw = dict(trials=700, seed=5, progress=False)  # 2 chunks per cell
    one = run_table1((4, 8), (0.25,), workers=1, **kw)
    two = run_table1((4, 8), (0.25,), workers=2, **kw)
    assert one == two
    assert run_table1((8,), (0.25,), workers=1, **kw) == [r for r in one if r["cameras"] == 8]  # cells are independent
    other = run_table1((4, 8), (0.25,), workers=1, trials=700, seed=6, progress=False)
    assert other != one


# -- statistics of the study -------------------------------------------------------------------------
def test_failure_floor_formula():
    assert failure_floor(4, 0.5) == pytest.approx(5 / 16)
    for c, p in ((4, 0.1), (8, 0.25), (15, 0.5)):  # P(Binomial(c, 1 - p) < 2)
        exact = sum(comb(c, k) * (1 - p) ** k * p ** (c - k) for k in range(2))
        assert failure_floor(c, p) == pytest.approx(exact)


def test_ours_meets_the_floor_and_beats_algorithm_2_on_gross_errors():
    rows = run_table1((4,), (0.5,), trials=2000, seed=1, progress=False)
    paper, ours = rows
    sd = np.sqrt(ours["failure_floor"] * (1 - ours["failure_floor"]) / 2000)
    assert ours["failure_rate"] <= ours["failure_floor"] + 4 * sd  # fails only without 2 inliers
    assert ours["gross_error_rate"] < paper["gross_error_rate"] / 3
    assert ours["median_error_cm"] < 1.0


def test_observations_follow_the_paper_recipe():
    rig = load_sim_rig(8)
    X, uv, out = simulate_observations(rig, 4000, 0.25, np.random.default_rng(0))
    n = out.size
    assert abs(out.mean() - 0.25) < 4 * np.sqrt(0.25 * 0.75 / n)
    lo, hi = rig.workspace_m
    assert ((X >= lo) & (X <= hi)).all()
    res = (uv - np.swapaxes(rig.project(X), 0, 1))[~out]
    assert res.std() == pytest.approx(1.3, rel=0.03) and abs(res.mean()) < 0.05
    size = rig.stacked()["image_size"]
    assert ((uv[out] >= -0.5) & (uv[out] <= np.broadcast_to(size, uv.shape)[out] - 0.5)).all()


# -- the goal checker can say "not met" ----------------------------------------------------------------------
def test_goal_checker_flags_misses():
    rows = run_table1((4, 8), (0.1,), trials=100, seed=0, progress=False)
    assert len(check_goals(rows)) == 4 and all(ok for _, ok, _ in check_goals(rows))
    assert len(check_goals([r for r in rows if r["cameras"] == 4])) == 3  # no c >= 8 cell: goal n/a
    bad = [dict(r, failure_rate=0.5, median_error_cm=9.0, gross_error_rate=0.01) if r["method"] == "ours" else r for r in rows]
    verdicts = {g: ok for g, ok, _ in check_goals(bad)}
    assert not any(verdicts.values())
    assert "0.84" in format_table(rows)  # the published E beside ours


# -- the rigs on disk are the documented formula ------------------------------------------------------------
@pytest.mark.parametrize("c", SIM_CAMERA_COUNTS)
def test_rig_files_match_the_generator(c):
    disk, fresh = load_sim_rig(c), make_sim_rig(c)
    assert disk.names == fresh.names and np.allclose(disk.workspace_m, fresh.workspace_m)
    for key in ("K", "dist8", "R", "t", "image_size"):
        assert np.allclose(disk.stacked()[key], fresh.stacked()[key], rtol=0, atol=1e-12), key
    # every camera sees the whole workspace box
    lo, hi = disk.workspace_m
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    uv = disk.project(corners)
    assert all(cam.in_image(uv[i]).all() for i, cam in enumerate(disk))


def test_published_table_is_complete():
    assert len(PAPER_TABLE1) == 20 and PAPER_TABLE1[(30, 0.5)] == (0.35, 0.0)


# -- bad input ----------------------------------------------------------------------------------------------
def test_bad_arguments(capsys):
    with pytest.raises(ValueError, match=r"--trials must be >= 1, got 0"):
        run_table1((4,), (0.1,), trials=0, progress=False)
    with pytest.raises(ValueError, match=r"every rate must be in \[0, 100\] %, got 150"):
        run_table1((4,), (1.5,), trials=10, progress=False)
    with pytest.raises(ValueError, match=r"--seed must be >= 0, got -1"):
        run_table1((4,), (0.1,), trials=10, seed=-1, progress=False)
    with pytest.raises(ValueError, match=r"--eps-px must be a positive number, got 0"):
        run_table1((4,), (0.1,), trials=10, eps_px=0, progress=False)
    with pytest.raises(ValueError, match=r"--workers must be >= 1"):
        run_table1((4,), (0.1,), trials=10, workers=0, progress=False)
    assert main(["sim", "table1", "--cameras", "7", "--trials", "5", "--no-progress"]) == 2  # no such rig file
    assert "sim_c7.yaml" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"n_cams must be an integer >= 2, got 1"):
        make_sim_rig(1)
    with pytest.raises(ValueError, match=r"p_outlier must be in \[0, 1\], got 2"):
        simulate_observations(make_sim_rig(4), 3, 2, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"rng must be a numpy.random.Generator, got int"):
        simulate_observations(make_sim_rig(4), 3, 0.1, 0)
