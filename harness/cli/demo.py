"""``rt2 demo``: the main job, quickly: the accuracy experiment (paper Sec. 3.2) on a short run.

A ball on the simulated WAM's end effector moves through the workspace of four ceiling cameras, with a
person and clutter nearby; RT2 (ours), the paper's RT2 and RTBlob track it on the same frames, with a
realistic calibration error (1.3 px) and camera-to-robot clock error, and the robot's kinematics is the
ground truth. This is ``rt2 accuracy --quick`` with a fixed seed (2.5 s of motion: usually too short for
one of the orange-ball episodes of the default scene, so RTBlob's failure mode rarely shows here): it
prints the summary table and where the histogram, the JSON and the session log are. The full run is
``rt2 accuracy`` (docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import os

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument("--out", default="out/demo", metavar="DIR", help="output folder (default out/demo)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), metavar="W",
                        help="worker processes (default 2, or 1 on one core)")


def run(args) -> int:
    from harness.cli import accuracy as cli

    acc = argparse.ArgumentParser()
    cli.add_arguments(acc)
    acc_args = acc.parse_args(["--quick", "--seed", str(args.seed), "--out", args.out, "--workers", str(args.workers)])
    print("rt2 demo: the accuracy experiment (paper Sec. 3.2), quick run; the full one is `rt2 accuracy`\n")
    code = cli.run(acc_args)
    print(f"\nre-evaluate offline: rt2 reevaluate {args.out}/session.mcap --tracker rt2 --eps-px 3")
    return code
