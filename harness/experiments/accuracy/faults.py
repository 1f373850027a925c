"""Injected camera faults (``rt2 accuracy --inject-faults``): what a real acquisition does now and then.

A :class:`FaultPlan` is a pure function of the frame count and the rig, placed at fixed shares of the
run; a faulted frame never registers the robot (:func:`harness.experiments.accuracy.evaluate.evaluate`), and the
statistics of each fault are over the scored frames it hits:

* ``no_frame``: one camera delivers no frame for a stretch (5 % of the run, at least 1 frame) from 45 %
  of the run: its image is None;
* ``wrong_size``: another camera delivers half-size frames for a few frames (1 %, at least 1) from 60 %:
  a (H/2, W/2, 3) image, which the trackers must skip, not crash on;
* ``non_monotonic``: at 75 % of the run the frame set's timestamp is set half a frame period *before*
  the previous frame set's.

The trackers go on with the other cameras and say so in the observation notes; the experiment counts the
frames each fault touched and what the trackers reported there.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["FAULT_KINDS", "FaultPlan", "affected_frames"]

FAULT_KINDS = ("no_frame", "wrong_size", "non_monotonic")


@dataclass(frozen=True)
class FaultPlan:
    """Which frames get which fault (empty plan = no faults).

    no_frame : (camera index, first frame, last frame + 1)
    wrong_size : (camera index, first frame, last frame + 1)
    non_monotonic_frame : the frame whose timestamp goes back, or -1
    """

    no_frame: tuple = (0, 0, 0)
    wrong_size: tuple = (0, 0, 0)
    non_monotonic_frame: int = -1

    @classmethod
    def none(cls) -> "FaultPlan":
        return cls()

    @classmethod
    def default(cls, n_frames: int, n_cams: int) -> "FaultPlan":
        """The plan of ``--inject-faults`` for ``n_frames`` frames on a rig of ``n_cams`` cameras."""
        if n_cams < 2 or n_frames < 4:
            raise ValueError(f"fault injection needs >= 2 cameras and >= 4 frames, got {n_cams} cameras and {n_frames} frames")
        a = int(0.45 * n_frames)
        b = int(0.60 * n_frames)
        return cls(
            no_frame=(n_cams - 2 if n_cams > 2 else 0, a, min(a + max(1, n_frames // 20), n_frames)),
            wrong_size=(1, b, min(b + max(1, n_frames // 100), n_frames)),
            non_monotonic_frame=max(int(0.75 * n_frames), 1),
        )

    @property
    def active(self) -> bool:
        return self.no_frame[2] > self.no_frame[1] or self.wrong_size[2] > self.wrong_size[1] or self.non_monotonic_frame >= 0

    def faults_at(self, k: int) -> tuple[str, ...]:
        """The fault kinds that hit frame ``k``."""
        out = []
        if self.no_frame[1] <= k < self.no_frame[2]:
            out.append("no_frame")
        if self.wrong_size[1] <= k < self.wrong_size[2]:
            out.append("wrong_size")
        if k == self.non_monotonic_frame:
            out.append("non_monotonic")
        return tuple(out)

    def apply(self, k: int, t_s: float, images: list, frame_period_s: float) -> tuple[float, list]:
        """The timestamp and images camera ``k`` delivers instead of the true ones (new list; inputs untouched)."""
        images = list(images)
        if self.no_frame[1] <= k < self.no_frame[2]:
            images[self.no_frame[0]] = None
        if self.wrong_size[1] <= k < self.wrong_size[2]:
            i = self.wrong_size[0]
            h, w = images[i].shape[:2]
            images[i] = cv2.resize(images[i], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        if k == self.non_monotonic_frame:
            t_s = t_s - 1.5 * frame_period_s  # half a period before the previous frame
        return t_s, images

    def to_dict(self) -> dict:
        return {"no_frame": list(self.no_frame), "wrong_size": list(self.wrong_size),
                "non_monotonic_frame": self.non_monotonic_frame}

    def summary(self, camera_names) -> list[str]:
        """Human-readable lines, one per active fault."""
        out = []
        c, a, b = self.no_frame
        if b > a:
            out.append(f"no_frame: camera {camera_names[c]} delivers no frame in frames {a}..{b - 1} ({b - a} frames)")
        c, a, b = self.wrong_size
        if b > a:
            out.append(f"wrong_size: camera {camera_names[c]} delivers half-size frames in frames {a}..{b - 1} ({b - a} frames)")
        if self.non_monotonic_frame >= 0:
            out.append(f"non_monotonic: frame {self.non_monotonic_frame}'s timestamp goes back 1.5 frame periods")
        return out


def affected_frames(plan: FaultPlan, n_frames: int) -> np.ndarray:
    """(n_frames,) bool, frames hit by any fault."""
    k = np.arange(n_frames)
    return ((plan.no_frame[1] <= k) & (k < plan.no_frame[2])) | ((plan.wrong_size[1] <= k) & (k < plan.wrong_size[2])) \
        | (k == plan.non_monotonic_frame)
