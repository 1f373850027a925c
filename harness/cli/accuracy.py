"""``rt2 accuracy``: the paper's accuracy experiment (Sec. 3.2) in the simulated lab. See docs/accuracy.md.

    rt2 accuracy --quick                       # about a minute: 600 frame sets
    rt2 accuracy --seed 0 --out out/accuracy   # the default run (4000 frame sets, the README's figures)
    rt2 accuracy --inject-faults --json errs.json --log-images all
    rt2 accuracy --ideal                       # exact calibration and synchronised clocks (the old, ideal run)
    rt2 accuracy --quick --robot panda         # the ball on another arm (data/robot/*.yaml, docs/robots.md)
"""

from __future__ import annotations

import argparse
import math
import os
from dataclasses import replace
from pathlib import Path

from harness.experiments.accuracy.config import DEFAULT_FRAMES, DEFAULT_LOG_IMAGES, QUICK_FRAMES, AccuracyConfig
from harness.experiments.accuracy.session_scene import SCENES
from harness.experiments.accuracy.stats import BASELINE_WORDS, TRACKER_KINDS, check_baseline, fmt, format_goals, format_table, rt2_goals
from harness.common.executor import add_sweep_arguments, options_from_args
from harness.common.options import named_by_options
from harness.logs.codecs import IMAGE_FORMATS
from harness.sim.robot.arms import is_link_address, load_arm

