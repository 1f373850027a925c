"""The RTBlob baseline (Lampert & Peters 2012) as a tracker with RT2's output type.

As published, and as the RT2 paper (Sec. 1.2 and 3.2) describes and evaluates it:

1. per camera, a colour likelihood image from the distance to a reference orange, correlated with
   a disk by FFT, and its maximum as the ball pixel (Eq. (1)-(3), ``tracker._rtblob_detect``);
2. two fixed stereo pairs (cameras 0+1 and 2+3), each triangulated on its own (Eq. (4),
   ``tracker._rtblob_pairs``);
3. both positions reported, with no consistency check and no outlier rejection; RT2's experiments
   use their mean as the single output, or the one pair's position when only one pair reports:

       (6) X = (1 / m) sum_{pairs p that report} X_p,   C = (1 / m^2) sum_p C_p

   (C assumes independent pairs; it is first-order and says nothing about wrong detections.)

So the baseline fails the way the RT2 paper reports: one camera that picks another orange object
moves one pair and hence the mean (the 25-30 cm mode of its error histogram, Sec. 3.2), and a pair
that triangulates two different objects can be off by metres. ``process`` returns a :class:`tracker.BallObservation`;
``process_with_info`` also returns the two pair positions in an :class:`RTBlobInfo`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from checks.arrays import describe
from tracker._rtblob_detect import RTBlobDetector, likelihood_reference
from tracker.images import image_problem
from tracker._rtblob_options import CORRELATION_METHODS, RTBlobOptions
from tracker._rtblob_pairs import pair_covariances, triangulate_fixed_pairs
from tracker.observation import BallObservation, FrameSet, Status
from tracker.rig import Rig

#: ``CORRELATION_METHODS``: the template-correlation choices of ``RTBlobOptions.correlation``;
#: ``likelihood_reference(image, options)``: the float64 colour likelihood the detector's lookup
#: table is tested and benchmarked against
__all__ = ["CORRELATION_METHODS", "RTBlobDetector", "RTBlobInfo", "RTBlobOptions", "RTBlobTracker", "likelihood_reference"]


@dataclass(frozen=True)
class RTBlobInfo:
    """What the published RTBlob reports beyond the single mean position.

    pair_cameras : (n_pairs, 2) int camera indices of each fixed pair, rig order
    pair_positions_m : (n_pairs, 3) each pair's own triangulation, world frame; NaN where the pair
        reported nothing (a camera did not see the ball, no frame, or parallel rays)
    pair_covariances_m2 : (n_pairs, 3, 3) Eq. (5) per pair (NaN where unavailable), or None when
        ``pixel_sigma_px`` is None
    scores : (n_cams,) peak response per camera (NaN where the camera was not processed)
    radius_px : (n_cams,) disk radius per camera (NaN for cameras in no pair)
    """

    pair_cameras: np.ndarray
    pair_positions_m: np.ndarray
    pair_covariances_m2: np.ndarray | None
    scores: np.ndarray
    radius_px: np.ndarray


class RTBlobTracker:
    """RTBlob on a rig: one :class:`RTBlobDetector` per paired camera, fixed-pair stereo, mean.

    rig : :class:`tracker.Rig`; images arrive in its camera order
    options : :class:`RTBlobOptions`

    Cameras in no pair are never looked at. Template radius per camera: ``template_radius_px``
    (one number, or one per camera), else ``fx * ball_radius_m / expected_distance_m``.
    """

    name = "rtblob"

    def __init__(self, rig: Rig, options: RTBlobOptions = RTBlobOptions()):
        if not isinstance(rig, Rig):
            raise ValueError(f"rig must be a tracker.Rig, got {describe(rig)}")
        if not isinstance(options, RTBlobOptions):
            raise ValueError(f"options must be RTBlobOptions, got {describe(options)}")
        self.rig = rig
        self.options = options
        self.pairs = self._resolve_pairs(options.pairs)  # (n_pairs, 2) int
        radius = self._radii()
        used = sorted({int(i) for i in self.pairs.ravel()})
        self.radius_px = np.full(len(rig), np.nan)
        self.radius_px[used] = radius[used]
        self.radius_px.setflags(write=False)
        self.detectors = tuple(
            RTBlobDetector(rig[i].image_size, radius[i], options) if i in used else None for i in range(len(rig))
        )
        self._used = used

    def __repr__(self) -> str:
        pairs = ", ".join(f"{self.rig[int(a)].name}+{self.rig[int(b)].name}" for a, b in self.pairs)
        return f"RTBlobTracker({len(self.rig)} cameras, pairs {pairs}, {self.options.correlation})"

    # -- construction helpers -----------------------------------------------------------------------
    def _resolve_pairs(self, pairs) -> np.ndarray:
        n = len(self.rig)
        out = []
        for p in pairs:
            idx = [self.rig.index(c) if isinstance(c, str) else int(c) for c in p]
            bad = [i for i in idx if i >= n]
            if bad:
                raise ValueError(
                    f"pairs {pairs!r} refer to camera {bad[0]} but the rig has {n} cameras {self.rig.names}; "
                    f"pass RTBlobOptions(pairs=...) with indices below {n}"
                )
            if idx[0] == idx[1]:
                raise ValueError(f"pair {p!r} names the same camera twice")
            out.append(idx)
        arr = np.array(out, dtype=int)
        arr.setflags(write=False)
        return arr

    def _radii(self) -> np.ndarray:
        r, n = self.options.template_radius_px, len(self.rig)
        if r is None:
            f = np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in self.rig])
            radius = f * self.options.ball_radius_m / self.options.expected_distance_m
            if (radius < 1.0).any():
                i = int(np.argmin(radius))
                raise ValueError(
                    f"the ball would be {radius[i]:.2f} px in camera {self.rig[i].name!r} at expected_distance_m="
                    f"{self.options.expected_distance_m:g}; set template_radius_px (>= 1) instead"
                )
            return radius
        if isinstance(r, tuple):
            if len(r) != n:
                raise ValueError(f"template_radius_px has {len(r)} radii for a rig of {n} cameras {self.rig.names}")
            return np.array(r, float)
        return np.full(n, float(r))

    # -- per frame set --------------------------------------------------------------------------------
    def process(self, frameset: FrameSet) -> BallObservation:
        """One :class:`BallObservation` (tracker ``rtblob``) for one frame set."""
        return self.process_with_info(frameset)[0]

    def process_with_info(self, frameset: FrameSet) -> tuple[BallObservation, RTBlobInfo]:
        """The observation and the published system's per-pair positions, see :class:`RTBlobInfo`.

        frameset : :class:`tracker.FrameSet` with one (H, W, 3) uint8 RGB image (or None) per camera.
        A missing frame or a frame of the wrong size skips that camera and says so in ``notes``;
        anything that is not an RGB uint8 image raises ``ValueError``.
        """
        t0 = time.perf_counter()
        rig, opts = self.rig, self.options
        if not isinstance(frameset, FrameSet):
            raise ValueError(f"frameset must be a tracker.FrameSet, got {describe(frameset)}")
        if not isinstance(frameset.t_s, (int, float, np.floating, np.integer)) or not np.isfinite(frameset.t_s):
            raise ValueError(f"frameset.t_s must be a finite number of seconds, got {describe(frameset.t_s)}")
        images = frameset.images
        if not isinstance(images, (tuple, list)) or len(images) != len(rig):
            got = f"{len(images)} images" if isinstance(images, (tuple, list)) else describe(images)
            raise ValueError(
                f"frameset.images must hold one image (or None) per camera, {len(rig)} for {rig.names}; got {got}"
            )
        notes: list[str] = []
        todo = []
        for i in self._used:  # validate everything before any work
            name = rig[i].name
            if images[i] is None:
                notes.append(f"camera {name}: no frame")
                continue
            problem = image_problem(images[i], rig[i].image_size, f"frameset.images[{i}] (camera {name!r})")
            if problem is not None:
                if problem[0] == "type":
                    raise ValueError(problem[1])
                notes.append(f"camera {name}: {problem[1]}; skipped")
                continue
            todo.append(i)
        n = len(rig)
        uv = np.full((n, 2), np.nan)
        scores = np.full(n, np.nan)
        for i in todo:  # Eq. (1)-(3): one disk correlation per image
            uv[i], scores[i] = self.detectors[i].detect_unchecked(images[i])
            if np.isnan(uv[i, 0]):
                notes.append(f"camera {rig[i].name}: no ball (peak {scores[i]:.3f} < min_score {opts.min_score:g})")
        X_pairs = triangulate_fixed_pairs(rig, uv, self.pairs)  # Eq. (4), every pair in one batch
        reported = np.isfinite(X_pairs).all(axis=1)
        for k, (a, b) in enumerate(self.pairs):
            if not reported[k] and np.isfinite(uv[[a, b]]).all():
                notes.append(f"pair {rig[int(a)].name}+{rig[int(b)].name}: rays parallel, no position")
        C_pairs = None
        if opts.pixel_sigma_px is not None:
            C_pairs = pair_covariances(rig, X_pairs, self.pairs, opts.pixel_sigma_px)  # Eq. (5)
        inliers = np.zeros(n, bool)
        position = covariance = None
        if reported.any():
            m = int(reported.sum())
            position = X_pairs[reported].mean(axis=0)  # Eq. (6)
            inliers[self.pairs[reported].ravel()] = True
            if C_pairs is not None:
                if np.isfinite(C_pairs[reported]).all():
                    covariance = C_pairs[reported].sum(axis=0) / m**2
                else:
                    notes.append("covariance unavailable: a pair's point is behind a camera or its rays are degenerate")
        info = RTBlobInfo(self.pairs, X_pairs, C_pairs, scores, np.asarray(self.radius_px))
        obs = BallObservation(
            t_s=float(frameset.t_s),
            position_m=position,
            covariance_m2=covariance,
            support=int(inliers.sum()),
            inliers=inliers,
            status=Status.OK if position is not None else Status.TOO_FEW_OBSERVATIONS,
            latency_s=time.perf_counter() - t0,
            tracker=self.name,
            uv_px=uv,
            notes=tuple(notes),
        )
        return obs, info
