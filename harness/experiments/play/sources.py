"""Observation sources of the playing sessions: what the tracker reports for the frame set at time t.

Both take the simulator's TRUE state at the capture time (ball centre and velocity, the WAM's joint
angles) and return a :class:`tracker.BallObservation` with capture time ``t_s`` and the profile's
latency (the session delivers it to the filter at ``t_s + latency_s``):

* :class:`SyntheticSource` -- fast: true position + noise, misses and outliers of the tracker's
  :class:`~harness.experiments.play.profiles.TrackerProfile`, only where the rig's cameras see the ball;
* :class:`VisionSource` -- the real thing: renders the rig's cameras (``harness.sim.render``; scene of
  ``harness.experiments.play.play_scene``: the ball, the WAM and its racket, a person, distractors) and runs
  ``tracker.Tracker`` of the chosen kind on the images (RTBlob set up first as its user would:
  ``harness.experiments.play.rtblob_setup.calibrate_rtblob``).

``SOURCES`` maps the ``--source`` names to the classes; unknown names raise and list the valid ones.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from harness.sim.lab import coverage
from harness.experiments.play.profiles import TrackerProfile
from tracker import BallObservation, Status

__all__ = ["SOURCES", "SyntheticSource", "VisionSource", "make_source"]


class SyntheticSource:
    """Observations drawn from a :class:`TrackerProfile` (see harness/experiments/play/profiles.py)."""

    name = "synthetic"

    def __init__(self, rig, profile: TrackerProfile, **_unused):
        self.rig, self.profile = rig, profile
        self.n_cams = len(rig)
        self.rng = np.random.default_rng(0)

    def reset(self, seed, **_unused) -> None:
        """A new ball: the noise stream of this ball comes from ``seed`` (int or SeedSequence)."""
        self.rng = np.random.default_rng(seed)

    def observe(self, frame_index: int, t_s: float, ball_m, ball_velocity_mps, q_true, *,
                n_seeing: int | None = None) -> BallObservation:
        """n_seeing : the cameras that see the ball, if the caller has counted them (``harness.sim.lab.coverage`` of
        many positions at once); None: counted here."""
        p, rng = self.profile, self.rng
        u = rng.random(4)  # always 4 draws per frame: the stream does not depend on the outcome
        noise = rng.standard_normal(3)
        direction = rng.standard_normal(3)
        seen = int(coverage(self.rig, np.asarray(ball_m, float)[None]).n_seeing[0]) if n_seeing is None else int(n_seeing)
        common = dict(t_s=float(t_s), latency_s=p.latency_s, tracker=p.tracker, uv_px=None)
        if seen < p.min_cameras:
            return BallObservation(position_m=None, covariance_m2=None, support=0, inliers=np.zeros(self.n_cams, bool),
                                   status=Status.TOO_FEW_OBSERVATIONS, notes=(f"synthetic: seen by {seen} cameras",), **common)
        if u[0] < p.p_miss:
            return BallObservation(position_m=None, covariance_m2=None, support=0, inliers=np.zeros(self.n_cams, bool),
                                   status=Status.NO_CONSENSUS, notes=("synthetic: missed",), **common)
        inliers = np.zeros(self.n_cams, bool)
        inliers[:seen] = True
        cov = np.eye(3) * p.noise_std_m**2
        if u[0] < p.p_miss + p.p_outlier:
            d = direction / max(np.linalg.norm(direction), 1e-12)
            X = np.asarray(ball_m, float) + d * (p.outlier_offset_m[0] + u[1] * (p.outlier_offset_m[1] - p.outlier_offset_m[0]))
            note = "synthetic: outlier"
        elif u[0] < p.p_miss + p.p_outlier + p.p_wild:
            lo, hi = (np.asarray(b, float) for b in p.wild_box_m)
            X = lo + u[1:4] * (hi - lo)
            note = "synthetic: wild"
        else:
            X = np.asarray(ball_m, float) + p.noise_std_m * noise
            note = ""
        return BallObservation(position_m=X, covariance_m2=cov, support=seen, inliers=inliers, status=Status.OK,
                               notes=(note,) if note else (), **common)


class VisionSource:
    """Rendered images through the real tracker (``tracker.make_tracker(kind, rig)``).

    renderer : :class:`harness.sim.render.Renderer` of ``rig`` (built once per worker, it caches the lab);
    scene_options : :class:`harness.experiments.play.play_scene.PlaySceneOptions`
    """

    name = "vision"

    def __init__(self, rig, profile: TrackerProfile, *, kinematics, renderer=None, scene_options=None, tracker=None):
        from harness.experiments.play.play_scene import PlayScene, PlaySceneOptions
        from harness.sim.render import Renderer
        from tracker import make_tracker

        self.rig, self.profile, self.kin = rig, profile, kinematics
        self.renderer = renderer if renderer is not None else Renderer(rig, seed=0)
        self._scene_cls = PlayScene
        self.scene_options = scene_options or PlaySceneOptions()
        if tracker is None:
            from harness.experiments.play.rtblob_setup import calibrate_rtblob

            kw = {"rtblob_options": calibrate_rtblob(rig, self.renderer, kinematics, self.scene_options)} \
                if profile.tracker == "rtblob" else {}
            tracker = make_tracker(profile.tracker, rig, **kw)
        self.tracker = tracker
        self.scene = None
        self.last_images = None

    def reset(self, seed, **_unused) -> None:
        """A new ball: new person and clutter from ``seed``; the tracker forgets the last ball."""
        self.scene = self._scene_cls(self.kin, self.scene_options, seed=seed)  # also offsets the frames' sensor noise
        self.tracker.reset()

    def observe(self, frame_index: int, t_s: float, ball_m, ball_velocity_mps, q_true) -> BallObservation:
        from tracker import FrameSet

        scene = self.scene.scene_at(frame_index, t_s, q_true, ball_m, ball_velocity_mps)
        images = self.renderer.render(scene)
        self.last_images = images
        obs = self.tracker.process(FrameSet(float(t_s), tuple(images), int(frame_index)))
        return dataclasses.replace(obs, latency_s=self.profile.latency_s)


#: ``--source`` name -> class
SOURCES = {"synthetic": SyntheticSource, "vision": VisionSource}


def make_source(name: str, rig, profile: TrackerProfile, **kwargs):
    """A source by name (``SOURCES``); kwargs go to the class (vision: kinematics=, renderer=, ...)."""
    if name not in SOURCES:
        raise ValueError(f"unknown observation source {name!r}; valid: {sorted(SOURCES)}")
    return SOURCES[name](rig, profile, **kwargs)
