"""``rt2 play --live``: the command-line side of :mod:`harness.experiments.play.live` (docs/play.md, "Live").

Prints the result table of ``rt2 play`` plus the latency budget; ``--json`` gets the same row with
``"live": true`` and ``latency_ms``; the session log is ``<out>/play_live_<tracker>_<filter>_synthetic_s<seed>.mcap``.
A lost robot link ends the run with the balls finished so far (``"partial": true``), the log closed with
the reason, a one-line error and exit code 1; SIGINT / SIGTERM stop it the same way (exit 130 / 143).
"""

from __future__ import annotations

import signal

__all__ = ["run_live"]

LAG_WARN_MS = 50.0  #: a simulated lab further behind real time than this is reported under the table


def _budget_lines(budget: dict) -> list[str]:
    names = {"exposure_to_obs_ms": "camera exposure -> observation at the policy",
             "obs_to_command_ms": "observation -> command sent",
             "command_to_robot_ms": "command sent -> robot state under it here",
             "plan_step_ms": "(a planning step of the policy)",
             "first_plan_ms": "(  of which a ball's first plan)",
             "world_lag_ms": "(simulated lab behind real time, per ball)"}
    out = ["latency budget (ms)            p50     p95     max      n"]
    for key, label in names.items():
        b = budget[key]
        if b["n"]:
            out.append(f"  {label:<46} {b['p50']:7.1f} {b['p95']:7.1f} {b['max']:7.1f} {b['n']:6d}")
        else:
            out.append(f"  {label:<46} {'-':>7} {'-':>7} {'-':>7} {0:6d}")
    return out


def run_live(args, config, open_log, print_rows) -> int:
    """open_log, print_rows : `rt2 play`'s session-log opener and result-table printer (the same as in process)."""
    from harness.common.fast_exit import exit_at_once_when_done
    from harness.common.outputs import atomic_write_json
    from harness.experiments.play.experiment import summarise
    from harness.experiments.play.live import LiveRun, latency_budget, play_live, play_live_local, prepare_policy
    from harness.experiments.play.log import write_ball
    from harness.link.client import LinkLostError, WamClient
    from policies.hitting import HittingOptions
    from policies.promp import ProMP
    from harness.sim.robot.arms import is_link_address

    kin = args.arm.kin  # the WAM: `rt2 play` checked that --live has no other arm
    promp = ProMP.load(args.promp, robot_id=str(kin.model.name), joint_names=kin.joint_names)
    player = prepare_policy(kin, promp, config.filter, HittingOptions(**config.policy))  # before any process or link
    log, path = open_log(args, config) if not args.no_log else (None, None)
    stop_signal: list[int] = []
    def on_signal(s, _frame):  # stop after this ball; once run_live returns, leave without the slow teardown
        stop_signal.append(s)
        exit_at_once_when_done(128 + stop_signal[0])

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    run, error, connected = LiveRun(), None, []

    def on_ball(i, result, record, serve):
        if log is not None:
            write_ball(log, i, config.tracker, result, record, serve)
        if not args.quiet:
            print(f"ball {i}: {result.outcome}{' (' + result.reason + ')' if result.reason else ''}", flush=True)

    def run_policy(robot, tracker, world):
        nonlocal run
        with WamClient(robot, client_name="rt2 play --live", timeout_s=1.0, request_timeout_s=1.0) as wam:
            connected.append(robot)
            if log is not None:
                log.write_metadata("link", {"address": robot, "bridge_id": wam.bridge_id, "tracker_stream": tracker,
                                            "world_stream": world, "clock": wam.clock.estimate().to_dict()})
            run = play_live(wam, tracker, world, player=player, balls=args.balls,
                            plan_lead_s=None if args.plan_lead_ms is None else args.plan_lead_ms / 1e3,
                            on_ball=on_ball, stop=lambda: bool(stop_signal))
        return run

    try:
        if not is_link_address(args.robot):  # no address (or --robot wam): the simulated world and tracker here
            play_live_local(balls=args.balls, seed=args.seed, profile=config.resolved_profile(), run_policy=run_policy,
                            observe_args=["--profiles", args.profiles] + (
                                ["--profile-json", str(args.profile_json)] if args.profile_json else []),
                            stopping=lambda: bool(stop_signal))
        else:
            run_policy(args.robot, args.tracker_stream, args.world_stream)
    except LinkLostError as exc:
        if not connected:  # no robot there: a bad address, not a lost link
            if log is not None:
                log.close(error=str(exc))
            raise ValueError(f"no robot link: {exc}") from None
        run = getattr(exc, "run", run)
        error = f"robot link lost: {exc}"
    except BaseException as exc:
        if log is not None:
            log.close(error=f"{type(exc).__name__}: {exc}")
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if stop_signal and error is None:
        error = f"stopped by signal {stop_signal[0]}"
    results = run.results
    row = summarise(config, results, args.seed) if results else None
    if row is not None:
        row.update(live=True, latency_ms=latency_budget(run), refused_commands=run.refused,
                   warm_up_ms=round(run.warm_up_s * 1e3, 1), gc=run.gc)
        if error or len(results) < args.balls:
            row["partial"] = True
        if log is not None:
            log.write_figures("summary", row)
    if log is not None:
        log.close(error=error)
        if row is not None:
            row["log"] = str(path)
    if row is not None:
        print_rows([row], args)
        for line in _budget_lines(row["latency_ms"]):
            print(line)
        if row.get("gc"):
            g = row["gc"]
            print(f"  (garbage collector in the policy process: {sum(g['collections_per_generation'])} collections, "
                  f"longest pause {g['pause_max_ms']:.1f} ms)")
        lag = row["latency_ms"]["world_lag_ms"]
        if lag["n"] and lag["max"] > LAG_WARN_MS:
            print(f"note: the simulated lab fell up to {lag['max'] / 1e3:.2f} s behind real time (the machine is short of "
                  f"CPU): the balls were played late and these figures say more about the machine than the policy")
    if args.json and row is not None:
        atomic_write_json(args.json, [row], "--json")
    if path is not None:
        print(f"session log: {path}")
    if error:
        print(f"rt2 play --live: {error} ({len(results)} of {args.balls} balls finished)", flush=True)
        return 128 + stop_signal[0] if stop_signal else 1
    return 0
