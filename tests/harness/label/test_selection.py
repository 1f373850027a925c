"""The page's suggestion rule and the selection study (``rt2 eval selection``)."""

from __future__ import annotations

import numpy as np
import pytest

from harness.cli import main as rt2_main
from harness.experiments.detector.coco import read_coco
from harness.label.selection import SelectionOptions, frame_number, run_selection, time_order
from harness.label.suggest import describe_image, suggest, uncertainty
from tracker.detection.synthetic import hand_made_model


# -- the rule -------------------------------------------------------------------------------------
def near_copies(rng, n_scenes=4, copies=6, d=32):
    """(n_scenes * copies, d) descriptors: scenes far apart, copies of one scene within 0.01."""
    scenes = rng.normal(size=(n_scenes, d))
    return np.repeat(scenes, copies, axis=0) + 0.01 * rng.normal(size=(n_scenes * copies, d))


def test_suggestions_cover_every_scene_before_a_second_copy_of_any():
    rng = np.random.default_rng(0)
    x = near_copies(rng)
    picks = suggest(x, np.ones(len(x)), [], 4)
    assert sorted(i // 6 for i in picks) == [0, 1, 2, 3]
    # a labelled scene is not suggested again until every other scene is labelled
    picks = suggest(x, np.ones(len(x)), [0, 6], 2)
    assert sorted(i // 6 for i in picks) == [2, 3]


def test_uncertainty_breaks_ties_between_equally_new_frames():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])
    assert suggest(x, np.array([0.0, 0.1, 0.9]), [0], 1) == [2]
    assert suggest(x, np.array([0.0, 0.9, 0.1]), [0], 1) == [1]


def test_uncertainty_is_one_minus_the_score_margin():
    assert uncertainty([]) == 1.0
    assert uncertainty([0.9]) == pytest.approx(0.1)
    assert uncertainty([0.6, 0.9]) == pytest.approx(0.7)


def test_descriptor_ignores_exposure_scale_and_tells_scenes_apart():
    rng = np.random.default_rng(1)
    a = rng.integers(20, 120, (48, 64, 3), dtype=np.uint8)
    b = rng.integers(20, 120, (48, 64, 3), dtype=np.uint8)
    da, db = describe_image(a), describe_image(b)
    assert da.shape == (16 * 12 * 3,) and np.linalg.norm(da) == pytest.approx(1.0)
    assert np.linalg.norm(da - describe_image(a)) == 0.0
    assert np.linalg.norm(da - db) > 0.5


@pytest.mark.parametrize("args, message", [
    ((np.zeros((3, 2)), np.zeros(2), [], 1), r"need descriptors \(n, d\) and uncertainties \(n,\)"),
    ((np.zeros((3, 2)), np.zeros(3), [5], 1), r"labelled indices must be in \[0, 3\)"),
])
def test_suggest_refuses_bad_input(args, message):
    with pytest.raises(ValueError, match=message):
        suggest(*args)


def test_everything_labelled_gives_no_suggestion():
    assert suggest(np.eye(3), np.ones(3), [0, 1, 2], 5) == []


# -- the study -------------------------------------------------------------------------------------
def test_frame_numbers_of_roboflow_rt2_and_label_names():
    assert frame_number("train_IMG_7370_MOV-0042_jpg.rf.3d324d4340266d607323009afe13e89a.jpg") == 42
    assert frame_number("f000123_cam2.png") == 123
    assert frame_number("cam1_s000017.png") == 17
    assert frame_number("rally_f000004.png") == 4
    assert frame_number("snapshot.png") is None


def test_time_order_refuses_names_without_a_frame_number(synthetic_ball_coco, tmp_path):
    labelled = read_coco(synthetic_ball_coco(12, 4))
    assert [frame_number(li.path) for li in time_order(labelled[::-1])] == list(range(12))
    import dataclasses

    with pytest.raises(ValueError, match=r"no frame number in the file name\(s\) \['snapshot.png'\]"):
        time_order([dataclasses.replace(labelled[0], path=tmp_path / "snapshot.png")] + labelled[1:])


def test_same_seed_same_figures_and_the_arms_use_what_they_say(synthetic_ball_coco):
    labelled = [li for li in read_coco(synthetic_ball_coco(30, 2)) if li.n_balls]  # 24 frames, every one with a ball
    opts = SelectionOptions(n_chosen=4, n_consecutive=8, pool_fraction=0.75, repeats=1, epochs=1, seed=1)
    model = hand_made_model()
    a = run_selection(labelled, model, opts, log=lambda line: None)
    b = run_selection(labelled, model, opts, log=lambda line: None)
    assert a == b
    chosen, consecutive = a["runs"]
    assert chosen["arm"] == "chosen" and sorted(chosen["frames"]) == a["chosen"] and len(a["chosen"]) == 4
    assert max(a["chosen"]) <= a["n_pool"] == 18 and a["n_held_out"] == 6
    f = consecutive["frames"]
    assert f == list(range(f[0], f[0] + 8)) and f[-1] <= 18


@pytest.mark.parametrize("argv, message", [
    (["--consecutive", "40"], "need a pool of at least 40"),
    (["--pool-fraction", "1.5"], r"--pool-fraction must be in \(0, 1\)"),
    (["--chosen", "1"], "n_chosen must be an integer >= 3"),
])
def test_bad_study_options_are_one_line(synthetic_ball_coco, capsys, argv, message):
    import re

    assert rt2_main(["eval", "selection", "--data", str(synthetic_ball_coco(30, 2)), "--epochs", "1", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert re.search(message, err), err
