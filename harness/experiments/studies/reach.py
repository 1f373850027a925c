"""Reachability of the hitting region (``rt2 sim reach``): IK (robot_models.ik) for the racket frame on a
grid over a region of the lab world, with the racket normal pointing at the opponent's court."""

from __future__ import annotations

import itertools
import sys

import numpy as np
from harness.common.progress import progress_bar
from harness.sim.robot.arms import HITTING_REGION_M

from robot_models import ArmKinematics, IkOptions

__all__ = ["HITTING_REGION_M", "OPPONENT_TARGET_M", "reachability"]


#: where the racket normal points: the centre of the opponent's half, 15 cm above the table
OPPONENT_TARGET_M = (0.685, 0.0, 0.91)


def reachability(kin: ArmKinematics, region_m, n_per_axis=(5, 7, 5), *, normal: str = "opponent",
                 seed: int = 0, options: IkOptions = IkOptions(), progress: bool = False) -> dict:
    """IK on a grid over ``region_m`` (2, 3); returns points (N, 3), success (N,) and errors per point.

    normal : ``"opponent"`` (towards OPPONENT_TARGET_M), ``"x"`` (+x), or ``"none"`` (position only).
    """
    choices = ("opponent", "x", "none")
    if normal not in choices:
        raise ValueError(f"unknown normal {normal!r}; valid: {list(choices)}")
    region = np.asarray(region_m, float)
    axes = [np.linspace(lo, hi, int(n)) for lo, hi, n in zip(region[0], region[1], n_per_axis)]
    pts = np.array(list(itertools.product(*axes)))
    rng = np.random.default_rng(seed)
    ok = np.zeros(len(pts), bool)
    pos_err = np.zeros(len(pts))
    ang_err = np.zeros(len(pts))
    for i, p in enumerate(progress_bar(pts, desc="IK", disable=not progress, file=sys.stderr, leave=False)):
        n = {"opponent": np.asarray(OPPONENT_TARGET_M) - p, "x": np.array([1.0, 0, 0]), "none": None}[normal]
        _, info = kin.ik(p, "racket", normal_world=n, options=options, rng=rng)
        ok[i], pos_err[i], ang_err[i] = info.success, info.pos_err_m, info.angle_err_rad
    return {"points_m": pts, "success": ok, "pos_err_m": pos_err, "angle_err_rad": ang_err}
