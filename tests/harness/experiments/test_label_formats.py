"""harness.experiments.detector.labels: the label formats labelling tools export (COCO, YOLO, labelme, CVAT,
Label Studio), read from the shapes their own documentation shows, refused with one line naming file and
field when malformed, and written back so that COCO -> format -> COCO keeps every box (on real images)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from harness.experiments.detector.coco import read_coco, write_coco
from harness.experiments.detector.labels import LABEL_FORMATS, LabelError, detect_format, read_labels, write_labels

ROOT = Path(__file__).resolve().parents[3]
REAL = ROOT.parent / "shared" / "data" / "real" / "phone_rally"


def _png(path: Path, w: int = 640, h: int = 480) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((h, w, 3), 80, np.uint8))
    return path


# -- each format's documented export shape -----------------------------------------------------------
def _roboflow_yolo(root: Path) -> Path:
    """Roboflow's YOLOv8 export: data.yaml with ../train/images, train/ and valid/ folders, list names."""
    for split, name in (("train", "f0001.jpg"), ("valid", "f0002.jpg")):
        _png(root / split / "images" / name)
        (root / split / "labels").mkdir(parents=True, exist_ok=True)
    (root / "train" / "labels" / "f0001.txt").write_text("1 0.5 0.5 0.0125 0.0166666\n0 0.1 0.1 0.05 0.05\n")
    # f0002 has no label file: a background image
    (root / "data.yaml").write_text("train: ../train/images\nval: ../valid/images\ntest: ../test/images\n\n"
                                    "nc: 2\nnames: ['person', 'ball']\n\nroboflow:\n  workspace: lab\n  version: 1\n")
    return root / "data.yaml"


def _ultralytics_yolo(root: Path) -> Path:
    """Ultralytics' layout (coco8.yaml): path + images/train, labels/train, names as a mapping."""
    _png(root / "images" / "train" / "a.png")
    (root / "labels" / "train").mkdir(parents=True)
    (root / "labels" / "train" / "a.txt").write_text("0 0.25 0.5 0.025 0.03333333\n")
    (root / "ball.yaml").write_text("path: .\ntrain: images/train\nval: images/train\nnames:\n  0: ball\n")
    return root


def _labelme(root: Path) -> Path:
    """labelme 5.x: one JSON beside each image; rectangle corners in any order, a circle, a polygon."""
    _png(root / "f1.png")
    doc = {"version": "5.5.0", "flags": {}, "imagePath": "f1.png", "imageData": None, "imageHeight": 480, "imageWidth": 640,
           "shapes": [{"label": "ball", "points": [[108.0, 58.0], [100.0, 50.0]], "group_id": None, "description": "",
                       "shape_type": "rectangle", "flags": {}, "mask": None},
                      {"label": "Ball", "points": [[300.0, 200.0], [304.0, 203.0]], "group_id": None, "shape_type": "circle", "flags": {}},
                      {"label": "person", "points": [[1, 1], [5, 5], [1, 9]], "group_id": None, "shape_type": "polygon", "flags": {}}]}
    (root / "f1.json").write_text(json.dumps(doc, indent=2))
    return root


def _cvat(root: Path) -> Path:
    """CVAT for images 1.1: annotations.xml + images/, meta with labels, a box, an ellipse, another label."""
    _png(root / "images" / "frame_000000.png")
    _png(root / "images" / "frame_000001.png")
    (root / "annotations.xml").write_text("""<?xml version="1.0" encoding="utf-8"?>
<annotations>
  <version>1.1</version>
  <meta>
    <task><id>7</id><name>balls</name><size>2</size><mode>annotation</mode><overlap>0</overlap>
      <labels><label><name>ball</name><color>#fa3253</color><type>any</type><attributes/></label>
              <label><name>racket</name><color>#33ddff</color><type>any</type><attributes/></label></labels>
    </task>
    <dumped>2024-05-01 10:00:00.000000+00:00</dumped>
  </meta>
  <image id="0" name="frame_000000.png" width="640" height="480">
    <box label="ball" source="manual" occluded="0" xtl="311.20" ytl="202.90" xbr="319.40" ybr="211.00" z_order="0">
    </box>
    <ellipse label="ball" source="manual" occluded="0" cx="100.0" cy="100.0" rx="4.0" ry="5.0" z_order="0"/>
    <polygon label="racket" source="manual" occluded="0" points="10.0,10.0;20.0,10.0;20.0,30.0" z_order="0"/>
  </image>
  <image id="1" name="frame_000001.png" width="640" height="480">
  </image>
</annotations>
""")
    return root


