"""``rt2 sim reach [--robot NAME|PATH.yaml]``: is the hitting region reachable with the racket facing the opponent?

Solves IK (robot_models.ik) for the racket frame on a grid over the hitting region (lab world) and
over the same region grown by ``--grow-m``, with the racket normal pointing from each point to a
target on the opponent's court. Prints the share of grid points reached per x slice.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from harness.experiments.studies.reach import HITTING_REGION_M, reachability
from harness.sim.robot.arms import load_arm

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", "--config", dest="robot", default=None, metavar="NAME|PATH.yaml",
                        help="the arm: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config (docs/robots.md)")
    parser.add_argument("--grid", type=int, nargs=3, default=[5, 7, 5], metavar=("NX", "NY", "NZ"))
    parser.add_argument("--grow-m", type=float, default=0.1, help="also test the region grown by this much")
    parser.add_argument("--normal", choices=["opponent", "x", "none"], default="opponent")
    parser.add_argument("--seed", type=int, default=0, help="seed of the IK restarts")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    arm = load_arm(args.robot)
    kin = arm.kin
    region = np.asarray(HITTING_REGION_M)
    grown = region + np.array([[-1.0], [1.0]]) * args.grow_m
    results = {}
    for name, box in (("hitting region", region), (f"grown by {args.grow_m:g} m", grown)):
        res = reachability(kin, box, args.grid, normal=args.normal, seed=args.seed, progress=True)
        xs = np.unique(res["points_m"][:, 0])
        rows = [{"x_m": float(x), "reached": int(res["success"][res["points_m"][:, 0] == x].sum()),
                 "points": int((res["points_m"][:, 0] == x).sum())} for x in xs]
        missed = res["points_m"][~res["success"]].round(3).tolist()
        results[name] = {"box_m": box.round(4).tolist(), "reached": int(res["success"].sum()), "points": len(res["success"]),
                         "by_x": rows, "missed_m": missed}
    if args.json:
        print(json.dumps({"robot": arm.name, "normal": args.normal, "seed": args.seed, "mount_T_base_to_world": kin.T_base_to_world.tolist(),
                          "results": results}, indent=1))
        return 0
    print(f"racket reachability of {arm.name} ({arm.config.where}), normal towards {args.normal}, seed {args.seed}")
    for name, r in results.items():
        print(f"\n{name}: {r['reached']}/{r['points']} reached, box {r['box_m']}")
        print(f"  {'x (m)':>8} {'reached':>8} {'of':>4}")
        for row in r["by_x"]:
            print(f"  {row['x_m']:8.3f} {row['reached']:8d} {row['points']:4d}")
        if r["missed_m"]:
            print(f"  missed: {r['missed_m'][:12]}{' ...' if len(r['missed_m']) > 12 else ''}")
    return 0
