"""``rt2 sim wam``: run a seeded ball-mount trajectory on the simulated WAM and measure its errors.

Reports (1) tracking: the true joints against the commanded reference, and the ball-mount position they
give; (2) "ground truth" error: the ball position from the *reported* joints (what an experiment
logs) against the true one, caused by the zero-offset bias, encoder quantisation and noise.
"""

from __future__ import annotations

import argparse
import json

from harness.experiments.studies.wam_errors import simulate

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", "--config", dest="robot", default=None, metavar="NAME|PATH.yaml",
                        help="the arm: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config (docs/robots.md)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the trajectory, the bias and the noise")
    parser.add_argument("--n-via", type=int, default=8, help="via points of the trajectory")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    r = simulate(args.robot, seed=args.seed, n_via=args.n_via)
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    print(f"simulated WAM, seed {r['seed']}: {r['ticks']} ticks ({r['duration_s']:.2f} s), "
          f"trajectory {r['trajectory_method']}")
    print(f"  zero-offset bias (deg):        {r['bias_deg']}")
    print(f"  joint tracking max (mrad):     {r['joint_tracking_max_mrad']}")
    print(f"  joint tracking rms (mrad):     {r['joint_tracking_rms_mrad']}")
    print(f"  saturated ticks per joint:     {r['saturated_ticks']}")
    print(f"  ticks against a hard stop:     {r['limit_ticks']}")
    print(f"  {'ball position error (mm)':34} {'median':>8} {'p95':>8} {'max':>8}")
    for name, key in (("true vs commanded (tracking)", "ball_tracking_mm"),
                      ("reported vs true (bias+encoder)", "ball_reported_vs_true_mm")):
        v = r[key]
        print(f"  {name:34} {v['median']:8.2f} {v['p95']:8.2f} {v['max']:8.2f}")
    return 0
