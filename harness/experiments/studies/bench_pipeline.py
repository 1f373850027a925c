"""``rt2 bench pipeline``: frame sets per second and latency of the whole tracker, 4 VGA cameras.

What is timed: :meth:`tracker.Tracker.process` only, from entry to return (its ``latency_s``, taken
with ``time.perf_counter``), on frame sets rendered *before* timing starts: balls flying through the
lab4_vga workspace at 200 Hz (toward the robot, bouncing on the table), with the data-set
distractors (a person, the robot arm, orange / white / yellow objects; ``harness.sim.render.scenes``).

Rows (one process, passes interleaved round-robin so that load changes hit every row alike):

* ``rt2 / full`` — ROI off: every camera's full frame every time (the detector, ``method="ours"``);
* ``rt2 / roi`` — ROI on: a window around the predicted ball pixel once the ball is tracked (the
  first frame of each flight, and frames after a lost ball, are full-frame searches);
* ``rt2-paper / full`` — the paper's system (Algorithm 1 argmax + Algorithm 2), full frame;
* ``rtblob / full`` — the RTBlob baseline (colour likelihood + disk correlation, fixed pairs);

each rt2 kind for every ``--workers`` value (with more than one worker also ``rt2 / roi`` with
``threads_for_roi``: windows on the threads too). ``framesets_per_s`` = frame sets / wall time of the
passes (back to back, one frame set after the other); ``p50_ms`` / ``p99_ms`` = percentiles of the
per-frame-set latency. ``ok_fraction`` and ``median_error_m`` (against the rendered truth) check that
the timed tracker actually tracks the ball. Goals: >= 250 frame sets/s and p99 <= 5 ms on
full frames, >= 1000 frame sets/s with ROI.
"""

from __future__ import annotations

import sys
import time

import numpy as np

__all__ = ["GOALS", "add_arguments", "bench", "run", "tracking_sequence"]

#: mode -> (min frame sets/s, max p99 ms): the per-frame path's speed goals (docs/pipeline.md)
GOALS = {"full": (250.0, 5.0), "roi": (1000.0, None)}
_G = np.array([0.0, 0.0, -9.81])


def tracking_sequence(seed: int, n_frames: int, *, rate_hz: float = 200.0, workspace_m=None):
    """Scenes of balls flying through the workspace toward the robot, one per frame.

    seed : all randomness; n_frames : frames; rate_hz : frame rate
    workspace_m : (2, 3) [min, max] box the flights cross (default ``harness.sim.lab.LAB4_WORKSPACE_M``)
    returns ``t_s (n,)``, list of :class:`harness.sim.render.Scene` (ball centre at mid-exposure),
        ``X_true_m (n, 3)`` ball centres, world frame, and ``flight (n,)`` int flight number.
    Each flight starts at the far (x max) side of the box with new distractors (a random data-set
    scene without its ball) and ends when the ball leaves the box; the ball bounces on the table.
    """
    from harness.sim import lab
    from harness.sim.render import Ball, Scene
    from harness.sim.render.scenes import SceneOptions, random_scene

    box = np.asarray(lab.LAB4_WORKSPACE_M if workspace_m is None else workspace_m, float)
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    z_table = lab.TABLE_TOP_Z_M + lab.BALL_RADIUS_M
    scenes, X_true, flight = [], np.empty((n_frames, 3)), np.empty(n_frames, int)
    f, k = 0, -1
    while f < n_frames:
        k += 1
        static = random_scene(rng, box, SceneOptions(p_no_ball=1.0), frame_index=0)
        X = np.array([box[1, 0] - 0.05, rng.uniform(-0.6, 0.6), rng.uniform(1.0, 1.5)])
        v = np.array([rng.uniform(-7.0, -3.5), rng.uniform(-0.6, 0.6), rng.uniform(-1.0, 1.0)])
        while f < n_frames and (box[0] <= X).all() and (X <= box[1]).all():
            ball = Ball(X.copy(), v.copy(), "orange")
            scenes.append(Scene(balls=(ball,), capsules=static.capsules, spheres=static.spheres, disks=static.disks,
                                boxes=static.boxes, exposure=static.exposure, frame_index=f))  # fmt: skip
            X_true[f], flight[f] = X, k
            f += 1
            X = X + v * dt + 0.5 * _G * dt * dt  # ballistic step
            v = v + _G * dt
            on_table = abs(X[0]) <= lab.TABLE_HALF_LENGTH_M and abs(X[1]) <= lab.TABLE_HALF_WIDTH_M
            if on_table and X[2] < z_table and v[2] < 0:  # bounce: mirror, lose 10 % of the normal speed
                X[2] = 2 * z_table - X[2]
                v[2] = -0.9 * v[2]
    return np.arange(n_frames) * dt, scenes, X_true, flight


