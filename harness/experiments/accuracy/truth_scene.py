"""The scene that ``rt2 track --source sim --truth-stream ADDR`` renders: the lab at an exposure time on
the host clock, from the lab truth stream (:mod:`harness.sim.lab_truth`) and the accuracy experiment's
scene presets (:mod:`harness.experiments.accuracy.session_scene`).
"""

from __future__ import annotations

import numpy as np

from harness.experiments.accuracy.session_scene import SCENES as PRESETS, SessionScene
from harness.sim.lab_truth import TruthSubscriber

__all__ = ["SCENES", "LabTruthScene"]


#: scenes of ``rt2 track --source sim --truth-stream``: the accuracy experiment's presets, or the arm alone
SCENES = ("accuracy", "accuracy-clean", "accuracy-harsh", "play")


class LabTruthScene:
    """Scene provider of the ``sim`` source on the host clock: ``provider(t_host_s) -> Scene``.

    The WAM at its TRUE joints from the truth stream at the exposure instant ``t_host_s`` (the ball on its
    end effector for the ``accuracy*`` scenes, with its velocity over +-``h_s`` for motion blur), the free
    balls of the stream, and the rest of the scene (person, clutter, distractor episodes) from the seed as
    :class:`harness.experiments.accuracy.session_scene.SessionScene` builds it, at scene time = ``t_host_s`` minus the first
    exposure asked. ``play``: the arm (without the mounted ball) and the free balls only.

    address : the truth stream; scene : one of :data:`SCENES`; seed : the session seed of the scene;
    wait_s : how long a frame waits for its truth; first_wait_s : how long the first one waits
    """

    def __init__(self, address: str, scene: str = "accuracy", *, seed: int = 0, wait_s: float = 0.5,
                 first_wait_s: float = 20.0, h_s: float = 0.001):
        from robot_models import WamKinematics, load_robot_config

        if scene not in SCENES:
            raise ValueError(f"unknown lab truth scene {scene!r}; valid: {list(SCENES)}")
        self.address, self.scene, self.seed = address, scene, int(seed)
        self.wait_s, self.first_wait_s, self.h_s = float(wait_s), float(first_wait_s), float(h_s)
        self.kin = WamKinematics.from_config(load_robot_config())
        preset = PRESETS["default" if scene in ("accuracy", "play") else scene.split("-", 1)[1]]
        if scene == "play":
            preset = PRESETS["clean"]
        self._session = SessionScene(self.kin.link_radii_m, np.asarray(self.kin.T_base_to_world)[:3, 3], preset,
                                     seed=self.seed)
        self._sub: TruthSubscriber | None = None
        self._t_first: float | None = None

    def open(self) -> "LabTruthScene":
        """Connect (called on first use; not in ``__init__`` so that the provider can be built before the stream)."""
        if self._sub is None:
            self._sub = TruthSubscriber(self.address, n_joints=self.kin.n_joints)
            self._sub.wait_first(self.first_wait_s)
        return self

    def __call__(self, t_host_s: float, frame_index: int = 0):
        self.open()
        if self._t_first is None:
            self._t_first = float(t_host_s)
        t_ns = int(round(t_host_s * 1e9))
        h_ns = int(round(self.h_s * 1e9))
        s_plus = self._sub.at(t_ns + h_ns, wait_s=self.wait_s)  # the latest instant needed: waits for it
        s = self._sub.at(t_ns, wait_s=0.0)
        s_minus = self._sub.at(t_ns - h_ns, wait_s=0.0)
        return self._compose(np.stack([s.q, s_plus.q, s_minus.q]), s.balls, float(t_host_s) - self._t_first,
                             frame_index)

    def warm_up_scene(self):
        """The scene with the arm at rest at home and one free ball (no stream needed): rendered once before the
        camera clock starts, so that compiling the renderer's kernels does not delay the first frames."""
        q = np.asarray(self.kin.q_home, float)
        return self._compose(np.stack([q, q, q]), np.array([[0.0, 0.0, 1.0]]), 0.0, 0)

    def _compose(self, Q, balls, t_scene_s: float, frame_index: int):
        """Q : (3, 7) true joints at t, t + h, t - h; balls : (m, 3) world."""
        from harness.sim.render import Ball, Scene

        links = self.kin.link_points(Q[:1], check_limits=False)[0]
        free = tuple(Ball(p, np.zeros(3), "orange") for p in balls)
        if self.scene == "play":
            ball = self.kin.positions(Q[:1], check_limits=False)[0]
            caps = self._session.arm_capsules(links, ball)[:-1]  # no stick: nothing mounted
            return Scene(balls=free, capsules=tuple(caps), exposure=self._session.exposure, frame_index=int(frame_index))
        P = self.kin.positions(Q, check_limits=False)
        velocity = (P[1] - P[2]) / (2 * self.h_s)
        scene = self._session.scene_at(frame_index, t_scene_s, links, P[0], velocity)
        return Scene(balls=scene.balls + free, capsules=scene.capsules, spheres=scene.spheres, boxes=scene.boxes,
                     exposure=scene.exposure, frame_index=scene.frame_index)

    def stats(self) -> dict:
        """Samples received, malformed and lost so far."""
        s = self._sub
        return {} if s is None else {"received": s.received, "malformed": s.malformed, "lost": s.lost}

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
