"""rt2 label --auto: the cameras label each other on a recorded simulated-lab session log; the labels against the
truth, the page showing them as proposals, rt2 train on them; the hostile-input table (one line, exit 2, nothing
written); rt2 eval autolabel's determinism."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
import re

import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import read_coco

RATE_HZ = 100.0
N_SETS = 24


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A session log of the simulated lab (lab4_vga, launcher flights of seed 0, frame sets k / 100 Hz, PNG images), and
    the truth: per frame set, per camera the BallTruth (None without a ball)."""
    from harness.live.sources.sim import LauncherFlights
    from harness.logs import SessionLogWriter
    from harness.sim.render import Renderer
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    renderer, flights = Renderer(rig, seed=0), LauncherFlights(0)
    path = tmp_path_factory.mktemp("autolabel") / "lab.mcap"
    truths = []
    with SessionLogWriter(path, metadata={"kind": "test"}, image_format="png") as w:
        for k in range(N_SETS):
            images, truth = renderer.render_labelled(flights(k / RATE_HZ))
            truths.append([t[0] if t else None for t in truth])
            for cam, img in zip(rig, images):
                w.write_image(k / RATE_HZ, cam.name, np.ascontiguousarray(img), k)
    return path, truths


@pytest.fixture(scope="module")
def labelled(recording, tmp_path_factory):
    path, _ = recording
    out = tmp_path_factory.mktemp("auto") / "labels"
    assert main(["label", "--auto", "--source", "replay", str(path), "--rig", "lab4_vga", "--out", str(out)]) == 0
    return out


def test_auto_labels_every_camera_near_the_truth_with_their_fields(recording, labelled, capsys):
    _, truths = recording
    images = read_coco(labelled)
    doc = json.loads((labelled / "annotations.json").read_text())
    assert len(images) >= 3 * N_SETS // 2
    for im, li in zip(doc["images"], images):
        assert im["camera"] in ("cam0", "cam1", "cam2", "cam3") and isinstance(im["frame_id"], int)
        assert im["rt2_frame"] == f"{im['camera']}_s{im['frame_id']:06d}" and li.path.name == im["rt2_frame"] + ".png"
        t = truths[im["frame_id"]][int(im["camera"][3:])]
        assert t is not None and t.visible
        assert np.linalg.norm(li.centers_px[0] - t.center_px) < 1.5
        assert isinstance(im["hard_negatives"], list)
    for ann in doc["annotations"]:
        assert ann["source"] == "auto" and ann["support"] >= 3 and 0 < ann["confidence"] <= 1 and isinstance(ann["detected"], bool)
    assert doc["info"]["description"].startswith("ball labels made with rt2 label --auto from replay")