#: RTBlob colour variants, uncalibrated (the speed is the point here: the work per frame does not
#: depend on the colour settings): the published-style RGB distance (default options), and the
#: brightness-invariant chromaticity (docs/rtblob.md). Neither is tuned to the rig's small, dark
#: ball; the experiments calibrate RTBlob per rig first (harness/experiments/play/rtblob_setup.py).
RTBLOB_VARIANTS = {"rgb": {}, "chromaticity": dict(colour_space="chromaticity", colour_sigma=0.08)}


def _configs(workers_list):
    """(tracker kind, mode, workers, variant) of every row."""
    out = []
    for w in workers_list:
        out += [("rt2", "full", w, ""), ("rt2", "roi", w, ""), ("rt2-paper", "full", w, "")]
        if w > 1:
            out.append(("rt2", "roi", w, "threads_for_roi"))
    out += [("rtblob", "full", 1, v) for v in RTBLOB_VARIANTS]
    return out


def bench(rig, model, framesets, X_true, flight, *, workers_list=(1, 2), repeats: int = 3, warmup: int = 20, progress: bool = True) -> list[dict]:
    """Rows (dicts): tracker, mode, workers, variant (RTBlob colour, or ``threads_for_roi``), framesets_per_s, p50_ms, p99_ms, ok_fraction,
    median_error_m, roi_fraction, retries_per_frame, cpu_per_wall (process CPU time / wall time
    during the passes: about 1 per busy thread on an idle machine, less when other jobs take the cores),
    cpu_ms_per_set (process CPU time per frame set: what one frame set costs, whatever the load). Flights restart the tracker (``reset``)."""
    from harness.common.progress import progress_bar

    from tracker import RTBlobOptions, Status, make_tracker

    configs = _configs(workers_list)
    trackers = {}
    for c in configs:
        kind, mode, w, variant = c
        if kind == "rtblob":
            kw = dict(rtblob_options=RTBlobOptions(**RTBLOB_VARIANTS[variant]))
        else:
            kw = dict(model=model, roi=(mode == "roi"), workers=w, threads_for_roi=variant == "threads_for_roi")
        trackers[c] = make_tracker(kind, rig, **kw)
    starts = np.flatnonzero(np.diff(flight, prepend=-1) != 0)
    for trk in trackers.values():  # warm-up: JIT, caches, thread start
        for fs in framesets[:warmup]:
            trk.process(fs)
        trk.reset(clear_stats=True)
    n = len(framesets)
    lat = {c: [] for c in configs}
    wall = {c: 0.0 for c in configs}
    cpu = {c: 0.0 for c in configs}
    err = {c: [] for c in configs}
    ok = {c: 0 for c in configs}
    bar = progress_bar(total=repeats * len(configs), desc="bench pipeline", file=sys.stderr, disable=not progress)
    for _ in range(repeats):
        for c in configs:
            trk = trackers[c]
            trk.reset(clear_stats=False)
            lat_c = np.empty(n)
            new_flight = np.zeros(n, bool)
            new_flight[starts] = True
            t0, c0 = time.perf_counter(), time.process_time()
            for i, fs in enumerate(framesets):
                if new_flight[i]:
                    trk.reset()
                obs = trk.process(fs)
                lat_c[i] = obs.latency_s
                if obs.position_m is not None:
                    err[c].append(float(np.linalg.norm(obs.position_m - X_true[i])))
                ok[c] += obs.status is Status.OK
            wall[c] += time.perf_counter() - t0
            cpu[c] += time.process_time() - c0
            lat[c].append(lat_c)
            bar.update()
    bar.close()
    rows = []
    for c in configs:
        kind, mode, w, variant = c
        trk = trackers[c]
        L = np.concatenate(lat[c]) * 1e3
        st = trk.stats
        searches = st.roi_searches + st.full_frame_searches
        rows.append(dict(
            tracker=kind, mode=mode, workers=w, variant=variant,
            framesets_per_s=repeats * n / wall[c],
            p50_ms=float(np.percentile(L, 50)), p99_ms=float(np.percentile(L, 99)),
            ok_fraction=ok[c] / (repeats * n),
            median_error_m=float(np.median(err[c])) if err[c] else None,
            roi_fraction=st.roi_searches / searches if searches else 0.0,
            retries_per_frame=st.full_frame_retries / st.frames if st.frames else 0.0,
            cpu_per_wall=cpu[c] / wall[c],
            cpu_ms_per_set=1e3 * cpu[c] / (repeats * n),
        ))  # fmt: skip
        trk.close()
    return rows


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="lab4_vga", help="rig name or file (default lab4_vga: 4 VGA ceiling cameras)")
    parser.add_argument("--model", default=None, help="segmentation model .npz (default: data/models/ball_seg_default.npz)")
    parser.add_argument("--frames", type=int, default=300, help="frame sets rendered before timing (about 3.7 MB each)")
    parser.add_argument("--repeats", type=int, default=3, help="timed passes over the frame sets per row")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="detector threads to measure (default: 1 2)")
    parser.add_argument("--cv-threads", type=int, default=1, help="OpenCV's own threads (cv2.setNumThreads; default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the flights, distractors and sensor noise")
    parser.add_argument("--json", default=None, help="also write the rows as JSON to this path")


