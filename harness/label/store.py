"""The labels of one ``rt2 label`` session, written to ``OUT/annotations.json`` after every change.

The file is the COCO shape :func:`harness.experiments.detector.coco.read_coco` reads (and ``rt2 train
--data OUT`` trains on): one ``images`` entry per *labelled* frame, in the order they were labelled,
with an ``rt2_frame`` field holding the frame's key; one ``ball`` annotation per box. A frame marked
"no ball" is an image entry without annotations (COCO's background image, what ``read_coco`` reads as
an image with no balls). Frames not labelled yet are not in the file.

Every change writes the image file first (copied or extracted into ``OUT/images/``) and then the whole
JSON atomically (temporary file, fsync, rename): when a request has been answered, its label is on disk,
and a server killed at any moment leaves the previous or the new file, never a torn one. On start, an
existing file is read back (checked by ``read_coco``) and labelling continues from it; labelled images
that are not frames of the current source are kept as they are.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np

from harness.experiments.detector.coco import ANNOTATIONS_FILE, LabelledImage, read_coco, write_coco
from harness.label.frames import FrameSet

__all__ = ["LabelStore", "check_boxes"]

#: boxes per image at most (a table-tennis scene shows a handful of balls)
MAX_BOXES = 32
MIN_BOX_PX = 1.0
#: how the ``info.description`` of a file this module wrote begins (a file without it is not resumed)
DESCRIPTION = "ball labels made with rt2 label"


def check_boxes(value, width: int, height: int, where: str) -> np.ndarray:
    """``value`` as (k, 4) COCO boxes ``[x, y, w, h]`` inside a ``width`` x ``height`` image, or ValueError naming it."""
    if not isinstance(value, list) or len(value) > MAX_BOXES:
        raise ValueError(f"{where}: 'boxes' must be a list of at most {MAX_BOXES} boxes [x, y, w, h], got {_short(value)}")
    rows = []
    for j, box in enumerate(value):
        ok = isinstance(box, list) and len(box) == 4
        ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in box)
        if not ok:
            raise ValueError(f"{where}: boxes[{j}] must be 4 finite numbers [x, y, w, h], got {_short(box)}")
        x, y, w, h = (float(v) for v in box)
        if w < MIN_BOX_PX or h < MIN_BOX_PX:
            raise ValueError(f"{where}: boxes[{j}] {_short(box)} must be at least {MIN_BOX_PX:g} px wide and high")
        if x < 0 or y < 0 or x + w > width or y + h > height:
            raise ValueError(f"{where}: boxes[{j}] {_short(box)} lies outside the {width}x{height} image")
        rows.append([x, y, w, h])
    return np.array(rows, float).reshape(-1, 4)


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class LabelStore:
    """Labels by frame key, saved on every change; an undo stack of this session's changes.

    frames : the session's :class:`~harness.label.frames.FrameSet`; out_dir : the data set folder
    """

    def __init__(self, frames: FrameSet, out_dir):
        self.frames = frames
        self.out_dir = Path(out_dir)
        self.json_path = self.out_dir / ANNOTATIONS_FILE
        self._index = {f.image_path.resolve(): i for i, f in enumerate(frames.frames)}
        self._labels: dict = {}  # key -> frame index (int) or a kept LabelledImage; values in label order
        self._boxes: dict = {}  # frame index -> (k, 4) boxes (k = 0: no ball)
        self._undo: list = []
        self._lock = threading.Lock()
        self.n_kept = 0
        if self.json_path.is_file():
            self._resume()

    def _resume(self) -> None:
        labelled = read_coco(self.json_path)  # checked like any COCO input first
        info = json.loads(self.json_path.read_text()).get("info")
        if not (isinstance(info, dict) and str(info.get("description", "")).startswith(DESCRIPTION)):
            raise ValueError(f"{self.json_path} was not written by rt2 label; it would be rewritten in rt2 label's shape (fields "
                             "other tools added dropped): label into a new --out folder (rt2 train takes several --data folders)")
        for li in labelled:
            i = self._index.get(li.path.resolve())
            if i is None:  # a labelled image of another source: kept as it is
                self._labels[f"kept:{li.path}"] = li
                self.n_kept += 1
                continue
            f = self.frames.frames[i]
            if (li.width, li.height) != (f.width, f.height):
                raise ValueError(f"{self.json_path}: {li.path.name} is labelled as {li.width}x{li.height} but the frame is "
                                 f"{f.width}x{f.height}; label into another --out folder")
            self._labels[f.key] = i
            self._boxes[i] = np.array(li.boxes_xywh, float).reshape(-1, 4)

    # -- reading --------------------------------------------------------------------------------
    def boxes(self, i: int):
        """(k, 4) boxes of frame ``i`` (k = 0: "no ball"), or None when it is not labelled."""
        with self._lock:
            b = self._boxes.get(i)
            return None if b is None else b.copy()

    def labelled(self) -> dict:
        """frame index -> (k, 4) boxes, for every labelled frame of the current source."""
        with self._lock:
            return {i: b.copy() for i, b in self._boxes.items()}

    def counts(self) -> dict:
        with self._lock:
            with_ball = sum(1 for b in self._boxes.values() if len(b))
            return {"labelled": len(self._boxes), "with_ball": with_ball, "no_ball": len(self._boxes) - with_ball,
                    "kept_from_file": self.n_kept, "can_undo": len(self._undo)}

    # -- changing -------------------------------------------------------------------------------
    def set(self, i: int, boxes) -> None:
        """Label frame ``i`` with ``boxes`` (k, 4) (k = 0: "no ball") and save; undoable."""
        f = self.frames.frames[i]
        boxes = np.array(boxes, float).reshape(-1, 4)
        with self._lock:
            self.frames.materialise(i)  # the image file first: the JSON never names a missing image
            self._undo.append((i, self._boxes.get(i)))
            self._labels.pop(f.key, None)  # a relabelled frame moves to the end (label order)
            self._labels[f.key] = i
            self._boxes[i] = boxes
            self._save()

    def undo(self) -> int | None:
        """Take back this session's last change and save; returns the frame it touched (None: nothing to undo)."""
        with self._lock:
            if not self._undo:
                return None
            i, before = self._undo.pop()
            key = self.frames.frames[i].key
            if before is None:
                self._labels.pop(key, None)
                self._boxes.pop(i, None)
            else:
                self._labels.setdefault(key, i)
                self._boxes[i] = before
            self._save()
            return i

    def _save(self) -> None:
        images, extra = [], []
        for key, v in self._labels.items():
            if isinstance(v, LabelledImage):
                images.append(v)
                extra.append({})
                continue
            f = self.frames.frames[v]
            b = self._boxes[v]
            centers = np.stack([b[:, 0] + b[:, 2] / 2 - 0.5, b[:, 1] + b[:, 3] / 2 - 0.5], axis=1) if len(b) else np.zeros((0, 2))
            images.append(LabelledImage(f.image_path.resolve(), f.width, f.height, b, centers))
            extra.append({"rt2_frame": key})
        info = {"description": f"{DESCRIPTION} from {self.frames.kind} {self.frames.spec}",
                "no_ball_images": "an image without annotations shows no ball"}
        write_coco(self.out_dir, images, image_extra=extra, info=info)