def test_auto_prints_labels_per_camera(recording, tmp_path, capsys):
    path, _ = recording
    assert main(["label", "--auto", "--source", "replay", str(path), "--rig", "lab4_vga", "--out", str(tmp_path / "o"),
                 "--max-frames", "8"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("rt2 label --auto: ") and " of 8 frame sets kept" in out
    kept = int(out.split("rt2 label --auto: ")[1].split(" of 8")[0])
    smoothed = int(re.search(r"; (\d+) positions smoothed along their flight\)", out).group(1))
    assert 0 <= smoothed <= kept
    for cam in ("cam0", "cam1", "cam2", "cam3"):
        assert f"  {cam}: " in out and " labels (" in out
    n = sum(int(line.split(": ")[1].split(" labels")[0]) for line in out.splitlines() if line.startswith("  cam"))
    assert n == len(read_coco(tmp_path / "o"))


def test_the_page_shows_auto_labels_as_proposals_least_sure_first_until_accepted(labelled, tmp_path):
    import shutil

    from harness.experiments.studies.eval_detector import DEFAULT_MODEL
    from harness.label.frames import open_frames
    from harness.label.session import LabelOptions, LabelSession
    from tracker import BallSegmentationModel

    out = tmp_path / "review"
    shutil.copytree(labelled, out)
    session = LabelSession(open_frames(out / "images", out), out, BallSegmentationModel.load(DEFAULT_MODEL), DEFAULT_MODEL,
                           LabelOptions(n_suggestions=5))
    try:
        state = session.state()
        n = len(read_coco(out))
        assert state["counts"]["auto"] == n and state["counts"]["labelled"] == 0 and state["can_train"]
        conf = {i: a[0]["confidence"] for i, a in session.store.auto().items()}
        assert state["suggestions"] == sorted(conf, key=lambda i: (conf[i], i))[:5]  # least sure first
        first = state["suggestions"][0]
        frame = session.frame(first)
        assert frame["labels"] is None and frame["auto"] and frame["proposals"][0]["auto"]
        assert frame["proposals"][0]["score"] == pytest.approx(conf[first]) and frame["fields"]["camera"]
        session.label({"frame": first, "boxes": [frame["proposals"][0]["box"]]})  # a person accepts it
        assert session.state()["counts"]["auto"] == n - 1 and session.state()["counts"]["labelled"] == 1
        assert first not in session.suggestions()
    finally:
        session.close()
    doc = json.loads((out / "annotations.json").read_text())
    assert sum(a.get("source") == "auto" for a in doc["annotations"]) == n - 1  # the others keep their fields
    assert all("camera" in im for im in doc["images"])


def test_rt2_train_trains_on_the_auto_labels(labelled, tmp_path, capsys):
    from tracker import BallSegmentationModel

    # --learned off: the learned stage reads the same labelled images as the filter (nothing of it is auto-label
    # specific) and its 4 x 400 optimiser steps were 80 % of this test's time. rt2 train's learned stage at its
    # defaults, written without --force: the page's training in tests/harness/label/test_browser.py
    # (test_label_by_keys_and_mouse_survive_a_kill_resume_and_train); its options and choice: test_learned_train.py
    assert main(["train", "--data", str(labelled), "--out", str(tmp_path / "m.npz"), "--epochs", "1", "--max-images", "12",
                 "--ball-colour", "orange", "--learned", "off"]) == 0
    assert "training from" in capsys.readouterr().out
    BallSegmentationModel.load(tmp_path / "m.npz")


# -- hostile inputs: one line, exit 2, nothing written ------------------------------------------------
@pytest.fixture(scope="module")
def hostile(recording, tmp_path_factory):
    from harness.logs import SessionLogWriter
    from tracker.rig_files import resolve_rig

    root = tmp_path_factory.mktemp("hostile")
    rig = resolve_rig("lab4_vga")
    rig.subset(["cam0", "cam1", "cam2"]).save(root / "three.yaml")
    with SessionLogWriter(root / "noimages.mcap", metadata={"kind": "test"}) as w:
        w.write_detections(0.0, "cam0", np.zeros((1, 2)), np.ones(1), 0)
    with SessionLogWriter(root / "noball.mcap", metadata={"kind": "test"}, image_format="png") as w:
        grey = np.full((480, 640, 3), 90, np.uint8)
        for k in range(6):
            for cam in rig:
                w.write_image(k / RATE_HZ, cam.name, grey, k)
    (root / "taken").mkdir()
    (root / "taken" / "annotations.json").write_text("{}")
    return root


HOSTILE = [
    (["--source", "replay", "LOG", "--rig", "ROOT/three.yaml"], r"--rig has 3 cameras .* but --source replay .* has 4 .*: they must be the same cameras"),
    (["--source", "replay", "ROOT/noimages.mcap", "--rig", "lab4_vga"], r"the log holds no camera images .* needs the images"),
    (["--source", "replay", "ROOT/noball.mcap", "--rig", "lab4_vga"], r"none of its 6 frame sets has 3 or more cameras agreeing on a ball"),
    (["--source", "replay", "ROOT/nowhere.mcap", "--rig", "lab4_vga"], r"no such session log"),
    (["--source", "video", "ROOT/nothing", "--rig", "lab4_vga"], r"--source video .*nothing: no such folder"),
    (["--source", "sim", "--rig", "lab4_vga"], r"--source sim: rt2 label --auto reads a recording"),
    (["--source", "replay", "LOG"], r"--auto needs --source SPEC .* and --rig RIG"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--min-support", "2"], r"--min-support must be an integer >= 3"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--flight-window", "-1"], r"--flight-window must be"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--smooth-window", "51"], r"--smooth-window must be an integer in \[0, 50\], got 51"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--max-size-ratio", "0.5"], r"--max-size-ratio must be in \[1, 10\], got 0.5"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--max-size-ratio", "nan"], r"--max-size-ratio must be in \[1, 10\], got nan"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--trim", "0"], r"--trim must be in \(0, 50\] px, got 0.0"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--trim", "nan"], r"--trim must be in \(0, 50\] px, got nan"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--max-reprojection", "-1"], r"--max-reprojection must be in \(0, 50\] px, got -1.0"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--max-flight-residual", "-1"], r"--max-flight-residual must be in \(0, 1\] m, got -1.0"),
    (["--source", "replay", "LOG", "--rig", "lab4_vga", "--out", "ROOT/taken"], r"already holds annotations.json"),
    (["--source", "replay", "LOG", "--rig", "nosuchrig"], r"nosuchrig"),
    (["SOURCE", "--source", "replay", "LOG", "--rig", "lab4_vga"], r"--auto takes the recording as --source SPEC"),
]