def _cvat_coco(root: Path) -> Path:
    """CVAT's COCO 1.0 export: annotations/instances_default.json naming files in images/."""
    _png(root / "images" / "frame_000000.png")
    (root / "annotations").mkdir(parents=True)
    doc = {"licenses": [{"name": "", "id": 0, "url": ""}], "info": {"contributor": "", "date_created": "", "description": "",
                                                                    "url": "", "version": "", "year": ""},
           "categories": [{"id": 1, "name": "ball", "supercategory": ""}],
           "images": [{"id": 1, "width": 640, "height": 480, "file_name": "frame_000000.png", "license": 0,
                       "flickr_url": "", "coco_url": "", "date_captured": 0}],
           "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "segmentation": [], "area": 66.4,
                            "bbox": [311.2, 202.9, 8.2, 8.1], "iscrowd": 0, "attributes": {"occluded": False, "rotation": 0.0}}]}
    (root / "annotations" / "instances_default.json").write_text(json.dumps(doc))
    return root


def _labelstudio(root: Path) -> Path:
    """Label Studio's JSON export: uploads with an 8-hex prefix, a cancelled annotation, predictions, an unlabelled task."""
    _png(root / "images" / "frame_a.png")
    _png(root / "images" / "frame_b.png")
    _png(root / "images" / "frame_c.png")
    rect = {"id": "Dx_aB91ISN", "type": "rectanglelabels", "from_name": "label", "to_name": "image",
            "original_width": 640, "original_height": 480, "image_rotation": 0,
            "value": {"x": 50.0, "y": 25.0, "width": 1.25, "height": 2.5, "rotation": 0, "rectanglelabels": ["ball"]}}
    tasks = [
        {"id": 1, "data": {"image": "/data/upload/3/5f1c2a9e-frame_a.png"}, "created_at": "2024-05-01T10:00:00Z",
         "annotations": [{"id": 1, "was_cancelled": True, "result": []},
                         {"id": 2, "completed_by": 1, "was_cancelled": False, "ground_truth": False, "lead_time": 4.2, "result": [rect]}],
         "predictions": [{"model_version": "m1", "score": 0.5, "result": [dict(rect, value=dict(rect["value"], x=10.0))]}]},
        {"id": 2, "data": {"image": "/data/local-files/?d=images/frame_b.png"},
         "annotations": [{"id": 3, "was_cancelled": False, "result": []}], "predictions": []},
        {"id": 3, "data": {"image": "http://localhost:8080/images/frame_c.png"}, "annotations": [], "predictions": []},
    ]
    (root / "project-1-at-2024-05-01-10-00-abc123.json").write_text(json.dumps(tasks))
    return root / "project-1-at-2024-05-01-10-00-abc123.json"


def _file(folder: Path, name: str, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)
    return folder


def _boxes(images):
    return {Path(li.path).name: np.round(li.boxes_xywh, 6).tolist() for li in images}


def test_roboflow_yolo_export(tmp_path):
    src = _roboflow_yolo(tmp_path)
    assert detect_format(tmp_path) == "yolo"
    got = read_labels(src)
    assert [li.path.name for li in got] == ["f0001.jpg", "f0002.jpg"]
    np.testing.assert_allclose(got[0].boxes_xywh, [[316.0, 236.0, 8.0, 8.0]], atol=1e-3)  # only class 'ball' (1)
    assert got[1].n_balls == 0 and (got[0].width, got[0].height) == (640, 480)


def test_ultralytics_yolo_layout(tmp_path):
    got = read_labels(_ultralytics_yolo(tmp_path), "auto")
    np.testing.assert_allclose(got[0].boxes_xywh, [[152.0, 232.0, 16.0, 16.0]], atol=1e-3)


