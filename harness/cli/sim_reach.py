"""``rt2 sim reach``: is the hitting region reachable with the racket facing the opponent?

Solves IK (robot_models.ik) for the racket frame on a grid over the hitting region (lab world) and
over the same region grown by ``--grow-m``, with the racket normal pointing from each point to a
target on the opponent's court. Prints the share of grid points reached per x slice.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys

import numpy as np
from tqdm import tqdm

from robot_models import IkOptions, WamKinematics

__all__ = ["add_arguments", "reachability", "run"]

HITTING_REGION_M = ((-1.6, -0.7, 0.8), (-1.1, 0.7, 1.4))
#: where the racket normal points: the centre of the opponent's half, 15 cm above the table
OPPONENT_TARGET_M = (0.685, 0.0, 0.91)


def reachability(kin: WamKinematics, region_m, n_per_axis=(5, 7, 5), *, normal: str = "opponent",
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
    for i, p in enumerate(tqdm(pts, desc="IK", disable=not progress, file=sys.stderr, leave=False)):
        n = {"opponent": np.asarray(OPPONENT_TARGET_M) - p, "x": np.array([1.0, 0, 0]), "none": None}[normal]
        _, info = kin.ik(p, "racket", normal_world=n, options=options, rng=rng)
        ok[i], pos_err[i], ang_err[i] = info.success, info.pos_err_m, info.angle_err_rad
    return {"points_m": pts, "success": ok, "pos_err_m": pos_err, "angle_err_rad": ang_err}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="robot YAML (default data/robot/wam.yaml)")
    parser.add_argument("--grid", type=int, nargs=3, default=[5, 7, 5], metavar=("NX", "NY", "NZ"))
    parser.add_argument("--grow-m", type=float, default=0.1, help="also test the region grown by this much")
    parser.add_argument("--normal", choices=["opponent", "x", "none"], default="opponent")
    parser.add_argument("--seed", type=int, default=0, help="seed of the IK restarts")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    kin = WamKinematics.from_config(args.config)
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
        print(json.dumps({"normal": args.normal, "seed": args.seed, "mount_T_base_to_world": kin.T_base_to_world.tolist(),
                          "results": results}, indent=1))
        return 0
    print(f"racket reachability, normal towards {args.normal}, seed {args.seed}")
    for name, r in results.items():
        print(f"\n{name}: {r['reached']}/{r['points']} reached, box {r['box_m']}")
        print(f"  {'x (m)':>8} {'reached':>8} {'of':>4}")
        for row in r["by_x"]:
            print(f"  {row['x_m']:8.3f} {row['reached']:8d} {row['points']:4d}")
        if r["missed_m"]:
            print(f"  missed: {r['missed_m'][:12]}{' ...' if len(r['missed_m']) > 12 else ''}")
    return 0
