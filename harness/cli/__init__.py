"""The ``rt2`` command line.

Each command lives in its own module exposing ``add_arguments(parser)`` and ``run(args) -> int``.
Modules are imported only when their command runs, so ``rt2 --help`` stays fast and inference
commands never import torch. Bad input (``ValueError``, missing files) ends with a one-line
message naming the problem and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

__all__ = ["COMMANDS", "main"]

#: command words -> (module, one-line help). Groups ("sim", "bench", ...) come from the prefixes.
COMMANDS: dict[tuple[str, ...], tuple[str, str]] = {
    ("demo",): ("harness.cli.demo", "the main job: a quick accuracy experiment (ball on the WAM, 3 trackers), printed as a table"),
    ("accuracy",): ("harness.cli.accuracy", "accuracy experiment (paper Sec. 3.2): ball on the simulated WAM, kinematics as ground truth, RT2 vs RTBlob"),
    ("reevaluate",): ("harness.cli.reevaluate", "re-run a tracker on a recorded session log (images or detections) and recompute its figures"),
    ("sim", "table1"): ("harness.experiments.studies.table1", "simulation study of the robust estimator (paper Table 1)"),
    ("sim", "dataset"): ("harness.experiments.studies.sim_dataset", "render a labelled synthetic ball data set (PNG + COCO annotations.json)"),
    ("bench", "renderer"): ("harness.experiments.studies.bench_renderer", "frames/s of the synthetic camera renderer on one core, per scene type"),
    ("bench", "estimator"): ("harness.experiments.studies.bench_estimator", "run time of the robust estimator vs cameras (paper Table 2)"),
    ("label",): ("harness.cli.label", "label ball frames in a browser (folder, video or session log): the model proposes, you accept; COCO saved as you go"),
    ("train",): ("harness.experiments.detector.train", "train the ball detector (5x5 filter + learned stage) from box labels"),
    ("train-shipped",): ("harness.experiments.detector.shipped", "train the shipped models' learned stage (white or orange) from the shared real data, drawn and pasted balls"),
    ("eval", "detector"): ("harness.experiments.studies.eval_detector", "ball detector recall, outlier rate and centre error on labelled images"),
    ("eval", "selection"): ("harness.cli.eval_selection", "do the frames rt2 label suggests train a better detector than consecutive ones? (one recording, later frames held out)"),
    ("eval", "autolabel"): ("harness.experiments.autolabel.study", "how good are rt2 label --auto's labels? kept frame sets, centre error and wrong labels against the truth (sim lab, caliscope)"),
    ("eval", "framesets"): ("harness.experiments.studies.eval_framesets", "trackers on random rendered frame sets: 3D recall and wrong positions (what the cameras together make of detector outliers)"),
    ("eval", "filters"): ("harness.experiments.studies.eval_filters", "ball filters raw vs ransac_kalman: prediction error on real/simulated flights, clean and with outliers"),
    ("bench", "detector"): ("harness.experiments.studies.bench_detector", "ms per VGA frame of the ball detector, full frame and ROI, vs torch"),
    ("bench", "rtblob"): ("harness.experiments.studies.bench_rtblob", "ms per VGA frame of the RTBlob baseline (colour likelihood + disk FFT + max)"),
    ("bench", "pipeline"): ("harness.experiments.studies.bench_pipeline", "frame sets/s and latency (p50/p99) of the whole tracker, 4 VGA cameras, full frame and ROI"),
    ("labels", "convert"): ("harness.cli.labels_convert", "convert ball labels between COCO, YOLO, labelme, CVAT and Label Studio (images linked in)"),
    ("log", "info"): ("harness.cli.log_info", "topics, counts, duration and provenance of a session log; recovery of unfinished logs"),
    ("bench", "log"): ("harness.experiments.studies.bench_log", "session-log write/read throughput, 4 VGA cameras at 200 Hz, per image format"),
    ("sim", "reach"): ("harness.cli.sim_reach", "an arm's racket reachability over the hitting region (IK on a grid; --robot NAME|PATH.yaml)"),
    ("sim", "wam"): ("harness.cli.sim_wam", "simulated WAM on a seeded ball-mount trajectory: tracking and reported-vs-true ball error"),
    ("bench", "policy"): ("harness.experiments.play.bench", "ms per planning step of the hitting policy (first plans, re-plans), fast vs reference planner"),
    ("bench", "link-flood"): ("harness.cli.bench_link", "a hostile peer floods the simulated robot bridge: a good client's state rate, gaps, bridge memory"),
    ("bench", "robot"): ("harness.cli.bench_robot", "run time of an arm's batched FK, Jacobian, IK and simulated ticks (numba vs numpy; --robot NAME)"),
    ("sim", "fit-flight"): ("harness.experiments.studies.fit_flight", "fit the ball flight/bounce model to 88 real launcher flights; held-out prediction error"),
    ("learn", "promp"): ("harness.experiments.studies.learn_promp", "learn the WAM hitting ProMP from the scripted teacher (MAP vs ML, held-out fit)"),
    ("play",): ("harness.cli.play", "playing sessions: served balls, tracker, filter, ProMP hitting policy, simulated WAM; success rates (`rt2 play compare`)"),
    ("track",): ("harness.cli.track", "the tracker as a real-time service: cameras -> tracker -> tennicam-compatible ZeroMQ stream, live view, session log"),
    ("bench", "replay"): ("harness.experiments.studies.bench_replay", "re-tracking a recorded rt2 track session from its JPEG images: frame sets/s with the images decoded in the tracker's thread vs by decoding threads"),
    ("bench", "live"): ("harness.cli.bench_live", "end-to-end latency (frame arrival -> message at a subscriber in another process) and sustained rate of rt2 track"),
    ("calib", "intrinsics"): ("harness.cli.calib_intrinsics", "one camera's K and distortion from ChArUco images or a video (per-view errors, coverage, std devs)"),
    ("calib", "wand"): ("harness.cli.calib_wand", "all cameras' poses by bundle adjustment of a wand (known ball spacings) or a ball moved through the volume"),
    ("calib", "board"): ("harness.cli.calib_board", "all cameras' poses by bundle adjustment of a ChArUco board seen by several cameras at once"),
    ("calib", "check"): ("harness.cli.calib_check", "calibrate a rig from rendered ChArUco views and a waved wand, and compare with its true geometry"),
    ("calib", "loop"): ("harness.cli.calib_loop", "the accuracy experiment with a self-made calibration vs the true rig (figures within 20 %)"),
    ("calib", "robot"): ("harness.cli.calib_robot", "robot base to world transform from a session log (ball on the end effector, joint states)"),
    ("robot", "serve"): ("harness.cli.robot_serve", "serve the simulated WAM in real time behind the robot link (ZeroMQ; docs/robot_link.md)"),
    ("robot", "check"): ("harness.cli.robot_check", "measure a robot link: state rate, gaps, delivery delay, clock offset, round trips, command to motion"),
    ("robot", "record"): ("harness.cli.robot_record", "record a robot's joint states over the link to a session log, in segments across link losses"),
    ("cache", "info"): ("harness.cli.cache_info", "what the disk cache of the simulated lab's slow parts holds (static room ray-casts, launcher flights), where, how large"),
    ("cache", "clear"): ("harness.cli.cache_clear", "empty the disk cache of the simulated lab's slow parts (computed again when next needed)"),
    ("robot", "check-config"): ("harness.cli.robot_check_config", "check an arm's robot config (data/robot/NAME.yaml or PATH.yaml): links, limits, reach of the hitting region"),
}

GROUP_HELP = {
    "sim": "simulation studies and synthetic data",
    "bench": "speed benchmarks (medians, ratios against a baseline run in the same process)",
    "eval": "evaluate a component on held-out data",
    "log": "inspect session logs",
    "labels": "labelled image sets: convert between labelling tools' formats",
    "learn": "learn movement primitives from demonstrations",
    "calib": "calibrate cameras (intrinsics, extrinsics) and the robot's base into the camera frame",
    "cache": "the disk cache of the simulated lab's slow, deterministic parts (README, \"The disk cache\")",
    "robot": "the robot: its link over the network (docs/robot_link.md) and its config (docs/robots.md)",
}


def _build_parser(argv: list[str]) -> tuple[argparse.ArgumentParser, dict]:
    parser = argparse.ArgumentParser(prog="rt2", description="Reliable real-time multi-camera ball tracking.")
    top = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    groups: dict[str, argparse._SubParsersAction] = {}
    leaves: dict[tuple[str, ...], argparse.ArgumentParser] = {}
    for words, (module, help_text) in COMMANDS.items():
        listed = help_text.replace("%", "%%")  # a command's line in its group's list is a format string ("within 20 %")
        if len(words) == 1:
            leaves[words] = top.add_parser(words[0], help=listed, description=help_text)
            continue
        group = words[0]
        if group not in groups:
            gp = top.add_parser(group, help=GROUP_HELP.get(group, "").replace("%", "%%"))
            groups[group] = gp.add_subparsers(dest="subcommand", metavar="SUBCOMMAND", required=True)
        leaves[words] = groups[group].add_parser(words[1], help=listed, description=help_text)
    # Import and configure only the command being run.
    for words, sub in leaves.items():
        if list(words) == argv[: len(words)]:
            importlib.import_module(COMMANDS[words][0]).add_arguments(sub)
    return parser, leaves


#: the options that seed numpy's generators (which take no seed below 0), by their fields in the parsed options
SEED_OPTIONS = {"seed": "--seed", "seeds": "--seeds", "train_seed": "--train-seed"}


def _check_seeds(args) -> None:
    """Every command's seeds before it runs: a seed below 0 named by its option (numpy's own error, "expected
    non-negative integer", names none, and some commands would meet it only minutes into a run)."""
    for field, flag in SEED_OPTIONS.items():
        value = getattr(args, field, None)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, int) and not isinstance(v, bool) and v < 0:
                raise ValueError(f"{flag} must be >= 0, got {v}")