def _cvat_yolo11(root: Path) -> Path:
    """CVAT's "YOLO 1.1" (Darknet) export: obj.data, obj.names, obj_train_data/ with images and labels, train.txt."""
    _png(root / "obj_train_data" / "frame_000000.png")
    _png(root / "obj_train_data" / "frame_000001.png")
    (root / "obj_train_data" / "frame_000000.txt").write_text("0 0.500000 0.500000 0.012500 0.016667\n1 0.1 0.1 0.1 0.1\n")
    (root / "obj_train_data" / "frame_000001.txt").write_text("")
    (root / "obj.names").write_text("ball\nracket\n")
    (root / "obj.data").write_text("classes = 2\ntrain = data/train.txt\nnames = data/obj.names\nbackup = backup/\n")
    (root / "train.txt").write_text("data/obj_train_data/frame_000000.png\ndata/obj_train_data/frame_000001.png\n")
    return root


def test_cvat_yolo_1_1_darknet_export(tmp_path):
    assert detect_format(_cvat_yolo11(tmp_path)) == "yolo" and detect_format(tmp_path / "obj.data") == "yolo"
    a, b = read_labels(tmp_path)
    np.testing.assert_allclose(a.boxes_xywh, [[316.0, 236.0, 8.0, 8.0]], atol=1e-3)
    assert b.n_balls == 0 and b.path.name == "frame_000001.png"


def test_yolo_segmentation_polygon_is_read_as_its_box(tmp_path):
    _roboflow_yolo(tmp_path)
    (tmp_path / "train/labels/f0001.txt").write_text("1 0.5 0.5 0.5125 0.5 0.5 0.5166666 0.4875 0.5\n")
    got = read_labels(tmp_path)
    np.testing.assert_allclose(got[0].boxes_xywh, [[312.0, 240.0, 16.0, 8.0]], atol=1e-3)


def test_yolo_pose_lines_are_read_by_their_box(tmp_path):
    """A pose line is a box and keypoints (here 2 keypoints x 3 = 11 fields, odd like a polygon): with kpt_shape
    in data.yaml only the box is read, never the keypoints as polygon points."""
    _roboflow_yolo(tmp_path)
    (tmp_path / "data.yaml").write_text("train: ../train/images\nval: ../valid/images\nkpt_shape: [2, 3]\nnames: ['person', 'ball']\n")
    (tmp_path / "train/labels/f0001.txt").write_text("1 0.5 0.5 0.0125 0.0166666 0.9 0.9 2 0.1 0.1 2\n")
    np.testing.assert_allclose(read_labels(tmp_path)[0].boxes_xywh, [[316.0, 236.0, 8.0, 8.0]], atol=1e-3)


def test_labelme_file(tmp_path):
    folder = _labelme(tmp_path)
    assert detect_format(folder) == "labelme" and detect_format(folder / "f1.json") == "labelme"
    (li,) = read_labels(folder)
    np.testing.assert_allclose(li.boxes_xywh, [[100, 50, 8, 8], [295, 195, 10, 10]])  # circle radius 5
    np.testing.assert_allclose(li.centers_px, [[103.5, 53.5], [299.5, 199.5]])


def test_cvat_for_images(tmp_path):
    assert detect_format(_cvat(tmp_path)) == "cvat"
    a, b = read_labels(tmp_path)
    np.testing.assert_allclose(a.boxes_xywh, [[311.2, 202.9, 8.2, 8.1], [96, 95, 8, 10]], atol=1e-9)
    assert b.n_balls == 0 and a.path == tmp_path / "images" / "frame_000000.png"


def test_cvat_coco_export(tmp_path):
    assert detect_format(_cvat_coco(tmp_path)) == "coco"
    (li,) = read_labels(tmp_path)
    assert li.path == tmp_path / "images" / "frame_000000.png"
    np.testing.assert_allclose(li.boxes_xywh, [[311.2, 202.9, 8.2, 8.1]])
    (li2,) = read_labels(tmp_path / "annotations" / "instances_default.json")  # the JSON itself
    assert li2.path == li.path


