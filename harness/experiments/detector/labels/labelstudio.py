"""Label Studio's JSON export (``Export`` -> ``JSON``): a list of tasks, each with its annotations::

    [{"id": 1,
      "data": {"image": "/data/upload/3/5f1c2a9e-frame_000123.png"},
      "annotations": [{"id": 7, "was_cancelled": false,
                       "result": [{"id": "Dx_aB91ISN", "type": "rectanglelabels", "from_name": "label",
                                   "to_name": "image", "original_width": 640, "original_height": 480,
                                   "image_rotation": 0,
                                   "value": {"x": 48.6, "y": 42.3, "width": 1.28, "height": 1.69,
                                             "rotation": 0, "rectanglelabels": ["ball"]}}]}],
      "predictions": []}]

``value`` is in percent of the image (0..100): ``x, y`` the top-left corner, ``width, height`` the size
(``rectanglelabels``), or ``x, y`` the centre and ``radiusX, radiusY`` the radii (``ellipselabels``).
Rotated boxes are refused. Per task the first annotation not ``was_cancelled`` is read (predictions,
the model's guesses, are not labels); a task without one was not labelled and is left out, an
annotation with an empty ``result`` is a background image. The image is found by the path in
``data.image``: uploads (``/data/upload/<project>/<8 hex>-<name>``), local files
(``/data/local-files/?d=<path>``) and URLs are looked for, by path and by file name, beside the JSON
and in its ``images/`` folder. Without ``original_width``/``original_height`` the size is read from the image.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlparse

from checks.files import MAX_DATA_BYTES, read_text_capped, short
from harness.experiments.detector.labels.common import LabelError, box_inside, find_image, image_size, is_ball, labelled, number

__all__ = ["is_labelstudio", "read_labelstudio", "write_labelstudio"]

EXPORT_JSON = "result.json"
_UPLOAD_PREFIX = re.compile(r"^[0-9a-f]{8}-")


def is_labelstudio(doc) -> bool:
    return isinstance(doc, list) and bool(doc) and isinstance(doc[0], dict) and "data" in doc[0] and (
        "annotations" in doc[0] or "completions" in doc[0])


def read_labelstudio(path) -> list:
    """Ball labels from a Label Studio JSON export (the file, or a folder holding exactly one such JSON)."""
    path = Path(path)
    if path.is_dir():
        found = [f for f in sorted(path.glob("*.json")) if is_labelstudio(_load(f))]
        if len(found) != 1:
            raise LabelError(f"{path}: expected one Label Studio JSON export in this folder, found {len(found)}")
        path = found[0]
    src = str(path)
    doc = _load(path)
    if not isinstance(doc, list):
        raise LabelError(f"{src}: expected a JSON list of tasks (Label Studio's JSON export), got {type(doc).__name__}")
    roots = [path.parent, path.parent / "images"]
    out = []
    for i, task in enumerate(doc):
        where = f"{src}: task {i} (id {short(task.get('id') if isinstance(task, dict) else None)})"
        if not isinstance(task, dict) or not isinstance(task.get("data"), dict):
            raise LabelError(f"{where}: missing field 'data' (an object naming the image)")
        anns = task.get("annotations", task.get("completions"))  # 'completions': Label Studio before 1.0
        if not isinstance(anns, list):
            raise LabelError(f"{where}: field 'annotations' must be a list, got {short(anns)}")
        ann = next((a for a in anns if isinstance(a, dict) and not a.get("was_cancelled")), None)
        if ann is None:
            continue  # not labelled
        image = _find(_image_ref(task["data"], where), roots, where)
        result = ann.get("result")
        if not isinstance(result, list):
            raise LabelError(f"{where}: field 'annotations[].result' must be a list, got {short(result)}")
        size = None
        boxes = []
        for j, r in enumerate(result):
            rw = f"{where}: result[{j}]"
            if not isinstance(r, dict) or not isinstance(r.get("value"), dict):
                raise LabelError(f"{rw}: field 'value' must be an object, got {short(r)}")
            kind = r.get("type")
            names = r["value"].get(kind) if isinstance(kind, str) else None
            if not (isinstance(names, list) and any(is_ball(n) for n in names)):
                continue
            if "original_width" in r or "original_height" in r:
                size = (_size(r, "original_width", rw), _size(r, "original_height", rw))
            elif size is None:
                size = image_size(image, rw)
            boxes.append(_value_box(kind, r["value"], size, rw))
        width, height = size if size is not None else image_size(image, where)
        out.append(labelled(image, width, height, boxes))
    if not out:
        raise LabelError(f"{src}: no labelled task (every task has no annotation, or only cancelled ones)")
    return out


def _load(path: Path):
    try:
        return json.loads(read_text_capped(path, MAX_DATA_BYTES, "Label Studio export"))
    except json.JSONDecodeError as exc:
        raise LabelError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None


def _size(r: dict, key: str, where: str) -> int:
    v = r.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
        raise LabelError(f"{where}: field {key!r} must be a positive integer, got {short(v)}")
    return v


def _image_ref(data: dict, where: str) -> str:
    """The image path a task names, without Label Studio's URL dressing (see the module docstring)."""
    ref = data.get("image")
    if ref is None:  # a labelling config may call it anything: take the one string value
        strings = [v for v in data.values() if isinstance(v, str)]
        ref = strings[0] if len(strings) == 1 else None
    if not isinstance(ref, str) or not ref:
        raise LabelError(f"{where}: field 'data.image' must name the image, got {short(data)}")
    url = urlparse(ref)
    if "d" in parse_qs(url.query):  # /data/local-files/?d=folder/frame.png
        return unquote(parse_qs(url.query)["d"][0])
    name = unquote(url.path)
    if "/data/upload/" in name:  # uploads get an 8-hex prefix: 5f1c2a9e-frame.png
        return name.rsplit("/", 1)[-1]
    return name.lstrip("/") if url.scheme else name


