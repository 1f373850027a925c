"""The labels of one ``rt2 label`` session, written to ``OUT/annotations.json`` after every change.

The file is the COCO shape :func:`harness.experiments.detector.coco.read_coco` reads (and ``rt2 train
--data OUT`` trains on): one ``images`` entry per *labelled* frame, in the order they were labelled,
with an ``rt2_frame`` field holding the frame's key; one ``ball`` annotation per box. A frame marked
"no ball" is an image entry without annotations (COCO's background image, what ``read_coco`` reads as
an image with no balls). Frames not labelled yet are not in the file.

Every change writes the image file first (copied or extracted into ``OUT/images/``) and then the whole
JSON atomically (temporary file, fsync, rename): when a request has been answered, its label is on disk,
and a server killed at any moment leaves the previous or the new file, never a torn one. On start, an
existing file is read back (checked by ``read_coco``) and labelling continues from it, whoever wrote it
(``rt2 label``, ``rt2 label --auto``, ``rt2 labels convert`` or another tool): its images are matched to the
source's frames by path, else by file name; the fields it adds to images and annotations are kept on every
rewrite, and a file another tool wrote is copied once to ``annotations.before-rt2-label.json`` first.
Labelled images that are not frames of the current source are kept as they are.

One writer per folder: the store holds an exclusive lock on ``OUT/.rt2-label.lock`` while it is open
(a second ``rt2 label`` on the same folder is refused). Every change bumps ``revision``; a change sent
with an older revision (a second tab that has not seen the first tab's change) is refused with
:class:`RevisionConflict`, never applied over it. Undo is per tab (``tab``) and takes back only that
tab's own changes, and only while nobody changed the frame since.

Labels of ``rt2 label --auto`` (annotations with ``"source": "auto"``) are kept in the file (``rt2 train``
reads them) and shown by the page as proposals until a person accepts or corrects them.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import threading
from pathlib import Path

import numpy as np

from harness.experiments.detector.coco import ANNOTATIONS_FILE, LabelledImage, read_coco, write_coco
from harness.label.frames import FrameSet

__all__ = ["LabelStore", "RevisionConflict", "check_boxes", "lock_folder"]

#: boxes per image at most (a table-tennis scene shows a handful of balls)
MAX_BOXES = 32
MIN_BOX_PX = 1.0
#: how the ``info.description`` of a file this module wrote begins (a file without it is not resumed)
DESCRIPTION = "ball labels made with rt2 label"
LOCK_FILE = ".rt2-label.lock"
BACKUP_FILE = "annotations.before-rt2-label.json"
_IMAGE_CORE = ("id", "file_name", "width", "height", "rt2_frame")
_ANN_CORE = ("id", "image_id", "category_id", "bbox", "area", "iscrowd", "center_px")


class RevisionConflict(Exception):
    """A change made on an older state of the labels (another tab changed them since): not applied."""


def lock_folder(out_dir):
    """An exclusive lock on ``out_dir/.rt2-label.lock`` (an open file; closing it unlocks), or ValueError naming the holder.

    The lock is the kernel's (``flock``): it goes with the process, so a killed ``rt2 label`` leaves none behind.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / LOCK_FILE
    fh = open(path, "a+")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip() or "?"
        fh.close()
        raise ValueError(f"--out {str(out_dir)!r}: another rt2 label (pid {holder}) is writing this folder; stop it first, "
                         "or label into another --out folder") from None
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return fh


def _file_extras(doc: dict) -> tuple[list, list]:
    """Per image of ``doc`` (file order, as ``read_coco``): its extra fields, and one dict of extra fields per ball annotation."""
    ball_ids = {c.get("id") for c in doc["categories"] if isinstance(c, dict) and str(c.get("name", "")).strip().lower() == "ball"}
    per_image: dict = {}
    for ann in doc["annotations"]:
        if ann["category_id"] in ball_ids:
            per_image.setdefault(ann["image_id"], []).append({k: v for k, v in ann.items() if k not in _ANN_CORE})
    images = [{k: v for k, v in im.items() if k not in _IMAGE_CORE} for im in doc["images"]]
    return images, [per_image.get(im["id"], []) for im in doc["images"]]