def run(args) -> int:
    import cv2
    from harness.common.progress import progress_bar

    from harness.common.outputs import atomic_write_json, check_output_file
    from harness.sim.render import Renderer

    check_output_file(args.json, "--json")  # before the benchmark, not after
    from tracker.rig_files import resolve_rig
    from tracker import FrameSet
    from tracker.pipeline import load_model

    if args.frames < 30:
        raise ValueError(f"--frames must be >= 30, got {args.frames}")
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    if any(w < 1 for w in args.workers):
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.cv_threads < 0:
        raise ValueError(f"--cv-threads must be >= 0, got {args.cv_threads}")
    model = load_model(args.model)
    rig = resolve_rig(args.rig)
    cv2.setNumThreads(args.cv_threads)
    t_s, scenes, X_true, flight = tracking_sequence(args.seed, args.frames)
    renderer = Renderer(rig, seed=args.seed)
    framesets = [
        FrameSet(float(t), tuple(renderer.render(s)), i)
        for i, (t, s) in enumerate(progress_bar(list(zip(t_s, scenes)), desc="render frame sets", file=sys.stderr))
    ]
    rows = bench(rig, model, framesets, X_true, flight, workers_list=args.workers, repeats=args.repeats)
    for r in rows:
        r["cv_threads"] = args.cv_threads
    base = next(r for r in rows if r["tracker"] == "rtblob" and r["variant"] == "rgb")["framesets_per_s"]
    W, H = rig[0].image_size
    print(f"tracker pipeline, {len(rig)} cameras {W}x{H} ({args.rig}), {args.frames} frame sets x {args.repeats} passes, "
          f"{int(flight.max()) + 1} flights, OpenCV threads {args.cv_threads}")  # fmt: skip
    print(f"{'tracker':<22} {'mode':<5} {'workers':>7} {'sets/s':>8} {'p50 ms':>7} {'p99 ms':>7} {'/rtblob':>8} {'ok %':>6} {'med err cm':>10} {'roi %':>6} {'cpu/wall':>8} {'cpu ms/set':>10}")
    for r in rows:
        e = "-" if r["median_error_m"] is None else f"{100 * r['median_error_m']:.2f}"
        name = r["tracker"] + (f" ({r['variant']})" if r["variant"] else "")
        print(f"{name:<22} {r['mode']:<5} {r['workers']:>7} {r['framesets_per_s']:8.0f} {r['p50_ms']:7.2f} {r['p99_ms']:7.2f} "
              f"{r['framesets_per_s'] / base:7.2f}x {100 * r['ok_fraction']:6.1f} {e:>10} {100 * r['roi_fraction']:6.1f} {r['cpu_per_wall']:8.2f} {r['cpu_ms_per_set']:10.2f}")  # fmt: skip
    print("/rtblob: frame sets/s relative to rtblob (rgb), the published colour model, same process; "
          "cpu/wall: CPU time of this process per wall second (< 1 per thread: other jobs took the cores); "
          "cpu ms/set: CPU time per frame set (with one worker, 1000 / it = frame sets/s on an idle core)")
    for r in rows:
        if r["tracker"] != "rt2" or r["variant"]:
            continue
        min_rate, max_p99 = GOALS[r["mode"]]
        met = r["framesets_per_s"] >= min_rate and (max_p99 is None or r["p99_ms"] <= max_p99)
        goal = f">= {min_rate:.0f} sets/s" + ("" if max_p99 is None else f", p99 <= {max_p99:g} ms")
        print(f"goal rt2 {r['mode']} workers={r['workers']}: {goal}: {'met' if met else 'NOT met'}")
    if args.json:
        atomic_write_json(args.json, rows, "--json")
    return 0
