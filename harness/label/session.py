"""One labelling session: the frames, what the detector proposes on each, the suggestions, the labels, training.

Everything the page asks for goes through :class:`LabelSession`; :mod:`harness.label.server` only
turns HTTP requests into its calls. On start every frame is read once: its descriptor and its
detector candidates (``tracker.BallDetector``, method ``ours``, up to 4 candidates, best first) are
kept, so the page never waits for the model.

Labels that ``rt2 label --auto`` wrote into the folder are proposals here: the frames holding them are
suggested first, the ones the cameras' consensus is least sure of (lowest ``confidence``) first, and a
person accepts or corrects each. Accepting a proposal whose confidence is below
``LabelOptions.confirm_below`` takes a second key press on the page (it says why).

A fixed camera's recording (``rt2 label --motion-cue``: a video, a session log, a folder of one camera's frames in
time order) carries a cue a single image does not: what moved. With ``LabelOptions.motion_cue`` each camera's frames
(:func:`harness.experiments.detector.subsets.camera_of` their keys) pass in order through a ``tracker.motion.MotionCue``
and a frame's candidates on cells that moved are proposed first, the still ones after them (never dropped: a ball
lying still is still proposed). A lamp the detector scores above the ball no longer comes first in every frame.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harness.label.frames import FrameSet
from harness.label.store import LabelStore, RevisionConflict, check_boxes
from harness.label.suggest import describe_image, suggest, uncertainty
from harness.label.training import TrainingJob
from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.model import BALL_COLOURS

__all__ = ["LabelOptions", "LabelSession", "RevisionConflict", "TrainRefused", "detect_and_describe"]

_TAB_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_")


@dataclass(frozen=True)
class LabelOptions:
    """Options of a labelling session.

    n_suggestions : frames the page lists as "label next"
    min_train_labels : labelled frames (at least 2 of them with a ball) before the page offers training
    train_args : extra ``rt2 train`` options for the page's training run (e.g. ``("--epochs", "2")``)
    model_name : weights file the training writes inside the output folder
    jpeg_quality : quality of the JPEG the page is sent (the saved images are the originals)
    confirm_below : a proposal scored below this takes a second key press to accept (0: never)
    ball_colour : the ball colour training uses (``rt2 train --ball-colour``); None: the page asks
    motion_cue : the frames are fixed cameras' sequences: candidates that moved are proposed first (module docstring)
    """

    n_suggestions: int = 10
    min_train_labels: int = 8
    train_args: tuple = ()
    model_name: str = "model.npz"
    jpeg_quality: int = 90
    confirm_below: float = 0.9
    ball_colour: str | None = None
    motion_cue: bool = False

    def __post_init__(self):
        if self.n_suggestions < 1 or self.min_train_labels < 3:
            raise ValueError("LabelOptions: n_suggestions must be >= 1 and min_train_labels >= 3 "
                             f"(train holds out frames for validation), got {self.n_suggestions}, {self.min_train_labels}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"LabelOptions.jpeg_quality must be in [1, 100], got {self.jpeg_quality}")
        if not 0.0 <= self.confirm_below <= 1.0:
            raise ValueError(f"--confirm-below must be in [0, 1], got {self.confirm_below}")
        if self.ball_colour is not None and self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"--ball-colour must be one of {BALL_COLOURS}, got {self.ball_colour!r}")


def detect_and_describe(frames: FrameSet, model: BallSegmentationModel, progress=None, motion_cue: bool = False):
    """Per frame: descriptor ``(n, d)``, candidates (list of (boxes (k, 4), scores (k,))) and uncertainty ``(n,)``;
    with ``motion_cue`` each frame's candidates that moved first (module docstring)."""
    from harness.experiments.detector.subsets import camera_of
    from tracker.motion import CameraCues, MotionOptions

    detector = BallDetector(model, DetectorOptions(method="ours"))
    desc, cands, unc = [], [], []
    cues = CameraCues(MotionOptions(regions=False))
    for i in range(len(frames)):
        image = frames.image(i)
        d = detector.detect(image)
        desc.append(describe_image(image))
        boxes, scores = d.boxes_xywh.copy(), d.scores.copy()
        if motion_cue:
            f = frames.frames[i]
            cue = cues.observe((camera_of(f.key), f.width, f.height), image)
            if len(d) and cue is not None:  # (the camera's first frame has no cue: the detector's order)
                order = np.argsort(~cue.moved(d.uv_px, boxes[:, 2:].max(axis=1)), kind="stable")
                boxes, scores = boxes[order], scores[order]
        cands.append((boxes, scores))
        unc.append(uncertainty(d.scores))
        if progress is not None:
            progress(i + 1, len(frames))
    return np.array(desc), cands, np.array(unc)


