"""``rt2 robot serve --sim [--robot NAME|PATH.yaml]``: a simulated arm (the WAM by default) in its own process,
in real time, behind the robot link. Any arm of a robot config is served (wam, panda, ur10, xarm7, or a lab's
own: docs/robots.md); the link's joint vectors have the arm's joint count, told in the ``welcome``
(harness/link/protocol.py).

Prints one line when it is ready (``--ready-json``: a JSON object with the bound endpoints, the pid and
the robot clock's epoch, for scripts and tests) and serves until SIGINT / SIGTERM or ``--duration``.
Protocol and what a lab's bridge must do: docs/robot_link.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys

from harness.link.bridge_core import check_endpoint
from harness.common.fast_exit import exit_at_once_when_done
from harness.common.options import named_by_options
from harness.link.bridge_sim import BridgeOptions, SimBridge
from harness.sim.robot.arms import load_arm
from harness.sim.robot.simulated_wam import SimulatedWam, SimWamOptions

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sim", action="store_true", required=True,
                        help="serve a simulated arm (--robot; the only back end in rt2; a lab serves its robot with its own "
                             "bridge, docs/robot_link.md)")
    parser.add_argument("--bind", default="tcp://127.0.0.1:7650",
                        help="command endpoint (ROUTER); port * = a free one (default tcp://127.0.0.1:7650)")
    parser.add_argument("--state-bind", default=None,
                        help="state stream endpoint (PUB); default: the command port + 1")
    parser.add_argument("--rate", type=float, default=None, help="control rate, Hz (default: the robot YAML's, 500)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the simulated arm's zero offsets and encoder noise "
                        "(--world play: the session's seed, serves and per-ball robots as `rt2 play --seed`)")
    parser.add_argument("--robot", "--config", dest="robot", default=None, metavar="NAME|PATH.yaml",
                        help="the arm: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config (docs/robots.md)")
    parser.add_argument("--watchdog", type=float, default=0.3, help="hold after this many seconds without a "
                        "command or heartbeat (default 0.3, as wam_node)")
    parser.add_argument("--clock-skew-ms", type=float, default=0.0,
                        help="add this to the robot clock (to test the clock-offset estimate)")
    parser.add_argument("--publish-truth", action="store_true",
                        help="add the simulator's true joint angles to every state (simulated scenes need them)")
    parser.add_argument("--truth-stream", default=None, metavar="ADDR",
                        help="also publish the lab truth stream (true joints on the host clock, for simulated cameras: "
                             "rt2 track --source sim --truth-stream ADDR) on this PUB endpoint, e.g. tcp://127.0.0.1:7652; "
                             "with --world play it also carries the balls (default there: a free port)")
    parser.add_argument("--batch", type=int, default=1, metavar="N",
                        help="run and publish the ticks N at a time (default 1: every state as its tick comes; on a busy "
                             "machine N > 1 uses less CPU at N - 1 ticks of extra delay; the stamps stay the ticks')")
    parser.add_argument("--world", default=None, choices=("play",),
                        help="also run a world next to the robot: play = the ball world of `rt2 play --live` (launcher "
                             "serves, 1 ms physics, racket contact from the true joints, outcomes; docs/play.md, 'Live')")
    parser.add_argument("--balls", type=int, default=10, help="--world play: balls to serve (default 10)")
    parser.add_argument("--world-bind", default="tcp://127.0.0.1:*", help="--world play: serve/outcome event stream "
                        "endpoint (default a free port)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--ready-json", action="store_true", help="print the ready line as JSON")


#: the largest --clock-skew-ms (a day: a test of the clock-offset estimate, not a clock that is off by years)
MAX_CLOCK_SKEW_MS = 86_400_000.0


def run(args) -> int:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s rt2 robot serve: %(levelname)s %(message)s")
    arm = load_arm(args.robot, check_reach=False)
    cfg, kin = arm.config, arm.kin
    sim_map = dict(cfg.simulator)
    if args.rate is not None:
        sim_map["control_rate_hz"] = args.rate
    sim_opts = SimWamOptions.from_mapping(sim_map, where=f"{cfg.where}: simulator (--rate)", n_joints=kin.n_joints)
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be > 0 s, got {args.duration!r}")
    for flag, value in (("--bind", args.bind), ("--state-bind", args.state_bind), ("--truth-stream", args.truth_stream),
                        ("--world-bind", args.world_bind)):
        if value is not None:
            check_endpoint(flag, value)  # bad input names the option the user typed
    if not math.isfinite(args.clock_skew_ms) or abs(args.clock_skew_ms) > MAX_CLOCK_SKEW_MS:
        raise ValueError(f"--clock-skew-ms must be a number of milliseconds within +-{MAX_CLOCK_SKEW_MS:g}, got {args.clock_skew_ms!r}")
    with named_by_options("BridgeOptions", {"watchdog_s": "--watchdog", "batch_ticks": "--batch"}):
        options = BridgeOptions(bind=args.bind, state_bind=args.state_bind, watchdog_s=args.watchdog,
                                clock_skew_ns=int(round(args.clock_skew_ms * 1e6)), publish_truth=args.publish_truth,
                                batch_ticks=args.batch,
                                truth_bind=None if args.world else args.truth_stream)
    if args.world == "play":
        from harness.experiments.play.world import WorldBridge, WorldOptions

        if arm.name != "wam":
            raise ValueError(f"--world play runs the WAM (rt2 play --live's world), not --robot {args.robot}")
        # the in-process session's simulated WAM (SimWamOptions()) so that live and in-process runs agree
        play_sim = SimWamOptions() if args.rate is None else SimWamOptions(control_rate_hz=args.rate)
        bridge = WorldBridge(kin, WorldOptions(balls=args.balls, seed=args.seed, truth_bind=args.truth_stream or "tcp://127.0.0.1:*",
                                               world_bind=args.world_bind, sim=play_sim), options)
        sim_opts = play_sim
    else:
        bridge = SimBridge(SimulatedWam(kin, sim_opts, seed=args.seed), options)
    for sig in (signal.SIGINT, signal.SIGTERM):  # stop serving; once run returns, leave without the slow teardown
        signal.signal(sig, lambda *_: (bridge.stop(), exit_at_once_when_done(0)))
    ready = {"command": bridge.command_endpoint, "state": bridge.state_endpoint, "pid": os.getpid(),
             "rate_hz": sim_opts.control_rate_hz, "watchdog_s": options.watchdog_s, "bridge_id": bridge.bridge_id,
             "epoch_monotonic_ns": bridge.epoch_ns, "clock_skew_ns": options.clock_skew_ns,
             "truth": bridge.truth_endpoint}
    if args.world:
        ready.update(world=bridge.world_endpoint, balls=args.balls, seed=args.seed)
    if args.ready_json:
        print(json.dumps(ready), flush=True)
    else:
        print(f"serving the simulated {arm.name} ({kin.n_joints} joints) at {sim_opts.control_rate_hz:g} Hz: commands {bridge.command_endpoint}, "
              f"states {bridge.state_endpoint}, "
              + (f"lab truth {bridge.truth_endpoint}, " if bridge.truth_endpoint else "") + f"watchdog {options.watchdog_s:g} s (Ctrl-C to stop)", flush=True)
    bridge.serve(args.duration)
    return 0
