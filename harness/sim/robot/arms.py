"""The arm of a run: ``--robot NAME|PATH.yaml`` to its robot config, kinematics and simulator options, checked once.

    arm = load_arm("panda")          # or "wam" (the default), or a robot YAML of your own (docs/robots.md)
    arm.kin, arm.config, arm.sim_options

A shipped arm's name or a robot config's path; :func:`is_link_address` tells the robot link's addresses
(``sim``, ``tcp://HOST:PORT``), which ``rt2 accuracy --robot`` and ``rt2 play --live --robot`` also take.
Besides what :meth:`robot_models.ArmKinematics.from_config` checks, an arm whose racket cannot get near the
hitting region from its mount is refused here (:func:`check_mount_reach`), naming the file and ``mount.xyz_m``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim.robot.simulated_wam import SimWamOptions
from robot_models import ArmKinematics, RobotConfig, load_robot_config

__all__ = ["Arm", "HITTING_REGION_M", "check_mount_reach", "is_link_address", "load_arm"]

#: where the racket must reach (lab world, [[x, y, z] min, [x, y, z] max], m): behind the robot's table end,
#: across the table's width, 4-64 cm above its top (``rt2 sim reach``)
HITTING_REGION_M = ((-1.6, -0.7, 0.8), (-1.1, 0.7, 1.4))


@dataclass(frozen=True, eq=False)
class Arm:
    """An arm loaded for a run: its config, kinematics (one workspace: one per thread) and simulator options."""

    config: RobotConfig
    kin: ArmKinematics
    sim_options: SimWamOptions

    @property
    def name(self) -> str:
        return self.config.name


def is_link_address(value: str | None) -> bool:
    """True for a robot link's address (``sim`` or ``SCHEME://...``), False for an arm (a name or a YAML path)."""
    return value is not None and (value == "sim" or "://" in str(value))


def check_mount_reach(kin: ArmKinematics, config: RobotConfig, region_m=HITTING_REGION_M) -> float:
    """Refuse a mount from which the racket cannot reach ``region_m`` (2, 3) whatever the joints do.

    The bound: the racket is at most ``kin.reach_bound_m`` from the base link's origin (the lengths of the chain's
    steps added up). Returns the distance from the mount to the region's nearest point, m; raises ValueError
    naming the file and ``mount.xyz_m`` when that exceeds the bound.
    """
    box = np.asarray(region_m, float)
    origin = kin.T_base_to_world[:3, 3]
    gap = float(np.linalg.norm(np.clip(origin, box[0], box[1]) - origin))
    if gap > kin.reach_bound_m:
        raise ValueError(f"{config.where}: mount.xyz_m: the arm cannot reach the hitting region {box.tolist()} m: its "
                         f"racket gets at most {kin.reach_bound_m:.2f} m from the base, the region is {gap:.2f} m away")
    return gap


def load_arm(spec: str | None = None, *, check_reach: bool = True) -> Arm:
    """The arm ``spec`` names (a shipped arm, a robot YAML path; None = the WAM), checked: its kinematics, its
    simulator options for its joints and (``check_reach``) a mount that can reach the hitting region. Raises
    ValueError / FileNotFoundError with one line naming the file and the field."""
    if is_link_address(spec):
        raise ValueError(f"--robot {spec!r} is a robot link's address, not an arm (a name or a robot YAML file)")
    config = load_robot_config(spec)
    kin = ArmKinematics.from_config(config)
    sim = SimWamOptions.from_mapping(dict(config.simulator), where=f"{config.where}: simulator", n_joints=kin.n_joints)
    if check_reach:
        check_mount_reach(kin, config)
    return Arm(config, kin, sim)
