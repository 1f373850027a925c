"""One labelling session: the frames, what the detector proposes on each, the suggestions, the labels, training.

Everything the page asks for goes through :class:`LabelSession`; :mod:`harness.label.server` only
turns HTTP requests into its calls. On start every frame is read once: its descriptor and its
detector candidates (``tracker.BallDetector``, method ``ours``, up to 4 candidates, best first) are
kept, so the page never waits for the model.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harness.label.frames import FrameSet
from harness.label.store import LabelStore, check_boxes
from harness.label.suggest import describe_image, suggest, uncertainty
from harness.label.training import TrainingJob
from tracker import BallDetector, BallSegmentationModel, DetectorOptions

__all__ = ["LabelOptions", "LabelSession", "detect_and_describe"]


@dataclass(frozen=True)
class LabelOptions:
    """Options of a labelling session.

    n_suggestions : frames the page lists as "label next"
    min_train_labels : labelled frames (at least 2 of them with a ball) before the page offers training
    train_args : extra ``rt2 train`` options for the page's training run (e.g. ``("--epochs", "2")``)
    model_name : weights file the training writes inside the output folder
    jpeg_quality : quality of the JPEG the page is sent (the saved images are the originals)
    """

    n_suggestions: int = 10
    min_train_labels: int = 8
    train_args: tuple = ()
    model_name: str = "model.npz"
    jpeg_quality: int = 90

    def __post_init__(self):
        if self.n_suggestions < 1 or self.min_train_labels < 3:
            raise ValueError("LabelOptions: n_suggestions must be >= 1 and min_train_labels >= 3 "
                             f"(train holds out frames for validation), got {self.n_suggestions}, {self.min_train_labels}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"LabelOptions.jpeg_quality must be in [1, 100], got {self.jpeg_quality}")


def detect_and_describe(frames: FrameSet, model: BallSegmentationModel, progress=None):
    """Per frame: descriptor ``(n, d)``, candidates (list of (boxes (k, 4), scores (k,))) and uncertainty ``(n,)``."""
    detector = BallDetector(model, DetectorOptions(method="ours"))
    desc, cands, unc = [], [], []
    for i in range(len(frames)):
        image = frames.image(i)
        d = detector.detect(image)
        desc.append(describe_image(image))
        cands.append((d.boxes_xywh.copy(), d.scores.copy()))
        unc.append(uncertainty(d.scores))
        if progress is not None:
            progress(i + 1, len(frames))
    return np.array(desc), cands, np.array(unc)


class LabelSession:
    """The state behind the page (thread-safe: the HTTP server answers requests in threads)."""

    def __init__(self, frames: FrameSet, out_dir, model: BallSegmentationModel, model_path, options: LabelOptions = LabelOptions(),
                 progress=None):
        self.frames = frames
        self.out_dir = Path(out_dir)
        self.options = options
        self.model_path = str(model_path)
        self.store = LabelStore(frames, out_dir)
        self.descriptors, self.candidates, self.uncertainty = detect_and_describe(frames, model, progress)
        self.training = TrainingJob(out_dir, options.model_name, options.train_args)
        self._lock = threading.Lock()

    # -- reading --------------------------------------------------------------------------------
    def frame_index(self, value) -> int:
        """A frame index from the page (int or decimal string), or ValueError / LookupError naming it."""
        if isinstance(value, bool) or not isinstance(value, (int, str)):
            raise ValueError(f"'frame' must be a frame index (integer), got {value!r}")
        if isinstance(value, str):
            if not value.isdigit() or len(value) > 9:
                raise LookupError(f"no frame {value!r}: frames are numbered 0 to {len(self.frames) - 1}")
            value = int(value)
        if not 0 <= value < len(self.frames):
            raise LookupError(f"no frame {value}: frames are numbered 0 to {len(self.frames) - 1}")
        return value

    def suggestions(self) -> list[int]:
        return suggest(self.descriptors, self.uncertainty, list(self.store.labelled()), self.options.n_suggestions)

    def state(self) -> dict:
        labelled = self.store.labelled()
        counts = self.store.counts()
        return {
            "source": self.frames.spec,
            "kind": self.frames.kind,
            "out": str(self.out_dir),
            "annotations": str(self.store.json_path),
            "model": self.model_path,
            "n_frames": len(self.frames),
            "frames": [{"i": i, "key": f.key, "labelled": None if i not in labelled else len(labelled[i])}
                       for i, f in enumerate(self.frames.frames)],
            "counts": counts,
            "suggestions": self.suggestions(),
            "min_train_labels": self.options.min_train_labels,
            "can_train": self._can_train(counts),
            "training": self.training.status(),
        }

    def frame(self, i: int) -> dict:
        f = self.frames.frames[i]
        boxes, scores = self.candidates[i]
        labels = self.store.boxes(i)
        return {
            "i": i,
            "key": f.key,
            "width": f.width,
            "height": f.height,
            "labels": None if labels is None else labels.tolist(),
            "proposals": [{"box": b.tolist(), "score": float(s)} for b, s in zip(boxes, scores)],
            "uncertainty": float(self.uncertainty[i]),
        }

    def jpeg(self, i: int) -> bytes:
        rgb = self.frames.image(i)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.options.jpeg_quality])
        if not ok:
            raise RuntimeError(f"frame {i}: cannot encode as JPEG")
        return buf.tobytes()

    # -- changing -------------------------------------------------------------------------------
    def label(self, body) -> dict:
        """``{"frame": i, "boxes": [[x, y, w, h], ...]}`` (``[]`` = no ball): save; returns the new counts and suggestions."""
        if not isinstance(body, dict):
            raise ValueError(f"the request body must be a JSON object {{'frame': i, 'boxes': [...]}}, got {type(body).__name__}")
        unknown = sorted(set(body) - {"frame", "boxes"})
        if unknown or "frame" not in body or "boxes" not in body:
            raise ValueError(f"the request body needs exactly the fields 'frame' and 'boxes', got {sorted(body)}")
        if isinstance(body["frame"], bool) or not isinstance(body["frame"], int):
            raise ValueError(f"'frame' must be a frame index (integer), got {json.dumps(body['frame'])[:80]}")
        i = self.frame_index(body["frame"])
        f = self.frames.frames[i]
        boxes = check_boxes(body["boxes"], f.width, f.height, f"frame {i} ({f.key})")
        self.store.set(i, boxes)
        return {"frame": i, "labels": boxes.tolist(), "counts": self.store.counts(), "suggestions": self.suggestions()}

    def undo(self) -> dict:
        i = self.store.undo()
        return {"frame": i, "counts": self.store.counts(), "suggestions": self.suggestions()}

    def _can_train(self, counts) -> bool:
        return counts["labelled"] + counts["kept_from_file"] >= self.options.min_train_labels and counts["with_ball"] >= 2

    def train(self) -> dict:
        """Start ``rt2 train`` on the labels (ValueError when too few are labelled or it is running)."""
        with self._lock:
            counts = self.store.counts()
            if not self._can_train(counts):
                raise ValueError(f"label at least {self.options.min_train_labels} frames, 2 or more with a ball, before training "
                                 f"(now {counts['labelled']} labelled, {counts['with_ball']} with a ball)")
            self.training.start()
        return self.training.status()

    def close(self) -> None:
        self.training.stop()
