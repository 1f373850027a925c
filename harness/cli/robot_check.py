"""``rt2 robot check --robot ADDR``: measure a robot link (the simulated WAM's or a lab's bridge).

Connects a :class:`WamClient`, listens for ``--duration`` seconds and reports what an experiment relies
on: the state stream's rate, gaps and lost states (``seq`` jumps), the delivery delay (arrival on the
harness clock minus the robot's stamp through the offset estimate), the clock offset and its
uncertainty, request round trips. With ``--move`` it also commands a small, slow wrist movement
(the arm's last joint, the WAM's joint_7, by ``--move-rad``, out and back over 1 s; ``--arm`` names the arm
behind the link: its joint names must be the bridge's) and reports command to motion: the acknowledgement
time and the controller's lag from the trajectory's start to the first reported motion. Without
``--move`` nothing is commanded (heartbeats only while moving). Figures: medians and p99 over the run.
"""

from __future__ import annotations

import argparse
import json

from harness.common.outputs import check_output_file
from harness.link.check import check_link
from harness.link.client import LinkLostError

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="tcp://127.0.0.1:7650", metavar="ADDR",
                        help="the bridge's command endpoint (default tcp://127.0.0.1:7650)")
    parser.add_argument("--duration", type=float, default=3.0, metavar="S", help="seconds of listening (default 3)")
    parser.add_argument("--arm", default=None, metavar="NAME|PATH.yaml",
                        help="the arm behind the link: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot "
                             "config (docs/robots.md)")
    parser.add_argument("--move", action="store_true",
                        help="also command a small slow wrist movement (the last joint) and measure command to motion")
    parser.add_argument("--move-rad", type=float, default=0.05, metavar="RAD", help="amplitude of --move (default 0.05 rad)")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the figures as JSON")


def run(args) -> int:
    from robot_models import ArmKinematics

    if not 0 < abs(args.move_rad) <= 0.2:
        raise ValueError(f"--move-rad must be in (0, 0.2] rad in size, got {args.move_rad!r}")
    out = check_output_file(args.json)
    kin = None if args.arm is None else ArmKinematics.from_config(args.arm)  # errors name the config file and field
    try:
        r = check_link(args.robot, duration_s=args.duration, move_rad=args.move_rad if args.move else None,
                       kinematics=kin)
    except LinkLostError as exc:
        raise ValueError(f"robot link: {exc}") from None
    c = r["clock"]
    print(f"robot link {r['address']}: {r['robot']} (bridge {r['bridge_id']}), {r['control_rate_hz']:g} Hz, "
          f"watchdog {r['watchdog_s']:g} s")
    print(f"  states received     {r['states']} at {r['state_rate_hz']} Hz; lost {r['states_lost']}, malformed {r['dropped_malformed']}")
    print(f"  {'(ms)':28} {'p50':>8} {'p99':>8} {'max':>8}")
    for name, key in (("stamp interval", "stamp_interval_ms"), ("arrival interval", "arrival_interval_ms"),
                      ("robot sample -> harness", "delivery_ms"), ("request round trip", "request_round_trip_ms")):
        v = r[key]
        print(f"  {name:28} {v['p50']!s:>8} {v['p99']!s:>8} {v['max']!s:>8}")
    print(f"  clock offset (robot - harness) {c['offset_ms']:.3f} ms +- {c['uncertainty_ms']:.3f} ms "
          f"({c['n_samples']} exchanges, min round trip {c['min_delay_ms']:.3f} ms)")
    if r["move"]:
        m = r["move"]
        print(f"  command -> robot: acknowledged in {m['command_ack_ms']:.2f} ms; first motion "
              f"{m['motion_onset_after_start_ms']:.1f} ms after the trajectory's start ({m['joint']}, "
              f"{m['amplitude_rad']:.3f} rad, back within {m['returned_within_rad']:.4f} rad)")
    if out is not None:
        out.write_text(json.dumps(r, indent=1))
    return 0
