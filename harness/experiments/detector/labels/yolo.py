"""YOLO labels with their ``data.yaml``, as Ultralytics, Roboflow ("YOLOv8"/"YOLO11") and CVAT ("YOLOv8") export.

A data set is a ``data.yaml`` and one text file of labels per image::

    # data.yaml                      # Roboflow writes ../train/images (relative to its own folder;
    train: images/train              #   Ultralytics, and so rt2, drop the leading ../ when that is not found)
    val: images/val                  # a folder of images, a .txt list of image paths, or a list of either
    names: {0: ball}                 # or a list: names: [ball]; nc: 1 optional
    path: .                          # optional root of the paths above (relative to the yaml's folder)

    # labels/train/frame_000123.txt (the image's path with its last /images/ replaced by /labels/, .txt):
    0 0.512 0.433 0.0125 0.0167      # class  x_centre y_centre width height, all as fractions of the image
    0 0.50 0.42 0.52 0.43 0.51 0.44  # or a polygon (segmentation, oriented-box exports): its bounding box is read
                                     # (a pose data set, with kpt_shape in data.yaml: the box before the keypoints)

Darknet's layout (CVAT's "YOLO 1.1" export) is read too: ``obj.data`` (``names = obj.names``,
``train = train.txt``, ``valid = valid.txt``), ``obj.names`` (one class per line), and each image's
``.txt`` beside it in ``obj_train_data/`` (the lists' ``data/`` prefix is Darknet's and is dropped).

An image without a label file, or with an empty one, has no ball (a background image). Only the class
named ``ball`` is read. Every split (train, val, test) is read; an image in several splits once; a
``test`` folder that does not exist is skipped (Roboflow names one whether or not it exported it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from checks.files import MAX_CONFIG_BYTES, MAX_DATA_BYTES, load_yaml_checked, read_text_capped, short
from harness.experiments.detector.labels.common import IMAGE_SUFFIXES, LabelError, box_inside, image_size, is_ball, labelled, number

__all__ = ["DATA_YAML", "read_yolo", "write_yolo"]

DATA_YAML = "data.yaml"
DARKNET_DATA = "obj.data"
IMAGE_LIST = "images.txt"
_SPLITS = ("train", "val", "test")


def _yaml_path(path: Path) -> Path:
    if path.is_dir():
        found = [path / DATA_YAML] if (path / DATA_YAML).is_file() else sorted(path.glob("*.yaml")) + sorted(path.glob("*.yml"))
        if not found:
            raise LabelError(f"{path}: no {DATA_YAML} (a YOLO data set names its images and classes there)")
        return found[0]
    return path


def _ball_class(doc: dict, src: str) -> tuple[int, int]:
    """(the ball's class id, the number of classes) from ``names`` (a list or an {id: name} mapping)."""
    if "names" not in doc:
        raise LabelError(f"{src}: missing field 'names' (the class names, e.g. names: [ball])")
    names = doc["names"]
    if isinstance(names, list):
        names = dict(enumerate(names))
    if not isinstance(names, dict) or not names or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in names):
        raise LabelError(f"{src}: field 'names' must be a list of class names or a mapping from class id to name, got {short(doc['names'])}")
    ball = [k for k, v in names.items() if is_ball(v)]
    if not ball:
        raise LabelError(f"{src}: field 'names' has no 'ball' class; classes present: {short(list(names.values()))}")
    nc = max(names) + 1
    if "nc" in doc and (isinstance(doc["nc"], bool) or not isinstance(doc["nc"], int) or doc["nc"] < nc):
        raise LabelError(f"{src}: field 'nc' must be an integer of at least {nc} (the classes named), got {short(doc['nc'])}")
    return ball[0], nc


def _split_images(entry, root: Path, src: str, field: str) -> list[Path]:
    """The image files one split names: a folder (searched recursively), a .txt list, or a list of those."""
    if isinstance(entry, list):
        return [p for i, e in enumerate(entry) for p in _split_images(e, root, src, f"{field}[{i}]")]
    if not isinstance(entry, str) or not entry.strip():
        raise LabelError(f"{src}: field {field!r} must be a folder, a .txt list of images or a list of those, got {short(entry)}")
    p = Path(entry)
    p = p if p.is_absolute() else root / p
    if not p.exists() and entry.startswith("../"):  # Roboflow's data.yaml: ../train/images beside the yaml
        p = root / entry[3:]
    if p.is_dir():
        return sorted(q for q in p.rglob("*") if q.suffix.lower() in IMAGE_SUFFIXES and q.is_file())
    if p.is_file() and p.suffix == ".txt":
        out = []
        for line in read_text_capped(p, MAX_DATA_BYTES, "YOLO image list").splitlines():
            line = line.strip()
            if line:  # Ultralytics: ./x is relative to the list's folder, other relative paths to the root
                q = Path(line) if Path(line).is_absolute() else (p.parent / line[2:] if line.startswith("./") else root / line)
                if not q.is_file() and line.startswith("data/"):  # Darknet lists data/obj_train_data/x.jpg
                    q = root / line[len("data/"):]
                if not q.is_file():
                    raise LabelError(f"{p}: lists {short(line)}, which does not exist (looked for {str(q)!r})")
                out.append(q)
        return out
    raise LabelError(f"{src}: field {field!r} names {short(entry)}, which does not exist (looked for {str(p)!r})")


