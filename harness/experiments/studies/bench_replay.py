"""``rt2 bench replay``: how fast a recorded ``rt2 track`` session is re-tracked from its JPEG images, with the
images decoded in the tracker's thread (``--decode-workers 0``) or by a pool of decoding threads.

    rt2 bench replay                                   # make a 5 s session of the simulated lab, then measure
    rt2 bench replay --log out/track.mcap --workers 0,2 --json out/bench_replay.json

The session (unless ``--log`` names one, recorded with ``--log-images all``): the simulated lab's four VGA
cameras, ``--distinct`` pre-rendered frame sets looped (launcher flights, seeded), tracked by ``rt2`` and
logged exactly as ``rt2 track --log-images all`` logs them (:class:`harness.live.session_log.LiveLog`, JPEG),
the tracker waiting for the log's writer so that no image is dropped.

Per worker count it measures, in this process, medians of ``--repeats`` runs:

* **decode**: every image message of the log read and decoded (``SessionLogReader.messages(workers=)``);
* **re-track**: ``rt2 reevaluate LOG --from images`` as the command runs it
  (:func:`harness.live.reevaluate_track.reevaluate_track`): read, decode, track every frame set.

Frame sets per second of wall time, and the ratio to ``--workers``' first entry (the baseline, run in the same
process). The figures of every re-track must be those of the baseline, byte for byte (``same_figures``):
decoding ahead never changes what the tracker sees. The goal: re-tracking >= 200 frame sets/s (4 VGA
cameras at 200 Hz: faster than real time) on the 2-core machine.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

__all__ = ["GOAL_FRAMESETS_PER_S", "add_arguments", "bench_log", "make_track_log", "run"]

#: re-tracking 4 VGA cameras recorded at 200 Hz faster than real time
GOAL_FRAMESETS_PER_S = 200.0


def add_arguments(parser) -> None:
    parser.add_argument("--log", metavar="LOG.mcap", default=None,
                        help="an rt2 track session log recorded with --log-images all (default: make one of the simulated lab)")
    parser.add_argument("--framesets", type=int, default=1000, help="frame sets of the session made (default 1000: 5 s at 200 Hz)")
    parser.add_argument("--distinct", type=int, default=200, help="distinct rendered frame sets, looped (default 200)")
    parser.add_argument("--workers", default=None,
                        help="comma list of decoding threads to compare; the first is the baseline (default 0,<cores>)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per worker count; the median is reported (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated lab's flights and noise (default 0)")
    parser.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def make_track_log(path: Path, *, framesets: int, distinct: int, seed: int, rate_hz: float = 200.0) -> dict:
    """Record ``framesets`` frame sets of the simulated lab (``distinct`` pre-rendered ones, looped) tracked by
    rt2 into the ``rt2 track`` session log ``path`` (JPEG, every image); returns the service's summary."""
    from harness.live.assembly import AssemblyOptions, FrameSetAssembler
    from harness.live.service import ServiceOptions, TrackingService
    from harness.live.session_log import LiveLog
    from harness.live.sources import open_sources
    from tracker.rig_files import resolve_rig
    from tracker import Tracker

    rig = resolve_rig("lab4_vga")
    sources = open_sources(["sim"], rig, rate_hz=rate_hz, seed=seed, speed=None, prerender_s=distinct / rate_hz,
                           duration_s=framesets / rate_hz)
    with Tracker(rig, "rt2") as tracker:
        log = LiveLog(path, rig, tracker, source="sim (bench replay)", seed=seed, log_images="all", image_format="jpeg",
                      overwrite=True)
        service = TrackingService(rig, tracker, log=log, options=ServiceOptions(status_period_s=0, gc_freeze=False))
        with FrameSetAssembler(sources, AssemblyOptions(rate_hz=rate_hz, lossless=True)) as asm:
            while True:
                afs = asm.get(1.0)
                if afs is None:
                    if asm.finished:
                        break
                    continue
                service.step(afs)
                while log.bg.pending > 16:  # the JPEG encoder sets the pace: no image dropped
                    time.sleep(0.002)
        service.finish(source=asm)
    summary = service.summary()
    if summary["log"]["dropped"]:
        raise RuntimeError(f"the bench's session log dropped messages ({summary['log']['dropped']}); it cannot be re-tracked")
    return summary


def _decode(path: Path, workers: int) -> tuple[float, int]:
    from harness.logs import SessionLogReader

    with SessionLogReader(path) as reader:
        t0, n = time.perf_counter(), 0
        for _ in reader.messages(["/camera/*/image"], workers=workers):
            n += 1
        return time.perf_counter() - t0, n


def _retrack(path: Path, workers: int) -> tuple[float, dict]:
    from harness.live.reevaluate_track import reevaluate_track
    from harness.logs import SessionLogReader

    with SessionLogReader(path) as reader:
        t0 = time.perf_counter()
        figures = reevaluate_track(reader, source="images", decode_workers=workers)
        return time.perf_counter() - t0, figures


