"""The accuracy experiment end to end (paper Sec. 3.2): robot, frames, trackers, registration, figures, log.

    result = run_accuracy(AccuracyConfig(seed=0, n_frames=600), "out/accuracy", workers=2)
    result.rows        # the --json list: one dict per tracker (mean_cm, ..., frac_missing)
    result.figures     # everything measured (registration, error bands, faults); no timing in it

Steps: simulate the WAM along a seeded trajectory (:mod:`.motion`); per frame set render the four
cameras and run every tracker on the same images (:mod:`.frames`, in worker processes by segment);
register the robot base to the camera world on the first ``register_fraction`` of the run and score the
rest (:mod:`.evaluate`); write the histogram (PNG, PDF), ``accuracy.json`` (the ``--json`` list),
``summary.json`` (figures + timing) and the session log ``session.mcap`` into the output folder.

Segments run on :mod:`harness.common.executor` (this process, local worker processes, or Ray). Stopped early
(SIGINT, SIGTERM, a lost worker): the frames that finished are scored (when enough of them register the
robot), the outputs are written with ``"partial"`` (rows) and ``partial`` (summary.json: why, frames done),
the session log is closed with the reason, and :attr:`AccuracyResult.partial` says so.
"""

from __future__ import annotations

import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.experiments.accuracy.config import DEFAULT_LOG_IMAGES, AccuracyConfig
from harness.experiments.accuracy.evaluate import TrackRecord, evaluate
from harness.experiments.accuracy.figure import plot_histogram
from harness.experiments.accuracy.frames import FrameProducer, calibrate, init_worker, run_segment
from harness.experiments.accuracy.motion import simulate_motion
from harness.experiments.accuracy.registration import register_rigid
from harness.experiments.accuracy.session_scene import SessionScene
from harness.experiments.accuracy.rig_error import estimated_rig
from harness.experiments.accuracy.accuracy_log import AccuracyLogWriter
from harness.experiments.accuracy.stats import check_goals
from harness.common.executor import Executor, SweepOptions, SweepStopped, in_task_order
from harness.logs import check_log_images
from harness.common.outputs import atomic_write_json, check_output_dir
from tracker.rig_files import resolve_rig
from harness.sim.robot import SimWamOptions
from robot_models import ArmKinematics, load_robot_config

__all__ = ["AccuracyResult", "run_accuracy", "write_outputs"]

#: below this many frames between logged images, workers would ship too many images: run in one process
_MIN_LOG_EVERY_FOR_WORKERS = 10


@dataclass
class AccuracyResult:
    """What :func:`run_accuracy` measured and wrote.

    rows : the ``--json`` list; figures : every figure (JSON-able, no timing); errors : {tracker: (n_scored,)
    metres, NaN = no position}; timing : wall time, frame rate, tracker latencies; paths : {what: Path}
    calibration_error : what the trackers' rig error is (:func:`harness.experiments.accuracy.rig_error.estimated_rig`'s info)
    scene_events : the distractor episodes during the run (:meth:`harness.experiments.accuracy.distractors.DistractorSchedule.summary`)
    """

    config: AccuracyConfig
    rows: list
    figures: dict
    errors: dict
    timing: dict
    motion_info: dict
    tracker_stats: dict
    scene_events: dict = field(default_factory=dict)
    rtblob_calibration: dict | None = None
    calibration_error: dict = field(default_factory=dict)
    truth: dict = field(default_factory=dict)
    paths: dict = field(default_factory=dict)
    partial: dict | None = None  #: stopped early: {"reason", "frames_done", "exit_code"}; None = complete


def _robot(config):
    cfg = load_robot_config(config.robot)
    kin = ArmKinematics.from_config(cfg)
    sim = SimWamOptions.from_mapping(dict(cfg.simulator), where=f"{cfg.where}: simulator", n_joints=kin.n_joints)
    return kin, sim


def _check_model(config) -> None:
    if any(k != "rtblob" for k in config.trackers) and not config.model_path().is_file():
        raise FileNotFoundError(f"segmentation model {str(config.model_path())!r} not found; train one with "
                                "`rt2 train` or pass --model PATH")


