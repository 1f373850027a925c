"""Ball labels in COCO format: read what labelling tools export, write what our simulator makes.

COCO (cocodataset.org/#format-data) is what CVAT, Label Studio and Roboflow export, so users bring
their own labelled images the same way as our synthetic data sets. A data set is a folder with
``annotations.json`` and the images it names (file names relative to the JSON's folder)::

    {"info": {...},
     "images":      [{"id": 1, "file_name": "f000000_cam0.png", "width": 640, "height": 480}, ...],
     "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [x, y, w, h],
                      "area": w * h, "iscrowd": 0,
                      "center_px": [u, v], "diameter_px": d, "visibility": 0.93, "ball_colour": "white"}, ...],
     "categories":  [{"id": 1, "name": "ball"}]}

Pixel conventions (they differ by half a pixel, and a sub-pixel tracker cares):

* ``bbox`` is COCO's: continuous coordinates where the image covers ``[0, width] x [0, height]``,
  so the top-left pixel spans ``[0, 1] x [0, 1]`` (what CVAT / Label Studio / Roboflow write).
* ``center_px`` (ours, optional per annotation) and :attr:`LabelledImage.centers_px` use the rt2 /
  OpenCV convention of :class:`tracker.Camera`: pixel ``(0, 0)`` is the *centre* of the top-left
  pixel. Without ``center_px`` the centre is the box centre, ``(x + w/2 - 0.5, y + h/2 - 0.5)``.

Images with no ball annotation are background examples. Only the category named ``ball`` is read;
other categories are ignored, and a file without a ``ball`` category is refused.

``ball_colour`` (ours, optional per annotation: ``"white"`` or ``"orange"``) says what the ball is, where the
set's maker knows it (``rt2 sim dataset``, the drawn stand-ins): a white ball under warm light or on a red rug
can look saturated enough to be measured orange (:func:`harness.experiments.detector.train.ball_colour`), and a
colour chosen by measuring would drop it from a white ball's evaluation and count the detector's hit on it as an
outlier. Without it, the colour is measured.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from harness.common.outputs import atomic_write_text
from checks.files import MAX_DATA_BYTES, read_text_capped, short

__all__ = ["ANNOTATIONS_FILE", "BALL_CATEGORY", "LABEL_COLOURS", "LabelledImage", "read_coco", "write_coco"]

ANNOTATIONS_FILE = "annotations.json"
BALL_CATEGORY = "ball"
_CORE_KEYS = ("id", "image_id", "category_id", "bbox", "area", "iscrowd", "center_px")
#: what an annotation's ``ball_colour`` may say (module docstring)
LABEL_COLOURS = ("white", "orange")
_BOX_TOL_PX = 1e-3  # boxes may touch the image border up to rounding


@dataclass(frozen=True)
class LabelledImage:
    """One image and its ball labels.

    path : image file (absolute when read by :func:`read_coco`; for :func:`write_coco` absolute
        or relative to the output folder)
    width, height : image size in pixels
    boxes_xywh : (n, 4) float COCO boxes ``[x, y, w, h]``, pixels (image covers [0, width] x [0, height])
    centers_px : (n, 2) float ball centres, rt2 pixels ((0, 0) = centre of the top-left pixel)
    camera : the rig camera that took it (COCO image field ``camera``, as ``rt2 sim dataset`` and ``rt2 label
        --auto`` write it: a name, or an integer read as one; a field of another kind is not read), or None
    time_s : when the camera took it, seconds (COCO image field ``time_s``, as ``rt2 sim dataset`` writes it), or None;
        a fixed camera's images in time order are a sequence (``rt2 eval detector --motion-cue``)
    ball_colours : () (no box's colour known: it is measured where it matters), or per box ``"white"``, ``"orange"``
        or None (unknown): the annotations' ``ball_colour`` (module docstring)
    """

    path: Path
    width: int
    height: int
    boxes_xywh: np.ndarray
    centers_px: np.ndarray
    camera: str | None = None
    time_s: float | None = None
    ball_colours: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "path", Path(self.path))
        t = self.time_s
        if t is not None:
            if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not math.isfinite(t):
                raise ValueError(f"LabelledImage {str(self.path)!r}: time_s must be None or a finite number of seconds, got {short(t)}")
            object.__setattr__(self, "time_s", float(t))
        if self.camera is not None and (not isinstance(self.camera, str) or not self.camera):
            raise ValueError(f"LabelledImage {str(self.path)!r}: camera must be None or a non-empty name, got {short(self.camera)}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValueError(f"LabelledImage {str(self.path)!r}: {name} must be a positive integer, got {short(v)}")
            object.__setattr__(self, name, int(v))
        boxes = _as_rows(self.boxes_xywh, 4)
        centers = _as_rows(self.centers_px, 2)
        if boxes.ndim != 2 or boxes.shape[1] != 4:
            raise ValueError(f"LabelledImage {str(self.path)!r}: boxes_xywh must have shape (n, 4), got {np.shape(self.boxes_xywh)}")
        if centers.shape != (len(boxes), 2):
            raise ValueError(
                f"LabelledImage {str(self.path)!r}: centers_px must have shape ({len(boxes)}, 2) to match boxes_xywh, "
                f"got {np.shape(self.centers_px)}"
            )
        if not (np.isfinite(boxes).all() and np.isfinite(centers).all()):
            raise ValueError(f"LabelledImage {str(self.path)!r}: boxes_xywh and centers_px must be finite")
        for arr in (boxes, centers):
            arr.setflags(write=False)
        object.__setattr__(self, "boxes_xywh", boxes)
        object.__setattr__(self, "centers_px", centers)
        colours = tuple(self.ball_colours)
        if colours and (len(colours) != len(boxes) or any(c is not None and c not in LABEL_COLOURS for c in colours)):
            raise ValueError(f"LabelledImage {str(self.path)!r}: ball_colours must be () or one of {LABEL_COLOURS} or None per box "
                             f"({len(boxes)}), got {short(self.ball_colours)}")
        object.__setattr__(self, "ball_colours", colours if any(c is not None for c in colours) else ())

    def only(self, keep) -> "LabelledImage":
        """The same image with only the boxes ``keep`` (a boolean mask or indices), their centres and colours."""
        idx = np.arange(self.n_balls)[np.asarray(keep)] if self.n_balls else np.zeros(0, int)
        colours = tuple(self.ball_colours[i] for i in idx) if self.ball_colours else ()
        return dataclasses.replace(self, boxes_xywh=self.boxes_xywh[idx], centers_px=self.centers_px[idx], ball_colours=colours)

    @property
    def n_balls(self) -> int:
        return len(self.boxes_xywh)


def _as_rows(value, n: int) -> np.ndarray:
    """Float array; an empty input (``[]``, ``np.zeros(0)``) becomes shape (0, n)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"LabelledImage: expected a numeric (k, {n}) array, got {short(value)}") from None
    return arr.reshape(0, n) if arr.size == 0 else arr


