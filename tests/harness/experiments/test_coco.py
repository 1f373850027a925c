"""harness.experiments.detector.coco: the COCO ball-label reader and writer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from harness.experiments.detector.coco import LabelledImage, read_coco, write_coco


def _touch_images(folder: Path, names) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"not really a png")  # the reader checks existence, not content


def _sample(folder: Path) -> list[LabelledImage]:
    _touch_images(folder, ["a.png", "b.png", "c.png"])
    return [
        LabelledImage(folder / "a.png", 640, 480, [[10.0, 20.0, 8.0, 8.0]], [[13.6, 23.4]]),
        LabelledImage(Path("b.png"), 640, 480, np.zeros((0, 4)), np.zeros((0, 2))),  # background
        LabelledImage(folder / "c.png", 320, 240, [[0.0, 0.0, 5.0, 6.0], [300.5, 230.0, 19.5, 10.0]], [[2.0, 2.5], [310.0, 234.5]]),
    ]


def _write_json(folder: Path, doc) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "annotations.json"
    p.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return p


def _doc(**overrides):
    doc = {
        "images": [{"id": 7, "file_name": "a.png", "width": 100, "height": 50}],
        "annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [10, 10, 6, 6]}],
        "categories": [{"id": 1, "name": "ball"}],
    }
    doc.update(overrides)
    return doc


# -- smoke -----------------------------------------------------------------------------------------
def test_round_trip_keeps_boxes_centres_and_background(tmp_path):
    images = _sample(tmp_path)
    extra = [[{"diameter_px": 8.0, "visibility": 1.0}], [], [{"diameter_px": 5.5, "visibility": 0.6}, {"diameter_px": 19.0, "visibility": np.float32(0.5)}]]
    json_path = write_coco(tmp_path, images, extra, image_extra=[{"camera": "cam0"}] * 3, info={"seed": 3})
    assert json_path == tmp_path / "annotations.json"
    back = read_coco(tmp_path)
    assert [b.path for b in back] == [tmp_path / "a.png", tmp_path / "b.png", tmp_path / "c.png"]
    for a, b in zip(images, back):
        assert (a.width, a.height) == (b.width, b.height)
        np.testing.assert_array_equal(a.boxes_xywh, b.boxes_xywh)
        np.testing.assert_array_equal(a.centers_px, b.centers_px)
    assert back[1].n_balls == 0
    doc = json.loads(json_path.read_text())
    assert doc["categories"] == [{"id": 1, "name": "ball", "supercategory": "sports ball"}]
    assert doc["info"]["seed"] == 3
    ann = doc["annotations"][2]
    assert ann["iscrowd"] == 0 and ann["area"] == 19.5 * 10.0 and ann["visibility"] == 0.5
    assert ann["center_px"] == [310.0, 234.5] and ann["diameter_px"] == 19.0
    assert doc["images"][0]["camera"] == "cam0" and doc["images"][1]["file_name"] == "b.png"


def test_reading_the_json_file_directly_is_the_same_as_its_folder(tmp_path):
    write_coco(tmp_path, _sample(tmp_path))
    a, b = read_coco(tmp_path), read_coco(tmp_path / "annotations.json")
    assert [x.path for x in a] == [x.path for x in b]


# -- shapes ----------------------------------------------------------------------------------------
def test_labelled_image_shapes_and_immutability(tmp_path):
    im = LabelledImage("x.png", 10, 10, [], [])
    assert im.boxes_xywh.shape == (0, 4) and im.centers_px.shape == (0, 2) and isinstance(im.path, Path)
    with pytest.raises(ValueError, match="read-only"):
        im.boxes_xywh[...] = 1
    im2 = LabelledImage("x.png", 10, 10, [[1, 1, 2, 2]], [[1.5, 1.5]])
    with pytest.raises(ValueError, match="read-only"):
        im2.boxes_xywh[0, 0] = 0


def test_centre_defaults_to_box_centre_in_rt2_pixels(tmp_path):
    _touch_images(tmp_path, ["a.png"])
    _write_json(tmp_path, _doc())
    (im,) = read_coco(tmp_path)
    # box [10, 16] x [10, 16] in COCO coordinates -> centre 13 -> rt2 pixel 12.5
    np.testing.assert_allclose(im.centers_px, [[12.5, 12.5]])


def test_other_categories_are_ignored_when_ball_exists(tmp_path):
    _touch_images(tmp_path, ["a.png"])
    anns = [
        {"id": 1, "image_id": 7, "category_id": 2, "bbox": [0, 0, 100, 50]},
        {"id": 2, "image_id": 7, "category_id": 1, "bbox": [1, 2, 3, 4]},
    ]
    _write_json(tmp_path, _doc(annotations=anns, categories=[{"id": 1, "name": "Ball"}, {"id": 2, "name": "racket"}]))
    (im,) = read_coco(tmp_path)
    np.testing.assert_array_equal(im.boxes_xywh, [[1, 2, 3, 4]])


# -- bad input -------------------------------------------------------------------------------------
def test_invalid_json_names_file_and_line(tmp_path):
    p = _write_json(tmp_path, '{"images": [\n  oops]}')
    with pytest.raises(ValueError, match=r"annotations\.json: not valid JSON: .* line 2"):
        read_coco(p)


def test_missing_file(tmp_path):
    with pytest.raises(ValueError, match="cannot read COCO file"):
        read_coco(tmp_path / "nope.json")


@pytest.mark.parametrize("key", ["images", "annotations", "categories"])
def test_missing_top_level_field(tmp_path, key):
    doc = _doc()
    del doc[key]
    _write_json(tmp_path, doc)
    with pytest.raises(ValueError, match=f"missing field '{key}'"):
        read_coco(tmp_path)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"images": [{"id": 7, "file_name": "a.png", "width": 100}]}, r"images\[0\]: missing field 'height'"),
        ({"images": [{"id": 7, "file_name": "a.png", "width": 0, "height": 5}]}, "image id 7: field 'width' must be a positive integer"),
        ({"annotations": [{"id": 3, "image_id": 7, "bbox": [1, 1, 2, 2]}]}, r"annotations\[0\] \(id 3\): missing field 'category_id'"),
        ({"annotations": [{"id": 3, "image_id": 99, "category_id": 1, "bbox": [1, 1, 2, 2]}]}, "annotation id 3: field 'image_id' refers to unknown image id 99"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 0, 2]}]}, "annotation id 3: field 'bbox' must have positive width"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [95, 1, 6, 2]}]}, r"annotation id 3: field 'bbox' .* lies outside image id 7 \(100x50, a.png\)"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [-1, 1, 6, 2]}]}, "annotation id 3: field 'bbox' .* lies outside"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2]}]}, "annotation id 3: field 'bbox' must be a list of 4 finite numbers"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2], "center_px": [1, None]}]}, "annotation id 3: field 'center_px' must be a list of 2"),
        ({"categories": [{"id": 1, "name": "person"}, {"id": 2, "name": "racket"}]}, r"no 'ball' category; categories present: \['person', 'racket'\]"),
        ({"images": "a.png"}, "field 'images' must be a list"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2], "ball_colour": "pink"}]},
         r"annotation id 3: field 'ball_colour' must be one of \['white', 'orange'\], got 'pink'"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2], "ball_colour": 1}]},
         "annotation id 3: field 'ball_colour' must be one of"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2], "ball_colour": "White"}]},
         "annotation id 3: field 'ball_colour' must be one of"),
        ({"annotations": [{"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2], "ball_colour": ["white"]}]},
         "annotation id 3: field 'ball_colour' must be one of"),
    ],
)
def test_bad_fields_are_named(tmp_path, change, match):
    _touch_images(tmp_path, ["a.png"])
    _write_json(tmp_path, _doc(**change))
    with pytest.raises(ValueError, match=match):
        read_coco(tmp_path)


def test_duplicate_ids(tmp_path):
    _touch_images(tmp_path, ["a.png"])
    two = [{"id": 7, "file_name": "a.png", "width": 100, "height": 50}] * 2
    _write_json(tmp_path, _doc(images=two))
    with pytest.raises(ValueError, match="image id 7: duplicate image id"):
        read_coco(tmp_path)
    ann = {"id": 3, "image_id": 7, "category_id": 1, "bbox": [1, 1, 2, 2]}
    _write_json(tmp_path, _doc(annotations=[ann, ann]))
    with pytest.raises(ValueError, match="annotation id 3: duplicate annotation id"):
        read_coco(tmp_path)


def test_missing_image_file_is_named(tmp_path):
    _write_json(tmp_path, _doc())
    with pytest.raises(ValueError, match=r"image id 7: field 'file_name' names 'a.png', which does not exist"):
        read_coco(tmp_path)


def test_top_level_must_be_an_object(tmp_path):
    _write_json(tmp_path, "[1, 2]")
    with pytest.raises(ValueError, match="expected a JSON object at the top level, got list"):
        read_coco(tmp_path)


def test_labelled_image_validates_its_arrays():
    with pytest.raises(ValueError, match=r"boxes_xywh must have shape \(n, 4\), got \(1, 3\)"):
        LabelledImage("x.png", 10, 10, [[1, 2, 3]], [[1, 2]])
    with pytest.raises(ValueError, match=r"centers_px must have shape \(1, 2\)"):
        LabelledImage("x.png", 10, 10, [[1, 2, 3, 4]], [])
    with pytest.raises(ValueError, match="width must be a positive integer, got 0"):
        LabelledImage("x.png", 0, 10, [], [])
    with pytest.raises(ValueError, match="must be finite"):
        LabelledImage("x.png", 10, 10, [[1, 2, np.nan, 4]], [[1, 2]])


def test_writer_refuses_bad_boxes_and_extras(tmp_path):
    inside = LabelledImage("a.png", 10, 10, [[1, 1, 2, 2]], [[1.5, 1.5]])
    outside = LabelledImage("a.png", 10, 10, [[9, 1, 2, 2]], [[9.5, 1.5]])
    with pytest.raises(ValueError, match="box 0 of 'a.png' is empty or outside the 10x10 image"):
        write_coco(tmp_path, [outside])
    with pytest.raises(ValueError, match=r"extra\[0\]\[0\] must not redefine \['bbox'\]"):
        write_coco(tmp_path, [inside], [[{"bbox": [0, 0, 1, 1]}]])
    with pytest.raises(ValueError, match=r"extra\[0\] has 2 entries for 1 boxes"):
        write_coco(tmp_path, [inside], [[{}, {}]])
    with pytest.raises(ValueError, match="extra has 2 entries for 1 images"):
        write_coco(tmp_path, [inside], [[{}], [{}]])
    with pytest.raises(ValueError, match=r"images\[0\] must be a LabelledImage, got dict"):
        write_coco(tmp_path, [{"path": "a.png"}])
    with pytest.raises(ValueError, match="not JSON-serialisable or not finite"):
        write_coco(tmp_path, [inside], [[{"visibility": float("nan")}]])


# -- statistical: random round trips ---------------------------------------------------------------
def test_random_round_trips_are_exact(tmp_path):
    rng = np.random.default_rng(5)
    names = [f"im{i}.png" for i in range(20)]
    _touch_images(tmp_path, names)
    images = []
    for n in names:
        k = int(rng.integers(0, 4))
        wh = rng.uniform(1, 30, (k, 2))
        xy = rng.uniform(0, 1, (k, 2)) * ([640, 480] - wh)
        images.append(LabelledImage(n, 640, 480, np.hstack([xy, wh]), xy + wh / 2 - 0.5 + rng.normal(0, 0.2, (k, 2))))
    write_coco(tmp_path, images)
    back = read_coco(tmp_path)
    for a, b in zip(images, back):
        np.testing.assert_array_equal(a.boxes_xywh, b.boxes_xywh)
        np.testing.assert_array_equal(a.centers_px, b.centers_px)


def test_a_declared_ball_colour_round_trips_per_box(tmp_path):
    _touch_images(tmp_path, ["a.png", "b.png"])
    images = [LabelledImage(tmp_path / "a.png", 100, 50, [[1, 1, 4, 4], [10, 10, 5, 5], [20, 20, 6, 6]], [[2, 2], [12, 12], [22, 22]],
                            ball_colours=("white", None, "orange")),
              LabelledImage(tmp_path / "b.png", 100, 50, [[1, 1, 4, 4]], [[2, 2]])]
    write_coco(tmp_path, images)
    doc = json.loads((tmp_path / "annotations.json").read_text())
    assert [a.get("ball_colour") for a in doc["annotations"]] == ["white", None, "orange", None]
    back = read_coco(tmp_path)
    assert back[0].ball_colours == ("white", None, "orange") and back[1].ball_colours == ()
    kept = back[0].only([True, False, True])
    assert kept.ball_colours == ("white", "orange") and kept.centers_px.tolist() == [[2, 2], [22, 22]]
    assert back[0].only([1]).ball_colours == ()  # no colour known among what is left: none
    assert back[1].only([False]).n_balls == 0


@pytest.mark.parametrize("colours, match", [
    (("white",), r"ball_colours must be \(\) or one of"),  # one for two boxes
    (("white", "pink"), "ball_colours must be"),
    (("white", 3), "ball_colours must be"),
])
def test_labelled_image_refuses_bad_ball_colours(tmp_path, colours, match):
    with pytest.raises(ValueError, match=match):
        LabelledImage(tmp_path / "a.png", 100, 50, [[1, 1, 4, 4], [10, 10, 5, 5]], [[2, 2], [12, 12]], ball_colours=colours)


def test_the_writer_refuses_a_bad_ball_colour_among_the_extras(tmp_path):
    _touch_images(tmp_path, ["a.png"])
    li = LabelledImage(tmp_path / "a.png", 100, 50, [[1, 1, 4, 4]], [[2, 2]])
    with pytest.raises(ValueError, match=r"extra\[0\]\[0\] field 'ball_colour' must be one of"):
        write_coco(tmp_path, [li], [[{"ball_colour": "blue"}]])
    write_coco(tmp_path, [li], [[{"ball_colour": "orange"}]])  # the label page keeps a file's own field so
    assert read_coco(tmp_path)[0].ball_colours == ("orange",)
