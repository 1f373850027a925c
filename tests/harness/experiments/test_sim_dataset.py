"""``rt2 sim dataset``: PNG images + COCO labels, deterministic for a seed."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import read_coco
from harness.sim.lab import preview_rig
from harness.sim.render import Renderer
from harness.sim.render.scenes import random_scene
from harness.experiments.studies.sim_dataset import generate


@pytest.fixture(scope="module")
def rig_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "preview.yaml"
    preview_rig(160, 120).save(path)
    return path


@pytest.fixture(scope="module")
def dataset(rig_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    generate(rig_file, 12, 5, out, progress=False)
    return out


# -- smoke -----------------------------------------------------------------------------------------
def test_cli_writes_images_and_annotations(rig_file, tmp_path):
    out = tmp_path / "ds"
    assert main(["sim", "dataset", "--rig", str(rig_file), "--frames", "2", "--seed", "1", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == ["f000000_cam0.png", "f000000_cam1.png", "f000001_cam0.png", "f000001_cam1.png"]
    assert len(read_coco(out)) == 4


# -- shapes / content --------------------------------------------------------------------------------
def test_labels_are_the_renderers_ground_truth(dataset, rig_file):
    labelled = read_coco(dataset)
    assert len(labelled) == 24
    doc = json.loads((dataset / "annotations.json").read_text())
    assert doc["info"]["seed"] == 5 and doc["info"]["frames"] == 12 and doc["info"]["cameras"] == ["cam0", "cam1"]
    assert all(a["visibility"] >= 0.5 and a["iscrowd"] == 0 and a["category_id"] == 1 for a in doc["annotations"])
    assert sum(li.n_balls for li in labelled) >= 8  # most frames show the ball
    # re-render frame 3 and compare labels and pixels (RGB order preserved through cv2's BGR files)
    from tracker import Rig

    renderer = Renderer(Rig.load(rig_file), seed=5)
    scene = random_scene(np.random.default_rng([5, 3]), renderer.rig.workspace_m, frame_index=3)
    images, truths = renderer.render_labelled(scene)
    for i in range(2):
        li = next(x for x in labelled if x.path.name == f"f000003_cam{i}.png")
        png = cv2.cvtColor(cv2.imread(str(li.path)), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(png, images[i])
        visible = [t for t in truths[i] if t.visible]
        assert li.n_balls == len(visible)
        for t, c, b in zip(visible, li.centers_px, li.boxes_xywh):
            np.testing.assert_allclose(c, t.center_px)
            np.testing.assert_allclose(b, t.box_xywh)


def test_hidden_balls_are_recorded_not_labelled(dataset):
    doc = json.loads((dataset / "annotations.json").read_text())
    for im in doc["images"]:
        assert {"camera", "frame", "hidden_balls"} <= set(im)
        assert all(0 < h["visibility"] < 0.5 for h in im["hidden_balls"])


def test_ball_colour_makes_every_ball_that_colour_and_keeps_the_scenes(rig_file, dataset, tmp_path):
    """--ball white: every rendered ball white (none orange), the rest of each scene as without it."""
    from harness.sim.render import Ball
    from harness.sim.render.scenes import SceneOptions

    white = tmp_path / "white"
    assert main(["sim", "dataset", "--rig", str(rig_file), "--frames", "12", "--seed", "5", "--ball", "white", "--out", str(white)]) == 0
    doc = json.loads((white / "annotations.json").read_text())
    assert doc["info"]["ball"] == "white" and "ball" not in json.loads((dataset / "annotations.json").read_text())["info"]
    rgb = {c: Ball([0, 0, 1], colour=c).colour for c in ("white", "orange")}
    from tracker import Rig

    ws = Rig.load(rig_file).workspace_m
    mixed = [random_scene(np.random.default_rng([5, f]), ws, frame_index=f) for f in range(12)]
    only = [random_scene(np.random.default_rng([5, f]), ws, SceneOptions(ball_colour="white"), frame_index=f) for f in range(12)]
    assert any(np.allclose(b.colour, rgb["orange"]) for s in mixed for b in s.balls)  # the default mixes colours
    # each label says what its ball is (not what it looks like after shading and exposure): the mixed set both colours
    assert {a["ball_colour"] for a in doc["annotations"]} == {"white"}
    mixed_doc = json.loads((dataset / "annotations.json").read_text())
    assert {a["ball_colour"] for a in mixed_doc["annotations"]} == {"white", "orange"}
    for a, b in zip(mixed, only):
        assert [x.position_m.tolist() for x in a.balls] == [x.position_m.tolist() for x in b.balls]
        assert all(np.allclose(x.colour, rgb["white"]) for x in b.balls)
        assert a.exposure == b.exposure and len(a.capsules) == len(b.capsules) and len(a.spheres) == len(b.spheres)
    # frames whose balls were all white already are the same pixels; the labels are the same balls
    same = [f for f, s in enumerate(mixed) if s.balls and all(np.allclose(x.colour, rgb["white"]) for x in s.balls)]
    assert same
    name = f"f{same[0]:06d}_cam0.png"
    assert (white / name).read_bytes() == (dataset / name).read_bytes()
    assert [a["bbox"] for a in doc["annotations"]] == [a["bbox"] for a in json.loads((dataset / "annotations.json").read_text())["annotations"]]


# -- bad input -------------------------------------------------------------------------------------
def test_bad_arguments(rig_file, dataset, tmp_path, capsys):
    with pytest.raises(ValueError, match="--frames must be an integer >= 1, got 0"):
        generate(rig_file, 0, 1, tmp_path / "x")
    with pytest.raises(ValueError, match="already holds a data set"):
        generate(rig_file, 1, 1, dataset)
    assert main(["sim", "dataset", "--rig", "nope", "--frames", "1", "--out", str(tmp_path / "y")]) == 2
    assert "unknown rig 'nope'" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="exists and is a file, not a folder"):
        generate(rig_file, 1, 1, tmp_path / "file")
    with pytest.raises(ValueError, match=r"--ball must be one of \['orange', 'white'\], got 'red'"):
        generate(rig_file, 1, 1, tmp_path / "z", ball="red")
    from harness.sim.render.scenes import SceneOptions

    with pytest.raises(ValueError, match=r"SceneOptions.ball_colour must be None or one of \['orange', 'white'\], got 'red'"):
        SceneOptions(ball_colour="red")
    assert not (tmp_path / "z").exists() or not (tmp_path / "z" / "annotations.json").exists()


# -- determinism -----------------------------------------------------------------------------------
def test_same_seed_identical_annotations_and_image_bytes_with_any_worker_count(rig_file, dataset, tmp_path):
    again = tmp_path / "again"
    generate(rig_file, 12, 5, again, workers=2, progress=False)
    assert (again / "annotations.json").read_bytes() == (dataset / "annotations.json").read_bytes()
    for name in ("f000000_cam0.png", "f000007_cam1.png", "f000011_cam0.png"):
        assert (again / name).read_bytes() == (dataset / name).read_bytes()
    other = tmp_path / "other"
    generate(rig_file, 2, 6, other, progress=False)
    assert (other / "f000000_cam0.png").read_bytes() != (dataset / "f000000_cam0.png").read_bytes()