# -- reading -------------------------------------------------------------------------------------
def read_coco(path, *, image_root=None) -> list[LabelledImage]:
    """Read ball labels from a COCO JSON file, or from a folder holding ``annotations.json``.

    path : the JSON file or its folder; image ``file_name`` entries are relative to the JSON's folder
    image_root : the folder ``file_name`` is relative to instead (CVAT's COCO export keeps the JSON in
        ``annotations/`` and the images in ``images/``)
    returns one :class:`LabelledImage` per entry of ``images`` (in file order; boxes in annotation order)

    Raises ``ValueError`` naming the file, the field (and annotation / image id) for: invalid JSON,
    missing ``images`` / ``annotations`` / ``categories`` or fields within them, duplicate ids,
    annotations of unknown images, no ``ball`` category, boxes with non-positive size or outside the
    image, malformed ``center_px``, and image files that do not exist.
    """
    path = Path(path)
    json_path = path / ANNOTATIONS_FILE if path.is_dir() else path
    src = str(json_path)
    text = read_text_capped(json_path, MAX_DATA_BYTES, "COCO file")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{src}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{src}: expected a JSON object at the top level, got {type(data).__name__}")
    for key in ("images", "annotations", "categories"):
        if key not in data:
            raise ValueError(f"{src}: missing field {key!r} (a COCO file has 'images', 'annotations' and 'categories')")
        if not isinstance(data[key], list):
            raise ValueError(f"{src}: field {key!r} must be a list, got {type(data[key]).__name__}")

    ball_ids = _ball_category_ids(data["categories"], src)
    root = json_path.parent if image_root is None else Path(image_root)
    images: dict = {}
    order = []
    for i, im in enumerate(data["images"]):
        where = f"{src}: images[{i}]"
        if not isinstance(im, dict):
            raise ValueError(f"{where} must be an object, got {type(im).__name__}")
        for key in ("id", "file_name", "width", "height"):
            if key not in im:
                raise ValueError(f"{where}: missing field {key!r}")
        where = f"{src}: image id {short(im['id'])}"
        if im["id"] in images:
            raise ValueError(f"{where}: duplicate image id")
        w, h = im["width"], im["height"]
        for name, v in (("width", w), ("height", h)):
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise ValueError(f"{where}: field {name!r} must be a positive integer, got {short(v)}")
        if not isinstance(im["file_name"], str) or not im["file_name"]:
            raise ValueError(f"{where}: field 'file_name' must be a non-empty string, got {short(im['file_name'])}")
        file = _inside(root, im["file_name"], where)
        if not file.is_file():
            raise ValueError(f"{where}: field 'file_name' names {short(im['file_name'])}, which does not exist (looked for {str(file)!r})")
        camera = im.get("camera")  # rt2's field; another tool's camera of another kind (a make, an object) is not a name
        camera = str(camera) if (isinstance(camera, str) and camera) or (isinstance(camera, int) and not isinstance(camera, bool)) else None
        t = im.get("time_s")
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t)):
            raise ValueError(f"{where}: field 'time_s' must be a finite number of seconds, got {short(t)}")
        images[im["id"]] = (file, w, h, [], [], camera, t, [])
        order.append(im["id"])

    seen_ann = set()
    for i, ann in enumerate(data["annotations"]):
        if not isinstance(ann, dict):
            raise ValueError(f"{src}: annotations[{i}] must be an object, got {type(ann).__name__}")
        for key in ("id", "image_id", "category_id", "bbox"):
            if key not in ann:
                raise ValueError(f"{src}: annotations[{i}] (id {short(ann.get('id'))}): missing field {key!r}")
        where = f"{src}: annotation id {short(ann['id'])}"
        if ann["id"] in seen_ann:
            raise ValueError(f"{where}: duplicate annotation id")
        seen_ann.add(ann["id"])
        if ann["image_id"] not in images:
            raise ValueError(f"{where}: field 'image_id' refers to unknown image id {short(ann['image_id'])}")
        if ann["category_id"] not in ball_ids:
            continue
        file, w, h, boxes, centers, _, _, colours = images[ann["image_id"]]
        box = _numbers(ann["bbox"], 4, "bbox", where)
        x, y, bw, bh = box
        if bw <= 0 or bh <= 0:
            raise ValueError(f"{where}: field 'bbox' must have positive width and height, got {short(ann['bbox'])}")
        if x < -_BOX_TOL_PX or y < -_BOX_TOL_PX or x + bw > w + _BOX_TOL_PX or y + bh > h + _BOX_TOL_PX:
            raise ValueError(
                f"{where}: field 'bbox' {short(ann['bbox'])} lies outside image id {short(ann['image_id'])} ({w}x{h}, {file.name})"
            )
        if "center_px" in ann:
            center = _numbers(ann["center_px"], 2, "center_px", where)
        else:
            center = [x + bw / 2 - 0.5, y + bh / 2 - 0.5]
        colour = ann.get("ball_colour")
        if colour is not None and colour not in LABEL_COLOURS:
            raise ValueError(f"{where}: field 'ball_colour' must be one of {list(LABEL_COLOURS)}, got {short(colour)}")
        boxes.append(box)
        centers.append(center)
        colours.append(colour)

    out = []
    for image_id in order:
        file, w, h, boxes, centers, camera, t, colours = images[image_id]
        out.append(
            LabelledImage(
                path=file,
                width=w,
                height=h,
                boxes_xywh=np.array(boxes, float).reshape(-1, 4),
                centers_px=np.array(centers, float).reshape(-1, 2),
                camera=camera,
                time_s=t,
                ball_colours=tuple(colours),
            )
        )
    return out


