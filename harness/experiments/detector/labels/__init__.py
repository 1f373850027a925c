"""Ball labels in the formats labelling tools export, read into one type and written back.

========== ==================================================================================== ============
format     what it reads                                                                        module
========== ==================================================================================== ============
coco       COCO JSON (``annotations.json``; CVAT's "COCO 1.0" ``annotations/instances_*.json``   coco.py
           with ``images/``; Label Studio's and Roboflow's COCO exports)
yolo       ``data.yaml`` + one ``.txt`` per image (Ultralytics, Roboflow, CVAT "YOLOv8"); also     yolo.py
           Darknet's ``obj.data`` + ``obj.names`` (CVAT "YOLO 1.1")
labelme    one labelme JSON per image                                                           labelme.py
cvat       CVAT for images 1.1 XML (``annotations.xml`` + ``images/``)                          cvat.py
labelstudio Label Studio's JSON export (a list of tasks)                                        labelstudio.py
========== ==================================================================================== ============

:func:`read_labels` takes a file or a folder and ``label_format="auto"`` finds the format from what it
holds (:func:`detect_format`); every reader returns :class:`~harness.experiments.detector.coco.LabelledImage`
and refuses a bad file with one line naming the file and the field. Only the label ``ball`` is read.
:func:`write_labels` writes a data set in any of them (images copied or hard-linked in), so
COCO -> format -> COCO keeps every box (``rt2 labels convert``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, NamedTuple

from checks.files import MAX_DATA_BYTES, read_text_capped
from harness.experiments.detector import coco
from harness.experiments.detector.labels.common import LabelError, place_images
from harness.experiments.detector.labels.cvat import ANNOTATIONS_XML, read_cvat, write_cvat
from harness.experiments.detector.labels.labelme import is_labelme, read_labelme, write_labelme
from harness.experiments.detector.labels.labelstudio import is_labelstudio, read_labelstudio, write_labelstudio
from harness.experiments.detector.labels.yolo import DARKNET_DATA, DATA_YAML, read_yolo, write_yolo

__all__ = ["LABEL_FORMATS", "LabelError", "LabelFormat", "detect_format", "read_labels", "write_labels"]


class LabelFormat(NamedTuple):
    read: Callable  # path -> list[LabelledImage]
    write: Callable  # (out_dir, images placed under out_dir/images) -> path of what it wrote
    what: str


def _read_coco(path) -> list:
    """COCO, also in CVAT's layout: ``annotations/instances_default.json`` naming files in ``../images/``."""
    path = Path(path)
    if path.is_dir() and not (path / coco.ANNOTATIONS_FILE).is_file():
        found = sorted((path / "annotations").glob("instances_*.json")) if (path / "annotations").is_dir() else []
        if not found:
            raise LabelError(f"{path}: no {coco.ANNOTATIONS_FILE} (nor CVAT's annotations/instances_*.json) in this folder")
        return [li for f in found for li in _read_coco(f)]
    json_path = path / coco.ANNOTATIONS_FILE if path.is_dir() else path
    return coco.read_coco(json_path, image_root=_coco_image_root(json_path))


def _coco_image_root(json_path: Path) -> Path:
    """The JSON's folder, or CVAT's ``images/`` beside its ``annotations/`` folder when the first image is there."""
    try:
        doc = json.loads(read_text_capped(json_path, MAX_DATA_BYTES, "COCO file"))
        first = doc["images"][0]["file_name"]
    except (ValueError, KeyError, IndexError, TypeError):
        return json_path.parent  # read_coco names the problem
    images = json_path.parent.parent / "images"
    if isinstance(first, str) and not (json_path.parent / first).exists() and (images / first).is_file():
        return images
    return json_path.parent


def _write_coco(out_dir, images) -> Path:
    return coco.write_coco(out_dir, images)