__all__ = ["add_arguments", "events_line", "format_report", "realism_line", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help=f"a run of about a minute ({QUICK_FRAMES} frame sets)")
    parser.add_argument("--seed", type=int, default=0, help="seeds robot, scene and sensor noise (default 0)")
    parser.add_argument("--out", default="out/accuracy", metavar="DIR",
                        help="folder for the figure (PNG, PDF), accuracy.json, summary.json, session.mcap (default out/accuracy)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help=f"frame sets (default {DEFAULT_FRAMES}, --quick {QUICK_FRAMES})")
    parser.add_argument("--rate-hz", type=float, default=200.0, metavar="R", help="camera frame rate (default 200)")
    add_sweep_arguments(parser, workers_default=min(2, os.cpu_count() or 1))  # --workers W, --ray [ADDRESS]
    parser.add_argument("--json", metavar="PATH", help="also write the per-tracker error statistics here (a JSON list)")
    parser.add_argument("--rig", default="lab4_vga", help="rig name or file (default lab4_vga)")
    parser.add_argument("--model", default=None, metavar="PATH", help="segmentation model .npz (default data/models/ball_seg_default.npz)")
    parser.add_argument("--trackers", nargs="+", default=list(TRACKER_KINDS), choices=TRACKER_KINDS, help="trackers to run")
    parser.add_argument("--eps-px", type=float, default=None, metavar="E", help="rt2 estimators' consistency threshold, px")
    parser.add_argument("--scene", default="default", choices=sorted(SCENES),
                        help="default (person in white, white clutter), harsh (orange shirt, orange cup, box and juggling ball), clean (arm and ball only)")
    parser.add_argument("--inject-faults", action="store_true",
                        help="a camera without frames for a stretch, wrong-size frames, a timestamp going back")
    parser.add_argument("--robot", default=None, metavar="NAME|PATH.yaml|ADDR|sim",
                        help="the arm carrying the ball: a shipped arm (wam, panda, ur10, xarm7; default wam) or a robot "
                             "config (docs/robots.md), simulated in this process; or run the WAM over the robot link "
                             "(docs/robot_link.md): a bridge serving its simulation truth (rt2 robot serve --sim "
                             "--publish-truth) at ADDR (tcp://HOST:PORT), or 'sim' to start one for this run")
    lv = parser.add_argument_group("live: robot, cameras + tracker and the experiment as separate processes (docs/accuracy.md, 'Live')")
    lv.add_argument("--live", action="store_true",
                    help="score the observations of rt2 track's stream against the robot's reported joints; alone (or with "
                         "--robot sim) it starts the simulated bridge and rt2 track --source sim itself")
    lv.add_argument("--tracker-stream", default=None, metavar="ADDR",
                    help="with --live and --robot ADDR: rt2 track's rt2 stream (e.g. tcp://127.0.0.1:7661)")
    lv.add_argument("--stream-timeout", type=float, default=None, metavar="S",
                    help="with --live: a stream silent this long is an error (default 10 s; 900 s when the processes are "
                         "started here, whose first frames wait for the renderer to compile)")
    r = parser.add_argument_group("realism (docs/accuracy.md); on by default")
    r.add_argument("--ideal", action="store_true",
                   help="switch every realism effect off: trackers get the exact rig, camera and robot clocks agree")
    r.add_argument("--no-calibration-error", action="store_true", help="the trackers get the exact (true) rig")
    r.add_argument("--no-clock-error", action="store_true", help="no camera-to-robot clock offset or jitter")
    r.add_argument("--reprojection-px", type=float, default=None, metavar="PX",
                   help="mean re-projection error of the trackers' calibration (default 1.3 px, the paper's)")
    g = parser.add_argument_group("session log (DIR/session.mcap, see docs/logging.md)")
    g.add_argument("--log-images", default=str(DEFAULT_LOG_IMAGES), metavar="all|none|N",
                   help=f"images to record: all, none, or every N-th frame set (default {DEFAULT_LOG_IMAGES}); detections are always recorded")
    g.add_argument("--log-image-format", default="png", choices=sorted(IMAGE_FORMATS),
                   help="png (default, lossless: re-evaluation from images is exact), jpeg, raw")
    g.add_argument("--no-log", action="store_true", help="write no session log")


#: the options of ``rt2 accuracy`` (and ``rt2 demo``), by the :class:`AccuracyConfig` field each fills
FLAGS = {"seed": "--seed", "n_frames": "--frames", "rate_hz": "--rate-hz", "rig": "--rig", "model": "--model", "trackers": "--trackers",
         "eps_px": "--eps-px", "inject_faults": "--inject-faults", "scene": "--scene", "robot": "--robot"}


def config_from_args(args) -> AccuracyConfig:
    frames = args.frames if args.frames is not None else (QUICK_FRAMES if args.quick else DEFAULT_FRAMES)
    if args.model is not None and not Path(args.model).is_file():
        raise FileNotFoundError(f"--model {args.model!r}: no such file")
    arm = "wam" if args.robot is None or is_link_address(args.robot) else args.robot
    load_arm(arm)  # a bad arm: one line naming the file and field, before anything runs
    # None is the config's "the tracker's own", not a value anyone types
    with named_by_options("AccuracyConfig", FLAGS, {"eps_px must be a positive number of pixels or None": "eps_px must be a positive number of pixels"}):
        config = AccuracyConfig(seed=args.seed, n_frames=frames, rate_hz=args.rate_hz, rig=args.rig, model=args.model,
                                trackers=tuple(args.trackers), eps_px=args.eps_px, inject_faults=args.inject_faults,
                                scene=SCENES[args.scene], robot=arm)
    if args.reprojection_px is not None:
        if args.ideal or args.no_calibration_error:
            raise ValueError("--reprojection-px sets the calibration error: it cannot go with --ideal or --no-calibration-error")
        if not 0 < args.reprojection_px <= 50:
            raise ValueError(f"--reprojection-px must be in (0, 50] px, got {args.reprojection_px!r}")
        config = config.with_(calibration_error=replace(config.calibration_error, target_reprojection_px=args.reprojection_px))
    return config.idealised(calibration=args.ideal or args.no_calibration_error, clock=args.ideal or args.no_clock_error)


def format_report(figures: dict, rows: list, *, header: str = "") -> str:
    """The printed summary: registration, the table beside the paper, error bands, goals, faults."""
    reg = figures["registration"]
    lines = [header] if header else []
    lines.append(f"registration ({reg['tracker']} OK positions of {figures['n_register']} frames, {figures.get('register_layout', 'first')}): "
                 f"{reg['inliers']}/{reg['pairs']} pairs kept, residual RMS {reg['rms_cm']:.2f} cm, max {reg['max_cm']:.2f} cm; "
                 f"uncertainty at the scored points {reg['std_at_scored_p90_cm']:.2f} cm (p90, 1 sigma); "
                 f"vs the true mount {reg['vs_true_mount']['rotation_deg']:.3f} deg, {reg['vs_true_mount']['translation_cm']:.2f} cm")
    if not reg["well_conditioned"]:
        lines.append(f"WARNING: the registration points (spread {reg['spread_cm'][0]:.1f} x {reg['spread_cm'][1]:.1f} x "
                     f"{reg['spread_cm'][2]:.1f} cm, std) fix the transform only to {reg['std_at_scored_p90_cm']:.2f} cm at the "
                     "scored points: the errors below include that (use more frames)")
    lines.append(f"scored: {figures['n_scored']} frame sets (the frames that do not register)\n")
    lines.append(format_table(rows))
    lines.append("\nshare of frames with a position in the paper's error bands:")
    lines.append(f"  {'tracker':10} {'<5cm':>8} {'5-10cm':>8} {'20-35cm':>8} {'>1m':>8} {'>10m':>8}")
    for kind, m in figures["modes"].items():
        vals = " ".join("       -" if v is None else f"{100 * v:7.2f}%" for v in m.values())
        lines.append(f"  {kind:10} {vals}")
    lines.append("\ngoals (rt2's accuracy):")
    lines.append(format_goals(rt2_goals(rows)))
    baseline = check_baseline(rows)
    if baseline:
        lines.append("\nthe baseline's published failure mode (RTBlob, paper Sec. 3.2; shown by cluttered scenes, not a goal):")
        lines.append(format_goals(baseline, BASELINE_WORDS))
    faults = figures.get("faults", {})
    if faults.get("injected"):
        lines.append("\ninjected faults:")
        lines += [f"  {p}" for p in faults["plan"]]
        for fault, entry in faults["by_kind"].items():
            per = "; ".join(f"{k}: {v['with_position']} with a position (median error "
                            f"{fmt(v['median_error_cm'], '.2f')} cm), {v['flagged']} flagged"
                            for k, v in entry.items() if isinstance(v, dict))
            lines.append(f"  {fault} ({entry['frames']} frame sets): {per}")
    return "\n".join(lines)


def realism_line(config, calibration_error: dict, motion_info: dict) -> str:
    """One line: the calibration error the trackers' rig has and the clock error (or that they are off)."""
    c = calibration_error or {"enabled": False}
    if c.get("enabled"):
        cal = (f"trackers' calibration: re-projection error {c['reprojection_px']['mean']:.2f} px mean "
               f"(p95 {c['reprojection_px']['p95']:.2f}), 3D {c['triangulation_after_rigid_mm']['median']:.1f} mm median "
               f"after a rigid fit, on {c['n_points']} workspace points")
    else:
        cal = "trackers' calibration: exact (the rig the images were rendered with)"
    clock = motion_info.get("clock", {})
    if config.motion.clock_offset_std_s or config.motion.clock_jitter_std_s:
        clk = (f"camera clock {clock.get('offset_ms', 0):+.2f} ms off the robot's, jitter {clock.get('jitter_std_ms', 0):.2f} ms "
               f"(ground truth moved {clock.get('gt_shift_mm', {}).get('median', 0):.2f} mm median)")
    else:
        clk = "clocks synchronised"
    return f"realism: {cal}; {clk}"


def link_line(link: dict) -> str:
    """One line: the robot over the link and its clock estimate (``rt2 accuracy --robot``)."""
    c = link["robot_clock_estimate"]
    return (f"robot over the link {link['address']} (bridge {link['bridge_id']}): clock offset uncertainty "
            f"{c['uncertainty_ms']:.3f} ms, estimate off the simulation's truth by {link['estimate_error_ms']:+.3f} ms")


def events_line(events: dict) -> str:
    """One line: the distractor episodes of the run (the scene's orange balls that come and go)."""
    if not events:
        return "distractors that come and go: none"
    h, r = events["held_orange_ball"], events["rolling_ball"]
    return (f"distractors that come and go: a held orange ball {100 * h['share_of_time']:.0f} % of the time "
            f"({h['episodes']} episode(s), {h['with_tosses']} with tosses), a ball rolling on the floor "
            f"{100 * r['share_of_time']:.0f} % ({r['episodes']})")


def _run_live(args, config) -> int:
    """``rt2 accuracy --live``: the three-process run (harness.experiments.accuracy.live)."""
    from harness.experiments.accuracy.live import run_live_accuracy, run_live_local
    from harness.experiments.accuracy.live_stream import format_budget
    from harness.common.outputs import atomic_write_json
    from harness.common.signal_stop import stop_on_signals

    if not args.live:
        raise ValueError("--tracker-stream goes with --live")
    if not is_link_address(args.robot) and config.robot != "wam":
        raise ValueError(f"--live runs the WAM (the simulated bridge's arm), not --robot {args.robot}")
    local = args.robot in (None, "sim", "wam")
    if local != (args.tracker_stream is None):
        raise ValueError("--live takes both --robot ADDR and --tracker-stream ADDR (processes you started), or neither "
                         "(it starts the simulated bridge and rt2 track itself)")
    if args.stream_timeout is not None and not (math.isfinite(args.stream_timeout) and 0 < args.stream_timeout <= 3600):
        raise ValueError(f"--stream-timeout must be in (0, 3600] s, got {args.stream_timeout}")
    status = lambda line: print(line, flush=True)  # noqa: E731
    # SIGINT / SIGTERM: the children stopped and the log closed on the way out, exit 128 + signal within 2 s
    with stop_on_signals():
        if local:
            res = run_live_local(config, args.out, log=not args.no_log, status=status,
                                 **({"start_timeout_s": args.stream_timeout} if args.stream_timeout else {}))
        else:
            res = run_live_accuracy(config, args.out, robot=args.robot, tracker_stream=args.tracker_stream,
                                    log=not args.no_log, stream_timeout_s=args.stream_timeout or 10.0, status=status)
    m, live = res.motion_info, res.motion_info["live"]
    c = live["robot_clock_estimate"]
    cams = "; ".join(f"{k} {'n/a' if v is None else format(v['offset_ms'], '+.1f') + ' ms (spread ' + format(v['spread_ms'], '.1f') + ')'}"
                     for k, v in live["camera_clock_offsets"].items())
    header = (f"rt2 accuracy --live: seed {config.seed}, {config.n_frames} frame sets at {config.rate_hz:g} Hz, rig {config.rig}, "
              f"{live['frames_received']} received from {live['tracker_stream']}, {res.timing['wall_s']:.0f} s\n"
              f"robot {live['robot']}: clock offset {c['offset_ms']:+.3f} ms, uncertainty {c['uncertainty_ms']:.3f} ms"
              + (f", off the simulation's truth by {m['robot_clock_error_ms']:+.3f} ms" if "robot_clock_error_ms" in m else "")
              + f"\ncameras' stamps vs arrival (offset + smallest transfer latency): {cams}\n"
              f"ground truth (FK of reported joints at the capture times) vs true ball: median "
              f"{m['gt_vs_true_mm']['median']:.1f} mm, max {m['gt_vs_true_mm']['max']:.1f} mm\n"
              + realism_line(res.config, res.calibration_error, m).replace(
                  "clocks synchronised", "camera clock: the cameras' own exposure stamps on the host clock")
              + f"\n{events_line(res.scene_events)}")
    print(format_report(res.figures, res.rows, header=header))
    print(format_budget(live["latency_budget"]))
    if args.json:
        atomic_write_json(args.json, res.rows, "--json")
    print("\nwrote: " + ", ".join(str(p) for p in res.paths.values()))
    return 0


def run(args) -> int:
    from harness.experiments.accuracy.experiment import run_accuracy
    from harness.common.outputs import atomic_write_json, check_output_file

    config = config_from_args(args)
    check_output_file(args.json, "--json")  # before the run, not after
    if args.live or args.tracker_stream is not None:
        return _run_live(args, config)
    motion_source = None
    if is_link_address(args.robot):
        from harness.experiments.accuracy.link_motion import link_motion_source

        motion_source = link_motion_source(args.robot)
    res = run_accuracy(config, args.out, sweep=options_from_args(args), log=not args.no_log, log_images=args.log_images,
                       image_format=args.log_image_format, motion_source=motion_source)
    m = res.motion_info
    if res.partial:
        print(f"PARTIAL ({res.partial['reason']}): the figures below score the {res.partial['frames_done']} of "
              f"{config.n_frames} frame sets that finished")
    header = (f"rt2 accuracy: seed {config.seed}, {config.n_frames} frame sets at {config.rate_hz:g} Hz "
              f"({config.n_frames / config.rate_hz:.1f} s), rig {config.rig}, {args.workers} worker(s), "
              f"{res.timing['wall_s']:.0f} s\n"
              f"robot {config.robot}: {m['via_points']} via points, ball speed median {m['ball_speed_mps']['median']:.2f} m/s "
              f"(max {m['ball_speed_mps']['max']:.2f}); ground truth (FK of reported joints) vs true ball: "
              f"median {m['gt_vs_true_mm']['median']:.1f} mm, max {m['gt_vs_true_mm']['max']:.1f} mm\n"
              f"{realism_line(config, res.calibration_error, m)}\n{events_line(res.scene_events)}"
              + (f"\n{link_line(m['link'])}" if "link" in m else ""))
    print(format_report(res.figures, res.rows, header=header))
    t = res.truth
    if t.get("registered_ground_truth_mm"):
        print("\nagainst the TRUE ball (simulation only; median / p99 / max, mm): " + "; ".join(
            f"{k[:-3]} {v['median']:.1f} / {v['p99']:.1f} / {v['max']:.1f}" for k, v in t.items() if v))
    if args.json:
        atomic_write_json(args.json, res.rows, "--json")
    print("\nwrote: " + ", ".join(str(p) for p in res.paths.values()) + (" (partial)" if res.partial else ""))
    return res.partial["exit_code"] if res.partial else 0
