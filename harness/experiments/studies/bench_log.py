"""``rt2 bench log``: session-log write and read throughput for a 4-camera VGA session at 200 Hz.

Per image format (jpeg, png, raw+lz4, and ``none`` = state only) it writes a synthetic session
(:mod:`harness.logs.synthetic`: camera-like frames with sensor noise, detections, two trackers,
ground truth, arm transforms and scene) with the synchronous writer on one thread
(``cv2.setNumThreads(1)``), reads it back decoding every message, and then replays it in real time
through :class:`~harness.logs.BackgroundLogWriter` to count what a live loop would drop. Medians of
``--repeats`` runs; the machine's load makes single runs noisy.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

__all__ = ["add_arguments", "run", "bench_format"]

FORMATS = ("jpeg", "png", "raw", "none")


def add_arguments(parser) -> None:
    parser.add_argument("--seconds", type=float, default=2.0, help="session length to write per run (default 2 s)")
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--rate-hz", type=float, default=200.0, help="frame sets per second of the session")
    parser.add_argument("--size", default="640x480", help="image size WxH (default VGA)")
    parser.add_argument("--formats", default=",".join(FORMATS), help=f"comma list from {FORMATS}")
    parser.add_argument("--repeats", type=int, default=3, help="runs per format; the median is reported")
    parser.add_argument("--live-seconds", type=float, default=None,
                        help="real-time replay through the background writer (default = --seconds; 0 = skip)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="PATH", help="also write the results as a JSON list to PATH ('-' = stdout)")
    parser.add_argument("--keep", metavar="DIR", help="keep the written logs in DIR (default: a deleted temp dir)")


def _write(path: Path, session, fmt: str, seed: int):
    from harness.logs import SessionLogWriter
    from harness.logs.synthetic import write_session

    t0, c0 = time.perf_counter(), time.process_time()
    with SessionLogWriter(path, metadata={"kind": "bench-log", "seed": seed}, overwrite=True,
                          image_format="jpeg" if fmt == "none" else fmt, log_images="none" if fmt == "none" else "all") as w:
        write_session(w, session, images=fmt != "none")
    return time.perf_counter() - t0, time.process_time() - c0


def _read(path: Path) -> tuple[float, int]:
    from harness.logs import SessionLogReader

    t0 = time.perf_counter()
    n = 0
    with SessionLogReader(path) as r:
        for _ in r.messages():
            n += 1
    return time.perf_counter() - t0, n


def _live(path: Path, session, fmt: str, seconds: float, seed: int) -> dict:
    """Replay ``seconds`` of the session at its real rate through the background writer; count drops."""
    from harness.logs import BackgroundLogWriter, SessionLogWriter
    from harness.logs.synthetic import write_session

    n = min(session.n_framesets, int(round(seconds * session.rate_hz)))
    clock = _PacedSlice(session, n)
    w = SessionLogWriter(path, metadata={"kind": "bench-log-live", "seed": seed}, overwrite=True,
                         image_format="jpeg" if fmt == "none" else fmt, log_images="none" if fmt == "none" else "all")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # drops are counted below
        bg = BackgroundLogWriter(w)
        t0 = time.perf_counter()
        write_session(_Paced(bg, clock), clock.session, images=fmt != "none")
        t_loop = time.perf_counter() - t0
        bg.close()
    t_total = time.perf_counter() - t0
    sub, drop = bg.submitted, bg.dropped
    n_img = sub.get("image", 0)
    return {"live_framesets": n, "live_loop_s": t_loop, "live_drain_s": t_total - t_loop,
            "live_dropped_images": drop.get("image", 0), "live_dropped_image_fraction": drop.get("image", 0) / n_img if n_img else 0.0,
            "live_dropped_state": sum(v for k, v in drop.items() if k != "image"), "live_max_late_ms": clock.max_late_s * 1e3}


class _PacedSlice:
    """The first ``n`` frame sets of a session, and the wall clock they are due at."""

    def __init__(self, session, n: int):
        from dataclasses import replace

        s = session
        self.session = replace(s, t_s=s.t_s[:n], ball_m=s.ball_m[:n], q=s.q[:n], qdot=s.qdot[:n], q_cmd=s.q_cmd[:n],
                               links_T=s.links_T[:n], tf_T=s.tf_T[:n], uv_px=s.uv_px[:n], scores=s.scores[:n],
                               observations=s.observations[:n])
        self.start = None
        self.max_late_s = 0.0

    def wait(self, t_s: float) -> None:
        now = time.perf_counter()
        if self.start is None:
            self.start = now - t_s
        due = self.start + t_s
        if due > now:
            time.sleep(due - now)
        else:
            self.max_late_s = max(self.max_late_s, now - due)


class _Paced:
    """Forwards to a writer; the first call of each frame set waits for its wall-clock time (a 200 Hz camera)."""

    def __init__(self, writer, clock: _PacedSlice):
        self._w, self._clock, self._last = writer, clock, None

    def __getattr__(self, name):
        fn = getattr(self._w, name)

        def call(t_s, *args, **kwargs):
            if t_s != self._last:
                self._clock.wait(t_s)
                self._last = t_s
            return fn(t_s, *args, **kwargs)

        return call


def bench_format(fmt: str, session, folder: Path, *, repeats: int, live_seconds: float, seed: int, keep: bool = False,
                 progress=None) -> dict:
    """One result row (see the module doc) for image format ``fmt``; logs are written to ``folder``."""
    path = folder / f"bench_{fmt}.mcap"
    writes, reads, cpu = [], [], []
    for _ in range(repeats):
        wall, cpu_s = _write(path, session, fmt, seed)
        writes.append(wall)
        cpu.append(cpu_s)
        size = path.stat().st_size
        dt, n_msgs = _read(path)
        reads.append(dt)
        if progress is not None:
            progress.update(1)
    n = session.n_framesets
    row = {
        "image_format": fmt if fmt != "raw" else "raw+lz4",
        "write_framesets_per_s": n / statistics.median(writes),
        "read_framesets_per_s": n / statistics.median(reads),
        "write_framesets_per_cpu_s": n / statistics.median(cpu),  # one thread: frame sets per second of one core
        "mb_per_s": size / 1e6 / statistics.median(writes),
        "file_mb": size / 1e6,
        "mb_per_session_s": size / 1e6 / (n / session.rate_hz),
        "messages": n_msgs,
        "write_runs_s": writes,
        "read_runs_s": reads,
    }
    row["keeps_up"] = row["write_framesets_per_s"] >= session.rate_hz
    row["keeps_up_on_a_free_core"] = row["write_framesets_per_cpu_s"] >= session.rate_hz
    if live_seconds > 0:
        row.update(_live(folder / f"live_{fmt}.mcap", session, fmt, live_seconds, seed))
    if not keep:
        for p in folder.glob(f"*_{fmt}.mcap"):
            p.unlink()
    return row


def run(args) -> int:
    import cv2
    from harness.common.progress import progress_bar

    from harness.common.outputs import atomic_write_text, check_output_file

    if args.json != "-":
        check_output_file(args.json, "--json")  # before the benchmark, not after
    from harness.logs.synthetic import make_session

    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ValueError(f"--formats: unknown {bad or formats}; valid: {list(FORMATS)}")
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must be WxH such as 640x480, got {args.size!r}") from None
    if args.seconds <= 0 or args.repeats < 1 or args.cameras < 1 or args.rate_hz <= 0:
        raise ValueError("--seconds, --rate-hz must be > 0 and --repeats, --cameras >= 1")
    live = args.seconds if args.live_seconds is None else args.live_seconds
    session = make_session(args.seconds, rate_hz=args.rate_hz, n_cameras=args.cameras, image_size=(w, h), seed=args.seed)
    rows = []
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core for the encoder, as in the live pipeline's logging thread
    try:
        with tempfile.TemporaryDirectory(prefix="rt2-bench-log-") as tmp:
            folder = Path(args.keep) if args.keep else Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            with progress_bar(total=len(formats) * args.repeats, desc="bench log", file=sys.stderr) as bar:
                for fmt in formats:
                    rows.append(bench_format(fmt, session, folder, repeats=args.repeats, live_seconds=live, seed=args.seed,
                                             keep=bool(args.keep), progress=bar))
    finally:
        cv2.setNumThreads(threads)
    print(f"session log, {args.cameras} cameras {w}x{h} at {args.rate_hz:g} Hz, {session.n_framesets} frame sets "
          f"({args.seconds:g} s), median of {args.repeats}; one encoder thread; machine load "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    head = (f"{'format':<8} {'write fs/s':>10} {'fs/cpu-s':>9} {'read fs/s':>10} {'write MB/s':>10} {'MB per s':>9} "
            f"{'keeps up':>8}")
    if live > 0:
        head += f" {'live drops':>10}"
    print(head)
    for r in rows:
        line = (f"{r['image_format']:<8} {r['write_framesets_per_s']:>10.0f} {r['write_framesets_per_cpu_s']:>9.0f} "
                f"{r['read_framesets_per_s']:>10.0f} "
                f"{r['mb_per_s']:>10.1f} {r['mb_per_session_s']:>9.1f} {('yes' if r['keeps_up'] else 'no'):>8}")
        if live > 0:
            line += f" {100 * r['live_dropped_image_fraction']:>9.1f}%"
        print(line)
    print("write fs/s: wall clock; fs/cpu-s: frame sets per CPU second of the writing thread (what one free core "
          "would do); MB per s: file size per second of session")
    if live > 0:
        print("live drops: share of images the background writer dropped while a loop fed it in real time "
              "(state messages dropped: " + ", ".join(f"{r['image_format']} {r['live_dropped_state']}" for r in rows) + ")")
    if args.json:
        text = json.dumps(rows, indent=2)
        if args.json == "-":
            print(text)
        else:
            atomic_write_text(args.json, text + "\n", "--json")
    return 0
