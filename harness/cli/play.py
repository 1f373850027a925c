"""``rt2 play`` and ``rt2 play compare``: playing sessions in closed loop, success rates with Wilson 95 % CIs.

    rt2 play --tracker rt2 --filter raw --balls 100 --seed 0 [--source synthetic|vision] [--workers 2] [--ray [ADDRESS]]
    rt2 play compare --balls 500 --seed 0 [--trackers rt2 rtblob] [--filters raw ransac_kalman]
    rt2 play profile --balls 20 --seed 0            # measure the synthetic profiles from the vision source
    rt2 play --balls 200 --robot panda              # another arm (data/robot/*.yaml) with its own ProMP

``compare`` plays the same served balls (same seed) with every tracker x filter combination. Output: a
table on stdout, ``--json PATH`` (a list of objects with keys tracker, filter, balls, successes,
success_rate, ci_low, ci_high, source, outcomes, ...), a bar chart ``<out>/play_<mode>_<source>_s<seed>.png``
and ``.pdf``, and one MCAP session log per configuration in ``--out`` (``--no-log`` to skip; images are
off unless ``--log-images``). See docs/play.md.

Stopped early (SIGINT, SIGTERM, a lost worker): the configurations done and the balls of the running one
that finished are printed and written (``"partial": true`` on that row), its session log is closed with
the reason, no figure is drawn; exit code 128 + signal.
"""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

from harness.common.executor import Executor, add_sweep_arguments, options_from_args
from harness.experiments.play.experiment import DEFAULT_PROMP, PlayConfig, run_configuration, summarise
from harness.experiments.play.profiles import PROFILE_SETS, PROFILES, load_profiles, profile_for

