"""labelme JSON: one file per image, as labelme saves it (``version`` 4.x / 5.x)::

    {"version": "5.5.0", "flags": {},
     "shapes": [{"label": "ball", "points": [[x1, y1], [x2, y2]], "group_id": null,
                 "description": "", "shape_type": "rectangle", "flags": {}}],
     "imagePath": "frame_000123.png", "imageData": null,
     "imageHeight": 480, "imageWidth": 640}

``imagePath`` is relative to the JSON's folder (labelme writes ``..\\images\\x.png`` on Windows; the bare
file name is also looked for beside the JSON). Points are pixel coordinates (continuous, as COCO's). A
``ball`` shape may be a ``rectangle`` (two opposite corners, any order), a ``circle`` (centre, then a point
on the circle), or a ``polygon`` (its bounding box); a ``point`` or ``line`` has no size and is refused.
Other labels are ignored; a file with no ``ball`` shape is a background image.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from checks.files import MAX_DATA_BYTES, read_text_capped, short
from harness.experiments.detector.labels.common import LabelError, box_inside, find_image, is_ball, labelled, number

__all__ = ["is_labelme", "read_labelme", "write_labelme"]

_KEYS = ("shapes", "imagePath")


def is_labelme(doc) -> bool:
    return isinstance(doc, dict) and all(k in doc for k in _KEYS)


def _load(path: Path):
    text = read_text_capped(path, MAX_DATA_BYTES, "labelme file")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise LabelError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None


def read_labelme(path) -> list:
    """Ball labels from one labelme JSON file, or from every labelme JSON in a folder (recursively, sorted)."""
    path = Path(path)
    if path.is_dir():
        files = []
        for f in sorted(path.rglob("*.json")):
            doc = _load(f)
            if is_labelme(doc):
                files.append((f, doc))
        if not files:
            raise LabelError(f"{path}: no labelme JSON files (with 'shapes' and 'imagePath') in this folder")
        return [_read_one(f, doc) for f, doc in files]
    return [_read_one(path, _load(path))]


def _read_one(src: Path, doc) -> object:
    if not isinstance(doc, dict):
        raise LabelError(f"{src}: expected a JSON object (a labelme file), got {type(doc).__name__}")
    for key in _KEYS:
        if key not in doc:
            raise LabelError(f"{src}: missing field {key!r} (a labelme file has 'shapes', 'imagePath', 'imageWidth', 'imageHeight')")
    image = find_image(doc["imagePath"], [src.parent], str(src), "imagePath")
    size = []
    for key in ("imageWidth", "imageHeight"):
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise LabelError(f"{src}: field {key!r} must be a positive integer, got {short(v)}")
        size.append(v)
    width, height = size
    if not isinstance(doc["shapes"], list):
        raise LabelError(f"{src}: field 'shapes' must be a list, got {type(doc['shapes']).__name__}")
    boxes = []
    for i, shape in enumerate(doc["shapes"]):
        where = f"{src}: shapes[{i}]"
        if not isinstance(shape, dict) or "label" not in shape:
            raise LabelError(f"{where} must be an object with 'label', 'points' and 'shape_type', got {short(shape)}")
        if not is_ball(shape["label"]):
            continue
        boxes.append(_shape_box(shape, where, width, height))
    return labelled(image, width, height, boxes)


def _shape_box(shape: dict, where: str, width: int, height: int) -> list[float]:
    kind = shape.get("shape_type") or "polygon"  # labelme 3 files have no shape_type: polygons
    pts = shape.get("points")
    if not isinstance(pts, list) or not all(isinstance(p, list) and len(p) == 2 for p in pts):
        raise LabelError(f"{where}: field 'points' must be a list of [x, y] pairs, got {short(pts)}")
    xy = [(number(p[0], where, "points"), number(p[1], where, "points")) for p in pts]
    if kind == "rectangle":
        if len(xy) != 2:
            raise LabelError(f"{where}: field 'points' of a rectangle must be 2 corners, got {len(xy)} points")
        (x1, y1), (x2, y2) = xy
        return box_inside(min(x1, x2), min(y1, y2), abs(x2 - x1), abs(y2 - y1), width, height, where, "points")
    if kind == "circle":
        if len(xy) != 2:
            raise LabelError(f"{where}: field 'points' of a circle must be the centre and a point on it, got {len(xy)} points")
        (cx, cy), (px, py) = xy
        r = math.hypot(px - cx, py - cy)
        return box_inside(cx - r, cy - r, 2 * r, 2 * r, width, height, where, "points")
    if kind == "polygon":
        if len(xy) < 3:
            raise LabelError(f"{where}: field 'points' of a polygon needs at least 3 points, got {len(xy)}")
        xs, ys = [p[0] for p in xy], [p[1] for p in xy]
        return box_inside(min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys), width, height, where, "points")
    raise LabelError(f"{where}: field 'shape_type' {short(kind)} cannot label a ball (it has no size); "
                     "use rectangle, circle or polygon")


def write_labelme(out_dir, images) -> Path:
    """One labelme JSON beside each image (``imagePath`` = its file name; rectangles labelled ``ball``).
    Returns ``out_dir``."""
    from harness.common.outputs import atomic_write_json

    for li in images:
        shapes = [{"label": "ball", "points": [[x, y], [x + w, y + h]], "group_id": None, "description": "",
                   "shape_type": "rectangle", "flags": {}} for x, y, w, h in li.boxes_xywh.tolist()]
        doc = {"version": "5.5.0", "flags": {}, "shapes": shapes, "imagePath": Path(li.path).name, "imageData": None,
               "imageHeight": li.height, "imageWidth": li.width}
        atomic_write_json(Path(li.path).with_suffix(".json"), doc, "labelme file", indent=2)
    return Path(out_dir)
