"""The page's suggestion rule and the selection study (``rt2 eval selection``)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from harness.cli import main as rt2_main
from harness.experiments.detector.coco import read_coco
from harness.label.selection import SelectionOptions, camera_of, frame_number, run_selection, time_order
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
    assert uncertainty([]) == 0.0  # nothing passed the detector: sure there is no ball, not 'cannot tell'
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
    with pytest.raises(ValueError, match=r"no frame number in the file name\(s\) \['snapshot.png'\]"):
        time_order([dataclasses.replace(labelled[0], path=tmp_path / "snapshot.png")] + labelled[1:])


def test_same_seed_same_figures_and_the_arms_use_what_they_say(synthetic_ball_coco):
    labelled = [li for li in read_coco(synthetic_ball_coco(30, 2)) if li.n_balls]  # 24 frames, every one with a ball
    opts = SelectionOptions(n_chosen=4, n_consecutive=8, pool_fraction=0.75, repeats=1, epochs=1, seed=1, from_model="none")
    model = hand_made_model()
    a = run_selection(labelled, model, opts, log=lambda line: None)
    b = run_selection(labelled, model, opts, log=lambda line: None)
    assert a == b
    chosen, consecutive = a["runs"]
    assert chosen["arm"] == "chosen" and sorted(chosen["frames"]) == a["chosen"] and len(a["chosen"]) == 4
    assert max(a["chosen"]) <= a["n_pool"] == 18 and a["n_held_out"] == 4  # 24 - 18 - a gap of 2
    f = consecutive["frames"]
    assert f == list(range(f[0], f[0] + 8)) and f[-1] <= 18
    assert a["trained_from"] == "scratch" and a["augment_copies"] == 0 and a["recordings"][0]["base"] is None


def two_camera_set(synthetic_ball_coco, tmp_path):
    """A COCO set of cameras cam0 and cam1 (30 frames each), the layout ``rt2 sim dataset`` writes."""
    import shutil

    from harness.experiments.detector.coco import write_coco

    out, images = tmp_path / "two", []
    out.mkdir()
    for cam, seed in (("cam0", 2), ("cam1", 3)):
        for li in read_coco(synthetic_ball_coco(30, seed)):
            path = out / li.path.name.replace("_cam0", f"_{cam}")
            shutil.copy(li.path, path)
            images.append(dataclasses.replace(li, path=path))
    write_coco(out, images)
    return out


def test_a_multi_camera_set_is_one_recording_per_camera_and_the_same_seed_gives_the_same_json(synthetic_ball_coco, tmp_path, capsys):
    data = two_camera_set(synthetic_ball_coco, tmp_path)
    model = tmp_path / "proposer.npz"
    hand_made_model().save(model)
    argv = ["eval", "selection", "--data", str(data), "--model", str(model), "--chosen", "4", "--consecutive", "6",
            "--repeats", "2", "--epochs", "1", "--from", "none", "--seed", "5"]
    assert rt2_main([*argv, "--json", str(tmp_path / "a.json")]) == 0
    assert rt2_main([*argv, "--json", str(tmp_path / "b.json")]) == 0
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    r = json.loads((tmp_path / "a.json").read_text())
    assert [c["camera"] for c in r["recordings"]] == ["cam0", "cam1"] and r["chosen"] is None
    assert len(r["runs"]) == 2 * 2 * 2 and {(x["camera"], x["arm"], x["seed"]) for x in r["runs"]} == {
        (c, a, s) for c in ("cam0", "cam1") for a in ("chosen", "consecutive") for s in (5, 6)}
    for rec in r["recordings"]:  # 30 frames: pool 18, gap 2, 10 held out; the consecutive arm starts at both ends of the pool
        assert (rec["n_pool"], rec["n_held_out"]) == (18, 10) and sorted(rec["consecutive_starts"]) == [1, 13]
    assert r["verdict"]["met"] in (True, False, None) and r["min"]["chosen"]["ours_recall"] <= r["median"]["chosen"]["ours_recall"]
    assert rt2_main([*argv, "--camera", "cam1", "--json", str(tmp_path / "c.json")]) == 0
    c = json.loads((tmp_path / "c.json").read_text())
    assert [x["camera"] for x in c["recordings"]] == ["cam1"] and c["chosen"] == c["recordings"][0]["chosen"]
    assert [x for x in r["runs"] if x["camera"] == "cam1"] == c["runs"]  # a camera's figures do not depend on the others
    assert "median [worst - best]" in capsys.readouterr().out


def test_camera_of_sim_and_label_names():
    assert camera_of("f000123_cam2.png") == "cam2"
    assert camera_of("cam1_s000017.png") == "cam1"
    assert camera_of("train_IMG_7370_MOV-0042_jpg.rf.3d324d4340266d607323009afe13e89a.jpg") == ""


def test_an_arm_without_a_ball_trains_no_model_and_scores_zero(synthetic_ball_coco):
    labelled = read_coco(synthetic_ball_coco(30, 2))
    no_ball = [li for li in labelled if not li.n_balls]
    import harness.label.selection as sel

    row = sel._train_and_score(no_ball, labelled[-4:], None, 0, SelectionOptions(epochs=1), 0)
    assert row["ours"] is None and "no ball boxes" in row["error"]
    assert sel._figures(row)["ours_recall"] == 0.0


#: hostile options of ``rt2 eval selection``: each refused with exit code 2 and one line naming the option or value
HOSTILE = [
    (["--consecutive", "40"], "need a pool of at least 40"),
    (["--pool-fraction", "1.5"], r"--pool-fraction must be in \(0, 1\)"),
    (["--pool-fraction", "0"], r"--pool-fraction must be in \(0, 1\)"),
    (["--pool-fraction", "nan"], r"--pool-fraction must be in \(0, 1\)"),
    (["--chosen", "1"], r"n_chosen \(--chosen\) must be an integer >= 3"),
    (["--consecutive", "2"], r"n_consecutive \(--consecutive\) must be an integer >= 3"),
    (["--repeats", "0"], r"repeats \(--repeats\) must be an integer >= 1"),
    (["--epochs", "0"], r"epochs \(--epochs\) must be an integer >= 1"),
    (["--gap", "-1"], r"gap_frames \(--gap\) must be an integer >= 0"),
    (["--gap", "100"], r"held out after a gap of 100"),
    (["--augment", "-3"], r"--augment\) must be an integer >= 0"),
    (["--from", "weights.txt"], r"--from must be a .npz weights file, 'shipped' or 'none'"),
    (["--from", "missing.npz"], r"missing.npz"),
    (["--camera", "cam7"], r"--camera cam7: not in the labelled set; its cameras: 'cam0'"),
    (["--camera", "cam0", "cam0"], r"--camera names a camera twice"),
    (["--thresholds", "best"], r"invalid choice: 'best'"),
    (["--ball-colour", "pink"], r"invalid choice: 'pink'"),
    (["--keep-base", "sometimes"], r"invalid choice: 'sometimes'"),
    (["--keep-base"], r"expected one argument"),
    (["--model", "nowhere.npz"], r"nowhere.npz"),
    (["--data", "/proc/no-such-set/annotations.json"], r"no-such-set"),
    (["--json", "/"], r"--json '/' is a folder"),
    (["--seed", "x"], r"invalid int value: 'x'"),
]


@pytest.mark.parametrize("argv, message", HOSTILE, ids=[" ".join(a) for a, _ in HOSTILE])
def test_bad_study_options_are_one_line(synthetic_ball_coco, capsys, argv, message):
    import re

    code = None
    try:
        code = rt2_main(["eval", "selection", "--data", str(synthetic_ball_coco(30, 2)), "--epochs", "1", "--chosen", "4", "--consecutive", "6", *argv])
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    assert code == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert err and re.search(message, err[-1]), captured.err
    assert "Traceback" not in captured.err and "training as rt2 train does" not in captured.out  # refused before any training


def test_fine_tuning_as_rt2_train_does_and_the_base_model_is_scored_too(synthetic_ball_coco, tmp_path):
    labelled = read_coco(synthetic_ball_coco(30, 2))
    base = tmp_path / "base.npz"
    hand_made_model().save(base)
    opts = SelectionOptions(n_chosen=4, n_consecutive=6, repeats=1, epochs=1, from_model=str(base), augment=1)
    r = run_selection(labelled, hand_made_model(), opts, log=lambda line: None)
    assert r["trained_from"] == str(base) and r["augment_copies"] == 1
    b = r["recordings"][0]["base"]
    assert 0.0 <= b["ours"]["recall"] <= 1.0 and b["topk"]["recall"] >= b["ours"]["recall"]
    assert all(isinstance(run["kept_base"], bool) for run in r["runs"] if not run["error"])  # rt2 train's guard, per training
