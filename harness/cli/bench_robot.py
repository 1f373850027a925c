"""``rt2 bench robot``: run time of the robot model and the simulated WAM (medians of repeats).

Rows: batched FK (numba kernel, numpy reference) against a per-configuration Pinocchio loop, measured in
the same process; link points for the renderer; one Jacobian; one IK solve; simulated ticks with the numba
kernel against its numpy reference.
"""

from __future__ import annotations

import argparse
import json

from harness.experiments.studies.bench_robot import bench_robot

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", type=int, default=5000, help="configurations per FK batch")
    parser.add_argument("--ticks", type=int, default=5000, help="simulated ticks per run")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", default=None, metavar="NAME|PATH.yaml",
                        help="the arm: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config (docs/robots.md)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    rows = bench_robot(args.n, args.ticks, args.repeats, args.seed, robot=args.robot)
    name = args.robot or "wam"
    if args.json:
        print(json.dumps({"robot": name, "n": args.n, "ticks": args.ticks, "repeats": args.repeats, "rows": rows}, indent=1))
        return 0
    print(f"robot benchmarks of {name}: N={args.n} configurations, {args.ticks} ticks, median of {args.repeats} repeats")
    print(f"  {'what':32} {'median (ms)':>12} {'per item (us)':>14}  speed-up")
    for r in rows:
        sp = f"x{r['speedup']:.1f} vs {r['speedup_vs']}" if r["speedup"] else ""
        print(f"  {r['what']:32} {r['median_s'] * 1e3:12.3f} {r['per_item_us']:14.3f}  {sp}")
    return 0
