"""What the cameras see in a playing session: the served ball, the WAM swinging its racket, a person, clutter.

One :class:`PlayScene` per ball draws what stays fixed (the person's build, clothes and stance beside the
table, the distractor objects, the exposure) from its seed, as the accuracy experiment's scenes do
(``harness.experiments.accuracy.session_scene``); :meth:`PlayScene.scene_at` builds one frame set's
:class:`harness.sim.render.Scene` from the TRUE state at the capture time:

* the WAM: a pedestal under the mount, one capsule per link between the frames of
  ``WamKinematics.link_points`` (radii ``link_radii_m``), a wooden handle from the tool plate to the
  racket blade, and the blade as a red/black disk (``Disk``, 75 mm radius, normal = racket frame z);
* the ball: orange, 40 mm, with its velocity (motion blur over the exposure);
* a person beside the table on the robot's half (``harness.sim.render.scenes.person``), the right hand
  moving slowly over the table corner and holding a ball at the fingertips (white, or orange with
  ``p_orange_held_ball``);
* distractors from :data:`DISTRACTORS` on the table and the floor, placed by the seed as
  :data:`harness.sim.render.placed_distractors.PLAY` says.

:data:`SCENES` names the presets of ``rt2 play --scene``:

* ``default`` -- the lab of the accuracy experiment's default scene, one ball in play: a person in a
  white, blue or red shirt holding a white ball, a white cup on the table and a white box on the
  floor. No orange thing but the served ball: a lab that ran the colour-based RTBlob for years (the
  paper's) kept orange objects out of the cameras' view;
* ``second_ball`` -- the default, but the person holds an ORANGE ball during the whole flight: a second
  real ball, consistent across the cameras. RT2 keeps both as 3D hypotheses and reports the one in
  play (docs/pipeline.md step 10); RTBlob's per-camera argmax mixes them (docs/play.md);
* ``harsh`` -- shirts including orange, an orange cup and a near-orange juggling ball on the table, a
  white and an orange box on the floor (the play scene before 2026-11-22): a colour tracker picks an
  orange object in nearly every frame;
* ``clean`` -- the arm, the racket and the ball only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim import lab
from harness.sim.render.placed_distractors import DISTRACTORS, PLAY, place_distractor
from harness.sim.render.scene_state import Ball, Capsule, Disk, Exposure, Scene, Sphere, colour_rgb
from harness.sim.render.scenes import ball_in_hand, person

__all__ = ["DISTRACTORS", "SCENES", "PlayScene", "PlaySceneOptions"]

_SKINS = ("skin_light", "skin_medium", "skin_tan", "skin_dark")


@dataclass(frozen=True)
class PlaySceneOptions:
    """person : draw the person; shirts : colours the person's shirt is drawn from (one per ball);
    p_orange_held_ball : share of the balls for which the person holds an orange ball (else white);
    distractors : names from :data:`DISTRACTORS`, each placed per ball by its seed;
    racket_front, racket_back : colours of the blade's two sides (the front faces the opponent);
    exposure_s, gain, light_level : the cameras' exposure."""

    person: bool = True
    shirts: tuple = ("white", "shirt_blue", "shirt_red")
    p_orange_held_ball: float = 0.0
    distractors: tuple = ("white_cup", "white_box")
    racket_front: str = "racket_red"
    racket_back: str = "racket_black"
    exposure_s: float = 0.002
    gain: float = 1.0
    light_level: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "distractors", tuple(self.distractors))
        object.__setattr__(self, "shirts", tuple(self.shirts))
        bad = [d for d in self.distractors if d not in DISTRACTORS]
        if bad:
            raise ValueError(f"unknown PlaySceneOptions.distractors {bad}; valid: {sorted(DISTRACTORS)}")
        if not self.shirts:
            raise ValueError("PlaySceneOptions.shirts must name at least one colour, got ()")
        for c in self.shirts:
            colour_rgb(c, "PlaySceneOptions.shirts")
        p = self.p_orange_held_ball
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0 <= p <= 1:
            raise ValueError(f"PlaySceneOptions.p_orange_held_ball must be a probability in [0, 1], got {p!r}")
        Exposure(self.exposure_s, self.gain, self.light_level)  # validates


#: ``rt2 play --scene`` presets (module docstring)
SCENES = {
    "default": PlaySceneOptions(),
    "second_ball": PlaySceneOptions(p_orange_held_ball=1.0),
    "harsh": PlaySceneOptions(shirts=("orange", "white", "shirt_blue", "shirt_red"), p_orange_held_ball=0.0,
                              distractors=("orange_cup", "white_box", "orange_sphere", "orange_box")),
    "clean": PlaySceneOptions(person=False, p_orange_held_ball=0.0, distractors=()),
}


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
        self.shirt = options.shirts[int(rng.integers(len(options.shirts)))]
        side = 1.0 if rng.random() < 0.5 else -1.0
        self.feet_xy = np.array([rng.uniform(-1.2, -0.6), side * (lab.TABLE_HALF_WIDTH_M + rng.uniform(0.45, 0.7))])
        self.hand_centre_m = np.array([self.feet_xy[0] - 0.2, side * 0.6, 1.0])
        self.hand_freq_hz = rng.uniform(0.2, 0.6, size=3)
        self.hand_phase = rng.uniform(0, 2 * np.pi, size=3)
        self.person_seed = int(rng.integers(2**31))
        self.distractors = tuple(place_distractor(rng, name, PLAY) for name in options.distractors)
        self.held_ball = "orange" if rng.random() < options.p_orange_held_ball else "white"
        self.exposure = Exposure(options.exposure_s, options.gain, options.light_level)
        self._fid = kinematics.frame_id("racket")
        self._mount = np.asarray(kinematics.T_base_to_world[:3, 3], float)

    def arm(self, q_true) -> tuple[list, list]:
        """Capsules (pedestal, links, handle) and the racket disk of the arm at joint angles q_true (n,)."""
        kin = self.kin
        P = kin.link_points(np.asarray(q_true, float), check_limits=False)
        r = kin.link_radii_m
        tip = len(r)  # the flange's point
        caps = [Capsule(self._mount * [1, 1, 0], self._mount - [0, 0, 0.12], 0.12, "robot_grey", 0.1)]
        for i in range(len(r)):
            if np.linalg.norm(P[i + 1] - P[i]) > 1e-6 or i == 0:
                caps.append(Capsule(P[i], P[i + 1], r[i], "robot_grey" if i < 3 else "robot_black", 0.25))
        T, _ = kin.fk_and_jacobian(np.asarray(q_true, float), self._fid)
        centre, normal = T[:3, 3], T[:3, 2]
        rim = centre - 0.075 * (centre - P[tip]) / max(np.linalg.norm(centre - P[tip]), 1e-9)
        caps.append(Capsule(P[tip], rim, 0.013, "wood", 0.05))
        return caps, [Disk(centre, normal, 0.075, self.options.racket_front, self.options.racket_back)]

    def scene_at(self, frame_index: int, t_s: float, q_true, ball_m, ball_velocity_mps) -> Scene:
        """Frame set ``frame_index`` at time ``t_s``: the arm at q_true (n,), the ball (3,) with velocity (3,)."""
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
            spheres.append(Sphere(ball_in_hand(c, tip), 0.02, self.held_ball, 0.35))  # at the fingertips, visible
        return Scene(balls=(Ball(ball_m, ball_velocity_mps, "orange"),), capsules=tuple(caps), spheres=tuple(spheres),
                     disks=tuple(disks), boxes=tuple(boxes), exposure=self.exposure,
                     frame_index=self.frame_base + int(frame_index))