def _find(ref: str, roots, where: str) -> Path:
    """The image ``ref`` names; an upload's name is also looked for without its 8-hex prefix."""
    try:
        return find_image(ref, roots, where, "data.image")
    except LabelError:
        base = ref.rsplit("/", 1)[-1]
        if not _UPLOAD_PREFIX.match(base):
            raise
        return find_image(_UPLOAD_PREFIX.sub("", base), roots, where, "data.image")


def _value_box(kind: str, v: dict, size, where: str) -> list[float]:
    width, height = size
    if kind == "rectanglelabels":
        if number(v.get("rotation", 0), where, "value.rotation") != 0:
            raise LabelError(f"{where}: field 'value.rotation' {short(v.get('rotation'))}: rotated boxes are not supported; "
                             "draw the ball's box unrotated")
        x, y, w, h = (number(v.get(k), where, f"value.{k}") for k in ("x", "y", "width", "height"))
        return box_inside(x * width / 100, y * height / 100, w * width / 100, h * height / 100, width, height, where, "value")
    if kind == "ellipselabels":
        x, y, rx, ry = (number(v.get(k), where, f"value.{k}") for k in ("x", "y", "radiusX", "radiusY"))
        cx, cy, rx, ry = x * width / 100, y * height / 100, rx * width / 100, ry * height / 100
        return box_inside(cx - rx, cy - ry, 2 * rx, 2 * ry, width, height, where, "value")
    raise LabelError(f"{where}: field 'type' {short(kind)} cannot label a ball (it has no size); use rectanglelabels or ellipselabels")


def write_labelstudio(out_dir, images) -> Path:
    """``out_dir/result.json``: one task per image (``data.image`` = ``/data/local-files/?d=images/...``,
    one ``rectanglelabels`` result per ball). Returns its path."""
    from harness.common.outputs import atomic_write_json

    out_dir = Path(out_dir)
    root = out_dir.resolve()
    tasks = []
    for i, li in enumerate(images):
        rel = Path(li.path).resolve().relative_to(root).as_posix()
        result = [{"id": f"ball{i}_{j}", "type": "rectanglelabels", "from_name": "label", "to_name": "image",
                   "original_width": li.width, "original_height": li.height, "image_rotation": 0,
                   "value": {"x": 100 * x / li.width, "y": 100 * y / li.height, "width": 100 * w / li.width,
                             "height": 100 * h / li.height, "rotation": 0, "rectanglelabels": ["ball"]}}
                  for j, (x, y, w, h) in enumerate(li.boxes_xywh.tolist())]
        tasks.append({"id": i + 1, "data": {"image": f"/data/local-files/?d={rel}"},
                      "annotations": [{"id": i + 1, "was_cancelled": False, "result": result}], "predictions": []})
    return atomic_write_json(out_dir / EXPORT_JSON, tasks, "Label Studio export", indent=1)