class LabelSession:
    """The state behind the page (thread-safe: the HTTP server answers requests in threads)."""

    def __init__(self, frames: FrameSet, out_dir, model: BallSegmentationModel, model_path, options: LabelOptions = LabelOptions(),
                 progress=None, lock=None):
        self.frames = frames
        self.out_dir = Path(out_dir)
        self.options = options
        self.model_path = str(model_path)
        self.store = LabelStore(frames, out_dir, lock)
        try:
            self.descriptors, self.candidates, self.uncertainty = detect_and_describe(frames, model, progress, options.motion_cue)
        except BaseException:
            self.store.close()
            raise
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
        """Unreviewed auto labels first (least confident first), then the page's rule (:func:`suggest`) on the rest."""
        auto = self.store.auto()
        first = sorted(auto, key=lambda i: (min(a.get("confidence", 0.0) for a in auto[i]), i))[: self.options.n_suggestions]
        rest = suggest(self.descriptors, self.uncertainty, list(self.store.labelled()), self.options.n_suggestions - len(first))
        return first + rest if len(first) < self.options.n_suggestions else first

    def ball_colour(self) -> str | None:
        """The colour the page trains on: the last one chosen (kept in the file), else ``--ball-colour``, else None."""
        chosen = self.store.info.get("ball_colour")
        return chosen if chosen in BALL_COLOURS else self.options.ball_colour

    def state(self) -> dict:
        labelled = self.store.labelled()
        auto = self.store.auto()
        counts = self.store.counts()
        return {
            "source": self.frames.spec,
            "kind": self.frames.kind,
            "out": str(self.out_dir),
            "annotations": str(self.store.json_path),
            "model": self.model_path,
            "n_frames": len(self.frames),
            "frames": [{"i": i, "key": f.key, "labelled": None if i not in labelled or i in auto else len(labelled[i]), "auto": i in auto}
                       for i, f in enumerate(self.frames.frames)],
            "skipped": [{"file": name, "why": why} for name, why in self.frames.skipped],
            "revision": self.store.revision,
            "counts": counts,
            "suggestions": self.suggestions(),
            "min_train_labels": self.options.min_train_labels,
            "confirm_below": self.options.confirm_below,
            "motion_cue": self.options.motion_cue,
            "ball_colour": self.ball_colour(),
            "ball_colours": list(BALL_COLOURS),
            "backup": None if self.store.backup is None else str(self.store.backup),
            "can_train": self._can_train(counts),
            "training": self.training.status(),
        }

    def frame(self, i: int) -> dict:
        f = self.frames.frames[i]
        boxes, scores = self.candidates[i]
        labels = self.store.boxes(i)
        auto = self.store.auto().get(i)
        proposals = [{"box": b.tolist(), "score": float(s), "auto": False} for b, s in zip(boxes, scores)]
        if auto is not None:  # the consensus's labels, not reviewed yet: proposals, before the detector's
            proposals = [{"box": b.tolist(), "score": float(a.get("confidence", 0.0)), "auto": True,
                          "support": a.get("support"), "reprojection_px": a.get("reprojection_px")}
                         for b, a in zip(labels, auto)] + proposals
            labels = None
        return {
            "i": i,
            "key": f.key,
            "width": f.width,
            "height": f.height,
            "labels": None if labels is None else labels.tolist(),
            "proposals": proposals,
            "auto": auto is not None,
            "fields": self.store.image_fields(i),
            "uncertainty": float(self.uncertainty[i]),
        }

    def jpeg(self, i: int) -> bytes:
        rgb = self.frames.image(i)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.options.jpeg_quality])
        if not ok:
            raise RuntimeError(f"frame {i}: cannot encode as JPEG")
        return buf.tobytes()

    # -- changing -------------------------------------------------------------------------------
    @staticmethod
    def _tab_and_revision(body, required: tuple, optional=("tab", "revision")):
        if not isinstance(body, dict):
            raise ValueError(f"the request body must be a JSON object, got {type(body).__name__}")
        unknown = sorted(set(body) - set(required) - set(optional))
        if unknown or any(k not in body for k in required):
            if not required:
                raise ValueError(f"the request body takes only the optional fields 'tab' and 'revision', got {sorted(body)}")
            need = " and ".join(f"'{k}'" for k in required)
            raise ValueError(f"the request body needs exactly the fields {need} (optional: 'tab', 'revision'), got {sorted(body)}")
        tab, revision = body.get("tab"), body.get("revision")
        if tab is not None and not (isinstance(tab, str) and 0 < len(tab) <= 64 and set(tab) <= _TAB_CHARS):
            raise ValueError(f"'tab' must be a name of 1-64 letters, digits, '-' or '_', got {json.dumps(tab)[:80]}")
        if revision is not None and (isinstance(revision, bool) or not isinstance(revision, int) or revision < 0):
            raise ValueError(f"'revision' must be a non-negative integer, got {json.dumps(revision)[:80]}")
        return tab, revision

    def label(self, body) -> dict:
        """``{"frame": i, "boxes": [[x, y, w, h], ...], "tab"?, "revision"?}`` (``[]`` = no ball): save; returns the new counts,
        suggestions and revision. An old ``revision`` raises :class:`RevisionConflict` (nothing saved)."""
        if not isinstance(body, dict):
            raise ValueError(f"the request body must be a JSON object {{'frame': i, 'boxes': [...]}}, got {type(body).__name__}")
        tab, revision = self._tab_and_revision(body, ("frame", "boxes"))
        if isinstance(body["frame"], bool) or not isinstance(body["frame"], int):
            raise ValueError(f"'frame' must be a frame index (integer), got {json.dumps(body['frame'])[:80]}")
        i = self.frame_index(body["frame"])
        f = self.frames.frames[i]
        boxes = check_boxes(body["boxes"], f.width, f.height, f"frame {i} ({f.key})")
        rev = self.store.set(i, boxes, tab=tab, revision=revision)
        return {"frame": i, "labels": boxes.tolist(), "revision": rev, "counts": self.store.counts(tab), "suggestions": self.suggestions()}

    def undo(self, body=None) -> dict:
        """``{"tab"?, "revision"?}``: take back that tab's last change (RevisionConflict when another change came between)."""
        tab, revision = self._tab_and_revision({} if body is None else body, ())
        i = self.store.undo(tab=tab, revision=revision)
        return {"frame": i, "revision": self.store.revision, "counts": self.store.counts(tab), "suggestions": self.suggestions()}

    def _can_train(self, counts) -> bool:
        n = counts["labelled"] + counts["auto"] + counts["kept_from_file"]
        return n >= self.options.min_train_labels and counts["with_ball"] + counts["auto"] >= 2

    def train(self, body=None) -> dict:
        """``{"ball_colour": "orange"|"white"|"any"}``: start ``rt2 train --ball-colour`` on the labels.

        ValueError for a missing or unknown colour; :class:`TrainRefused` (a ValueError) when too few frames are
        labelled or a run is going.
        """
        body = {} if body is None else body
        if not isinstance(body, dict) or sorted(set(body) - {"ball_colour"}):
            raise ValueError(f"the request body must be {{'ball_colour': one of {list(BALL_COLOURS)}}}, got {json.dumps(body)[:80]}")
        with self._lock:
            counts = self.store.counts()
            if not self._can_train(counts):
                raise TrainRefused(f"label at least {self.options.min_train_labels} frames, 2 or more with a ball, before training "
                                   f"(now {counts['labelled']} labelled, {counts['with_ball']} with a ball)")
            colour = body.get("ball_colour", self.ball_colour())
            if colour not in BALL_COLOURS:
                raise ValueError(f"choose the ball colour to train on ('ball_colour': one of {list(BALL_COLOURS)}), got {json.dumps(colour)}: "
                                 "the shipped model to start from and the balls learnt depend on it")
            try:
                self.training.start(colour)
            except ValueError as exc:
                raise TrainRefused(str(exc)) from None
            self.store.remember(ball_colour=colour)
        return self.training.status()

    def close(self) -> None:
        self.training.stop()
        self.store.close()


class TrainRefused(ValueError):
    """Training cannot start now (too few labels, a run going): the server answers 409."""
