"""``rt2 robot check-config NAME|PATH.yaml``: is an arm's robot config usable? One line per problem, exit 2 if any.

Checks, in order (a problem in the first two stops there: nothing after them can be checked):

1. the YAML file: format, known fields, numbers, per-joint counts (``robot_models.load_robot_config``);
2. the URDF: the base and flange links found, every joint between them revolute or prismatic with limits,
   limit overrides within the URDF's range, the counts equal to the chain's joints, the home posture inside
   the limits (``robot_models.ArmKinematics.from_config``);
3. the simulator options for that many joints (``harness.sim.robot.SimWamOptions``);
4. the mount: the racket can get near the hitting region at all (a bound from the chain's lengths), then the
   share of a grid over the hitting region the racket reaches facing the opponent (IK, as ``rt2 sim reach``),
   at least ``--min-share``.

A hitting ProMP for the arm (``data/promp/NAME_hitting.npz``, what ``rt2 play --robot NAME`` loads) is
reported, not required (``rt2 learn promp --robot NAME`` makes one). See docs/robots.md.
"""

from __future__ import annotations

import argparse

import numpy as np

__all__ = ["add_arguments", "check_config", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("robot", metavar="NAME|PATH.yaml", help="a shipped arm (wam, panda, ur10, xarm7) or a robot config")
    parser.add_argument("--grid", type=int, nargs=3, default=[3, 5, 3], metavar=("NX", "NY", "NZ"),
                        help="IK grid over the hitting region (default 3 5 3)")
    parser.add_argument("--min-share", type=float, default=0.8,
                        help="share of the grid the racket must reach facing the opponent (default 0.8)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the IK restarts")


def check_config(spec: str, *, grid=(3, 5, 3), min_share: float = 0.8, seed: int = 0, progress: bool = False) -> tuple[list[str], list[str]]:
    """``(problems, notes)``: one line each. No problems = the config is usable. ``progress``: the IK grid's progress
    bar on stderr (a fine ``grid`` takes minutes: ~2.5 ms per point)."""
    from harness.experiments.studies.learn_promp import default_promp
    from harness.experiments.studies.reach import reachability
    from harness.sim.robot.arms import HITTING_REGION_M, check_mount_reach
    from harness.sim.robot.simulated_wam import SimWamOptions
    from robot_models import ArmKinematics, load_robot_config

    try:
        config = load_robot_config(spec)
        kin = ArmKinematics.from_config(config)
    except (ValueError, FileNotFoundError) as exc:
        return [str(exc)], []
    problems = []
    notes = [f"{config.where}: {kin.n_joints} joints {list(kin.joint_names)} from {config.base_link!r} to "
             f"{config.flange_link!r} of {config.urdf_path}"]
    try:
        SimWamOptions.from_mapping(dict(config.simulator), where=f"{config.where}: simulator", n_joints=kin.n_joints)
    except ValueError as exc:
        problems.append(str(exc))
    try:
        check_mount_reach(kin, config)
    except ValueError as exc:
        problems.append(str(exc))
    else:
        res = reachability(kin, HITTING_REGION_M, tuple(grid), seed=seed, progress=progress)
        share = float(np.mean(res["success"]))
        line = (f"the racket reaches {int(res['success'].sum())}/{len(res['success'])} points of the hitting region "
                f"{np.asarray(HITTING_REGION_M).tolist()} m facing the opponent ({100 * share:.0f} %)")
        if share < min_share:
            problems.append(f"{config.where}: mount.xyz_m: {line}, below {100 * min_share:.0f} %")
        else:
            notes.append(f"{config.where}: mount: {line}")
    promp = default_promp(config.name)
    notes.append(f"hitting ProMP: {promp}" if promp.is_file() else
                 f"hitting ProMP: none at {promp} (rt2 play --robot needs one: rt2 learn promp --robot {spec})")
    return problems, notes


def run(args) -> int:
    if not 0 < args.min_share <= 1:
        raise ValueError(f"--min-share must be in (0, 1], got {args.min_share}")
    if min(args.grid) < 1:
        raise ValueError(f"--grid needs at least one point per axis, got {args.grid}")
    problems, notes = check_config(args.robot, grid=args.grid, min_share=args.min_share, seed=args.seed, progress=True)
    for line in notes:
        print(line)
    for line in problems:
        print(f"PROBLEM {line}")
    print(f"{args.robot}: {'usable' if not problems else f'{len(problems)} problem(s)'}")
    return 2 if problems else 0
