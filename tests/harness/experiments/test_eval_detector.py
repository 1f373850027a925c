"""rt2 eval detector: the metric definitions on hand-made cases, a run on a synthetic set, JSON, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import read_coco
from harness.experiments.detector.scores import operating_points, score_detections
from harness.experiments.studies.eval_detector import EVAL_METHODS, evaluate
from tracker.detection.synthetic import hand_made_model

JSON_KEYS = {"method", "recall", "outlier_rate", "median_center_error_px", "p95_center_error_px"}


# -- the definitions ---------------------------------------------------------------------------------
def test_inlier_within_two_radii_outlier_beyond():
    c = [np.array([[50.0, 50.0]])]
    d = [np.array([8.0])]  # radius 4: two radii = 8 px
    s = score_detections("x", c, d, [np.array([[57.9, 50.0]])])
    assert s.recall == 1.0 and s.outlier_rate == 0.0 and s.median_center_error_px == pytest.approx(7.9)
    s = score_detections("x", c, d, [np.array([[58.1, 50.0]])])
    assert s.recall == 0.0 and s.outlier_rate == 1.0 and np.isnan(s.median_center_error_px)


def test_no_ball_images_and_misses():
    centers = [np.zeros((0, 2)), np.array([[10.0, 10.0]]), np.array([[30.0, 30.0]]), np.zeros((0, 2))]
    diams = [np.zeros(0), np.array([10.0]), np.array([10.0]), np.zeros(0)]
    dets = [np.array([[5.0, 5.0]]), np.array([[10.5, 10.0]]), np.zeros((0, 2)), np.zeros((0, 2))]
    s = score_detections("x", centers, diams, dets)
    assert s.n_balls == 2 and s.recall == 0.5
    assert s.n_detections == 2 and s.n_outliers == 1 and s.outlier_rate == 0.5  # a detection where no ball is
    assert s.median_center_error_px == pytest.approx(0.5)


def test_topk_any_candidate_hits_every_stray_candidate_counts():
    centers = [np.array([[10.0, 10.0]])]
    diams = [np.array([10.0])]
    dets = [np.array([[80.0, 80.0], [10.2, 10.0], [np.nan, np.nan]])]  # NaN padding is not a detection
    s = score_detections("topk", centers, diams, dets)
    assert s.recall == 1.0 and s.n_detections == 2 and s.outlier_rate == 0.5
    assert s.median_center_error_px == pytest.approx(0.2)


def test_outlier_breakdown():
    centers = [np.zeros((0, 2)), np.zeros((0, 2)), np.array([[10.0, 10.0]])]
    diams = [np.zeros(0), np.zeros(0), np.array([10.0])]
    dets = [np.array([[5.0, 5.0], [9.0, 9.0]]), np.zeros((0, 2)), np.array([[10.0, 10.0], [50.0, 50.0]])]
    s = score_detections("x", centers, diams, dets)
    assert s.n_outliers == 3 and s.n_outliers_with_ball == 1
    assert s.n_images_without_ball == 2 and s.n_false_alarm_images == 1


# -- the operating points: the best recall under an outlier bound at a stricter threshold -------------------
def _points_case(kinds_scores, bounds=(0.02, 0.25)):
    """One ball (d 10 at (50, 50)) per image; per image (kind, score): "hit" on it, "out" off it, "none" no detection."""
    c = [np.array([[50.0, 50.0]]) for _ in kinds_scores]
    d = [np.array([10.0]) for _ in kinds_scores]
    uv = {"hit": np.array([[50.0, 50.0]]), "out": np.array([[0.0, 0.0]]), "none": np.zeros((0, 2))}
    return operating_points(c, d, [uv[k] for k, _ in kinds_scores], [s for _, s in kinds_scores], bounds=bounds)


def test_operating_points_take_the_highest_threshold_with_the_most_balls_within_each_bound():
    p = _points_case([("hit", 0.91), ("out", 0.8), ("hit", 0.7), ("hit", 0.6), ("hit", 0.5), ("none", float("nan"))])
    # <= 2 %: the first image alone (the outlier at 0.8 comes next); a threshold in (0.8, 0.91], short: 0.9
    assert p[0.02] == {"recall": pytest.approx(1 / 6), "outlier_rate": 0.0, "threshold": 0.9, "n_detections": 1}
    # <= 25 %: all five detections (one outlier in five); no lower score seen: the lowest kept, at 6 decimals
    assert p[0.25] == {"recall": pytest.approx(4 / 6), "outlier_rate": pytest.approx(0.2), "threshold": 0.5, "n_detections": 5}


def test_operating_points_keep_a_score_whole_and_say_none_where_no_threshold_fits():
    # two candidates of one score are kept together: 1 outlier in 2 is over 25 %, so only the 0.95 image counts
    p = _points_case([("hit", 0.95), ("hit", 0.6), ("out", 0.6)])
    assert p[0.25]["n_detections"] == 1 and p[0.25]["threshold"] == 0.9
    p = _points_case([("out", 0.9), ("hit", 0.5)], bounds=(0.02,))
    assert p[0.02] == {"recall": 0.0, "outlier_rate": 0.0, "threshold": None, "n_detections": 0}
    assert _points_case([("hit", 0.7)])[0.02]["threshold"] == 0.7  # the lowest kept itself, no lower score
    assert _points_case([("hit", 0.654321987), ("out", 0.6543)])[0.02]["threshold"] == 0.65432  # in (0.6543, 0.654321987]


def test_small_balls_not_in_recall_but_not_outliers():
    s = score_detections("x", [np.array([[10.0, 10.0]])], [np.array([4.0])], [np.array([[11.0, 10.0]])], min_diameter_px=6)
    assert s.n_balls == 0 and np.isnan(s.recall) and s.outlier_rate == 0.0


# -- accuracy on a synthetic held-out set ------------------------------------------------------------
def test_evaluate_hand_made_model_on_synthetic_set(synthetic_ball_coco):
    labelled = read_coco(synthetic_ball_coco(30, 1))
    scores = evaluate(hand_made_model(), labelled, progress=False)
    assert [s.method for s in scores] == list(EVAL_METHODS)
    by = {s.method: s for s in scores}
    assert by["paper"].n_balls == 24 and by["paper"].n_images == 30
    for m in EVAL_METHODS:
        assert by[m].recall >= 0.95 and by[m].median_center_error_px < 0.3
    assert by["paper"].outlier_rate <= 0.05
    assert by["topk"].recall >= by["ours"].recall
    assert by["topk"].n_detections >= by["ours"].n_detections


# -- command line, JSON and determinism --------------------------------------------------------------
def _model_and_data(synthetic_ball_coco, tmp_path):
    """The hand-made model saved as a file, and a 30-image synthetic COCO set."""
    return hand_made_model().save(tmp_path / "hand.npz"), str(synthetic_ball_coco(30, 1))


def test_cli_json(synthetic_ball_coco, tmp_path, capsys):
    model, data = _model_and_data(synthetic_ball_coco, tmp_path)
    out1, out2 = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--json", str(out1)]) == 0
    table = capsys.readouterr().out
    assert "paper" in table and "topk" in table and "recall" in table
    rows = json.loads(out1.read_text())
    assert [r["method"] for r in rows] == ["paper", "ours", "topk"]
    assert set(rows[0]) == set(rows[2]) == JSON_KEYS and set(rows[1]) == JSON_KEYS | {"operating_points"}
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--json", str(out2)]) == 0
    assert out1.read_text() == out2.read_text()  # same data, same figures
    # ours' best recall at <= 2 % outliers, and the threshold that gives it: the run at that threshold has those figures
    point = rows[1]["operating_points"]["0.02"]
    assert set(rows[1]["operating_points"]) == {"0.01", "0.02"} and point["outlier_rate"] <= 0.02 and point["recall"] > 0
    assert f"<= 2 % outliers: recall {100 * point['recall']:.2f} %" in table
    assert "(--t-high " in table or "this run's threshold" in table
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--t-high", str(point["threshold"]), "--json", str(out2)]) == 0
    strict = json.loads(out2.read_text())[1]
    assert strict["recall"] == pytest.approx(point["recall"]) and strict["outlier_rate"] == pytest.approx(point["outlier_rate"])


def test_cli_colour_selection_and_figure(synthetic_ball_coco, tmp_path, capsys):
    model, data = _model_and_data(synthetic_ball_coco, tmp_path)
    out, fig = tmp_path / "w.json", tmp_path / "fig.png"
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--figure", str(fig)]) == 0
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--ball-colour", "white", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert all(r["recall"] is None for r in rows)  # no white balls: recall undefined (null), every detection an outlier
    assert rows[0]["outlier_rate"] == 1.0
    assert "white balls" in capsys.readouterr().out
    import cv2

    assert cv2.imread(str(fig)).shape[1] == 2 * 3 * 160  # image | probability | detection, scaled 2x


def test_cli_scores_the_models_own_colour_by_default(synthetic_ball_coco, tmp_path, capsys):
    import dataclasses

    from tracker import BallSegmentationModel

    model, data = _model_and_data(synthetic_ball_coco, tmp_path)
    white = dataclasses.replace(BallSegmentationModel.load(model), ball_colour="white").save(tmp_path / "white.npz")
    default, explicit = tmp_path / "d.json", tmp_path / "e.json"
    assert main(["eval", "detector", "--data", data, "--model", str(white), "--json", str(default)]) == 0
    out = capsys.readouterr().out
    assert "white balls" in out and "the model's own colour" in out
    assert main(["eval", "detector", "--data", data, "--model", str(white), "--ball-colour", "white", "--json", str(explicit)]) == 0
    assert default.read_text() == explicit.read_text()
    # a model whose colour is not recorded scores every ball, as before
    assert BallSegmentationModel.load(model).ball_colour == "any"


def _two_camera_set(synthetic_ball_coco, tmp_path):
    """The 30-image set with a ``camera`` field on every image (its file names say cam0): the ball-free images and
    every third other one "right", the rest "left"."""
    import shutil

    src = synthetic_ball_coco(30, 1)
    dst = tmp_path / "two"
    shutil.copytree(src, dst)
    coco = json.loads((dst / "annotations.json").read_text())
    with_ball = {a["image_id"] for a in coco["annotations"]}
    for k, im in enumerate(coco["images"]):
        im["camera"] = "right" if im["id"] not in with_ball or k % 3 == 0 else "left"
    (dst / "annotations.json").write_text(json.dumps(coco))
    return dst


def test_cli_per_camera_rows_and_the_camera_option(synthetic_ball_coco, tmp_path, capsys):
    model, _ = _model_and_data(synthetic_ball_coco, tmp_path)
    data = _two_camera_set(synthetic_ball_coco, tmp_path)
    assert {li.camera for li in read_coco(data)} == {"left", "right"}  # the field, not the file names' cam0
    out = tmp_path / "all.json"
    assert main(["eval", "detector", "--data", str(data), "--model", str(model), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "per camera:" in printed and "\nleft     ours " in printed and "\nright    topk " in printed
    rows = {r["method"]: r for r in json.loads(out.read_text())}
    whole = {s.method: s for s in evaluate(hand_made_model(), read_coco(synthetic_ball_coco(30, 1)), progress=False)}
    for m in EVAL_METHODS:
        split = rows[m]["per_camera"]
        assert set(split) == {"left", "right"}
        assert sum(c["n_images"] for c in split.values()) == 30 and sum(c["n_balls"] for c in split.values()) == whole[m].n_balls
        assert sum(c["n_detections"] for c in split.values()) == whole[m].n_detections
        assert rows[m]["recall"] == pytest.approx(whole[m].recall)  # the whole set's figures are unchanged by the split
    for name in ("left", "right"):
        one = tmp_path / f"{name}.json"
        assert main(["eval", "detector", "--data", str(data), "--model", str(model), "--camera", name, "--json", str(one)]) == 0
        assert "per camera" not in capsys.readouterr().out  # one camera: no split
        for r in json.loads(one.read_text()):
            assert set(r) - {"operating_points"} == JSON_KEYS
            assert {k: r[k] for k in JSON_KEYS - {"method"}} == {k: rows[r["method"]]["per_camera"][name][k] for k in JSON_KEYS - {"method"}}


@pytest.mark.parametrize("field, read", [("cam2", "cam2"), (3, "3"), ({"make": "x"}, None), (True, None), ("", None), (None, None)])
def test_coco_camera_field_is_a_name_or_not_read(synthetic_ball_coco, tmp_path, field, read):
    import shutil

    dst = tmp_path / "c"
    shutil.copytree(synthetic_ball_coco(30, 1), dst)
    coco = json.loads((dst / "annotations.json").read_text())
    coco["images"][0]["camera"] = field
    (dst / "annotations.json").write_text(json.dumps(coco))
    assert read_coco(dst)[0].camera == read


def test_camera_selection_of_a_set_that_names_no_camera():
    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.detector.subsets import image_camera, select_cameras

    one = [LabelledImage(f"frame_{i:03d}.jpg", 64, 48, np.zeros((0, 4)), np.zeros((0, 2))) for i in range(3)]
    assert [image_camera(li) for li in one] == ["", "", ""]
    with pytest.raises(ValueError, match=r"--camera cam0: not in the labelled set; its cameras: none \(the COCO image field 'camera'"):
        select_cameras(one, ["cam0"])


# -- bad input ---------------------------------------------------------------------------------------
def test_bad_inputs(tmp_path, capsys, synthetic_ball_coco):
    with pytest.raises(ValueError, match="one entry per image"):
        score_detections("x", [np.zeros((0, 2))], [], [])
    with pytest.raises(ValueError, match="unknown method 'best'"):
        evaluate(hand_made_model(), [], methods=("best",))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"xx")
    assert main(["eval", "detector", "--data", str(synthetic_ball_coco(30, 1)), "--model", str(bad)]) == 2
    assert "bad.npz" in capsys.readouterr().err
    model = hand_made_model().save(tmp_path / "hand.npz")
    assert main(["eval", "detector", "--data", str(tmp_path / "nowhere"), "--model", str(model)]) == 2
    assert "nowhere" in capsys.readouterr().err
    data = str(synthetic_ball_coco(30, 1))  # its file names say cam0
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--camera", "cam0", "cam4"]) == 2
    assert "--camera cam4: not in the labelled set; its cameras: cam0" in capsys.readouterr().err
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--learned-threshold", "0.3"]) == 2
    assert "--learned-threshold 0.3: the model has no learned stage" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "1", "1.5", "-0.2", "nan", "abc", ""])
def test_learned_threshold_refuses_what_is_no_probability(synthetic_ball_coco, capsys, value):
    args = ["eval", "detector", "--data", str(synthetic_ball_coco(30, 1)), "--model", "data/models/ball_seg_white.npz", "--learned-threshold", value]
    assert main(args) == 2
    assert f"--learned-threshold must be a probability in (0, 1) or 'track', got {value!r}" in capsys.readouterr().err


@pytest.mark.parametrize("option, message", [
    (["--max-candidates", "0"], "--max-candidates must be a positive number of candidates, got 0"),
    (["--max-images", "0"], "--max-images must be a positive number of images, got 0"),
    (["--max-images", "-3"], "--max-images must be a positive number of images, got -3"),
    (["--learned-threshold", "1.5"], "--learned-threshold must be a probability in (0, 1) or 'track', got '1.5'"),
    (["--ball-diameter-px", "40:10"], "--ball-diameter-px must be LO:HI with 0 < LO <= HI"),
    (["--t-high", "2"], "--t-high must be a probability in (0, 1), got 2"),
])
def test_option_values_are_refused_before_any_image_is_read(synthetic_ball_coco, tmp_path, capsys, option, message):
    """A wrong option value is named at once, not after the images were read and sorted by colour (slow on a large
    set): a set whose images cannot be read shows which comes first."""
    import shutil

    data = tmp_path / "unreadable"
    shutil.copytree(synthetic_ball_coco(30, 1), data)
    for image in data.glob("*.png"):
        image.write_bytes(b"not a png")
    args = ["eval", "detector", "--data", str(data), "--model", "data/models/ball_seg_white.npz", *option]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert main(["eval", "detector", "--data", str(data), "--model", "data/models/ball_seg_white.npz"]) == 2
    assert "f000000_cam0.png" in capsys.readouterr().err  # the images' own error, where the options are right


@pytest.mark.parametrize("model, value, message", [
    ("data/models/ball_seg_white.npz", "-1", "--coarse-side must be 0 (one pass) or a side of 64 px up to below the stage's full scale (960 px), got -1"),
    ("data/models/ball_seg_white.npz", "63", "--coarse-side must be 0 (one pass) or a side of 64 px up to below the stage's full scale (960 px), got 63"),
    ("data/models/ball_seg_white.npz", "960", "--coarse-side must be 0 (one pass) or a side of 64 px up to below the stage's full scale (960 px), got 960"),
    ("data/models/ball_seg_default.npz", "640", "--coarse-side 640: the model has no learned stage"),
    ("data/models/ball_seg_white.npz", "--coarse-context=-1", "--coarse-context must be 0 to 256 network pixels around a coarse peak's window, got -1"),
    ("data/models/ball_seg_white.npz", "--coarse-context=257", "--coarse-context must be 0 to 256 network pixels around a coarse peak's window, got 257"),
    ("data/models/ball_seg_default.npz", "--coarse-context=24", "--coarse-context 24: the model has no learned stage"),
])
def test_coarse_side_refuses_what_the_stage_cannot_search(synthetic_ball_coco, capsys, model, value, message):
    option = [value] if value.startswith("--") else ["--coarse-side", value]
    args = ["eval", "detector", "--data", str(synthetic_ball_coco(30, 1)), "--model", model, *option]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_cli_thresholds_override_the_model(synthetic_ball_coco, tmp_path, capsys):
    model, data = _model_and_data(synthetic_ball_coco, tmp_path)
    base, strict = tmp_path / "base.json", tmp_path / "strict.json"
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--json", str(base)]) == 0
    assert main(["eval", "detector", "--data", data, "--model", str(model), "--t-high", "0.999999", "--json", str(strict)]) == 0
    assert "T_h=0.999999" in capsys.readouterr().out
    b, s = json.loads(base.read_text()), json.loads(strict.read_text())
    assert s[1]["recall"] < b[1]["recall"]  # a T_h no ball reaches loses balls
    for args, message in ((["--t-high", "1.5"], "--t-high must be a probability in (0, 1), got 1.5"), (["--t-low", "0.99999999"], "need T_l < T_h")):
        assert main(["eval", "detector", "--data", data, "--model", str(model), *args]) == 2
        assert message in capsys.readouterr().err


def test_ball_diameter_widens_the_area_and_large_balls_are_named(synthetic_ball_coco, tmp_path, capsys):
    """A model whose accepted blob area is smaller than the labelled balls rejects them whatever their colour:
    the output says so, and --ball-diameter-px (the balls' sizes when no rig says them) lets them through."""
    import dataclasses

    from harness.experiments.studies.eval_detector import area_from_diameters

    small = dataclasses.replace(hand_made_model(), area_range_px=np.array([2.0, 12.0]))  # balls of 6-14 px make larger blobs
    path = small.save(tmp_path / "small.npz")
    data = str(synthetic_ball_coco(30, 0))
    narrow, wide = tmp_path / "narrow.json", tmp_path / "wide.json"
    assert main(["eval", "detector", "--data", data, "--model", str(path), "--ball-colour", "any", "--json", str(narrow)]) == 0
    out = capsys.readouterr().out
    assert "labelled balls are larger than the accepted blob area (max 12 px" in out and "--ball-diameter-px" in out
    assert main(["eval", "detector", "--data", data, "--model", str(path), "--ball-colour", "any", "--ball-diameter-px", "6:14",
                 "--json", str(wide)]) == 0
    assert "accepted blob area 2-154 px (--ball-diameter-px 6:14" in capsys.readouterr().out
    n, w = json.loads(narrow.read_text()), json.loads(wide.read_text())
    assert n[1]["method"] == "ours" and w[1]["recall"] > n[1]["recall"] + 0.5
    assert n[0] == w[0]  # the paper's Algorithm 1 has no shape test
    assert area_from_diameters(small, (1, 2)) == (1, 12)  # widens, never narrows
    for bad in ("20", "a:b", "0:10", "30:20"):
        assert main(["eval", "detector", "--data", data, "--model", str(path), "--ball-diameter-px", bad]) == 2
        assert "--ball-diameter-px must be LO:HI" in capsys.readouterr().err


def test_probability_figure_has_titles_a_legend_and_says_no_detection(synthetic_ball_coco, tmp_path):
    import dataclasses

    import cv2

    from harness.experiments.studies.eval_detector import probability_figure

    labelled = read_coco(synthetic_ball_coco(30, 1))
    model = hand_made_model()
    blind = dataclasses.replace(model, bias=-50.0)  # every probability ~0: neither method finds anything

    def yellow_text(path):  # "no detection" is written in yellow with a dark outline, in the detection column only
        rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        mask = (rgb[..., 0] > 230) & (rgb[..., 1] > 230) & (rgb[..., 2] < 40)
        return rgb, mask

    rgb, mask = yellow_text(probability_figure(blind, labelled, tmp_path / "blind.png"))
    assert mask[:, 2 * 320 :].sum() > 50 and not mask[:, : 2 * 320].any()
    title_band, legend_band = rgb[:28], rgb[-26:]
    assert (title_band < 100).all(axis=2).sum() > 100 and (legend_band < 100).all(axis=2).sum() > 100  # dark text on white
    _, seen = yellow_text(probability_figure(model, labelled, tmp_path / "sees.png"))
    assert not seen.any()  # where the model finds the ball, no "no detection"


# -- the motion cue: a fixed camera's sequence ---------------------------------------------------------
ORANGE = (245, 120, 20)


def _sequence(tmp_path, times, name="seq", camera="cam0"):
    """A fixed camera's frames (96x128, noise) with a still ball-sized orange lamp and an orange ball moving 4 px a
    frame; frame ``f`` at ``times[f]`` seconds (None: no ``time_s`` field)."""
    import cv2

    from harness.experiments.detector.coco import LabelledImage, write_coco
    from tracker.detection.synthetic import draw_disk

    out = tmp_path / name
    out.mkdir()
    labelled, extra = [], []
    for f, t in enumerate(times):
        img = np.clip(np.random.default_rng([5, f]).normal(100, 3, (96, 128, 3)), 0, 255).astype(np.uint8)
        draw_disk(img, (30.0, 40.0), 12.0, ORANGE)
        c = np.array([[60.0 + 4 * f, 60.0]])
        draw_disk(img, c[0], 10.0, ORANGE)
        path = out / f"frame_{f:04d}.png"
        cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        labelled.append(LabelledImage(path, 128, 96, np.array([[c[0, 0] - 4.5, c[0, 1] - 4.5, 10.0, 10.0]]), c))
        extra.append({"camera": camera} | ({} if t is None else {"time_s": t}))
    write_coco(out, labelled, image_extra=extra)
    return out


def test_motion_cue_drops_the_still_lamp_of_a_fixed_cameras_sequence(tmp_path, capsys):
    model = str(hand_made_model().save(tmp_path / "hand.npz"))
    data = str(_sequence(tmp_path, [0.005 * f for f in range(12)]))
    runs = {}
    for cue in ([], ["--motion-cue"]):
        out = tmp_path / f"cue{len(cue)}.json"
        assert main(["eval", "detector", "--data", data, "--model", model, "--json", str(out), *cue]) == 0
        runs[bool(cue)] = ({r["method"]: r for r in json.loads(out.read_text())}, capsys.readouterr().out)
    (plain, _), (cued, printed) = runs[False], runs[True]
    assert "motion_cue" not in plain["topk"] and "motion_cue" not in cued["paper"]  # added only where it was used
    assert cued["topk"]["motion_cue"] == cued["ours"]["motion_cue"]
    info = cued["topk"]["motion_cue"]
    assert info["sequences"] == 1 and info["images_without_cue"] == 1  # the first frame starts the background
    assert info["candidates_dropped"] >= 11  # the lamp, in every later frame
    assert "motion cue: 1 camera sequence(s) searched in time order (0 earlier frame(s) shown first)" in printed
    assert plain["topk"]["outlier_rate"] >= 0.4  # without the cue the lamp is a candidate in every frame
    assert cued["topk"]["recall"] == plain["topk"]["recall"] == 1.0
    assert cued["topk"]["outlier_rate"] <= 1 / 12 + 1e-9 < plain["topk"]["outlier_rate"]  # only the first frame's lamp
    assert cued["ours"]["recall"] >= plain["ours"]["recall"]
    # a time range: the frame before it starts the background, so every scored frame has a cue
    out = tmp_path / "range.json"
    assert main(["eval", "detector", "--data", data, "--model", model, "--json", str(out), "--motion-cue", "--time-range", "6:"]) == 0
    assert "(1 earlier frame(s) shown first)" in capsys.readouterr().out
    rows = {r["method"]: r for r in json.loads(out.read_text())}
    assert rows["topk"]["motion_cue"]["images_without_cue"] == 0 and rows["topk"]["outlier_rate"] == 0.0


@pytest.mark.parametrize("times, without_cue", [
    ([0.005 * f for f in range(8)], 1),
    ([0.005 * f for f in range(4)] * 2, 2),  # the clock went back: another recording, the background starts again
    ([0.005 * f for f in range(4)] + [2.0 + 0.005 * f for f in range(4)], 2),  # a gap of more than max_gap_s
    ([None] * 8, 1),  # no time stamps: the file names' order, no gaps known
])
def test_motion_cue_starts_again_where_the_sequence_breaks(tmp_path, times, without_cue):
    from tracker.motion import MotionOptions

    scores = evaluate(hand_made_model(), read_coco(_sequence(tmp_path, times)), progress=False, motion_cue=MotionOptions(regions=False))
    assert {s.method: s for s in scores}["topk"].motion_cue["images_without_cue"] == without_cue


def test_camera_sequences_are_per_camera_in_time_order():
    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.detector.subsets import camera_sequences, frames_before

    names = ["f000002_cam1", "f000001_cam0", "f000010_cam1", "f000002_cam0", "f000001_cam1"]
    images = [LabelledImage(f"{n}.png", 64, 48, np.zeros((0, 4)), np.zeros((0, 2))) for n in names]
    assert camera_sequences(images) == [[4, 0, 2], [1, 3]]
    assert [li.path.stem for li in frames_before(images, [images[2], images[3]])] == ["f000002_cam1", "f000001_cam0"]
    assert frames_before(images, images) == []


@pytest.mark.parametrize("value, error", [("0.5", "must be a finite number of seconds"), (True, "must be a finite number"),
                                          (float("nan"), "must be a finite number"), ([0.1], "must be a finite number")])
def test_coco_time_s_must_be_seconds(tmp_path, value, error):
    data = _sequence(tmp_path, [0.0, 0.01])
    coco = json.loads((data / "annotations.json").read_text())
    coco["images"][1]["time_s"] = value
    (data / "annotations.json").write_text(json.dumps(coco))
    with pytest.raises(ValueError, match=rf"annotations.json: image id \d+: field 'time_s' {error}"):
        read_coco(data)


def test_coco_time_s_is_read(tmp_path):
    assert [li.time_s for li in read_coco(_sequence(tmp_path, [0, 0.01, None]))] == [0.0, 0.01, None]


def test_motion_cue_refuses_a_figure(tmp_path, capsys):
    model = str(hand_made_model().save(tmp_path / "hand.npz"))
    data = str(_sequence(tmp_path, [0.0, 0.01]))
    assert main(["eval", "detector", "--data", data, "--model", model, "--motion-cue", "--figure", str(tmp_path / "f.png")]) == 2
    assert "--figure draws single images, without the motion cue" in capsys.readouterr().err


def test_a_learned_stage_is_warned_of_balls_wider_than_it_was_trained_on_not_of_the_filters_area():
    from pathlib import Path

    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.studies.eval_detector import too_large
    from tracker import BallSegmentationModel

    white = BallSegmentationModel.load(Path(__file__).resolve().parents[3] / "data" / "models" / "ball_seg_white.npz")
    rally = LabelledImage("r.jpg", 1920, 1080, [[100, 100, 41, 41]], [[120, 120]])  # 41 px, shrunk by 2 for the network: 20.5
    near = LabelledImage("n.jpg", 640, 480, [[100, 100, 120, 120]], [[160, 160]])  # 120 px at full scale: wider than 48
    assert too_large(white, [rally], 6.0) == (0, 1, 0.0)  # the filter's 156 px area would have rejected it
    assert too_large(white, [rally, near], 6.0) == (1, 2, 0.0)
    import dataclasses

    assert too_large(dataclasses.replace(white, learned=None), [rally], 6.0)[0] == 1  # the same filter alone: its area