def run_accuracy(config: AccuracyConfig, out_dir, *, workers: int = 1, log: bool = True,
                 log_images=DEFAULT_LOG_IMAGES, image_format: str = "png", log_flush_s: float = 1.0,
                 progress: bool = True, sweep: SweepOptions | None = None, motion_source=None) -> AccuracyResult:
    """Run the experiment (see the module docstring); outputs go to ``out_dir`` (created, files replaced).

    workers : processes rendering and tracking segments (1 = this process); sweep : where the segments run
    (overrides ``workers``; e.g. Ray); log : write ``session.mcap`` with images every ``log_images`` frame
    sets ("all", "none", N) in ``image_format``, flushed at least every ``log_flush_s`` seconds;
    progress : a tqdm bar on stderr. Stopped early: see the module docstring; if too few frames finished to
    register the robot, raises ValueError after closing the log (no figures to write).
    motion_source : None = the simulated WAM in this process; else a callable ``(kin, config) -> RobotMotion``,
    e.g. the robot over the robot link (``rt2 accuracy --robot``, :mod:`harness.experiments.accuracy.link_motion`).
    """
    if not isinstance(config, AccuracyConfig):
        raise ValueError(f"config must be an AccuracyConfig, got {type(config).__name__}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    sweep = sweep if sweep is not None else SweepOptions(workers=workers)
    every = check_log_images(log_images) if log else 0
    _check_model(config)
    out = check_output_dir(out_dir, "--out")  # a file there, a folder that cannot be written, a full disk: now
    t0 = time.perf_counter()
    rig = resolve_rig(config.rig)  # the TRUE rig: the renderer draws with it
    box = rig.workspace_m if rig.workspace_m is not None else config.motion.box_world_m  # where the error is measured
    tracker_rig, cal_error = estimated_rig(rig, config.calibration_error, seed=config.seed, workspace_m=box)  # what the trackers get
    kin, sim_options = _robot(config)
    if motion_source is None:
        motion = simulate_motion(kin, config.n_frames, config.rate_hz, seed=config.seed, options=config.motion,
                                 sim_options=sim_options)
    else:
        motion = motion_source(kin, config)
    n = config.n_frames
    records = {kind: TrackRecord.empty(n) for kind in config.trackers}
    latency = {kind: np.full(n, np.nan) for kind in config.trackers}
    stats: dict = {}
    session = {}

    def open_log(rtblob_cal):  # called once RTBlob's calibration is known (it goes into the metadata)
        session["rtblob_calibration"] = rtblob_cal
        if log:
            session["writer"] = AccuracyLogWriter(out / "session.mcap", config, tracker_rig, motion, kin, true_rig=rig,
                                                  calibration_error=cal_error, rtblob_calibration=rtblob_cal,
                                                  log_images=every or "none", image_format=image_format, overwrite=True,
                                                  flush_period_s=log_flush_s)

    from harness.common.progress import progress_bar

    bar = progress_bar(total=n, desc="accuracy", unit="frame", file=sys.stderr, disable=not progress, smoothing=0.05)
    partial = None
    try:
        try:
            with Executor(sweep) as ex:
                for fr in _frames(config, rig, tracker_rig, motion, kin, open_log, ex, every, stats, bar):
                    writer = session.get("writer")
                    with ex.hold_stop():  # a finished frame set is recorded and logged whole, or not at all
                        for kind, obs in fr.observations.items():
                            records[kind].put(fr.index, obs)
                            latency[kind][fr.index] = obs.latency_s
                        if writer is not None:
                            writer.write_frame(fr)
        except SweepStopped as stop:  # keep what finished: score it if enough frames register the robot
            done = np.all([r.present for r in records.values()], axis=0)  # every tracker's answer is in
            partial = {"reason": str(stop), "frames_done": int(done.sum()), "exit_code": stop.exit_code}
            if not done.any():
                raise ValueError(f"accuracy: {stop} before any frame set finished") from None
        t_frames = time.perf_counter() - t0
        try:
            figures, errors = evaluate(config, records, motion.gt_world_m, np.ones(n, bool), motion.T_base_to_world, rig.names)
        except ValueError as exc:
            if partial is None:
                raise
            raise ValueError(f"accuracy: {partial['reason']} after {partial['frames_done']} of {n} frame sets: too few "
                             f"to score ({exc}); the finished frames are in the session log") from None
        if partial is not None:
            figures["partial"] = partial
            for row in figures["rows"]:
                row["partial"] = True
        timing = {
            "wall_s": round(time.perf_counter() - t0, 2), "frames_wall_s": round(t_frames, 2),
            "workers": sweep.workers, "backend": sweep.backend,
            "latency_ms": {k: {"p50": round(float(np.nanmedian(v)) * 1e3, 3), "p99": round(float(np.nanpercentile(v, 99)) * 1e3, 3)}
                           for k, v in latency.items()},
        }
        events = SessionScene(kin.link_radii_m, motion.T_base_to_world[:3, 3], config.scene, seed=config.seed).events
        result = AccuracyResult(config, figures["rows"], figures, errors, timing, motion.info, stats,
                                scene_events=events.summary(float(motion.t_s[-1]), float(motion.t_s[0])),
                                rtblob_calibration=session.get("rtblob_calibration"), calibration_error=cal_error,
                                truth=_against_truth(config, records, motion, figures), partial=partial)
        write_outputs(result, out)
        if session.get("writer") is not None:
            extra = {"timing": timing, **({"partial": partial} if partial else {})}
            session.pop("writer").finish(figures, extra=extra)
            result.paths["log"] = out / "session.mcap"
    except BaseException as exc:
        if session.get("writer") is not None:
            reason = partial["reason"] + ", partial" if partial else f"{type(exc).__name__}: {exc}"
            session.pop("writer").close(error=reason)
        raise
    finally:
        bar.close()
    return result


def _against_truth(config, records, motion, figures) -> dict:
    """What only a simulation knows (summary.json, not the figures): over the scored frames, each tracker's
    and the registered ground truth's distance to where the ball really was (FK of the true joints), mm.

    The trackers work in the estimated rig's world frame, which differs from the true one by a small rigid
    motion when the calibration has errors: the true ball is first mapped into it by a rigid fit of the true
    ball to the registration tracker's OK positions over the registration frames (trimmed, as the
    registration; an oracle registration without the robot's joint errors)."""
    T = np.asarray(figures["registration"]["T_base_to_world"])
    true = motion.ball_true_world_m
    in_reg = config.register_mask
    scored = ~in_reg
    ref = records[config.registration_tracker]
    pairs = in_reg & ref.ok & np.isfinite(ref.position_m[:, 0])
    if pairs.sum() >= 10:
        T_true_to_est, _ = register_rigid(true[pairs], ref.position_m[pairs], config.registration)
        true = true @ T_true_to_est[:3, :3].T + T_true_to_est[:3, 3]
    gt_reg = motion.gt_base_m @ T[:3, :3].T + T[:3, 3]

    def q(e):
        e = e[scored]
        e = e[np.isfinite(e)] * 1e3
        return {"median": round(float(np.median(e)), 3), "p99": round(float(np.percentile(e, 99)), 3),
                "max": round(float(e.max()), 3)} if e.size else None

    out = {"registered_ground_truth_mm": q(np.linalg.norm(gt_reg - true, axis=1))}
    out.update({f"{k}_mm": q(np.linalg.norm(r.position_m - true, axis=1)) for k, r in records.items()})
    return out


def _add_stats(total: dict, part: dict) -> None:
    for kind, d in part.items():
        acc = total.setdefault(kind, {})
        for key, v in d.items():
            acc[key] = acc.get(key, 0) + v


def _frames(config, rig, tracker_rig, motion, kin, open_log, executor: Executor, every: int, stats: dict, bar):
    """Yield FrameResults in frame order, from this process or from the executor's workers;
    ``open_log(rtblob_calibration)`` is called before the first frame."""
    segments = config.segments()
    opts = executor.options
    one_process = (opts.ray_address is None and opts.workers == 1) or len(segments) == 1 or (0 < every < _MIN_LOG_EVERY_FOR_WORKERS)
    if one_process:
        producer = FrameProducer(config, rig, motion, kin.link_radii_m, tracker_rig=tracker_rig, log_images_every=every)
        cal = producer.calibration()
        open_log(cal)
        producer.start(cal)
        try:
            for a, b in segments:
                for fr in producer.segment(a, b):
                    bar.update(1)
                    yield fr
                _add_stats(stats, producer.stats())
        finally:
            producer.close()
        return
    # workers build their producer (renderer, scene) once: both maps share the initialization
    setup = {"initializer": init_worker, "initargs": (config, rig, tracker_rig, motion, kin.link_radii_m, every),
             "init_key": uuid.uuid4().hex}
    (_, cal), = list(executor.map(calibrate, [None], **setup))
    open_log(cal)
    tasks = [(a, b, cal) for a, b in segments]
    for _, (frames, seg_stats) in in_task_order(executor.map(run_segment, tasks, **setup)):
        _add_stats(stats, seg_stats)
        bar.update(len(frames))
        yield from frames


def write_outputs(result: AccuracyResult, out: Path, *, stem: str = "accuracy") -> dict:
    """Histogram (PNG, PDF), the --json list and summary.json into ``out``; returns and records the paths."""
    cfg = result.config
    title = (f"accuracy: ball on the WAM, {cfg.n_frames} frame sets at {cfg.rate_hz:g} Hz, seed {cfg.seed}, "
             f"{result.figures['n_scored']} scored\n{cfg.realism}")
    if result.partial is None:
        png, pdf = plot_histogram(result.errors, [out / f"{stem}_hist.png", out / f"{stem}_hist.pdf"], title=title)
    else:  # stopped early: within the 2 s a signal allows, no figure (its numbers are in the JSON files)
        png = pdf = None
    js = out / f"{stem}.json"
    atomic_write_json(js, result.rows, "--out")
    summary = out / "summary.json"
    doc = {"config": cfg.to_dict(), "figures": result.figures, "goals": [list(g) for g in check_goals(result.rows)],
           "motion": result.motion_info, "calibration_error": result.calibration_error, "scene_events": result.scene_events,
           "rtblob_calibration": result.rtblob_calibration,
           "against_true_ball": result.truth,
           "tracker_stats": result.tracker_stats, "timing": result.timing}
    atomic_write_json(summary, doc, "--out", default=float)
    result.paths.update({**({"png": png, "pdf": pdf} if png else {}), "json": js, "summary": summary})
    return result.paths