def _ball_category_ids(categories: list, src: str) -> set:
    names = []
    ids = set()
    for i, cat in enumerate(categories):
        if not isinstance(cat, dict) or "id" not in cat or "name" not in cat:
            raise ValueError(f"{src}: categories[{i}] must be an object with 'id' and 'name', got {short(cat)}")
        names.append(cat["name"])
        if isinstance(cat["name"], str) and cat["name"].strip().lower() == BALL_CATEGORY:
            ids.add(cat["id"])
    if not ids:
        raise ValueError(f"{src}: field 'categories' has no {BALL_CATEGORY!r} category; categories present: {short(names)}")
    return ids


def _inside(root: Path, file_name: str, where: str) -> Path:
    """``root / file_name``, refusing a name that leaves the data folder (absolute, ``..``, a drive)."""
    rel = Path(file_name)
    if rel.is_absolute() or rel.drive or ".." in rel.parts or "\\" in file_name:
        raise ValueError(f"{where}: field 'file_name' {short(file_name)} must be a path inside the data folder "
                         f"{str(root)!r} (relative, without '..')")
    return root / rel


def _numbers(value, n: int, field: str, where: str) -> list[float]:
    ok = isinstance(value, (list, tuple)) and len(value) == n
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise ValueError(f"{where}: field {field!r} must be a list of {n} finite numbers, got {short(value)}")
    return [float(v) for v in value]