def bench_log(path: Path, workers: list[int], *, repeats: int, progress=None) -> list[dict]:
    """One row per worker count (module docstring); the first is the baseline of the ratios."""
    rows, base_figures = [], None
    for w in workers:
        dec, ret, same = [], [], True
        n_images = n_sets = 0
        for _ in range(repeats):
            dt, n_images = _decode(path, w)
            dec.append(dt)
            dt_re, figures = _retrack(path, w)
            ret.append(dt_re)
            n_sets = figures["frame_sets"]
            text = json.dumps(figures, sort_keys=True, default=str)
            base_figures = text if base_figures is None else base_figures
            same &= text == base_figures
            if progress is not None:
                progress(f"  workers {w}: decode {n_images / 4 / dt:.0f}, re-track {n_sets / dt_re:.0f} frame sets/s")
        rows.append({"decode_workers": w, "images": n_images, "frame_sets": n_sets,
                     "decode_framesets_per_s": n_images / 4 / statistics.median(dec),
                     "retrack_framesets_per_s": n_sets / statistics.median(ret),
                     "decode_runs_s": dec, "retrack_runs_s": ret, "same_figures": same})
    for r in rows:
        r["retrack_speed_up"] = r["retrack_framesets_per_s"] / rows[0]["retrack_framesets_per_s"]
        r["decode_speed_up"] = r["decode_framesets_per_s"] / rows[0]["decode_framesets_per_s"]
    return rows


def _workers(text: str | None) -> list[int]:
    from harness.logs.reader import MAX_DECODE_WORKERS

    if text is None:
        return [0, os.cpu_count() or 1]
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        out = []
    if not out or any(not 0 <= w <= MAX_DECODE_WORKERS for w in out):
        raise ValueError(f"--workers must be a comma list of whole numbers in [0, {MAX_DECODE_WORKERS}], got {text!r}")
    return out


def run(args) -> int:
    from harness.common.outputs import atomic_write_text, check_output_file

    workers = _workers(args.workers)
    if args.repeats < 1 or args.framesets < 1 or not 1 <= args.distinct <= 2000:
        raise ValueError(f"need --repeats >= 1, --framesets >= 1, --distinct in [1, 2000]; got {args.repeats}, "
                         f"{args.framesets}, {args.distinct}")
    if args.log is not None and not Path(args.log).is_file():
        raise FileNotFoundError(f"--log {args.log!r}: no such file")
    check_output_file(args.json, "--json")
    say = lambda line: print(line, flush=True)  # noqa: E731
    with tempfile.TemporaryDirectory(prefix="rt2-bench-replay-") as tmp:
        path = Path(args.log) if args.log else Path(tmp) / "track.mcap"
        if args.log is None:
            say(f"rt2 bench replay: recording {args.framesets} frame sets of the simulated lab (4 VGA cameras, JPEG) ...")
            make_track_log(path, framesets=args.framesets, distinct=args.distinct, seed=args.seed)
        size_mb = path.stat().st_size / 1e6
        load0 = os.getloadavg()[0]
        rows = bench_log(path, workers, repeats=args.repeats, progress=say)
        load1 = os.getloadavg()[0]
    print(f"re-tracking {path.name if args.log else 'the recorded session'} ({rows[0]['frame_sets']} frame sets, "
          f"{size_mb:.0f} MB), median of {args.repeats}; 1-min load average {load0:.1f} -> {load1:.1f} on "
          f"{os.cpu_count()} cores")
    print(f"{'workers':>8}{'decode fs/s':>13}{'x':>7}{'re-track fs/s':>15}{'x':>7}  same figures")
    for r in rows:
        print(f"{r['decode_workers']:>8d}{r['decode_framesets_per_s']:>13.1f}{r['decode_speed_up']:>7.2f}"
              f"{r['retrack_framesets_per_s']:>15.1f}{r['retrack_speed_up']:>7.2f}  {'yes' if r['same_figures'] else 'NO'}")
    best = max(r["retrack_framesets_per_s"] for r in rows)
    print(f"goal: re-tracking >= {GOAL_FRAMESETS_PER_S:g} frame sets/s: {'met' if best >= GOAL_FRAMESETS_PER_S else 'NOT met'} "
          f"(best {best:.0f}); x = ratio to {rows[0]['decode_workers']} workers in the same process")
    if args.json:
        doc = {"log": str(args.log) if args.log else None, "cpus": os.cpu_count(), "load_average_1min": [load0, load1],
               "repeats": args.repeats, "goal_framesets_per_s": GOAL_FRAMESETS_PER_S, "rows": rows}
        atomic_write_text(args.json, json.dumps(doc, indent=1) + "\n", "--json")
        print(f"wrote {args.json}")
    return 0 if all(r["same_figures"] for r in rows) else 1