def test_labelstudio_export(tmp_path):
    src = _labelstudio(tmp_path)
    assert detect_format(src) == "labelstudio" and detect_format(tmp_path) == "labelstudio"
    a, b = read_labels(src)  # task 3 has no annotation: not labelled, left out
    assert (a.path.name, b.path.name) == ("frame_a.png", "frame_b.png")
    np.testing.assert_allclose(a.boxes_xywh, [[320, 120, 8, 12]])  # the annotation, not the prediction
    assert b.n_balls == 0


# -- the round trip on real images ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def real_subset(tmp_path_factory):
    if not (REAL / "annotations.json").is_file():
        pytest.skip(f"the real data set is not at {REAL}")
    return read_coco(REAL)[:12]


@pytest.mark.parametrize("fmt", list(LABEL_FORMATS))
def test_coco_to_format_to_coco_keeps_every_box(tmp_path, real_subset, fmt):
    out = tmp_path / fmt
    write_labels(out, real_subset, fmt)
    assert detect_format(out) == fmt
    back = read_labels(out)
    again = tmp_path / "coco_again"
    write_labels(again, back, "coco")
    final = read_labels(again)
    assert len(final) == len(real_subset) == 12
    want, got = _boxes(real_subset), _boxes(final)
    assert want.keys() == got.keys() and sum(map(len, want.values())) == sum(map(len, got.values())) == 12
    for name in want:
        np.testing.assert_allclose(got[name], want[name], atol=1e-6)
    assert {Path(li.path).name: (li.width, li.height) for li in final} == {Path(li.path).name: (li.width, li.height) for li in real_subset}


def test_round_trip_keeps_background_images_and_folders(tmp_path):
    imgs = [_png(tmp_path / "src" / "cam0" / "f.png"), _png(tmp_path / "src" / "cam1" / "f.png", 320, 240)]
    from harness.experiments.detector.labels.common import labelled

    src = [labelled(imgs[0], 640, 480, [[10, 10, 6, 6]]), labelled(imgs[1], 320, 240, np.zeros((0, 4)))]
    for fmt in LABEL_FORMATS:
        write_labels(tmp_path / fmt, src, fmt)
        back = sorted(read_labels(tmp_path / fmt), key=lambda li: str(li.path))
        assert [li.path.parent.name for li in back] == ["cam0", "cam1"], fmt  # same names in two folders stay apart
        assert [li.n_balls for li in back] == [1, 0] and (back[1].width, back[1].height) == (320, 240), fmt


# -- hostile inputs: one line naming file and field ---------------------------------------------------------
def _mutate_json(path: Path, fn) -> Path:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))
    return path


def _set(d, keys, value):
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = value