def is_auto(ann_extras) -> bool:
    """Whether these annotation fields are ``rt2 label --auto``'s, not reviewed by a person yet."""
    return bool(ann_extras) and all(a.get("source") == "auto" for a in ann_extras)


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
    """Labels by frame key, saved on every change; a revision number; an undo stack per tab.

    frames : the session's :class:`~harness.label.frames.FrameSet`; out_dir : the data set folder
    lock : the folder's lock (:func:`lock_folder`) when the caller took it already (before extracting frames)
    Holds the folder's lock from construction until :meth:`close`.
    """

    def __init__(self, frames: FrameSet, out_dir, lock=None):
        self.frames = frames
        self.out_dir = Path(out_dir)
        self.json_path = self.out_dir / ANNOTATIONS_FILE
        self._lock_file = lock if lock is not None else lock_folder(self.out_dir)
        self._index = {}
        for i, f in enumerate(frames.frames):
            self._index.setdefault(f.image_path.resolve(), i)
            self._index.setdefault(f.source_path.resolve(), i)
        self._labels: dict = {}  # key -> frame index (int) or a kept (LabelledImage, image extra, ann extras); label order
        self._boxes: dict = {}  # frame index -> (k, 4) boxes (k = 0: no ball)
        self._extra: dict = {}  # frame index -> (image extra fields, [annotation extra fields]) kept from the file
        self._path: dict = {}  # frame index -> the image path the file names, when it is not the frame's image_path
        self._undo: list = []  # (tab, frame, before, change number)
        self._last_change: dict = {}  # frame index -> number of the change that last touched it
        self._lock = threading.Lock()
        self.revision = 0
        self.n_kept = 0
        self.info: dict = {}
        self.backup: Path | None = None
        try:
            if self.json_path.is_file():
                self._resume()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Let go of the folder's lock (the labels are on disk already)."""
        if self._lock_file is not None:
            self._lock_file.close()
            self._lock_file = None

    def _resume(self) -> None:
        labelled = read_coco(self.json_path)  # checked like any COCO input first
        doc = json.loads(self.json_path.read_text())
        info = doc.get("info")
        self.info = dict(info) if isinstance(info, dict) else {}
        if not str(self.info.get("description", "")).startswith(DESCRIPTION):  # another tool's file: a copy first
            self.backup = self.out_dir / BACKUP_FILE
            if not self.backup.exists():
                shutil.copyfile(self.json_path, self.backup)
        by_name: dict = {}
        for i, f in enumerate(self.frames.frames):
            for name in {f.image_path.name, f.source_path.name}:
                by_name.setdefault(name, set()).add(i)
        for li, im_extra, ann_extra in zip(labelled, *_file_extras(doc)):
            i = self._index.get(li.path.resolve())
            if i is None and len(by_name.get(li.path.name, ())) == 1:  # the same image elsewhere (a converted set)
                (i,) = by_name[li.path.name]
            if i is None or self.frames.frames[i].key in self._labels:  # a labelled image of another source: kept as it is
                self._labels[f"kept:{li.path}"] = (li, im_extra, ann_extra)
                self.n_kept += 1
                continue
            f = self.frames.frames[i]
            if (li.width, li.height) != (f.width, f.height):
                raise ValueError(f"{self.json_path}: {li.path.name} is labelled as {li.width}x{li.height} but the frame is "
                                 f"{f.width}x{f.height}; label into another --out folder")
            self._labels[f.key] = i
            self._boxes[i] = np.array(li.boxes_xywh, float).reshape(-1, 4)
            self._extra[i] = (im_extra, ann_extra)
            if li.path.resolve() != f.image_path.resolve():
                self._path[i] = li.path.resolve()

    # -- reading --------------------------------------------------------------------------------
    def boxes(self, i: int):
        """(k, 4) boxes of frame ``i`` (k = 0: "no ball"), or None when it is not labelled."""
        with self._lock:
            b = self._boxes.get(i)
            return None if b is None else b.copy()

    def labelled(self) -> dict:
        """frame index -> (k, 4) boxes, for every labelled frame of the current source (auto labels included)."""
        with self._lock:
            return {i: b.copy() for i, b in self._boxes.items()}

    def auto(self) -> dict:
        """frame index -> annotation fields (one dict per box) of the auto labels no person has reviewed yet."""
        with self._lock:
            return {i: [dict(a) for a in e[1]] for i, e in self._extra.items() if i in self._boxes and is_auto(e[1])}

    def image_fields(self, i: int) -> dict:
        """The extra fields the file gives frame ``i``'s image entry (e.g. ``camera``, ``frame_id``)."""
        with self._lock:
            return dict(self._extra.get(i, ({}, []))[0])

    def counts(self, tab=None) -> dict:
        with self._lock:
            auto = sum(1 for i, e in self._extra.items() if i in self._boxes and is_auto(e[1]))
            with_ball = sum(1 for i, b in self._boxes.items() if len(b) and not is_auto(self._extra.get(i, ({}, []))[1]))
            labelled = len(self._boxes) - auto
            return {"labelled": labelled, "with_ball": with_ball, "no_ball": labelled - with_ball, "auto": auto,
                    "kept_from_file": self.n_kept, "can_undo": sum(1 for u in self._undo if u[0] == tab)}

    # -- changing -------------------------------------------------------------------------------
    def _check_revision(self, revision) -> None:
        if revision is not None and revision != self.revision:
            raise RevisionConflict(f"the labels changed in another tab or window (revision {self.revision}, this page had {revision}): "
                                   "not saved; the page reloads them, look and label again")

    def set(self, i: int, boxes, *, tab=None, revision=None) -> int:
        """Label frame ``i`` with ``boxes`` (k, 4) (k = 0: "no ball") and save; undoable by ``tab``; returns the new revision.

        revision : the revision the change was made on (None: do not check); an older one raises RevisionConflict
        """
        f = self.frames.frames[i]
        boxes = np.array(boxes, float).reshape(-1, 4)
        with self._lock:
            self._check_revision(revision)
            if i not in self._path:
                self.frames.materialise(i)  # the image file first: the JSON never names a missing image
            before = (self._boxes.get(i), self._extra.get(i))
            self._labels.pop(f.key, None)  # a relabelled frame moves to the end (label order)
            self._labels[f.key] = i
            self._boxes[i] = boxes
            im_extra = self._extra.get(i, ({}, []))[0]
            self._extra[i] = (im_extra, [{} for _ in boxes])  # a person's boxes: the file's per-box fields (auto) go
            self._save()
            self.revision += 1
            self._undo.append((tab, i, before, self.revision))
            self._last_change[i] = self.revision
            return self.revision

    def undo(self, *, tab=None, revision=None) -> int | None:
        """Take back ``tab``'s last change and save; returns the frame it touched (None: nothing of this tab to undo).

        Raises RevisionConflict for an old ``revision``, or when another change touched that frame since (then not undone).
        """
        with self._lock:
            self._check_revision(revision)
            k = next((k for k in range(len(self._undo) - 1, -1, -1) if self._undo[k][0] == tab), None)
            if k is None:
                return None
            _, i, (boxes, extra), change = self._undo.pop(k)
            key = self.frames.frames[i].key
            if self._last_change.get(i) != change:
                raise RevisionConflict(f"frame {i + 1} ({key}) was changed since, in another tab: this tab's change to it is not undone")
            if boxes is None:
                self._labels.pop(key, None)
                self._boxes.pop(i, None)
                self._extra.pop(i, None)
            else:
                self._labels.setdefault(key, i)
                self._boxes[i] = boxes
                if extra is not None:
                    self._extra[i] = extra
            self._save()
            self.revision += 1
            self._last_change[i] = self.revision
            return i

    def remember(self, **fields) -> None:
        """Keep these fields in the file's ``info`` (e.g. the ball colour training used); saved now when labels exist."""
        with self._lock:
            self.info.update(fields)
            if self._labels:
                self._save()

    def _save(self) -> None:
        images, extra, image_extra = [], [], []
        for key, v in self._labels.items():
            if isinstance(v, tuple):
                li, im_extra, ann_extra = v
                images.append(li)
                image_extra.append(im_extra)
                extra.append(ann_extra if len(ann_extra) == li.n_balls else [{} for _ in range(li.n_balls)])
                continue
            f = self.frames.frames[v]
            b = self._boxes[v]
            centers = np.stack([b[:, 0] + b[:, 2] / 2 - 0.5, b[:, 1] + b[:, 3] / 2 - 0.5], axis=1) if len(b) else np.zeros((0, 2))
            images.append(LabelledImage(self._path.get(v, f.image_path.resolve()), f.width, f.height, b, centers))
            im_extra, ann_extra = self._extra.get(v, ({}, []))
            image_extra.append({**im_extra, "rt2_frame": key})
            extra.append(ann_extra if len(ann_extra) == len(b) else [{} for _ in range(len(b))])
        info = {**self.info, "description": f"{DESCRIPTION} from {self.frames.kind} {self.frames.spec}",
                "no_ball_images": "an image without annotations shows no ball"}
        write_coco(self.out_dir, images, extra, image_extra=image_extra, info=info)