@pytest.mark.parametrize("args, message", HOSTILE, ids=[" ".join(a)[:60] for a, _ in HOSTILE])
def test_hostile_auto_input_is_one_line_exit_2_and_nothing_written(recording, hostile, tmp_path, capsys, args, message):
    import re

    path, _ = recording
    out = tmp_path / "new"
    argv = ["label", "--auto"] + [str(path) if a == "LOG" else a.replace("ROOT", str(hostile)) for a in args]
    if "--out" not in argv:
        argv += ["--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if "error" in line.lower() or "Traceback" in line]
    assert len(errors) == 1 and err[-1] == errors[0], err  # one line (a progress line may come before it)
    assert err[-1].startswith("rt2 label: error: ") and re.search(message, err[-1]), err
    assert not out.exists()
    assert (hostile / "taken" / "annotations.json").read_text() == "{}"


def test_eval_autolabel_same_seed_same_figures(tmp_path, capsys):
    for run in ("a", "b"):
        assert main(["eval", "autolabel", "--scene", "lab", "--frames", "12", "--seed", "3", "--json", str(tmp_path / f"{run}.json")]) == 0
    a, b = (json.loads((tmp_path / f"{r}.json").read_text()) for r in ("a", "b"))
    assert a == b and a["figures"]["frame_sets"] == 12
    assert "rt2 eval autolabel --scene lab: 12 frame sets" in capsys.readouterr().out


def test_rt2_train_min_support_keeps_only_the_surest_auto_labels(labelled, tmp_path, capsys):
    from harness.experiments.autolabel.output import auto_support, keep_supported

    support = auto_support([labelled])
    images = read_coco(labelled)
    assert len(support) == len(images) and min(support.values()) >= 3
    top = max(support.values())
    assert len(keep_supported(images, [labelled], top)) == sum(s == top for s in support.values())
    assert keep_supported(images, [labelled], top + 1) == []
    # the flag: every auto label below the support asked for leaves no image to train on
    assert main(["train", "--data", str(labelled), "--out", str(tmp_path / "m.npz"), "--min-support", str(top + 1)]) == 2
    assert not (tmp_path / "m.npz").exists()
    assert main(["train", "--data", str(labelled), "--out", str(tmp_path / "m.npz"), "--min-support", "1"]) == 2
    assert "--min-support must be an integer >= 2" in capsys.readouterr().err


def test_eval_autolabel_refuses_an_unknown_held_out_camera_before_the_work(tmp_path, capsys):
    assert main(["eval", "autolabel", "--scene", "lab", "--frames", "5", "--train-held-out", "cam9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["rt2 eval autolabel: error: --train-held-out 'cam9': the lab rig's cameras are ['cam0', 'cam1', 'cam2', 'cam3']"]


@pytest.mark.parametrize("args, message", [
    (["--trim", "-3"], "--trim must be in (0, 50] px, got -3.0"),
    (["--max-size-ratio", "0.5"], "--max-size-ratio must be in [1, 10], got 0.5"),
    (["--flight-window", "51"], "--flight-window must be an integer in [0, 50], got 51"),
    (["--smooth-window", "-1"], "--smooth-window must be an integer in [0, 50], got -1"),
])
def test_eval_autolabel_names_the_option_of_a_bad_value(tmp_path, capsys, args, message):
    """The study takes rt2 label --auto's options: a bad value is named by the option, as the command names it."""
    assert main(["eval", "autolabel", "--scene", "lab", "--frames", "5", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"rt2 eval autolabel: error: {message}"]


def test_eval_autolabel_held_out_training_that_finds_no_ball_is_one_line_not_a_figure(monkeypatch, capsys):
    """When no threshold of the fine-tune finds a ball (:class:`NoBallFoundError`), ``--train-held-out`` says so in one
    line naming the camera and the training, exit 2, instead of scoring a model that finds nothing (0 % -> 0 %)."""
    import harness.experiments.detector.train as train_module

    def no_ball(labelled, opts, **kw):
        raise train_module.NoBallFoundError("no threshold finds a ball: (the trainer's line)")

    monkeypatch.setattr(train_module, "train", no_ball)
    assert main(["eval", "autolabel", "--scene", "lab", "--frames", "6", "--seed", "3", "--train-held-out", "cam3", "--epochs", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.fullmatch(r"rt2 eval autolabel: error: --train-held-out cam3: the training on \d+ auto labels of the other "
                                          r"cameras: no threshold finds a ball: \(the trainer's line\)", err[0]), err


def test_eval_autolabel_held_out_training_reports_its_learned_stages_choice(monkeypatch, capsys, tmp_path):
    """What the trained model's learned stage is (the cross-validated choice the training made), printed and in the
    JSON: a stage kept at a new threshold explains a held-out figure that new weights did not make. (The trainer stands in
    for rt2 train here: it returns the base with a made-up choice; the real training is the README's command.)"""
    from types import SimpleNamespace

    import harness.experiments.detector.train as train_module
    from harness.experiments.detector.learned_train import StageChoice

    choices = [StageChoice("shipped", 0.2, SimpleNamespace(recall=0.873, outlier_rate=0.724, median_center_error_px=4.53)),
               StageChoice("scratch", 0.8, SimpleNamespace(recall=0.047, outlier_rate=0.0, median_center_error_px=2.15))]

    def made_up(labelled, opts, *, base, **kw):
        assert opts.learned == "auto"  # as rt2 train at its defaults
        cams = {li.camera for li in labelled}  # each label names its camera, as rt2 label --auto's do: folds by camera
        assert None not in cams and cams <= {"cam0", "cam1", "cam2"} and len(cams) >= 2
        return base, {"kept_base": True, "learned": {"chosen": choices[0], "choices": choices, "folds_by": "camera", "single_threshold": 0.15}}

    monkeypatch.setattr(train_module, "train", made_up)
    out = tmp_path / "ho.json"
    assert main(["eval", "autolabel", "--scene", "lab", "--frames", "6", "--seed", "3", "--train-held-out", "cam3", "--json", str(out)]) == 0
    assert ("  its learned stage: shipped by cross-validation, folds by camera (shipped: recall 87.3%, outliers 72.4%, median 4.53 px "
            "at threshold 0.2; scratch: recall 4.7%, outliers 0.0%, median 2.15 px at threshold 0.8); single images at threshold 0.15"
            ) in capsys.readouterr().out
    stage = json.loads(out.read_text())["held_out_training"]["learned_stage"]
    assert stage["chosen"] == "shipped" and stage["threshold"] == 0.2 and len(stage["choices"]) == 2
    assert stage["folds_by"] == "camera" and stage["single_threshold"] == 0.15


def test_eval_autolabel_train_out_writes_the_model_trained_on_every_cameras_labels(monkeypatch, capsys, tmp_path):
    """``--train-out M.npz``: rt2 train's defaults on the kept labels of every camera (none held out), the model written
    where asked and loadable, one line saying what it was trained on. (The trainer stands in for rt2 train here and
    records what it was given; the real training is the README's command.)"""
    import harness.experiments.detector.train as train_module
    from tracker.pipeline import load_model

    given = {}

    def recording(labelled, opts, *, base, **kw):
        given["cameras"] = {Path(li.path).stem.split("_", 1)[1] for li in labelled}
        given["n"], given["learned"] = len(labelled), opts.learned
        return base, {"kept_base": True}

    monkeypatch.setattr(train_module, "train", recording)
    out, js = tmp_path / "auto.npz", tmp_path / "a.json"
    assert main(["eval", "autolabel", "--scene", "lab", "--frames", "24", "--seed", "3", "--train-out", str(out), "--json", str(js)]) == 0
    assert "cam3" in given["cameras"] and len(given["cameras"]) >= 3 and given["learned"] == "auto"  # no camera held out
    assert load_model(str(out)).description == load_model(None).description
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line == f"  trained on {given['n']} auto labels of every camera (the guard kept the base's filter); wrote {out}"
    assert json.loads(js.read_text())["train_out"] == {"out": str(out), "train_images": given["n"], "kept_base": True, "learned_stage": None}


@pytest.mark.parametrize("argv, message", [
    (["--train-out", "model.txt"], "--train-out must end in .npz, got 'model.txt'"),
    (["--train-out", "/dev/null/m.npz"], "--train-out"),
    (["--scene", "lab", "--ball", "white"], "--ball applies to --scene caliscope (the lab's ball is its renderer's), got --scene lab"),
    (["--scene", "lab", "--crop-frames", "58:"], "--crop-frames applies to --scene caliscope"),
    (["--scene", "caliscope", "--crop-frames", "58:"], "--crop-frames applies to --ball white only"),
    (["--scene", "caliscope", "--ball", "orange", "--ball-crops", "x"], "--ball-crops applies to --ball white only"),
    (["--scene", "caliscope", "--ball", "white", "--crop-frames", "9:3"], "frames '9:3' select no image"),
    (["--scene", "caliscope", "--ball", "white", "--ball-crops", "/nonexistent/rally"], "--ball-crops '/nonexistent/rally': no COCO annotations.json there"),
])
def test_eval_autolabel_ball_options_refused_before_the_work(argv, message, capsys):
    """The caliscope scene's real white balls (``--ball white``) and their options: what does not apply or does not
    exist is one line, exit 2, before any frame set is rendered."""
    assert main(["eval", "autolabel", "--frames", "5", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rt2 eval autolabel: error: ") and message in err[0], err


def test_eval_autolabel_real_white_balls_in_the_caliscope_frames(tmp_path, capsys):
    """``--ball white``: the rally's real balls pasted along the flights; the run says which, and its labels are
    scored against the pasted balls' truth (a few frame sets: the plumbing; the figures are the README's)."""
    from harness.sim.semireal import DEFAULT_RALLY

    if not (DEFAULT_RALLY / "annotations.json").is_file():
        pytest.skip(f"the real rally frames are not at {DEFAULT_RALLY}")
    out = tmp_path / "w.json"
    assert main(["eval", "autolabel", "--scene", "caliscope", "--ball", "white", "--crop-frames", "58:", "--model",
                 "data/models/ball_seg_white.npz", "--frames", "6", "--flight-frames", "6", "--seed", "1", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["ball"] == "white" and r["crop_frames"] == "58:" and r["figures"]["frame_sets"] == 6
    assert r["figures"]["wrong_labels"] == 0


# -- the flight, the trimming and the second look -----------------------------------------------------------------
def test_the_flight_prediction_fits_its_neighbours_and_stops_at_a_pause():
    from harness.experiments.autolabel.consensus import flight_prediction, flight_span_s

    t = np.r_[np.arange(6) * 0.01, 1.0 + np.arange(6) * 0.01]  # two flights a pause apart
    g = np.array([0.0, 0.0, -9.81])
    P = np.array([[1.0, 2.0, 0.5]]) + np.outer(t, [3.0, -1.0, 2.0]) + 0.5 * np.outer(t * t, g)
    have = np.ones(len(t), bool)
    span = flight_span_s(t, 3)
    assert span == pytest.approx(0.035)
    np.testing.assert_allclose(flight_prediction(t, P, have, 2, 3, span), P[2], atol=1e-9)  # a parabola through 5
    np.testing.assert_allclose(flight_prediction(t, P, have, 5, 3, span), P[5], atol=1e-9)  # only its own flight's 3
    P2 = P.copy()
    P2[6:] += 5.0  # the next flight elsewhere: no neighbour across the pause
    np.testing.assert_allclose(flight_prediction(t, P2, have, 5, 3, span), P[5], atol=1e-9)
    assert not np.allclose(flight_prediction(t, P2, have, 5, 3), P[5], atol=1e-3)  # without the span it would be pulled off
    have[[1, 3]] = False
    assert flight_prediction(t, P, have, 2, 1, span) is None  # fewer than 2 neighbours
    assert flight_span_s([0.0], 3) == np.inf


def test_trimming_drops_the_off_centre_camera_and_keeps_min_support():
    from harness.experiments.autolabel.consensus import AutoOptions, trimmed
    from tracker.rig_files import resolve_rig
    from tracker.triangulation import reprojection_errors, triangulate

    rig = resolve_rig("lab4_vga")
    X = np.array([0.2, 0.3, 1.0])
    uv = rig.project(X).copy()
    uv[1] += [2.6, 0.0]  # one camera's blob off the ball's centre, inside the consensus's tolerance
    X0, err0 = triangulate(rig, uv)
    from dataclasses import make_dataclass

    E = make_dataclass("E", [("inliers", object), ("support", int), ("reproj_error_px", object)], frozen=True)
    X1, est = trimmed(X0, uv, E(np.ones(4, bool), 4, err0), rig, AutoOptions(trim_px=1.0))
    assert est.support == 3 and not est.inliers[1] and np.linalg.norm(X1 - X) < 1e-6
    np.testing.assert_allclose(est.reproj_error_px, reprojection_errors(X1, uv, rig), atol=1e-9)
    same_X, same = trimmed(X0, uv, E(np.ones(4, bool), 4, err0), rig, AutoOptions(trim_px=50.0))  # nothing that far: unchanged
    assert same.support == 4 and np.array_equal(same_X, X0)
    three = E(np.array([True, True, True, False]), 3, err0)
    assert trimmed(X0, uv, three, rig, AutoOptions(trim_px=0.01))[1] is three  # never below min_support


def test_frame_sets_outside_the_workspace_are_counted_apart():
    from harness.experiments.autolabel.study import score_labels
    from harness.sim.render.truth import BallTruth

    seen = [BallTruth(np.array([10.0, 10.0]), 8.0, 1.0, np.array([6.0, 6.0, 8.0, 8.0]))] * 4
    box = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    fig = score_labels([], [seen, seen, seen[:2] + [None, None]], [np.array([0.5, 0.5, 0.5]), np.array([0.5, 0.5, 1.2]), None], box)
    assert fig["eligible"] == 1 and fig["outside_workspace"] == 1 and fig["kept_share"] == 0.0
    fig = score_labels([], [seen], [np.array([0.5, 0.5, 1.05])], box)  # within the consensus's 0.1 m margin
    assert fig["eligible"] == 1 and fig["outside_workspace"] == 0


def test_label_precision_is_split_by_the_balls_diameter_and_smear():
    from harness.experiments.autolabel.consensus import FrameSetLabels
    from harness.experiments.autolabel.study import format_report, score_labels, smear_ratio
    from harness.sim.render.truth import BallTruth

    # per camera: true diameter, box (x, y, w, h) of the smeared ball, the label's error (px, along u)
    cams = [(10.0, [0, 0, 10, 10], 0.5), (30.0, [0, 0, 30, 30], 2.0), (50.0, [0, 0, 80, 50], 1.0), (70.0, [0, 0, 70, 140], 3.0)]
    truths = [[BallTruth(np.array([100.0, 100.0]), d, 1.0, np.array(b, float)) for d, b, _ in cams]]
    centre = np.array([[100.0 + e, 100.0] for *_, e in cams])
    fs = FrameSetLabels(0, 0, 0.0, np.zeros(3), 4, 0.5, np.ones(4, bool), np.zeros(4), centre, np.array([d for d, *_ in cams]), 1.0, ((),) * 4)
    assert [smear_ratio(t) for t in truths[0]] == [0.0, 0.0, 0.6, 1.0]
    fig = score_labels([fs], truths)
    assert fig["by_diameter"] == {"0-20px": {"labels": 1, "within_1_5px": 1.0}, "20-40px": {"labels": 1, "within_1_5px": 0.0},
                                  "40-60px": {"labels": 1, "within_1_5px": 1.0}, ">=60px": {"labels": 1, "within_1_5px": 0.0}}
    assert fig["by_smear"] == {"round": {"labels": 2, "within_1_5px": 0.5}, "smeared": {"labels": 2, "within_1_5px": 0.5}}
    assert fig["median_error_of_diameter"] == pytest.approx(np.median([0.05, 2 / 30, 0.02, 3 / 70]))
    report = format_report("lab", fig, {"agreed": 1, "second_look": 0, "kept": 1})
    assert "0-20px 100.0% of 1" in report and "smeared 50.0% of 2" in report
    empty = score_labels([], truths)  # no label: the splits say so, no division by zero
    assert empty["by_smear"]["round"] == {"labels": 0, "within_1_5px": None} and empty["median_error_of_diameter"] is None


@pytest.fixture(scope="module")
def drawn_once():
    """The caliscope scene's frame sets with the drawn ball, drawn once per module: the comparisons below run
    ``rt2 eval autolabel`` twice (a flag on, then off) on the same seed, so the second run (and the next test's first
    60 frame sets, seed 0 as well) gets the very images the first drew (drawing was 80 % of a run). Kept as each
    image's pixels that differ from the session's real background frame (about 0.1 % of them), rebuilt on that
    background (decoded from the same files in every run), bit for bit what the drawing returned."""
    import copy

    from harness.sim.semireal import SemiRealSession

    draw = SemiRealSession.flight_frameset
    drawn = {}

    def once(self, n, j, flight, *, crop=False):
        k, P, V = flight
        if self.real is not None or self.options.moving:  # pasted real balls, moving backgrounds: drawn every time
            return draw(self, n, j, flight, crop=crop)
        key = (str(self.folder), repr(self.options), self.seed, n, j, k, P[j].tobytes(), V[j].tobytes())
        if key not in drawn:
            images, truths, centre, k_bg, *source = draw(self, n, j, flight, crop=True)
            backs = self._frames[k_bg]
            diffs = []
            for img, back in zip(images, backs):
                assert img.shape == back.shape and img.dtype == back.dtype
                at = np.flatnonzero(img != back)
                diffs.append((at, img.reshape(-1)[at].copy()))
            drawn[key] = (diffs, copy.deepcopy(truths), centre.copy(), k_bg, source[0])
        diffs, truths, centre, k_bg, source = drawn[key]
        images = []
        for (at, values), back in zip(diffs, self._frames[k_bg]):
            img = back.copy()
            img.reshape(-1)[at] = values
            images.append(img)
        out = (images, copy.deepcopy(truths), centre.copy(), k_bg)
        return (*out, source) if crop else out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SemiRealSession, "flight_frameset", once)
        yield drawn


def test_the_second_look_keeps_more_frame_sets_and_no_wrong_label(tmp_path, drawn_once):
    """The drawn orange ball in the real caliscope frames: the second look (windows where the flight puts the ball, at
    half the thresholds) keeps frame sets the first look missed; none of its labels is wrong."""
    from harness.sim.semireal import DEFAULT_SESSION

    if not (DEFAULT_SESSION / "camera_array.toml").is_file():
        pytest.skip(f"the caliscope session is not at {DEFAULT_SESSION}")
    figures = {}
    for flag in ("--second-look", "--no-second-look"):
        out = tmp_path / f"{flag}.json"
        assert main(["eval", "autolabel", "--scene", "caliscope", "--frames", "60", "--seed", "0", flag, "--json", str(out)]) == 0
        figures[flag] = json.loads(out.read_text())
    on, off = figures["--second-look"], figures["--no-second-look"]
    assert on["counts"]["second_look"] > 0 and off["counts"]["second_look"] == 0
    assert on["figures"]["kept_eligible"] > off["figures"]["kept_eligible"]
    assert on["figures"]["wrong_labels"] == 0
    assert on["figures"]["within_1_5px"] >= 0.95  # the goal: the silhouette's centres (99.4 %; the weighted centroid's: 90 %)


def test_the_silhouette_centre_is_not_pulled_towards_the_lit_side():
    """A shaded orange disk (its probability higher on the lit side): the silhouette's centroid lands nearer the disk's
    centre than the probability-weighted centroid, which moves towards the light."""
    from harness.experiments.autolabel.consensus import centring
    from tracker.pipeline import load_model

    model = load_model(None)
    rng = np.random.default_rng(0)
    H, W, c, d = 200, 240, np.array([120.3, 99.6]), 60.0
    img = np.clip(rng.normal(100, 4, (H, W, 3)), 0, 255)
    yy, xx = np.mgrid[0:H, 0:W]
    inside = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= (d / 2) ** 2
    shade = 0.775 + 0.225 * np.clip(0.7 * ((xx - c[0]) + (c[1] - yy)) / (d / 2), -1, 1)  # lit towards +u, -v
    img[inside] = np.array([245.0, 120.0, 20.0]) * shade[inside, None]
    img = img.astype(np.uint8)
    p = model.probability(img, (0, 0, W, H)).astype(float) * ((xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= (d / 2 + 3) ** 2)
    weighted = np.array([(p * xx).sum(), (p * yy).sum()]) / p.sum()
    silhouette = centring(model)(img, c + [2.0, -1.0], d)
    assert np.linalg.norm(silhouette - c) < 0.6
    assert np.linalg.norm(silhouette - c) < 0.8 * np.linalg.norm(weighted - c)


def test_recentring_moves_the_position_to_the_drawn_balls_centres():
    """Orange disks drawn where a ball at X projects; from a consensus position 8 mm off, re-centring (the centroid of the
    filter's silhouette at each projection, triangulated, twice) lands within 1 mm; where fewer than min_support
    cameras can be measured, the consensus's position stays."""
    from harness.experiments.autolabel.consensus import AutoOptions, centring, recentred, recentred_centres
    from tracker.detection.synthetic import draw_disk
    from tracker.pipeline import load_model
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    X = np.array([0.1, 0.4, 1.1])
    rng = np.random.default_rng(0)
    images = []
    for cam in rig:
        W, H = cam.image_size
        img = np.clip(rng.normal(100, 4, (H, W, 3)), 0, 255).astype(np.uint8)
        d = 0.04 * cam.K[0, 0] / cam.depth(X[None])[0]
        draw_disk(img, cam.project(X[None])[0], d, (245, 120, 20))
        images.append(img)
    centre = centring(load_model(None))
    start = X + np.array([0.008, -0.004, 0.003])
    assert np.linalg.norm(recentred(images, start, rig, centre, AutoOptions()) - X) < 1e-3
    X1, uv = recentred_centres(images, start, rig, centre, AutoOptions())  # the centres it was triangulated from
    assert np.linalg.norm(X1 - X) < 1e-3 and np.isfinite(uv).all() and np.abs(uv - rig.project(X1)).max() < 0.5
    blank = [images[0], images[1]] + [np.full_like(images[2], 100)] * 2  # two cameras without the ball
    assert np.array_equal(recentred(blank, start, rig, centre, AutoOptions()), start)
    held = recentred_centres(blank, start, rig, centre, AutoOptions())
    assert np.array_equal(held[0], start) and held[1] is None  # did not hold: no centres
    assert centring(load_model("data/models/ball_seg_white.npz")).__name__ == "silhouette_or_edge"  # the white ball: its grey silhouette, else its edge


def test_the_orange_models_centring_uses_the_filter_then_the_edge():
    """The orange model for real cameras (a learned stage its filter does not refine, the filter of the ball's colour):
    re-centring takes the filter's silhouette where the filter sees the ball (as the default does: the same centre) and
    the ball's edge where it does not (a ball of a colour the filter misses; the default then has none)."""
    from harness.experiments.autolabel.consensus import centring
    from tracker.detection.synthetic import draw_disk
    from tracker.pipeline import load_model

    real, default = load_model("data/models/ball_seg_orange.npz"), load_model(None)
    assert real.ball_colour == "orange" and not real.learned.filter_refines
    centre = centring(real)
    assert centre.__name__ == "filter_or_edge"
    rng = np.random.default_rng(1)
    c, d = np.array([80.4, 70.7]), 30.0
    for colour, filter_sees in (((245, 120, 20), True), ((40, 60, 230), False)):  # orange; blue: the filter sees nothing
        img = np.clip(rng.normal(100, 3, (150, 160, 3)), 0, 255).astype(np.uint8)
        draw_disk(img, c, d, colour)
        got, own = centre(img, c + [1.5, -1.0], d), centring(default)(img, c + [1.5, -1.0], d)
        assert got is not None and np.linalg.norm(got - c) < 0.5, (colour, got)
        if filter_sees:
            assert np.allclose(got, own)
        else:
            assert own is None


def test_a_camera_off_centre_beyond_the_tolerance_is_measured_again_not_lost(tmp_path, drawn_once):
    """The orange model for real cameras with its centres from grey's edge (looser than a filter's: the shaded side
    leans them; as the file was before its edge fit looked at the chroma, here its ball colour "any"): where a
    consistent set fails the 3 px test, each camera is measured again where the ball projects and the frame set kept
    when >= 3 of those centres agree within it; no label is wrong for it (400 frame sets: 92.9 -> 98.9 % kept)."""
    from harness.sim.semireal import DEFAULT_SESSION

    if not (DEFAULT_SESSION / "camera_array.toml").is_file():
        pytest.skip(f"the caliscope session is not at {DEFAULT_SESSION}")
    from tracker.pipeline import load_model

    grey = tmp_path / "orange_grey_edges.npz"
    dataclasses.replace(load_model("data/models/ball_seg_orange.npz"), ball_colour="any").save(grey)
    figures = {}
    for flag in ("--recentre", "--no-recentre"):
        out = tmp_path / f"{flag}.json"
        assert main(["eval", "autolabel", "--scene", "caliscope", "--frames", "80", "--seed", "0", "--model",
                     str(grey), flag, "--json", str(out)]) == 0
        figures[flag] = json.loads(out.read_text())
    on, off = figures["--recentre"], figures["--no-recentre"]
    assert on["counts"]["recentred_agreement"] > 0 and off["counts"]["recentred_agreement"] == 0
    assert on["figures"]["kept_eligible"] > off["figures"]["kept_eligible"]
    assert on["figures"]["wrong_labels"] == 0 and on["figures"]["kept_share"] >= 0.95