HOSTILE = [
    # (case, builder returning the path to read, regex the one-line error must match)
    ("yolo: no names", lambda t: (_roboflow_yolo(t), (t / "data.yaml").write_text("train: ../train/images\n"))[0], r"data\.yaml: missing field 'names'"),
    ("yolo: no ball class", lambda t: (_roboflow_yolo(t), (t / "data.yaml").write_text("train: train/images\nnames: [person]\n"))[0],
     r"data\.yaml: field 'names' has no 'ball' class"),
    ("yolo: names not a list", lambda t: (_roboflow_yolo(t), (t / "data.yaml").write_text("train: train/images\nnames: ball\n"))[0],
     r"data\.yaml: field 'names' must be a list"),
    ("yolo: missing split folder", lambda t: (_roboflow_yolo(t), (t / "data.yaml").write_text("train: nowhere\nnames: [ball]\n"))[0],
     r"data\.yaml: field 'train' names 'nowhere', which does not exist"),
    ("yolo: four fields", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("1 0.5 0.5 0.1\n"))[0],
     r"f0001\.txt: line 1: expected 5 fields"),
    ("yolo: six fields", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("1 0.5 0.5 0.1 0.1 0.9\n"))[0],
     r"f0001\.txt: line 1: expected 5 fields .* got 6"),
    ("yolo: class not a number", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("b 0.5 0.5 0.1 0.1\n"))[0],
     r"f0001\.txt: line 1: field 'class' must be an integer"),
    ("yolo: class out of range", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("7 0.5 0.5 0.1 0.1\n"))[0],
     r"f0001\.txt: line 1: field 'class' 7 is not a class"),
    ("yolo: pixels not fractions", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("1 320 240 8 8\n"))[0],
     r"f0001\.txt: line 1: fields x_centre y_centre width height must be fractions"),
    ("yolo: nan", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("1 nan 0.5 0.1 0.1\n"))[0],
     r"f0001\.txt: line 1: field 'x_centre' must be a finite number"),
    ("yolo: box off the image", lambda t: (_roboflow_yolo(t), (t / "train/labels/f0001.txt").write_text("1 0.99 0.5 0.1 0.1\n"))[0],
     r"f0001\.txt: line 1: field 'box' .* outside the 640x480 image"),
    ("yolo: yaml alias bomb", lambda t: (_roboflow_yolo(t), (t / "data.yaml").write_text("a: &a [1]\nnames: *a\n"))[0],
     r"data\.yaml: not valid YAML: .*aliases"),
    ("yolo 1.1: no names file", lambda t: (_cvat_yolo11(t), (t / "obj.names").unlink())[0], r"obj\.data: field 'names' names 'data/obj\.names', which does not exist"),
    ("yolo 1.1: no ball in obj.names", lambda t: (_cvat_yolo11(t), (t / "obj.names").write_text("racket\n"))[0], r"obj\.names: field 'names' has no 'ball' class"),
    ("yolo 1.1: obj.data line", lambda t: (_cvat_yolo11(t), (t / "obj.data").write_text("names obj.names\n"))[0], r"obj\.data: line 1: expected 'key = value'"),
    ("yolo 1.1: listed image missing", lambda t: (_cvat_yolo11(t), (t / "obj_train_data" / "frame_000001.png").unlink())[0],
     r"train\.txt: lists 'data/obj_train_data/frame_000001\.png', which does not exist"),
    ("labelme: no imagePath", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d.pop("imagePath")), r"f1\.json: missing field 'imagePath'"),
    ("labelme: image missing", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d.update(imagePath="..\\img\\gone.png")),
     r"f1\.json: field 'imagePath' names .*gone\.png.*which does not exist"),
    ("labelme: width 0", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d.update(imageWidth=0)), r"f1\.json: field 'imageWidth' must be a positive integer"),
    ("labelme: point shape", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d["shapes"][0].update(shape_type="point", points=[[3, 3]])),
     r"f1\.json: shapes\[0\]: field 'shape_type' 'point' cannot label a ball"),
    ("labelme: points not pairs", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d["shapes"][0].update(points=[1, 2, 3, 4])),
     r"f1\.json: shapes\[0\]: field 'points' must be a list of \[x, y\] pairs"),
    ("labelme: empty rectangle", lambda t: _mutate_json(_labelme(t) / "f1.json", lambda d: d["shapes"][0].update(points=[[5, 5], [5, 9]])),
     r"f1\.json: shapes\[0\]: field 'points' must have positive width and height"),
    ("labelme: broken JSON", lambda t: ((_labelme(t) / "f1.json").write_text('{"shapes": ['), t / "f1.json")[1], r"f1\.json: not valid JSON"),
    ("cvat: box off the image", lambda t: (_cvat(t), (t / "annotations.xml").write_text((t / "annotations.xml").read_text().replace('xbr="319.40"', 'xbr="700"')))[0],
     r"annotations\.xml: <image> 0 \(id '0'\) <box>: field 'xtl/ytl/xbr/ybr' .* outside the 640x480 image"),
    ("cvat: xtl not a number", lambda t: (_cvat(t), (t / "annotations.xml").write_text((t / "annotations.xml").read_text().replace('xtl="311.20"', 'xtl="abc"')))[0],
     r"annotations\.xml: <image> 0 \(id '0'\) <box>: field 'xtl' must be a number"),
    ("cvat: missing ybr", lambda t: (_cvat(t), (t / "annotations.xml").write_text((t / "annotations.xml").read_text().replace('ybr="211.00"', '')))[0],
     r"<box>: missing attribute 'ybr'"),
    ("cvat: points shape", lambda t: (_cvat(t), (t / "annotations.xml").write_text((t / "annotations.xml").read_text().replace(
        '<polygon label="racket"', '<points label="ball"').replace("</image>\n  <image id=\"1\"", "</image>\n  <image id=\"1\"")))[0],
     r"<points>: a <points> cannot label a ball"),
    ("cvat: image missing", lambda t: (_cvat(t), (t / "images" / "frame_000001.png").unlink())[0],
     r"annotations\.xml: <image> 1 \(id '1'\): field 'name' names 'frame_000001\.png', which does not exist"),
    ("cvat: no ball label", lambda t: (_cvat(t), (t / "annotations.xml").write_text((t / "annotations.xml").read_text().replace("<name>ball</name>", "<name>bal</name>")))[0],
     r"annotations\.xml: element <labels> has no 'ball' label"),
    ("cvat: video export", lambda t: _file(t, "annotations.xml",
        '<annotations><version>1.1</version><track id="0" label="ball"><box frame="0" outside="0" xtl="1" ytl="1" xbr="5" ybr="5"/></track></annotations>'),
     r"annotations\.xml: element <track>: this is CVAT's video export"),
    ("cvat: entity expansion", lambda t: _file(t, "annotations.xml",
        '<?xml version="1.0"?><!DOCTYPE a [<!ENTITY x "xxxxxxxx">]><annotations>&x;</annotations>'),
     r"annotations\.xml: XML with a DOCTYPE or entities is refused"),
    ("cvat: broken XML", lambda t: _file(t, "annotations.xml", "<annotations><image"), r"annotations\.xml: not valid XML"),
    ("labelstudio: percent over 100", lambda t: _mutate_json(_labelstudio(t), lambda d: _set(d, [0, "annotations", 1, "result", 0, "value", "x"], 99.5)),
     r"\.json: task 0 \(id 1\): result\[0\]: field 'value' box .* outside the 640x480 image"),
    ("labelstudio: rotated box", lambda t: _mutate_json(_labelstudio(t), lambda d: _set(d, [0, "annotations", 1, "result", 0, "value", "rotation"], 30)),
     r"task 0 \(id 1\): result\[0\]: field 'value\.rotation' 30: rotated boxes are not supported"),
    ("labelstudio: width missing", lambda t: _mutate_json(_labelstudio(t), lambda d: d[0]["annotations"][1]["result"][0]["value"].pop("width")),
     r"task 0 \(id 1\): result\[0\]: field 'value\.width' must be a finite number"),
    ("labelstudio: original_width text", lambda t: _mutate_json(_labelstudio(t), lambda d: _set(d, [0, "annotations", 1, "result", 0, "original_width"], "640")),
     r"result\[0\]: field 'original_width' must be a positive integer"),
    ("labelstudio: image missing", lambda t: _mutate_json(_labelstudio(t), lambda d: _set(d, [1, "data", "image"], "/data/local-files/?d=images/gone.png")),
     r"task 1 \(id 2\): field 'data\.image' names 'images/gone\.png', which does not exist"),
    ("labelstudio: keypoint ball", lambda t: _mutate_json(_labelstudio(t), lambda d: _set(d, [0, "annotations", 1, "result", 0], {
        "type": "keypointlabels", "original_width": 640, "original_height": 480, "value": {"x": 5, "y": 5, "keypointlabels": ["ball"]}})),
     r"result\[0\]: field 'type' 'keypointlabels' cannot label a ball"),
    ("labelstudio: no data", lambda t: _mutate_json(_labelstudio(t), lambda d: d[0].pop("data")), r"task 0 \(id 1\): missing field 'data'"),
    ("coco: no ball category (CVAT layout)", lambda t: _mutate_json(_cvat_coco(t) / "annotations" / "instances_default.json",
                                                                    lambda d: d["categories"][0].update(name="balls")),
     r"instances_default\.json: field 'categories' has no 'ball' category"),
    ("auto: unknown JSON", lambda t: _file(t, "x.json", '{"hello": 1}') / "x.json",
     r"x\.json: a JSON file in no label format rt2 reads"),
    ("labelstudio: JSON-MIN export", lambda t: _file(t, "min.json", json.dumps([{"image": "/data/upload/1/a.png", "id": 1, "label": []}])) / "min.json",
     r"min\.json: tasks without field 'data': this looks like Label Studio's JSON-MIN export"),
    ("auto: empty folder", lambda t: (t.mkdir(exist_ok=True), t)[1], r"cannot tell the label format"),
    ("auto: no such path", lambda t: t / "nope", r"nope: no such file or folder"),
]


