"""What the cameras see in a playing session: the served ball, the WAM swinging its racket, a person, clutter.

One :class:`PlayScene` per ball draws what stays fixed (the person's build, clothes and stance beside the
table, the distractor objects, the exposure) from its seed, as the accuracy experiment's scenes do
(``harness.accuracy.scene``); :meth:`PlayScene.scene_at` builds one frame set's
:class:`harness.render.Scene` from the TRUE state at the capture time:

* the WAM: a pedestal under the mount, one capsule per link between the frames of
  ``WamKinematics.link_points`` (radii ``link_radii_m``), a wooden handle from the tool plate to the
  racket blade, and the blade as a red/black disk (``Disk``, 75 mm radius, normal = racket frame z);
* the ball: orange, 40 mm, with its velocity (motion blur over the exposure);
* a person beside the table on the robot's half (``harness.render.scenes.person``), the right hand
  moving slowly over the table corner and holding a white ball;
* orange / white / near-orange distractors on the table and the floor (like the accuracy scenes').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness import lab
from harness.render.scene import Ball, Box, Capsule, Disk, Exposure, Scene, Sphere
from harness.render.scenes import person

__all__ = ["PlayScene", "PlaySceneOptions"]

_SKINS = ("skin_light", "skin_medium", "skin_tan", "skin_dark")
_SHIRTS = ("orange", "white", "shirt_blue", "shirt_red")
_NEAR_ORANGE = (0.95, 0.5, 0.12)


def _distractor(rng, i: int):
    """Things a colour detector may take for the ball, in turn: an orange cup on the table, a white box on
    the floor, a near-orange juggling ball on the table, an orange box on the floor (robot's side)."""
    kind = i % 4
    on_table = kind in (0, 2)
    xy = rng.uniform([-1.25, -0.65], [-0.2, 0.65]) if on_table else (
        lab.ROBOT_BASE_M[:2] + rng.uniform(0.7, 1.4) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)]))
    z0 = lab.TABLE_TOP_Z_M if on_table else 0.0
    yaw = rng.uniform(0, np.pi)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    if kind == 2:
        r = rng.uniform(0.03, 0.045)
        return Sphere([xy[0], xy[1], z0 + r], r, _NEAR_ORANGE, 0.2)
    size = {0: [0.07, 0.07, rng.uniform(0.09, 0.12)], 1: [rng.uniform(0.2, 0.35), rng.uniform(0.15, 0.25), 0.15],
            3: [rng.uniform(0.25, 0.4), rng.uniform(0.2, 0.3), rng.uniform(0.15, 0.3)]}[kind]
    colour = "white" if kind == 1 else "orange"
    return Box([xy[0], xy[1], z0 + size[2] / 2 + 1e-3], size, R, colour, 0.05)


@dataclass(frozen=True)
class PlaySceneOptions:
    """person : draw the person; n_distractors : clutter objects; racket_front, racket_back : colours of
    the blade's two sides (the front faces the opponent, i.e. the cameras over the opponent's half);
    exposure_s, gain, light_level : the cameras' exposure."""

    person: bool = True
    n_distractors: int = 4
    racket_front: str = "racket_red"
    racket_back: str = "racket_black"
    exposure_s: float = 0.002
    gain: float = 1.0
    light_level: float = 1.0

    def __post_init__(self):
        if isinstance(self.n_distractors, bool) or not isinstance(self.n_distractors, int) or not 0 <= self.n_distractors <= 20:
            raise ValueError(f"PlaySceneOptions.n_distractors must be an integer in [0, 20], got {self.n_distractors!r}")
        Exposure(self.exposure_s, self.gain, self.light_level)  # validates


class PlayScene:
    """The fixed part of one ball's scene plus the per-frame composition (module docstring)."""

    def __init__(self, kinematics, options: PlaySceneOptions = PlaySceneOptions(), *, seed=0):
        if not isinstance(options, PlaySceneOptions):
            raise ValueError(f"options must be PlaySceneOptions, got {type(options).__name__}")
        self.kin, self.options = kinematics, options
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        rng = np.random.default_rng(ss)
        self.frame_base = int(rng.integers(2**20)) * 4096  # frame_index offset: per-ball sensor noise
        self.skin = _SKINS[int(rng.integers(len(_SKINS)))]
        self.shirt = _SHIRTS[int(rng.integers(len(_SHIRTS)))]
        side = 1.0 if rng.random() < 0.5 else -1.0
        self.feet_xy = np.array([rng.uniform(-1.2, -0.6), side * (lab.TABLE_HALF_WIDTH_M + rng.uniform(0.45, 0.7))])
        self.hand_centre_m = np.array([self.feet_xy[0] - 0.2, side * 0.6, 1.0])
        self.hand_freq_hz = rng.uniform(0.2, 0.6, size=3)
        self.hand_phase = rng.uniform(0, 2 * np.pi, size=3)
        self.person_seed = int(rng.integers(2**31))
        self.distractors = tuple(_distractor(rng, i) for i in range(options.n_distractors))
        self.exposure = Exposure(options.exposure_s, options.gain, options.light_level)
        self._fid = kinematics.frame_id("racket")
        self._mount = np.asarray(kinematics.T_base_to_world[:3, 3], float)

    def arm(self, q_true) -> tuple[list, list]:
        """Capsules (pedestal, links, handle) and the racket disk of the arm at joint angles q_true (7,)."""
        kin = self.kin
        P = kin.link_points(np.asarray(q_true, float), check_limits=False)
        r = kin.link_radii_m
        caps = [Capsule(self._mount * [1, 1, 0], self._mount - [0, 0, 0.12], 0.12, "robot_grey", 0.1)]
        for i in range(8):
            if np.linalg.norm(P[i + 1] - P[i]) > 1e-6 or i == 0:
                caps.append(Capsule(P[i], P[i + 1], r[i], "robot_grey" if i < 3 else "robot_black", 0.25))
        T, _ = kin.fk_and_jacobian(np.asarray(q_true, float), self._fid)
        centre, normal = T[:3, 3], T[:3, 2]
        rim = centre - 0.075 * (centre - P[8]) / max(np.linalg.norm(centre - P[8]), 1e-9)
        caps.append(Capsule(P[8], rim, 0.013, "wood", 0.05))
        return caps, [Disk(centre, normal, 0.075, self.options.racket_front, self.options.racket_back)]

    def scene_at(self, frame_index: int, t_s: float, q_true, ball_m, ball_velocity_mps) -> Scene:
        """Frame set ``frame_index`` at time ``t_s``: the arm at q_true (7,), the ball (3,) with velocity (3,)."""
        caps, disks = self.arm(q_true)
        spheres, boxes = [], []
        for d in self.distractors:
            (spheres if isinstance(d, Sphere) else boxes).append(d)
        if self.options.person:
            wave = 0.1 * np.sin(2 * np.pi * self.hand_freq_hz * t_s + self.hand_phase)
            c, s, tip = person(np.random.default_rng(self.person_seed), self.feet_xy, hand_target=self.hand_centre_m + wave,
                               skin=self.skin, shirt=self.shirt)
            caps += c
            spheres += s
            spheres.append(Sphere(tip + [0.0, 0.0, 0.01], 0.02, "white", 0.35))
        return Scene(balls=(Ball(ball_m, ball_velocity_mps, "orange"),), capsules=tuple(caps), spheres=tuple(spheres),
                     disks=tuple(disks), boxes=tuple(boxes), exposure=self.exposure,
                     frame_index=self.frame_base + int(frame_index))