#: the folder of rt2's own packages (a warning raised in their code speaks to the user; a library's names its origin)
_OWN_CODE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _warning_line(cmd: str):
    """``warnings.formatwarning`` for a command's run: one line, ``rt2 CMD: warning: ...`` (Python's own format adds the
    source line the warning was raised from, which says nothing to a user). A warning of a library's code other than
    a ``UserWarning`` (numpy's ``RuntimeWarning``, a ``DeprecationWarning``) keeps its category and where it came from."""

    def line(message, category, filename, lineno, line=None):
        own = os.path.abspath(str(filename)).startswith(_OWN_CODE + os.sep) and "site-packages" not in str(filename)
        if own or issubclass(category, UserWarning):
            return f"rt2 {cmd}: warning: {message}\n"
        return f"rt2 {cmd}: {category.__name__}: {message} ({filename}:{lineno})\n"

    return line


def main(argv: list[str] | None = None) -> int:
    if argv is None:  # a process of its own (not a call from a test): started by ReadyProcess, die with the parent
        from harness.common.spawn import die_with_parent_from_env

        die_with_parent_from_env()
    argv = list(sys.argv[1:] if argv is None else argv)
    parser, _ = _build_parser(argv)
    args = parser.parse_args(argv)
    words = tuple(w for w in (args.command, getattr(args, "subcommand", None)) if w)
    cmd = " ".join(words)
    before = warnings.formatwarning
    warnings.formatwarning = _warning_line(cmd)
    try:
        _check_seeds(args)
        return int(importlib.import_module(COMMANDS[words][0]).run(args) or 0)
    except BrokenPipeError:  # output piped into `head` & co.: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (ValueError, FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        print(f"rt2 {cmd}: error: {exc}", file=sys.stderr)
        return 2
    except ConnectionError as exc:  # a robot link or stream lost at run time (LinkLostError): a failure, not bad input
        print(f"rt2 {cmd}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a full disk, a file-size limit, an I/O error while writing: one line, not a traceback
        where = f" ({exc.filename})" if exc.filename else ""
        print(f"rt2 {cmd}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C; or SIGINT / SIGTERM inside stop_on_signals (exit 128 + signal)
        print(f"rt2 {cmd}: {exc or 'interrupted'}", file=sys.stderr)
        return getattr(exc, "exit_code", 130)
    finally:
        warnings.formatwarning = before


if __name__ == "__main__":
    sys.exit(main())