# -- writing -------------------------------------------------------------------------------------
def write_coco(
    out_dir,
    images: Sequence[LabelledImage],
    extra: Sequence[Sequence[Mapping]] | None = None,
    *,
    image_extra: Sequence[Mapping] | None = None,
    info: Mapping | None = None,
) -> Path:
    """Write ``out_dir/annotations.json`` for ``images`` (the image files are the caller's job).

    images : the labelled images; ``path`` absolute or relative to ``out_dir`` (stored relative)
    extra : optional, per image a sequence of one mapping per box with more annotation fields,
        e.g. ``{"diameter_px": 7.9, "visibility": 0.93}`` (JSON-serialisable; must not redefine
        ``id``, ``image_id``, ``category_id``, ``bbox``, ``area``, ``iscrowd``, ``center_px``)
    image_extra : optional, per image a mapping of more image fields (e.g. ``{"camera": "cam2"}``)
    info : the COCO ``info`` object (a description and the pixel convention are filled in when absent)
    returns the path of the JSON file

    Every annotation has category ``ball`` (id 1), ``iscrowd: 0``, ``area = w * h`` and
    ``center_px`` (rt2 pixel convention, see the module docstring); ``ball_colour`` where the image's
    :attr:`LabelledImage.ball_colours` knows it. An image's ``camera`` and ``time_s`` are written where it has them.
    """
    out_dir = Path(out_dir)
    images = list(images)
    for i, im in enumerate(images):
        if not isinstance(im, LabelledImage):
            raise ValueError(f"write_coco: images[{i}] must be a LabelledImage, got {type(im).__name__}")
    if extra is not None:
        extra = list(extra)
        if len(extra) != len(images):
            raise ValueError(f"write_coco: extra has {len(extra)} entries for {len(images)} images")
    if image_extra is not None:
        image_extra = list(image_extra)
        if len(image_extra) != len(images):
            raise ValueError(f"write_coco: image_extra has {len(image_extra)} entries for {len(images)} images")
    out_dir.mkdir(parents=True, exist_ok=True)
    root = out_dir.resolve()

    img_rows, ann_rows = [], []
    for i, im in enumerate(images):
        path = im.path if im.path.is_absolute() else root / im.path
        rel = Path(os.path.relpath(path, root))
        if ".." in rel.parts:
            raise ValueError(f"write_coco: image {str(im.path)!r} lies outside the output folder {str(root)!r}; "
                             "a data set's images live in its folder")
        row = {"id": i + 1, "file_name": rel.as_posix(), "width": im.width, "height": im.height}
        if im.camera is not None:  # what read_coco reads back (image_extra may say it again)
            row["camera"] = im.camera
        if im.time_s is not None:
            row["time_s"] = im.time_s
        if image_extra is not None:
            row.update(_extra_fields(image_extra[i], ("id", "file_name", "width", "height"), f"image_extra[{i}]"))
        img_rows.append(row)
        per_box = extra[i] if extra is not None else None
        if per_box is not None and len(per_box) != im.n_balls:
            raise ValueError(f"write_coco: extra[{i}] has {len(per_box)} entries for {im.n_balls} boxes of {str(im.path)!r}")
        for j, (box, center) in enumerate(zip(im.boxes_xywh, im.centers_px)):
            x, y, w, h = (float(v) for v in box)
            if w <= 0 or h <= 0 or x < -_BOX_TOL_PX or y < -_BOX_TOL_PX or x + w > im.width + _BOX_TOL_PX or y + h > im.height + _BOX_TOL_PX:
                raise ValueError(
                    f"write_coco: box {j} of {str(im.path)!r} is empty or outside the {im.width}x{im.height} image: {box.tolist()}"
                )
            ann = {
                "id": len(ann_rows) + 1,
                "image_id": i + 1,
                "category_id": 1,
                "bbox": [x, y, w, h],
                "area": w * h,
                "iscrowd": 0,
                "center_px": [float(center[0]), float(center[1])],
            }
            if im.ball_colours and im.ball_colours[j] is not None:
                ann["ball_colour"] = im.ball_colours[j]
            if per_box is not None:  # (may give ``ball_colour`` too: the label page keeps a file's fields so)
                ann.update(_extra_fields(per_box[j], _CORE_KEYS, f"extra[{i}][{j}]"))
                if ann.get("ball_colour") not in (None, *LABEL_COLOURS):
                    raise ValueError(f"write_coco: extra[{i}][{j}] field 'ball_colour' must be one of {list(LABEL_COLOURS)}, "
                                     f"got {short(ann['ball_colour'])}")
            ann_rows.append(ann)

    info = dict(info or {})
    info.setdefault("description", "rt2 ball labels")
    info.setdefault("center_px_convention", "rt2/OpenCV: pixel (0, 0) is the centre of the top-left pixel")
    doc = {
        "info": info,
        "images": img_rows,
        "annotations": ann_rows,
        "categories": [{"id": 1, "name": BALL_CATEGORY, "supercategory": "sports ball"}],
    }
    json_path = out_dir / ANNOTATIONS_FILE
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"write_coco: a field is not JSON-serialisable or not finite: {exc}") from None
    atomic_write_text(json_path, text + "\n", "annotations")  # never a half-written annotations.json
    return json_path


def _extra_fields(fields: Mapping, reserved: tuple, where: str) -> dict:
    if not isinstance(fields, Mapping):
        raise ValueError(f"write_coco: {where} must be a mapping, got {type(fields).__name__}")
    clash = sorted(set(fields) & set(reserved))
    if clash:
        raise ValueError(f"write_coco: {where} must not redefine {clash}")
    return {str(k): _plain(v) for k, v in fields.items()}


def _plain(value):
    """numpy scalars / arrays -> JSON-friendly Python values."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