MODES = ("play", "compare", "profile", "observe")
FILTER_NAMES = ("raw", "ransac_kalman")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mode", nargs="?", default="play", choices=MODES,
                        help="play (one configuration, default), compare (trackers x filters), profile (measure "
                             "the synthetic source's numbers from the vision source), observe (the synthetic tracker "
                             "of --live as a process: truth stream in, rt2 stream out)")
    parser.add_argument("--tracker", default="rt2", help=f"tracker of `rt2 play`: {', '.join(PROFILES)} (default rt2)")
    parser.add_argument("--filter", default="raw", help=f"ball filter of `rt2 play`: {', '.join(FILTER_NAMES)} (default raw)")
    parser.add_argument("--trackers", nargs="+", default=["rt2", "rtblob"], help="trackers of `compare` (default rt2 rtblob)")
    parser.add_argument("--filters", nargs="+", default=list(FILTER_NAMES), help="filters of `compare` (default both)")
    parser.add_argument("--balls", type=int, default=100, help="served balls per configuration (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the serves and the session noise (default 0)")
    parser.add_argument("--source", default="synthetic", choices=("synthetic", "vision"),
                        help="observations: synthetic (noise + outliers of the tracker's profile, fast) or vision "
                             "(rendered cameras + the real tracker)")
    parser.add_argument("--scene", default="default",
                        help="vision source: what else the cameras see, a preset of harness.experiments.play.play_scene.SCENES: default "
                             "(a person, white clutter), second_ball (the person holds an orange ball), harsh (orange "
                             "clutter), clean (the arm and the ball)")
    add_sweep_arguments(parser)
    parser.add_argument("--rate-hz", type=float, default=None, help="tracker frame rate (default: rt2 180, rtblob 60)")
    parser.add_argument("--latency-ms", type=float, default=None, help="tracker latency (default 10 ms)")
    parser.add_argument("--plan-latency-ms", type=float, default=0.0,
                        help="in process: a planning step of the policy takes this long (it plans this far ahead from "
                             "what has arrived, and its command reaches the robot this much later); default 0, the "
                             "paper's instantaneous policy. Live, planning takes its real time (see --plan-lead-ms)")
    parser.add_argument("--planner", default="fast",
                        help="the hitting policy's planner: fast (compiled return, reduced ProMP conditioning; default) or "
                             "reference (the public ball model and the ProMP API in sequence): the same plans to "
                             "rounding, ~2.4x slower per planning step (rt2 bench policy)")
    parser.add_argument("--profiles", default="vision", choices=sorted(PROFILE_SETS),
                        help="synthetic source's error model: vision (measured from the vision source, default) or "
                             "paper (the paper's real-robot RTBlob outliers); see harness/experiments/play/profiles.py")
    parser.add_argument("--profile-json", type=Path, default=None, help="synthetic profiles from this JSON (rt2 play profile --json), "
                        "on top of --profiles")
    parser.add_argument("--promp", type=Path, default=None,
                        help=f"hitting ProMP (default data/promp/NAME_hitting.npz of the --robot: {DEFAULT_PROMP.name} for the WAM)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument("--out", type=Path, default=Path("out/play"), help="figure and session logs (default out/play)")
    parser.add_argument("--no-log", action="store_true", help="write no session logs")
    parser.add_argument("--log-images", type=int, default=0, metavar="N",
                        help="vision source: log the images of every N-th frame set (default 0: none)")
    parser.add_argument("--no-figure", action="store_true", help="draw no figure")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    live = parser.add_argument_group("live play (rt2 play --live; docs/play.md, 'Live')")
    live.add_argument("--live", action="store_true", help="play in real time: the policy in this process over the "
                      "tracker stream and the robot link; without --robot it starts the simulated world+robot and the "
                      "synthetic tracker as child processes")
    parser.add_argument("--robot", default=None, metavar="NAME|PATH.yaml|ADDR",
                        help="the arm that plays: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config "
                             "(docs/robots.md); with --live (the WAM): the robot link's command endpoint (tcp://HOST:PORT)")
    live.add_argument("--tracker-stream", default=None, help="--live: the tracker's rt2 stream (tcp://HOST:PORT)")
    live.add_argument("--world-stream", default=None, help="--live / observe: the world's serve and outcome events "
                      "(tcp://HOST:PORT, the world bridge's ready line)")
    live.add_argument("--plan-lead-ms", type=float, default=None, help="--live: plan this far ahead of the robot "
                      "clock (default: the longest of the last 5 planning steps of the same kind -- first plan of a ball "
                      "or re-plan --, at most 200 ms)")
    live.add_argument("--truth", default=None, help="observe: the world's lab truth stream (tcp://HOST:PORT)")
    live.add_argument("--publish", default="tcp://127.0.0.1:7661", help="observe: rt2 stream endpoint (default "
                      "tcp://127.0.0.1:7661, as rt2 track)")
    live.add_argument("--publish-tennicam", default=None, help="observe: also the tennicam stream here")
    live.add_argument("--ready-json", action="store_true", help="observe: print a JSON ready line with the endpoints")


def _check(args) -> None:
    if args.balls < 1:
        raise ValueError(f"--balls must be >= 1, got {args.balls}")
    if args.rate_hz is not None and not args.rate_hz > 0:
        raise ValueError(f"--rate-hz must be > 0, got {args.rate_hz}")
    if args.latency_ms is not None and not 0 <= args.latency_ms < 1000:
        raise ValueError(f"--latency-ms must be in [0, 1000), got {args.latency_ms}")
    if not 0 <= args.plan_latency_ms <= 500:
        raise ValueError(f"--plan-latency-ms must be in [0, 500], got {args.plan_latency_ms}")
    if args.live and args.plan_latency_ms:
        raise ValueError("--plan-latency-ms models planning time in process; live, planning takes its real time "
                         "(--plan-lead-ms sets how far ahead the policy plans)")
    if args.log_images < 0:
        raise ValueError(f"--log-images must be >= 0, got {args.log_images}")
    from policies.hitting import PLANNERS

    if args.planner not in PLANNERS:
        raise ValueError(f"unknown --planner {args.planner!r}; valid: {list(PLANNERS)}")
    from harness.experiments.studies.learn_promp import default_promp
    from harness.sim.robot.arms import is_link_address, load_arm

    link = is_link_address(args.robot)
    args.arm = load_arm(None if link else args.robot)  # a bad arm: one line naming the file and the field
    if args.live and args.arm.name != "wam":
        raise ValueError(f"--live plays the WAM (the simulated world's arm), not --robot {args.robot}")
    if args.promp is None:
        args.promp = default_promp(args.arm.name)
        if not args.promp.is_file():
            raise FileNotFoundError(f"no hitting ProMP for {args.arm.name} at {args.promp}: learn one with "
                                    f"`rt2 learn promp --robot {args.robot}` or pass --promp PATH")
    if not args.promp.is_file():
        raise FileNotFoundError(f"--promp: no such file {args.promp}")
    for f in ([args.filter] if args.mode == "play" else args.filters):
        if f not in FILTER_NAMES:
            raise ValueError(f"unknown filter {f!r}; valid: {list(FILTER_NAMES)}")
    from harness.experiments.play.play_scene import SCENES

    if args.scene not in SCENES:
        raise ValueError(f"unknown --scene {args.scene!r}; valid: {sorted(SCENES)}")
    if args.log_images and args.source != "vision":
        raise ValueError("--log-images needs --source vision (the synthetic source makes no images)")
    if args.live or args.mode == "observe":
        if args.mode not in ("play", "observe"):
            raise ValueError(f"--live plays one configuration: `rt2 play --live`, not `rt2 play {args.mode} --live`")
        if args.source != "synthetic":
            raise ValueError("--live supports --source synthetic (the rendered-camera tracker over the truth stream, "
                             "rt2 track --source sim, is not wired to the live world yet)")
        if args.plan_lead_ms is not None and not 0 <= args.plan_lead_ms <= 500:
            raise ValueError(f"--plan-lead-ms must be in [0, 500], got {args.plan_lead_ms}")
        from harness.live.publish import parse_address

        given = {"--robot": args.robot if link else None, "--tracker-stream": args.tracker_stream,
                 "--world-stream": args.world_stream}
        if args.mode == "observe":
            given = {"--truth": args.truth, "--world-stream": args.world_stream}
            missing = [k for k, v in given.items() if v is None]
            if missing:
                raise ValueError(f"rt2 play observe needs {' and '.join(missing)}")
            parse_address(args.publish, default_port=7661)
        elif any(v is not None for v in given.values()):
            missing = [k for k, v in given.items() if v is None]
            if missing:
                raise ValueError(f"--live with a robot address needs {', '.join(given)}; missing {', '.join(missing)}")
        for k, v in given.items():
            if v is not None:
                _check_endpoint(k, v)


def _check_endpoint(option: str, value: str) -> None:
    """``tcp://HOST:PORT`` with a port 1..65535, else a one-line ValueError naming the option."""
    import re

    m = re.match(r"^tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):([0-9]{1,5})$", value.strip())
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise ValueError(f"{option} must be an endpoint like tcp://127.0.0.1:7650, got {value!r}")


def _configs(args, profiles) -> list[PlayConfig]:
    pairs = [(args.tracker, args.filter)] if args.mode == "play" else [(t, f) for t in args.trackers for f in args.filters]
    out = []
    for tracker, filt in pairs:
        prof = profile_for(tracker, profiles).with_timing(args.rate_hz, None if args.latency_ms is None else args.latency_ms / 1e3)
        out.append(PlayConfig(tracker, filt, args.source, prof, str(args.promp), scene=args.scene, record=not args.no_log,
                              record_images_every=args.log_images, plan_latency_s=args.plan_latency_ms / 1e3,
                              policy={"planner": args.planner}, robot=_robot_spec(args)))
    return out


def _robot_spec(args) -> str:
    """The arm of the sessions as PlayConfig keeps it: a shipped arm's name or a robot config's path."""
    arm = getattr(args, "arm", None)
    if arm is None or arm.config.path is None:
        return "wam"
    from robot_models.config import ROBOT_CONFIG_DIR

    return arm.name if arm.config.path.resolve() == (ROBOT_CONFIG_DIR / f"{arm.name}.yaml") else str(arm.config.path)


def _open_log(args, config: PlayConfig):
    from harness.logs import LogWriterOptions, SessionLogWriter

    args.out.mkdir(parents=True, exist_ok=True)
    live = "_live" if getattr(args, "live", False) else ""
    path = args.out / f"play{live}_{config.tracker}_{config.filter}_{config.source}_s{args.seed}.mcap"
    meta = {"kind": "play", "seed": args.seed, "ball_slot_s": 10.0, "live": bool(live),
            "config": {"tracker": config.tracker, "filter": config.filter, "source": config.source, "scene": config.scene,
                       "profiles": args.profiles, "plan_latency_s": config.plan_latency_s, "policy": config.policy,
                       "balls": args.balls, "profile": config.resolved_profile().__dict__, "promp": config.promp_path,
                       "robot": config.robot}}
    joints = args.arm.kin.joint_names if getattr(args, "arm", None) is not None else None
    log = SessionLogWriter(path, metadata=meta, log_images="all" if args.log_images else "none", overwrite=True,
                           options=LogWriterOptions(joint_names=tuple(joints)) if joints else None)
    return log, path


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_dir, check_output_file

    _check(args)
    check_output_file(args.json, "--json")  # the outputs before the sessions, not after
    if args.mode != "profile" and not (args.no_log and args.no_figure):
        check_output_dir(args.out, "--out")
    base = PROFILE_SETS[args.profiles]
    profiles = load_profiles(args.profile_json, base) if args.profile_json else dict(base)
    if args.mode == "profile":
        from harness.experiments.play.measure import run_profile

        return run_profile(args, profiles)
    if args.mode == "observe":
        return _run_observe(args, profiles)
    if args.live:
        from harness.cli.play_live import run_live

        return run_live(args, _configs(args, profiles)[0], _open_log, _print)
    from policies.promp import ProMP

    kin = args.arm.kin
    ProMP.load(args.promp, robot_id=str(kin.model.name), joint_names=kin.joint_names)  # fails here, not in a worker
    if not args.no_log:  # load the kernel the session log draws the arm with now, not while a signal stops the run
        kin.link_points([0.0] * kin.n_joints, check_limits=False)
    rows, logs, stopped = [], [], []
    with Executor(options_from_args(args)) as executor:
        for config in _configs(args, profiles):
            log, path = _open_log(args, config) if not args.no_log else (None, None)
            logs += [path] if path is not None else []
            error = None
            try:
                def on_ball(i, result, record, serve, _log=log, _tracker=config.tracker):
                    if _log is not None:
                        from harness.experiments.play.log import write_ball

                        write_ball(_log, i, _tracker, result, record, serve, kinematics=kin)

                results = run_configuration(config, balls=args.balls, seed=args.seed, progress=not args.quiet,
                                            on_ball=on_ball, executor=executor, stopped=stopped)
                if not results:  # stopped before the first ball of this configuration finished
                    error = f"{stopped[0]} before any ball finished"
                    break
                row = summarise(config, results, args.seed)
                row["profiles" if config.source == "synthetic" else "scene"] = args.profiles if config.source == "synthetic" else args.scene
                if stopped:
                    row["partial"] = True
                    error = f"{stopped[0]}: partial, {len(results)} of {args.balls} balls finished"
                if log is not None:
                    log.write_figures("summary", row)
            except BaseException as exc:
                error = f"{type(exc).__name__}: {exc}"
                raise
            finally:
                if log is not None:
                    log.close(error=error)
            if path is not None:
                row["log"] = str(path)
            rows.append(row)
            if stopped:
                break
    if stopped:
        print(f"PARTIAL ({stopped[0]}): {len(rows)} configuration(s) reported, the last one "
              f"{'with the balls that finished' if rows and rows[-1].get('partial') else 'complete'}; no figure")
    if rows:
        _print(rows, args)
    if args.json:
        atomic_write_json(args.json, rows, "--json")
    if not args.no_figure and not stopped:
        from harness.experiments.play.figure import draw

        for p in draw(rows, args.out / f"play_{args.mode}_{args.source}_s{args.seed}", title=_title(args)):
            print(f"figure: {p}")
    for p in logs:
        print(f"session log: {p}")
    return stopped[0].exit_code if stopped else 0


def _run_observe(args, profiles) -> int:
    import json
    import signal

    from harness.common.fast_exit import exit_at_once_when_done
    from harness.experiments.play.observe import ObservationService

    prof = profile_for(args.tracker, profiles).with_timing(args.rate_hz, None if args.latency_ms is None else args.latency_ms / 1e3)
    service = ObservationService(args.truth, args.world_stream, prof, seed=args.seed, publish_addr=args.publish,
                                 tennicam_addr=args.publish_tennicam)
    stopping = []
    for sig in (signal.SIGINT, signal.SIGTERM):  # stop; once run returns, leave without the slow teardown
        signal.signal(sig, lambda *_: (stopping.append(1), exit_at_once_when_done(0)))
    ready = {"rt2": service.address, "tennicam": service.publisher.addresses.get("tennicam"), "tracker": prof.tracker,
             "rate_hz": prof.rate_hz, "latency_ms": prof.latency_s * 1e3, "seed": args.seed}
    print(json.dumps(ready) if args.ready_json else f"rt2 play observe: publishing {prof.tracker} observations on "
          f"{service.address} (Ctrl-C to stop)", flush=True)
    try:
        stats = service.run(stop=lambda: bool(stopping))
    finally:
        service.close()
    if not args.ready_json:
        print(f"published {stats['published']} observations of {stats['balls']} balls")
    return 0


def _title(args) -> str:
    return (f"rt2 play {args.mode}: {args.arm.name}, {args.balls} balls, seed {args.seed}, {args.source} observations "
            f"({datetime.date.today().isoformat()})")


def _print(rows, args) -> None:
    what = f"profiles {args.profiles}" if args.source == "synthetic" else f"scene {args.scene}"
    print(f"rt2 play {args.mode}  robot {args.arm.name}  source {args.source} ({what})  balls {args.balls}  seed {args.seed}")
    print(f"{'tracker':<10} {'filter':<14} {'Hz':>5} {'success':>9} {'rate':>6} {'95% CI (Wilson)':>17}  outcomes")
    for r in rows:
        outcomes = ", ".join(f"{k} {v}" for k, v in sorted(r["outcomes"].items(), key=lambda kv: -kv[1]))
        print(f"{r['tracker']:<10} {r['filter']:<14} {r['rate_hz']:>5.0f} {r['successes']:>4}/{r['balls']:<4} "
              f"{100 * r['success_rate']:>5.1f}% [{100 * r['ci_low']:5.1f}, {100 * r['ci_high']:5.1f}] %  {outcomes}")