@pytest.mark.parametrize("case,build,message", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_malformed_label_files_are_refused_in_one_line(tmp_path, case, build, message):
    path = build(tmp_path / "set")
    with pytest.raises(ValueError) as err:
        read_labels(path)
    text = str(err.value)
    assert "\n" not in text and len(text) < 600, text
    assert __import__("re").search(message, text), (case, text)
    assert str(tmp_path / "set") in text, text  # names the file


def test_unknown_format_lists_the_valid_ones(tmp_path):
    with pytest.raises(ValueError, match="unknown label format 'voc'; valid: coco, yolo, labelme, cvat, labelstudio"):
        read_labels(tmp_path, "voc")


def test_label_error_is_a_value_error():
    assert issubclass(LabelError, ValueError)  # the CLI's exit code 2 for bad input


# -- the command line ---------------------------------------------------------------------------------------
def _rt2(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "harness.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def test_convert_command_and_label_format_in_eval(tmp_path):
    src = _labelstudio(tmp_path / "ls")
    r = _rt2("labels", "convert", str(src), "--to", "yolo", "--out", str(tmp_path / "y"))
    assert r.returncode == 0, r.stderr
    assert "read 2 images (1 balls, 1 without a ball) as labelstudio" in r.stdout
    back = read_labels(tmp_path / "y" / "data.yaml")
    np.testing.assert_allclose(back[0].boxes_xywh, [[320, 120, 8, 12]], atol=1e-9)
    again = _rt2("labels", "convert", str(src), "--to", "yolo", "--out", str(tmp_path / "y"))
    assert again.returncode == 2 and "--out" in again.stderr and "not an empty folder" in again.stderr
    bad = _rt2("labels", "convert", str(tmp_path / "nope"), "--to", "coco", "--out", str(tmp_path / "z"))
    assert bad.returncode == 2 and "no such file or folder" in bad.stderr and "Traceback" not in bad.stderr
    ev = _rt2("eval", "detector", "--data", str(tmp_path / "y"), "--label-format", "yolo", "--ball-colour", "any")
    assert ev.returncode == 0, ev.stderr
    assert "2 images" in ev.stdout
    wrong = _rt2("eval", "detector", "--data", str(tmp_path / "y"), "--label-format", "cvat")
    assert wrong.returncode == 2 and "annotations.xml" in wrong.stderr


def test_coco_to_coco_keeps_camera_time_and_ball_colour(tmp_path):
    """What rt2's own sets carry besides the boxes (the camera a frame came from and when: folds by camera and the
    motion cue; what each ball is) survives ``rt2 labels convert --to coco`` (it was dropped: a converted semi-real
    set had no cameras)."""
    from harness.experiments.detector.coco import LabelledImage

    src = tmp_path / "src"
    a, b = _png(src / "a.png"), _png(src / "b.png")
    write_coco(src, [LabelledImage(a, 640, 480, [[10, 10, 8, 8]], [[13.5, 13.5]], camera="cam2", time_s=0.25, ball_colours=("white",)),
                     LabelledImage(b, 640, 480, [[20, 20, 8, 8], [40, 40, 9, 9]], [[23.5, 23.5], [44, 44]], ball_colours=(None, "orange"))])
    r = _rt2("labels", "convert", str(src), "--to", "coco", "--out", str(tmp_path / "c"))
    assert r.returncode == 0, r.stderr
    back = read_coco(tmp_path / "c")
    assert [(li.camera, li.time_s, li.ball_colours) for li in back] == [("cam2", 0.25, ("white",)), (None, None, (None, "orange"))]