def _exists(entry: str, root: Path) -> bool:
    p = Path(entry) if Path(entry).is_absolute() else root / entry
    return p.exists() or (entry.startswith("../") and (root / entry[3:]).exists())


def label_path(image: Path) -> Path:
    """Ultralytics' rule: the image's path with its last ``/images/`` replaced by ``/labels/``, suffix ``.txt``."""
    s = image.as_posix()
    i = s.rfind("/images/")
    if i < 0:
        return image.with_suffix(".txt")
    return Path(s[:i] + "/labels/" + s[i + len("/images/"):]).with_suffix(".txt")


def _darknet(path: Path) -> tuple[dict, str, str]:
    """Darknet's ``obj.data`` (``key = value`` lines) as the data.yaml keys: train/val lists and the names
    read from ``obj.names`` (one per line). Returns (doc, the file naming the classes, source for messages)."""
    src = str(path)
    doc = {}
    for n, line in enumerate(read_text_capped(path, MAX_CONFIG_BYTES, "YOLO obj.data").splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if line:
            key, sep, value = line.partition("=")
            if not sep:
                raise LabelError(f"{src}: line {n}: expected 'key = value', got {short(line)}")
            doc[key.strip()] = value.strip()
    if not doc.get("names"):
        raise LabelError(f"{src}: missing field 'names' (the file of class names, e.g. names = obj.names)")
    names = path.parent / doc["names"]
    if not names.is_file() and doc["names"].startswith("data/"):
        names = path.parent / doc["names"][len("data/"):]
    if not names.is_file():
        raise LabelError(f"{src}: field 'names' names {short(doc['names'])}, which does not exist (looked for {str(names)!r})")
    classes = [ln.strip() for ln in read_text_capped(names, MAX_CONFIG_BYTES, "YOLO obj.names").splitlines() if ln.strip()]
    out = {"names": classes}
    for key, split in (("train", "train"), ("valid", "val")):
        if doc.get(key):
            out[split] = doc[key][len("data/"):] if doc[key].startswith("data/") and not (path.parent / doc[key]).exists() else doc[key]
    return out, str(names), src


def read_yolo(path) -> list:
    """Ball labels of a YOLO data set: ``path`` is its ``data.yaml`` (Ultralytics) or ``obj.data`` (Darknet,
    CVAT's "YOLO 1.1"), or the folder holding one (module docstring)."""
    path = Path(path)
    darknet = path / DARKNET_DATA if path.is_dir() and (path / DARKNET_DATA).is_file() and not (path / DATA_YAML).is_file() else (
        path if path.suffix == ".data" else None)
    if darknet is not None:
        yml = darknet
        doc, names_src, src = _darknet(darknet)
        ball, nc = _ball_class(doc, names_src)
    else:
        yml = _yaml_path(path)
        src = str(yml)
        doc = load_yaml_checked(yml, "YOLO data.yaml", max_bytes=MAX_CONFIG_BYTES)
        if not isinstance(doc, dict):
            raise LabelError(f"{src}: expected a mapping (train, val, names), got {type(doc).__name__}")
        ball, nc = _ball_class(doc, src)
    root = yml.parent
    if doc.get("path") not in (None, ""):
        if not isinstance(doc["path"], str):
            raise LabelError(f"{src}: field 'path' must be a folder, got {short(doc['path'])}")
        root = Path(doc["path"]) if Path(doc["path"]).is_absolute() else yml.parent / doc["path"]
        if not root.is_dir():
            raise LabelError(f"{src}: field 'path' names {short(doc['path'])}, which is not a folder (looked for {str(root)!r})")
    splits = [k for k in _SPLITS if doc.get(k) not in (None, "")]
    if not splits:
        raise LabelError(f"{src}: no field 'train', 'val' or 'test' names any images")
    seen, images = set(), []
    for k in splits:
        if k == "test" and isinstance(doc[k], str) and not _exists(doc[k], root):
            continue  # Roboflow lists test: ../test/images whether or not it exported a test split
        for p in _split_images(doc[k], root, src, k):
            if p.resolve() not in seen:
                seen.add(p.resolve())
                images.append(p)
    out = []
    for image in images:
        width, height = image_size(image, src)
        txt = image.with_suffix(".txt") if darknet is not None else label_path(image)  # Darknet: beside the image
        boxes = _read_label_file(txt, ball, nc, width, height, pose="kpt_shape" in doc)
        out.append(labelled(image, width, height, boxes))
    return out


def _read_label_file(txt: Path, ball: int, nc: int, width: int, height: int, *, pose: bool = False) -> list:
    """Boxes of class ``ball`` in one label file; ``pose``: a pose data set (``kpt_shape``), whose lines are a
    box followed by keypoints, so only the first 5 fields are read."""
    if not txt.is_file():
        return []
    boxes = []
    for n, line in enumerate(read_text_capped(txt, MAX_CONFIG_BYTES, "YOLO label file").splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        where = f"{txt}: line {n}"
        if pose and len(fields) > 5:
            fields = fields[:5]
        polygon = len(fields) >= 7 and len(fields) % 2 == 1  # segmentation: class x1 y1 x2 y2 x3 y3 ...
        if len(fields) != 5 and not polygon:
            raise LabelError(f"{where}: expected 5 fields 'class x_centre y_centre width height' (or a polygon "
                             f"'class x1 y1 x2 y2 x3 y3 ...'), got {len(fields)}: {short(line)}")
        try:
            cls = int(fields[0])
        except ValueError:
            raise LabelError(f"{where}: field 'class' must be an integer class id, got {short(fields[0])}") from None
        if not 0 <= cls < nc:
            raise LabelError(f"{where}: field 'class' {cls} is not a class of data.yaml (0..{nc - 1})")
        if polygon:  # its bounding box, as Ultralytics makes of a segment for detection
            xy = [number(v, where, "x" if k % 2 == 0 else "y") for k, v in enumerate(fields[1:])]
            if max(abs(v) for v in xy) > 1.0 + 1e-6:
                raise LabelError(f"{where}: polygon points must be fractions of the image (0..1), got {short(line)}")
            xs, ys = xy[0::2], xy[1::2]
            xc, yc, w, h = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2, max(xs) - min(xs), max(ys) - min(ys)
        else:
            xc, yc, w, h = (number(v, where, f) for v, f in zip(fields[1:], ("x_centre", "y_centre", "width", "height")))
        if max(abs(xc), abs(yc), abs(w), abs(h)) > 1.0 + 1e-6:
            raise LabelError(f"{where}: fields x_centre y_centre width height must be fractions of the image (0..1), got {short(line)}")
        if cls == ball:
            bw, bh = w * width, h * height
            boxes.append(box_inside(xc * width - bw / 2, yc * height - bh / 2, bw, bh, width, height, where, "box"))
    return boxes


def write_yolo(out_dir, images) -> Path:
    """``out_dir/data.yaml`` (class 0 = ball; train and val = the list ``images.txt``, in order) and
    ``out_dir/labels/...txt`` for ``images`` already placed under ``out_dir/images/``. Returns the yaml's path."""
    out_dir = Path(out_dir)
    from harness.common.outputs import atomic_write_text

    for li in images:
        rel = Path(li.path).resolve().relative_to(out_dir.resolve())
        txt = label_path(out_dir / rel)
        txt.parent.mkdir(parents=True, exist_ok=True)
        lines = []
        for x, y, w, h in np.asarray(li.boxes_xywh, float).tolist():
            lines.append(f"0 {(x + w / 2) / li.width!r} {(y + h / 2) / li.height!r} {w / li.width!r} {h / li.height!r}")
        atomic_write_text(txt, "".join(line + "\n" for line in lines), "YOLO labels")
    listed = "".join(f"./{Path(li.path).resolve().relative_to(out_dir.resolve()).as_posix()}\n" for li in images)
    atomic_write_text(out_dir / IMAGE_LIST, listed, "YOLO image list")  # keeps the images' order
    yml = out_dir / DATA_YAML
    atomic_write_text(yml, f"# YOLO data set written by rt2 (Ultralytics layout)\ntrain: {IMAGE_LIST}\nval: {IMAGE_LIST}\n"
                           "nc: 1\nnames:\n  0: ball\n", "data.yaml")
    return yml