LABEL_FORMATS: dict[str, LabelFormat] = {
    "coco": LabelFormat(_read_coco, _write_coco, "COCO JSON (annotations.json)"),
    "yolo": LabelFormat(read_yolo, write_yolo, "YOLO: data.yaml + labels/*.txt (Ultralytics, Roboflow)"),
    "labelme": LabelFormat(read_labelme, write_labelme, "labelme: one JSON per image"),
    "cvat": LabelFormat(read_cvat, write_cvat, "CVAT for images 1.1 XML (annotations.xml)"),
    "labelstudio": LabelFormat(read_labelstudio, write_labelstudio, "Label Studio JSON export"),
}


def _format(name: str) -> LabelFormat:
    if name not in LABEL_FORMATS:
        raise ValueError(f"unknown label format {name!r}; valid: {', '.join(LABEL_FORMATS)} (or auto)")
    return LABEL_FORMATS[name]


def _json_kind(path: Path, *, strict: bool = False) -> str | None:
    """Which format a JSON file is in, by its top-level shape (None if none; ``strict``: a parse error is raised)."""
    text = read_text_capped(path, MAX_DATA_BYTES, "label file")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        if strict:
            raise LabelError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
        return None
    if isinstance(doc, dict) and ("images" in doc or "annotations" in doc or "categories" in doc):
        return "coco"
    if isinstance(doc, dict) and "shapes" in doc:
        return "labelme"
    if isinstance(doc, list) and doc and all(isinstance(t, dict) for t in doc[:10]) and any(
            k in doc[0] for k in ("data", "annotations", "completions", "predictions")):
        return "labelstudio"
    if strict and isinstance(doc, list) and doc and isinstance(doc[0], dict) and "image" in doc[0]:
        raise LabelError(f"{path}: tasks without field 'data': this looks like Label Studio's JSON-MIN export; "
                         "export as 'JSON' (the full export, with annotations) instead")
    return None


def detect_format(path) -> str:
    """The label format of a file or folder (module docstring), or ``ValueError`` saying what was looked for."""
    path = Path(path)
    if not path.exists():
        raise LabelError(f"{path}: no such file or folder")
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix in (".yaml", ".yml", ".data"):
            return "yolo"
        if suffix == ".xml":
            return "cvat"
        if suffix == ".json":
            kind = _json_kind(path, strict=True)
            if kind is None:
                raise LabelError(f"{path}: a JSON file in no label format rt2 reads (COCO has 'images' and 'annotations', "
                                 "labelme 'shapes' and 'imagePath', Label Studio is a list of tasks with 'data')")
            return kind
        raise LabelError(f"{path}: not a label file rt2 reads (.json, .xml, data.yaml); give --label-format")
    if (path / coco.ANNOTATIONS_FILE).is_file() or list((path / "annotations").glob("instances_*.json")):
        return "coco"
    if (path / DATA_YAML).is_file() or (path / DARKNET_DATA).is_file() or any(path.glob("*.yaml")) or any(path.glob("*.yml")):
        return "yolo"
    if (path / ANNOTATIONS_XML).is_file():
        return "cvat"
    kinds = {k for k in (_json_kind(f) for f in sorted(path.glob("*.json"))[:50]) if k}
    if not kinds and any(path.rglob("*.json")):
        kinds = {"labelme"} if any(_json_kind(f) == "labelme" for f in list(path.rglob("*.json"))[:50]) else set()
    if len(kinds) == 1:
        return kinds.pop()
    raise LabelError(f"{path}: cannot tell the label format (looked for annotations.json, annotations/instances_*.json, "
                     f"data.yaml, annotations.xml, labelme or Label Studio JSON; found {sorted(kinds) or 'none'}); "
                     "give --label-format")


def read_labels(path, label_format: str = "auto") -> list:
    """Ball labels from ``path`` (a file or folder) in ``label_format`` (one of :data:`LABEL_FORMATS`, or ``auto``)."""
    name = detect_format(path) if label_format == "auto" else label_format
    return _format(name).read(path)


def write_labels(out_dir, images, label_format: str) -> Path:
    """Write ``images`` as a data set in ``label_format`` under ``out_dir``: the images are hard-linked (or
    copied) into ``out_dir/images/`` unless already inside ``out_dir``. Returns the annotation file written."""
    fmt = _format(label_format)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return fmt.write(out_dir, place_images(list(images), out_dir))

