"""Distractor objects standing in the lab (cups, boxes, a near-orange juggling ball), placed by a seed.

One function, :func:`place_distractor`, used by the accuracy experiment's scenes and the play scenes, with
two named placements (:class:`DistractorPlacement`):

========================  ===================  ====================
                          ``ACCURACY``         ``PLAY``
========================  ===================  ====================
floor objects from the    0.6-1.4 m            0.7-1.4 m
robot's pedestal
juggling ball radius      5-7 cm (10-14 cm     3-4.5 cm (6-9 cm
                          across)              across)
white floor box           as the orange box    0.2-0.35 x 0.15-0.25
                                               x 0.15 m
cup specular              0.1                  0.05
a floor position draws    angle, then          distance, then
                          distance             angle
========================  ===================  ====================

The two were written separately and nothing in the lab asks for the difference; both are kept, named, so
that every seeded figure of ``rt2 accuracy`` and ``rt2 play`` stays the same. A new scene picks one of them.
Objects on the table stand on the robot's half (x in [-1.25, -0.2] m, |y| <= 0.65 m) in both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim import lab
from harness.sim.render.scene_state import Box, Sphere

__all__ = ["ACCURACY", "DISTRACTORS", "NEAR_ORANGE", "PLAY", "DistractorPlacement", "place_distractor"]

#: the juggling ball's colour: near the ball's orange
NEAR_ORANGE = (0.95, 0.5, 0.12)
#: distractor objects by name: (shape, colour, where); "table": the robot's half of the table,
#: "floor": around the robot's pedestal
DISTRACTORS = {
    "white_cup": ("cup", "white", "table"),
    "white_box": ("box", "white", "floor"),
    "orange_cup": ("cup", "orange", "table"),
    "orange_box": ("box", "orange", "floor"),
    "orange_sphere": ("sphere", NEAR_ORANGE, "table"),  # a juggling ball
}


@dataclass(frozen=True)
class DistractorPlacement:
    """How :func:`place_distractor` places and sizes the objects (the module docstring compares the two).

    floor_ring_m : (min, max) distance of a floor object from the robot's pedestal, m
    sphere_radius_m : (min, max) radius of the juggling ball, m
    white_box_m : ((min, max) length, (min, max) width, height) of a white floor box, m; None: sized as the
        orange box (0.25-0.4 x 0.2-0.3 x 0.15-0.3 m)
    cup_specular : the cups' specular share (boxes: 0.05, the ball: 0.2)
    distance_first : a floor position draws its distance before its angle (else the angle first)
    """

    floor_ring_m: tuple[float, float]
    sphere_radius_m: tuple[float, float]
    white_box_m: tuple | None
    cup_specular: float
    distance_first: bool


#: the accuracy experiment's scenes (harness.experiments.accuracy.session_scene)
ACCURACY = DistractorPlacement(floor_ring_m=(0.6, 1.4), sphere_radius_m=(0.05, 0.07), white_box_m=None,
                               cup_specular=0.1, distance_first=False)
#: the play scenes (harness.experiments.play.play_scene)
PLAY = DistractorPlacement(floor_ring_m=(0.7, 1.4), sphere_radius_m=(0.03, 0.045),
                           white_box_m=((0.2, 0.35), (0.15, 0.25), 0.15), cup_specular=0.05, distance_first=True)


def place_distractor(rng: np.random.Generator, name: str, placement: DistractorPlacement) -> Box | Sphere:
    """The object ``name`` of :data:`DISTRACTORS`, placed, turned and sized by ``rng`` as ``placement`` says."""
    shape, colour, where = DISTRACTORS[name]
    if where == "table":
        xy = rng.uniform([-1.25, -0.65], [-0.2, 0.65])
        z0 = lab.TABLE_TOP_Z_M
    else:
        if placement.distance_first:
            dist = rng.uniform(*placement.floor_ring_m)
            ang = rng.uniform(0, 2 * np.pi)
        else:
            ang = rng.uniform(0, 2 * np.pi)
            dist = rng.uniform(*placement.floor_ring_m)
        xy = lab.ROBOT_BASE_M[:2] + dist * np.array([np.cos(ang), np.sin(ang)])
        z0 = 0.0
    yaw = rng.uniform(0, np.pi)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    if shape == "sphere":
        r = rng.uniform(*placement.sphere_radius_m)
        return Sphere([xy[0], xy[1], z0 + r], r, colour, 0.2)
    if shape == "cup":
        size = [0.07, 0.07, rng.uniform(0.09, 0.12)]
    elif colour == "white" and placement.white_box_m is not None:
        (l0, l1), (w0, w1), height = placement.white_box_m
        size = [rng.uniform(l0, l1), rng.uniform(w0, w1), height]
    else:
        size = [rng.uniform(0.25, 0.4), rng.uniform(0.2, 0.3), rng.uniform(0.15, 0.3)]
    return Box([xy[0], xy[1], z0 + size[2] / 2 + 1e-3], size, R, colour,
               placement.cup_specular if shape == "cup" else 0.05)
