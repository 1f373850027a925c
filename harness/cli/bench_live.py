"""``rt2 bench live``: end-to-end latency and sustained rate of ``rt2 track``, measured by a subscriber
in another process.

    rt2 bench live --source sim --duration 20 --json out/bench_live.json
    rt2 bench live --rigs lab4_vga lab8_vga lab9_ace --modes roi --json out/bench_rigs.json   # a row per rig and mode
    rt2 bench live --source replay out/track.mcap --modes roi --json out/bench_live_replay.json

Parses the options and prints the table, the goals and the JSON; the measurement (the service per mode,
the subscriber process, the figures, the goals) is :mod:`harness.live.bench`'s.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from harness.cli.track import add_source_arguments, flag_errors, lab_truth_scene, track_config
from harness.live.bench import ACQUIRED_WITHIN_M, GOALS, bench_live, check_options
from tracker.rig_files import resolve_rig
from harness.live.stats import format_budget

__all__ = ["GOALS", "add_arguments", "format_table", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_source_arguments(parser)
    parser.add_argument("--duration", type=float, default=15.0, metavar="S", help="seconds per mode, warm-up included (default 15)")
    parser.add_argument("--warmup", type=float, default=3.0, metavar="S", help="seconds left out at the start of each mode (default 3)")
    parser.add_argument("--modes", default="roi,full", help="comma-separated: roi (rt2 as it runs), full (full-frame search); default both")
    parser.add_argument("--rigs", nargs="+", default=None, metavar="RIG",
                        help="measure each of these rigs in turn on the same scene (names in data/rigs or files), one table "
                             "row per rig and mode (default: --rig alone)")
    parser.add_argument("--json", metavar="PATH", help="write the figures as JSON (with --rigs: {\"rigs\": [one document per rig]})")


def run(args) -> int:
    modes = check_options(args)
    if args.json and Path(args.json).is_dir():
        raise ValueError(f"--json {args.json!r} is a folder; give a file name")
    rigs = list(args.rigs) if args.rigs else [args.rig]
    for rig in rigs:
        resolve_rig(rig)  # every rig checked before the first is measured
    docs = []
    for rig in rigs:
        rig_args = argparse.Namespace(**{**vars(args), "rig": rig})
        config = track_config(rig_args)  # the service's options, checked once; each mode sets its streams and duration
        with flag_errors():
            docs.append(bench_live(rig_args, modes, config, progress=lambda line: print(line, flush=True),
                                   truth_scene=lab_truth_scene))
    print(format_table(docs, args))
    for doc in docs:
        goals, target = doc["goals_met"], doc["goals"]
        if goals is not None:
            print(f"goals ({doc['rig']}, roi at {target['rate_hz']:g} Hz): sustained {target['rate_hz']:g}/s "
                  f"{'met' if goals['rate'] else 'NOT met'}, p99 <= {target['p99_ms']:g} ms {'met' if goals['p99'] else 'NOT met'}"
                  + ("" if goals["max"] is None else f", max <= {target['max_ms']:g} ms {'met' if goals['max'] else 'NOT met'}")
                  + f", no drops by rt2 {'met' if goals['no_drops_by_rt2'] else 'NOT met'}")
        full = doc.get("full_goals_met")
        if full is not None:
            print(f"goals ({doc['rig']}, full frame, the 5x5 filter alone): sustained {doc['full_goals']['rate_hz']:g}/s "
                  f"{'met' if full['rate'] else 'NOT met'}, longest wait <= {doc['full_goals']['wait_periods']:g} period "
                  f"{'met' if full['wait'] else 'NOT met'}")
        for r in doc["modes"]:
            print("\n".join(format_budget(r["latency_budget_ms"], f"{doc['rig']}, mode {r['mode']}")))
    if args.json:
        from harness.logs.codecs import to_json_value

        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        out = docs[0] if not args.rigs else {"rigs": docs}
        Path(args.json).write_text(json.dumps(to_json_value(out, "live bench", lenient=True), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def format_table(docs: list, args) -> str:
    """One row per rig and mode of ``docs`` (:func:`harness.live.bench.bench_live`'s documents)."""
    head = (f"{'rig':<10}{'cams':>5}{'mode':>6}{'sets/s':>9}{'p50 ms':>9}{'p90 ms':>9}{'p99 ms':>9}{'max ms':>9}{'<=10 ms':>9}{'tracker p50':>13}"
            f"{'dropped by rt2':>16}{'of which skipped':>18}{'waited max':>12}{'late (source)':>15}{'cpu ms/set':>12}{'faults/set':>12}"
            f"{'ok':>8}{'3D err mm':>11}{'new ball: sets p50/max':>24}")
    lines = [f"end-to-end latency: first frame's arrival -> message at a subscriber in another process "
             f"({args.rate_hz:g} Hz requested, 1-min load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)", head]
    for doc, r in ((doc, r) for doc in docs for r in doc["modes"]):
        lat, err = r["latency_ms"], r["error_3d_mm"]
        lines.append(f"{Path(str(doc['rig'])).stem:<10}{doc['cameras']:>5}{r['mode']:>6}{r['rate_hz']:>9.1f}{lat['p50']:>9.2f}{lat['p90']:>9.2f}{lat['p99']:>9.2f}{lat['max']:>9.1f}"
                     f"{100 * r['share_within_10ms']:>8.1f}%"
                     f"{r['tracker_ms']['p50']:>13.2f}{r['dropped_by_rt2_total']:>16d}{r['skipped_framesets']:>18d}"
                     f"{r['backlog_wait_periods'].get('max', float('nan')):>8.2f} per"
                     f"{sum(r['by_the_source']['late_frames_per_camera']):>15d}"
                     f"{r['process_per_set']['cpu_ms']:>12.2f}{r['process_per_set']['page_faults']:>12.1f}"
                     f"{100 * r['ok_share']:>7.1f}%{'-' if err is None else format(err['median'], '.1f'):>11}{_acquired(r.get('acquisition')):>24}")
    lines.append(f"(skipped: frame sets the tracker could not take before --max-backlog newer ones came; waited max: the "
                 f"longest a tracked set waited for the tracker, in frame periods; cpu ms/set, faults/set: the service "
                 f"process's CPU time and page faults per published set, whatever the load; ok: share of the measured sets "
                 f"with status ok; 3D err: median distance of the ok positions from the sim scene's ball; new ball: frame sets "
                 f"from a new ball's first to its first ok position within {100 * ACQUIRED_WITHIN_M:g} cm, median / longest, and how "
                 f"many of the new balls were acquired)")
    return "\n".join(lines)


def _acquired(acq) -> str:
    if not acq:
        return "-"
    if not acq["acquired"]:
        return f"none of {acq['new_balls']}"
    return f"{acq['frame_sets_p50']:g} / {acq['frame_sets_max']:g} ({acq['acquired']}/{acq['new_balls']})"

