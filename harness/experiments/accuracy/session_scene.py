"""What the cameras see in the accuracy experiment: the WAM carrying the ball, a person beside it, clutter.

One :class:`SessionScene` per session draws everything that stays fixed (the person's build, clothes
and stance, the distractor objects, the exposure) from its seed; :meth:`SessionScene.scene_at` then
builds frame ``k``'s :class:`harness.sim.render.Scene` from the robot's TRUE link positions and ball:

* the WAM: a pedestal from the floor to the mount, one capsule per link between consecutive frames
  of ``WamKinematics.link_points`` (radii ``link_radii_m``), the last one ending at the tool plate,
  and a thin stick from the tool plate to the ball (so the arm never covers the ball's centre);
* the ball: orange, 40 mm, at the true ``ball_mount`` position with its velocity (motion blur);
* a person standing beside the table near the robot (white or orange shirt, skin-coloured arms),
  the right hand moving smoothly (a sum of seeded sinusoids) over the table's corner next to the
  robot, holding a white ball (``harness.sim.render.scenes.person``, the same build every frame);
* distractors from :data:`DISTRACTORS` (white and orange cups and boxes, a near-orange juggling ball), placed as
  :data:`harness.sim.render.placed_distractors.ACCURACY` says
  on the table's robot half and on the floor around the robot, placed by the seed;
* distractors that come and go (:mod:`harness.experiments.accuracy.distractors`): now and then the person holds or
  tosses a second, orange ball instead of the white one, and stray orange balls roll across the floor.

:data:`SCENES` names the presets of ``rt2 accuracy --scene``: ``default`` (a lab session: white shirt, a
white cup and box, the orange ball episodes and rolling balls), ``harsh`` (orange shirt, every static
distractor, and the episodes) and ``clean`` (the arm and the ball only).

Everything is a function of (seed, frame time), so any worker can build any frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim import lab
from harness.sim.render.placed_distractors import ACCURACY, DISTRACTORS, place_distractor
from harness.sim.render.scene_state import Ball, Capsule, Exposure, Scene, Sphere, colour_rgb
from harness.sim.render.scenes import ball_in_hand, person
from harness.experiments.accuracy.distractors import DistractorSchedule

__all__ = ["DISTRACTORS", "SCENES", "SHIRTS", "SceneOptions", "SessionScene"]

#: shirt colours ("orange/white shirt" distractors); None in SceneOptions draws one with the seed
SHIRTS = ("white", "orange")
_SKINS = ("skin_light", "skin_medium", "skin_tan", "skin_dark")


@dataclass(frozen=True)
class SceneOptions:
    """Options of :class:`SessionScene`.

    person : draw the person beside the robot
    shirt : a shirt colour name, or None to draw it from :data:`SHIRTS` with the seed
    held_ball : colour of the ball in the person's hand ("white", "orange") or None for an empty hand
    distractors : names from :data:`DISTRACTORS`, each placed by the seed
    orange_ball_gap_s : mean time between the person's orange-ball episodes, seconds (None: never;
        needs ``person``); orange_ball_hold_s : (min, max) length of an episode; p_toss : share of the
        episodes in which the ball is tossed up and caught
    rolling_ball_gap_s : mean time between stray orange balls rolling across the floor (None: never);
        rolling_speed_mps : (min, max) their initial speed
    exposure_s, gain, light_level : the cameras' exposure (constant over the session)
    """

    person: bool = True
    shirt: str | None = "white"
    held_ball: str | None = "white"
    distractors: tuple = ("white_cup", "white_box")
    orange_ball_gap_s: float | None = 12.0
    orange_ball_hold_s: tuple = (1.5, 4.0)
    p_toss: float = 0.3
    rolling_ball_gap_s: float | None = 25.0
    rolling_speed_mps: tuple = (0.3, 1.2)
    exposure_s: float = 0.002
    gain: float = 1.0
    light_level: float = 1.0

    def __post_init__(self):
        if self.held_ball not in (None, "white", "orange"):
            raise ValueError(f"SceneOptions.held_ball must be None, 'white' or 'orange', got {self.held_ball!r}")
        object.__setattr__(self, "distractors", tuple(self.distractors))
        bad = [d for d in self.distractors if d not in DISTRACTORS]
        if bad:
            raise ValueError(f"unknown SceneOptions.distractors {bad}; valid: {sorted(DISTRACTORS)}")
        if self.shirt is not None:
            colour_rgb(self.shirt, "SceneOptions.shirt")
        for name in ("orange_ball_gap_s", "rolling_ball_gap_s"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.5 <= v <= 1e6):
                raise ValueError(f"SceneOptions.{name} must be a mean gap in [0.5, 1e6] s or None, got {v!r}")
        for name, lo, hi in (("orange_ball_hold_s", 0.1, 60.0), ("rolling_speed_mps", 0.0, 10.0)):
            v = tuple(getattr(self, name))
            if len(v) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v) or not lo <= v[0] <= v[1] <= hi:
                raise ValueError(f"SceneOptions.{name} must be (min, max) with {lo:g} <= min <= max <= {hi:g}, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        if isinstance(self.p_toss, bool) or not isinstance(self.p_toss, (int, float)) or not 0 <= self.p_toss <= 1:
            raise ValueError(f"SceneOptions.p_toss must be a probability in [0, 1], got {self.p_toss!r}")
        Exposure(self.exposure_s, self.gain, self.light_level)  # validates


#: presets of ``rt2 accuracy --scene``
SCENES = {
    "default": SceneOptions(),
    "harsh": SceneOptions(shirt="orange", distractors=tuple(DISTRACTORS)),
    "clean": SceneOptions(person=False, held_ball=None, distractors=(), orange_ball_gap_s=None, rolling_ball_gap_s=None),
}


def _unit(v):
    return v / np.linalg.norm(v)


class SessionScene:
    """The fixed part of a session's scene plus the per-frame composition (see the module docstring).

    link_radii_m : (n + 1,) capsule radii of an arm of n joints (``ArmKinematics.link_radii_m``; the WAM's 8)
    mount_world_m : (3,) where the arm's base plate is (top of the pedestal), world
    """

    def __init__(self, link_radii_m, mount_world_m, options: SceneOptions = SceneOptions(), *, seed: int = 0):
        if not isinstance(options, SceneOptions):
            raise ValueError(f"options must be SceneOptions, got {type(options).__name__}")
        self.options = options
        self.link_radii_m = np.asarray(link_radii_m, float)
        if self.link_radii_m.ndim != 1 or len(self.link_radii_m) < 2 or not (self.link_radii_m > 0).all():
            raise ValueError(f"link_radii_m must be (n + 1,) positive radii, got {self.link_radii_m.tolist()}")
        self.mount_world_m = np.asarray(mount_world_m, float)
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))
        self.shirt = options.shirt or SHIRTS[int(rng.integers(len(SHIRTS)))]
        self.skin = _SKINS[int(rng.integers(len(_SKINS)))]
        side = 1.0 if rng.random() < 0.5 else -1.0
        self.feet_xy = np.array([rng.uniform(-1.3, -0.8), side * (lab.TABLE_HALF_WIDTH_M + rng.uniform(0.45, 0.6))])
        # the right hand's path: over the table corner next to the robot, a sum of two sinusoids per axis
        self.hand_centre_m = np.array([self.feet_xy[0] - 0.25, side * 0.62, 1.0])
        self.hand_amp_m = np.array([0.22, 0.12, 0.15])
        self.hand_freq_hz = rng.uniform(0.1, 0.35, size=(2, 3))
        self.hand_phase = rng.uniform(0, 2 * np.pi, size=(2, 3))
        self.person_seed = int(rng.integers(2**31))
        self.distractors = tuple(place_distractor(rng, name, ACCURACY) for name in options.distractors)
        self.exposure = Exposure(options.exposure_s, options.gain, options.light_level)
        self.events = DistractorSchedule(options, np.random.SeedSequence([int(seed), 6]))

    def hand_target_m(self, t_s: float) -> np.ndarray:
        """(3,) where the person's right hand reaches at time ``t_s``, world."""
        wave = np.sin(2 * np.pi * self.hand_freq_hz * t_s + self.hand_phase).sum(axis=0) / 2
        return self.hand_centre_m + self.hand_amp_m * wave

    def arm_capsules(self, links_world_m, ball_world_m) -> list:
        """Pedestal, links and the ball stick of one arm pose. links_world_m : (n + 2, 3) (``link_points``; the
        WAM's 9); ball_world_m : (3,)."""
        P = np.asarray(links_world_m, float)
        r = self.link_radii_m
        if P.shape != (len(r) + 1, 3):
            raise ValueError(f"links_world_m must have shape ({len(r) + 1}, 3) for {len(r)} link radii, got {P.shape}")
        tip = P[-1]  # the tool plate
        last = len(r) - 1  # the segment that ends at the tool plate: the last link whose origin is not the plate
        while last > 0 and np.linalg.norm(P[last] - tip) < 1e-9:  # (the xArm7's link7 is its flange: its full cap
            last -= 1                                            # would swallow the ball)
        caps = [Capsule(self.mount_world_m * [1, 1, 0], self.mount_world_m - [0, 0, 0.12], 0.12, "robot_grey", 0.1)]
        for i in range(last):
            caps.append(Capsule(P[i], P[i + 1], r[i], "robot_grey" if i < 3 else "robot_black", 0.25))
        axis = _unit(np.asarray(ball_world_m) - tip)
        end = tip - r[last] * axis  # the last link's cap ends at the tool plate
        start = P[last] if np.linalg.norm(end - P[last]) > 1e-9 else end
        caps.append(Capsule(start, end, r[last], "robot_grey", 0.25))
        caps.append(Capsule(tip, np.asarray(ball_world_m) - 0.016 * axis, 0.005, "robot_grey", 0.2))
        return caps

    def scene_at(self, frame_index: int, t_s: float, links_world_m, ball_world_m, ball_velocity_mps) -> Scene:
        """Frame ``frame_index`` at time ``t_s``: the arm (links_world_m (n + 2, 3), true), the ball (3,), its velocity (3,)."""
        caps = self.arm_capsules(links_world_m, ball_world_m)
        spheres, boxes, balls = [], [], [Ball(ball_world_m, ball_velocity_mps, "orange")]
        for d in self.distractors:
            (spheres if isinstance(d, Sphere) else boxes).append(d)
        if self.options.person:
            c, s, tip = person(np.random.default_rng(self.person_seed), self.feet_xy,
                               hand_target=self.hand_target_m(t_s), skin=self.skin, shirt=self.shirt)
            caps += c
            spheres += s
            orange = self.events.held_ball(t_s, ball_in_hand(c, tip, grip="fist"))
            if orange is not None:  # an orange-ball episode: it replaces the white ball in the hand
                balls.append(orange)
            elif self.options.held_ball is not None:
                spheres.append(Sphere(ball_in_hand(c, tip), 0.02, self.options.held_ball, 0.35))
        balls += self.events.rolling_balls(t_s)
        return Scene(balls=tuple(balls), capsules=tuple(caps), spheres=tuple(spheres), boxes=tuple(boxes),
                     exposure=self.exposure, frame_index=int(frame_index))
