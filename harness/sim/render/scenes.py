"""Seeded random scenes for labelled data sets: the ball among the things that fool a colour detector.

:func:`random_scene` draws one frame's :class:`~harness.sim.render.scene_state.Scene` from a generator:

* the ball (orange or white) somewhere in the workspace, flying at up to ``max_speed_mps`` or
  nearly still; often held by / next to a skin-coloured hand; sometimes just behind the net or
  a robot link (partial occlusion); sometimes no ball at all, sometimes a second one lying around;
* a person (legs, torso in a random shirt colour, which may be orange or white, head, two arms
  with skin-coloured forearms and hands) standing beside or behind the table;
* a robot arm: a pedestal at the lab's robot base and a random 3-link grey/black chain, often
  with a red/black racket;
* orange / white / yellow distractor spheres and boxes on the table, on the floor or held;
* exposure, gain and illumination varied around an auto-exposure target.

Everything comes from the ``rng`` passed in: the same generator state gives the same scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim import lab
from harness.sim.render.renderer import RenderOptions
from harness.sim.render.scene_state import Ball, Box, Capsule, Disk, Exposure, Scene, Sphere

__all__ = ["BALL_COLOURS", "SceneOptions", "ball_in_hand", "person", "random_scene", "robot_arm"]

#: the ball colours a scene may be limited to (``SceneOptions.ball_colour``)
BALL_COLOURS = ("orange", "white")

_SKINS = ("skin_light", "skin_medium", "skin_tan", "skin_dark")
_SHIRTS = ("shirt_blue", "shirt_red", "shirt_black", "shirt_green", "white", "orange", "yellow")
_REFERENCE_EXPOSURE_S = RenderOptions().reference_exposure_s  # brightness 1 at this shutter time
_DISTRACTOR_COLOURS = ("orange", "white", "yellow", (0.95, 0.55, 0.15), (0.98, 0.97, 0.92))


@dataclass(frozen=True)
class SceneOptions:
    """Probabilities and ranges of :func:`random_scene`.

    p_no_ball : frames without any ball
    p_near_hand : the ball is held by / next to the person's hand
    p_near_net : the ball is just behind or over the net (from the robot's cameras)
    p_second_ball : a second ball lies on the table or the floor
    p_white : the ball is white (else orange)
    p_person, p_robot, p_racket : a person / a robot arm / a racket on the arm is present
    max_distractors : up to this many distractor spheres and boxes
    max_speed_mps : flying balls move at up to this speed
    brightness : (min, max) auto-exposure target, 1 = nominal
    exposure_s : (min, max) shutter time, seconds
    ball_colour : None = each ball white or orange at random (``p_white``; the lying second ball half and half); a
        colour (``"white"``, ``"orange"``) = every ball that colour, the rest of the scene as with None (the same
        random draws: the same seed gives the same scene but for the balls' colour)
    """

    p_no_ball: float = 0.12
    p_near_hand: float = 0.35
    p_near_net: float = 0.1
    p_second_ball: float = 0.1
    p_white: float = 0.4
    p_person: float = 0.85
    p_robot: float = 0.7
    p_racket: float = 0.6
    max_distractors: int = 5
    max_speed_mps: float = 8.0
    brightness: tuple = (0.55, 1.6)
    exposure_s: tuple = (0.0008, 0.003)
    ball_colour: str | None = None

    def __post_init__(self):
        if self.ball_colour is not None and self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"SceneOptions.ball_colour must be None or one of {list(BALL_COLOURS)}, got {self.ball_colour!r}")
        for name in ("p_no_ball", "p_near_hand", "p_near_net", "p_second_ball", "p_white", "p_person", "p_robot", "p_racket"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not 0 <= v <= 1:
                raise ValueError(f"SceneOptions.{name} must be a probability in [0, 1], got {v!r}")
        if not isinstance(self.max_distractors, int) or self.max_distractors < 0:
            raise ValueError(f"SceneOptions.max_distractors must be a non-negative integer, got {self.max_distractors!r}")
        for name in ("brightness", "exposure_s"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"SceneOptions.{name} must be (min, max) with 0 < min <= max, got {getattr(self, name)!r}")


def _unit(v):
    return v / np.linalg.norm(v)


def _elbow(shoulder, hand, upper_m, fore_m, bend_dir):
    """Two-link IK: elbow position reaching ``hand`` from ``shoulder`` (hand clamped to reach)."""
    d = hand - shoulder
    L = np.linalg.norm(d)
    L = min(max(L, 0.05), upper_m + fore_m - 1e-3)
    axis = _unit(d)
    hand = shoulder + axis * L
    a = (upper_m**2 - fore_m**2 + L**2) / (2 * L)
    h = np.sqrt(max(upper_m**2 - a**2, 0.0))
    perp = bend_dir - axis * (bend_dir @ axis)
    perp = _unit(perp) if np.linalg.norm(perp) > 1e-6 else _unit(np.cross(axis, [0.0, 0.0, 1.0]) + 1e-9)
    return shoulder + axis * a + perp * h, hand


def person(rng: np.random.Generator, feet_xy, *, hand_target=None, skin=None, shirt=None):
    """A standing person as capsules and spheres; returns (capsules, spheres, right-hand tip).

    feet_xy : (2,) position on the floor, metres; hand_target : (3,) where the right hand reaches
    (else a random pose); skin / shirt : colour names (else random).
    """
    skin = skin or _SKINS[rng.integers(len(_SKINS))]
    shirt = shirt or _SHIRTS[rng.integers(len(_SHIRTS))]
    height = rng.uniform(0.92, 1.08)  # scale of a 1.75 m person
    facing = rng.uniform(-np.pi, np.pi) if hand_target is None else None
    base = np.array([feet_xy[0], feet_xy[1], 0.0])
    if facing is None:
        d = np.asarray(hand_target, float)[:2] - base[:2]
        facing = np.arctan2(d[1], d[0]) + rng.uniform(-0.5, 0.5)
    fwd = np.array([np.cos(facing), np.sin(facing), 0.0])
    left = np.array([-fwd[1], fwd[0], 0.0])
    hip, neck = base + [0, 0, 0.95 * height], base + [0, 0, 1.42 * height]
    caps, sph = [], []
    for side in (-1, 1):  # legs
        foot = base + side * 0.12 * left + fwd * rng.uniform(-0.15, 0.15)
        caps.append(Capsule(hip + side * 0.1 * left, foot + [0, 0, 0.06], 0.075, "jeans", 0.05))
    caps.append(Capsule(hip, neck - [0, 0, 0.05], rng.uniform(0.15, 0.18), shirt, 0.05))
    head = neck + [0, 0, 0.2 * height]
    sph.append(Sphere(head, 0.1, skin, 0.15))
    sph.append(Sphere(head + [0, 0, 0.035] - 0.03 * fwd, 0.09, "hair_dark" if rng.random() < 0.6 else "hair_brown", 0.1))
    tip = None
    for side in (-1, 1):  # side -1: right arm (the one that reaches)
        shoulder = neck + side * 0.19 * left - [0, 0, 0.04]
        if side == -1 and hand_target is not None:
            target = np.asarray(hand_target, float)
        else:
            target = shoulder + fwd * rng.uniform(0.0, 0.5) + side * left * rng.uniform(0.05, 0.3) + [0, 0, rng.uniform(-0.55, 0.2)]
        elbow, wrist = _elbow(shoulder, target - 0.08 * _unit(target - shoulder), 0.3 * height, 0.27 * height, -fwd * 0.3 + [0, 0, -1.0])
        sleeve = shirt if rng.random() < 0.5 else skin
        caps.append(Capsule(shoulder, elbow, 0.05, sleeve, 0.05))
        caps.append(Capsule(elbow, wrist, 0.04, skin, 0.12))
        hand_dir = _unit(wrist - elbow)
        hand_tip = wrist + 0.09 * hand_dir
        caps.append(Capsule(wrist, hand_tip, 0.035, skin, 0.12))
        if side == -1:
            tip = hand_tip
    return caps, sph, tip


def ball_in_hand(capsules, tip, *, ball_radius_m: float = 0.02, grip: str = "fingertips") -> np.ndarray:
    """(3,) centre of a ball held in a :func:`person`'s hand.

    capsules : the person's capsules; tip : (3,) the hand tip :func:`person` returned (the hand is the
    capsule ending there, wrist -> tip). ``grip="fingertips"``: just beyond the tip along the hand,
    touching the hand's cap and slightly up, so the ceiling cameras see nearly all of it;
    ``grip="fist"``: half inside the hand's cap, as a ball closed in the fingers (about half of it
    visible from above).
    """
    tip = np.asarray(tip, float)
    hand = next((c for c in capsules if np.array_equal(c.p1_m, tip)), None)
    if hand is None:
        raise ValueError("ball_in_hand: no capsule of the person ends at the given hand tip")
    if grip not in ("fingertips", "fist"):
        raise ValueError(f"unknown grip {grip!r}; valid: ['fingertips', 'fist']")
    axis = _unit(hand.p1_m - hand.p0_m)
    reach = hand.radius_m + (0.4 if grip == "fingertips" else -0.5) * ball_radius_m
    return tip + axis * reach + [0.0, 0.0, 0.5 * ball_radius_m]


def robot_arm(rng: np.random.Generator, *, racket: bool = True):
    """A random pose of a 7-DoF-arm look-alike on the lab's robot base (capsules, disks).

    The robot's own model lives elsewhere; this only has to look like one to a detector:
    a pedestal, shoulder, upper arm, forearm and wrist in grey/black, and maybe a racket.
    """
    base = lab.ROBOT_BASE_M
    shoulder = base + [0, 0, 1.25]
    caps = [Capsule(base, base + [0, 0, 1.1], 0.13, "robot_grey", 0.1), Capsule(base + [0, 0, 1.1], shoulder, 0.1, "robot_black", 0.2)]
    up_dir = _unit(np.array([rng.uniform(0.2, 1.0), rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.8)]))
    elbow = shoulder + 0.55 * up_dir
    fore_dir = _unit(up_dir + rng.normal(0, 0.8, 3))
    wrist = elbow + 0.3 * fore_dir
    ee_dir = _unit(fore_dir + rng.normal(0, 0.5, 3))
    ee = wrist + 0.06 * ee_dir
    caps += [
        Capsule(shoulder, elbow, 0.065, "robot_grey", 0.25),
        Capsule(elbow, wrist, 0.05, "robot_black", 0.25),
        Capsule(wrist, ee, 0.04, "robot_grey", 0.25),
    ]
    disks = []
    if racket:
        centre = ee + 0.19 * ee_dir
        caps.append(Capsule(ee, ee + 0.1 * ee_dir, 0.015, "wood", 0.05))
        normal = _unit(np.cross(ee_dir, rng.normal(0, 1, 3)))
        disks.append(Disk(centre, normal, 0.075))
    return caps, disks


def _distractor(rng, holder_tip):
    colour = _DISTRACTOR_COLOURS[rng.integers(len(_DISTRACTOR_COLOURS))]
    where = rng.choice(["table", "floor", "held"] if holder_tip is not None else ["table", "floor"])
    if where == "table":
        xy = rng.uniform([-lab.TABLE_HALF_LENGTH_M + 0.1, -lab.TABLE_HALF_WIDTH_M + 0.1], [lab.TABLE_HALF_LENGTH_M - 0.1, lab.TABLE_HALF_WIDTH_M - 0.1])
        z0 = lab.TABLE_TOP_Z_M
    elif where == "floor":
        xy = rng.uniform([-3.5, -2.5], [1.5, 2.5])
        z0 = 0.0
    else:
        xy, z0 = holder_tip[:2], holder_tip[2] - 0.05
    if rng.random() < 0.5:  # a sphere that is not a table-tennis ball (juggling ball, lamp globe)
        r = rng.uniform(0.028, 0.09)
        return Sphere([xy[0], xy[1], z0 + r], r, colour, rng.uniform(0.0, 0.4))
    kind = rng.integers(3)
    size = [rng.uniform(0.06, 0.1), rng.uniform(0.06, 0.1), rng.uniform(0.08, 0.14)] if kind == 0 else (
        [0.21, 0.297, 0.002] if kind == 1 else [rng.uniform(0.15, 0.4), rng.uniform(0.1, 0.3), rng.uniform(0.05, 0.2)])
    yaw = rng.uniform(0, np.pi)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    return Box([xy[0], xy[1], z0 + size[2] / 2 + 1e-3], size, R, colour, rng.uniform(0.0, 0.2))


def _ball_position(rng, box, options):
    x = rng.uniform(box[0], box[1])
    if abs(x[0]) < lab.TABLE_HALF_LENGTH_M and abs(x[1]) < lab.TABLE_HALF_WIDTH_M and x[2] < lab.TABLE_TOP_Z_M + 0.03:
        x[2] = lab.TABLE_TOP_Z_M + 0.02 + rng.uniform(0.0, 0.3)  # not inside the table
    return x


def random_scene(rng: np.random.Generator, workspace_m=None, options: SceneOptions | None = None, *, frame_index: int = 0) -> Scene:
    """One random data-set frame (see the module docstring).

    rng : the randomness (e.g. ``np.random.default_rng([seed, frame_index])``)
    workspace_m : (2, 3) [min, max] box where free balls appear (default: the lab4 workspace)
    """
    opt = options or SceneOptions()
    box = np.asarray(lab.LAB4_WORKSPACE_M if workspace_m is None else workspace_m, float)
    caps, sph, disks, boxes, balls = [], [], [], [], []
    has_ball = rng.random() >= opt.p_no_ball
    mode = rng.choice(["free", "hand", "net"], p=_mode_p(opt))
    tip = None
    if rng.random() < opt.p_robot:
        c, d = robot_arm(rng, racket=rng.random() < opt.p_racket)
        caps += c
        disks += d
    if rng.random() < opt.p_person or (has_ball and mode == "hand"):
        if has_ball and mode == "hand":
            target = _ball_position(rng, box, opt)
            c, s, tip = person(rng, _feet_near(rng, target), hand_target=target)
        else:
            feet = np.array([rng.uniform(-3.2, 0.8), rng.choice([-1, 1]) * rng.uniform(1.0, 2.0)])
            c, s, tip = person(rng, feet)
        caps += c
        sph += s
    if has_ball:
        colour = "white" if rng.random() < opt.p_white else "orange"
        colour = opt.ball_colour or colour
        if mode == "hand" and tip is not None:  # held between the fingers or just released
            pos = tip + rng.normal(0, 0.03, 3)
            vel = rng.normal(0, 0.3, 3)
        elif mode == "net":
            span = lab.NET_HALF_SPAN_M - 0.05
            pos = np.array([rng.uniform(0.0, 0.25), rng.uniform(-span, span), rng.uniform(0.78, 0.95)])
            vel = np.array([rng.uniform(-6.0, -1.0), rng.uniform(-1, 1), rng.uniform(-1, 2)])
        else:
            pos = _ball_position(rng, box, opt)
            if rng.random() < 0.3:
                vel = rng.normal(0, 0.2, 3)
            else:
                speed = rng.uniform(1.0, opt.max_speed_mps)
                vel = speed * _unit(np.array([-1.0, rng.uniform(-0.4, 0.4), rng.uniform(-0.5, 0.5)]))
        balls.append(Ball(pos, vel, colour))
        if rng.random() < opt.p_second_ball:  # a ball lying on the table or the floor
            on_table = rng.random() < 0.5
            xy = rng.uniform([-1.3, -0.7], [1.3, 0.7]) if on_table else rng.uniform([-3.5, -2.5], [1.0, 2.5])
            z = (lab.TABLE_TOP_Z_M if on_table else 0.0) + 0.02
            second = "white" if rng.random() < 0.5 else "orange"
            balls.append(Ball([xy[0], xy[1], z], (0, 0, 0), opt.ball_colour or second))
    for _ in range(int(rng.integers(0, opt.max_distractors + 1))):
        item = _distractor(rng, tip if not (has_ball and mode == "hand") else None)
        (sph if isinstance(item, Sphere) else boxes).append(item)
    # auto-exposure: a target brightness from a shutter time, the lights and the gain
    target = rng.uniform(*opt.brightness)
    exposure_s = rng.uniform(*opt.exposure_s)
    light = rng.uniform(0.7, 1.3)
    gain = float(np.clip(target * _REFERENCE_EXPOSURE_S / (exposure_s * light), 0.25, 8.0))
    return Scene(
        balls=tuple(balls), capsules=tuple(caps), spheres=tuple(sph), disks=tuple(disks), boxes=tuple(boxes),
        exposure=Exposure(exposure_s, gain, light), frame_index=frame_index,
    )  # fmt: skip


def _free_floor(xy) -> bool:
    """Not inside the table (plus 0.25 m) and not on the robot's base (0.5 m)."""
    in_table = abs(xy[0]) < lab.TABLE_HALF_LENGTH_M + 0.25 and abs(xy[1]) < lab.TABLE_HALF_WIDTH_M + 0.25
    return not in_table and np.hypot(*(xy - lab.ROBOT_BASE_M[:2])) > 0.5


def _feet_near(rng, target):
    """Where a person stands to reach ``target``: 0.35-0.6 m away on free floor."""
    for _ in range(20):
        ang = rng.uniform(0, 2 * np.pi)
        feet = target[:2] + rng.uniform(0.35, 0.6) * np.array([np.cos(ang), np.sin(ang)])
        if _free_floor(feet):
            return feet
    side = 1.0 if target[1] >= 0 else -1.0  # beside the table, level with the target
    return np.array([target[0], side * (lab.TABLE_HALF_WIDTH_M + 0.35)])


def _mode_p(opt):
    p_hand, p_net = opt.p_near_hand, opt.p_near_net
    return [max(1 - p_hand - p_net, 0.0), p_hand, p_net] / np.sum([max(1 - p_hand - p_net, 0.0), p_hand, p_net])
