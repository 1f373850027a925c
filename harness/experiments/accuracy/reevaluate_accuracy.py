"""Re-evaluate an accuracy session log offline: re-run trackers on what was recorded, recompute the figures.

Two sources (``source="auto"`` picks the first that applies):

* ``images``: every frame set's images were logged (``--log-images all``): build the trackers exactly as
  the live run did (config, rig and segmentation weights from the log, RTBlob's calibration from the
  metadata), reset them at the same segment starts, and run them on the logged images with the
  timestamps the frame sets were delivered with (the ``t_s`` of the logged observations). PNG/raw
  images are lossless, so with the same settings the observations and hence the figures are the
  live run's, bit for bit (JPEG logs re-run on the compressed images and differ a little).
* ``detections``: the robust estimator of each rt2 tracker re-run on the logged candidates (every
  candidate the live estimator saw), then rt2's 3D size test on their logged blob areas (logs written
  before the areas were logged: the size test is left out, and a note says so). RTBlob has no
  estimator to re-run: its logged observations are scored as recorded.

Ground truth is the logged ``/ground_truth/ball`` (FK of the reported joints); registration and scoring
are :func:`harness.experiments.accuracy.evaluate.evaluate`, as live. The log is streamed in log-time order, one
frame set at a time (memory: the reader's current chunks plus one frame set). A log that was not
finished cleanly is re-evaluated on the frames recovered; the last, possibly incomplete one is dropped.
"""

from __future__ import annotations

import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.experiments.accuracy.config import AccuracyConfig
from harness.experiments.accuracy.evaluate import TrackRecord, evaluate
from harness.experiments.accuracy.trackers import DETECTION_SUFFIX, build_trackers
from tracker import CandidateEstimator, FrameSet, Status
from tracker.detection import BallDetector, BallSegmentationModel

__all__ = ["SOURCES", "Reevaluation", "reevaluate_accuracy"]

SOURCES = ("auto", "images", "detections")


@dataclass
class Reevaluation:
    """What :func:`reevaluate_accuracy` did and found.

    rows : the ``--json`` list for the re-run trackers; figures : as the live run's; errors : {tracker: (n,) m}
    live_rows : the live run's rows of the same trackers (None when the log has no figures)
    source : "images" or "detections"; how : {tracker: "re-run on images" / ...}; notes : what to know
    """

    rows: list
    figures: dict
    errors: dict
    live_rows: list | None
    source: str
    how: dict
    config: AccuracyConfig
    notes: list = field(default_factory=list)

    @property
    def identical(self) -> bool | None:
        """The re-evaluated rows equal the live ones exactly (None without live figures)."""
        return None if self.live_rows is None else self.rows == self.live_rows


def _model_from_log(reader, tmp: Path) -> BallSegmentationModel:
    path = tmp / "model.npz"
    path.write_bytes(reader.attachment("model.npz"))
    return BallSegmentationModel.load(path)


def _pick_source(source: str, session: dict, environment: dict) -> str:
    every = environment.get("writer", {}).get("log_images_every", 0)
    if source == "auto":
        return "images" if every == 1 else "detections"
    if source == "images" and every != 1:
        got = "no images" if every == 0 else f"images of every {every}th frame set only"
        raise ValueError(f"cannot re-run on images: the log has {got}; record with --log-images all, or use the detections")
    return source


def reevaluate_accuracy(reader, *, trackers=None, eps_px=None, source: str = "auto", progress: bool = True,
                        decode_workers: int = 0) -> Reevaluation:
    """Re-run ``trackers`` (default: every tracker of the log) on an accuracy log (a SessionLogReader)."""
    if source not in SOURCES:
        raise ValueError(f"unknown source {source!r}; valid: {list(SOURCES)}")
    where = str(reader.path)
    session = reader.metadata("session")
    config = AccuracyConfig.from_dict(session.get("config"), where=f"{where}: session metadata 'config'")
    logged = list(config.trackers)
    wanted = list(dict.fromkeys(trackers)) if trackers else logged
    bad = [t for t in wanted if t not in logged]
    if bad:
        raise ValueError(f"{where}: tracker(s) {bad} were not run in this session; it has {logged}")
    if eps_px is not None:
        config = config.with_(eps_px=float(eps_px))
    src = _pick_source(source, session, reader.metadata("environment"))
    rig = reader.rig()
    names = rig.names
    if names != session.get("camera_names"):
        raise ValueError(f"{where}: the attached rig's cameras {names} differ from the session's {session.get('camera_names')}")
    notes = []
    if not reader.finished_cleanly:
        rec = reader.recovery
        notes.append(f"the log was not finished cleanly ({rec.text if rec is not None else 'no summary'}); "
                     + ("every frame set is in it" if reader.data_complete else
                        "re-evaluating the frames recovered, the last recovered frame set dropped"))
    n = config.n_frames
    how, runners, spare = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        model = _model_from_log(reader, Path(tmp)) if any(k != "rtblob" for k in wanted) and src == "images" else None
        if src == "images":
            runners = build_trackers(config.with_(trackers=tuple(wanted)), rig, model, session.get("rtblob_calibration"))
            if config.warmup_frames > 0:  # the next segment's trackers, warmed up while the current ones record
                spare = build_trackers(config.with_(trackers=tuple(wanted)), rig, model, session.get("rtblob_calibration"))
            how = {k: "re-run on the logged images" for k in wanted}
        else:
            # the detector the trackers ran: its edge loss (0 for a learned stage) and its size test record
            det = BallDetector(_model_from_log(reader, Path(tmp))) if any(k in DETECTION_SUFFIX for k in wanted) else None
            for k in wanted:
                if k in DETECTION_SUFFIX:
                    runners[k] = CandidateEstimator(rig, k, eps_px=config.eps_px, edge_px=det.edge_loss_px, size_ratio=det.size_ratio)
                    how[k] = "estimator, size test and support hand-over re-run on the logged detections"
                else:
                    how[k] = "logged observations scored as recorded (no estimator to re-run without images)"
        records = _stream(reader, config, session, src, {"current": runners, "spare": spare}, names, n, progress,
                          decode_workers)
        if records.pop("_no_areas", False):
            notes.append("the log has no blob areas (written before they were logged): rt2's 3D size test was not re-run")
    for r in [*runners.values(), *spare.values()]:
        if hasattr(r, "close"):
            r.close()
    gt_world, gt_present = records.pop("_gt")
    figures, errors = evaluate(config, records, gt_world, gt_present, np.asarray(session["T_base_to_world_nominal"]), names)
    rows = [r for r in figures["rows"] if r["tracker"] in wanted]
    live = reader.figures().get("accuracy")
    live_rows = None if live is None else [r for r in live.get("rows", []) if r["tracker"] in wanted]
    if figures["n_present"] < n:
        notes.append(f"{figures['n_present']} of {n} frame sets available")
    return Reevaluation(rows, figures, {k: errors[k] for k in wanted}, live_rows, src, how, config, notes)


def _stream(reader, config, session, src, sets, names, n, progress, decode_workers: int = 0) -> dict:
    """Read the log frame set by frame set; returns {tracker: TrackRecord, "_gt": (gt_world, present)}.

    sets : {"current": {kind: runner}, "spare": {kind: tracker} or {}}: with images, the spare trackers are
    reset at the start of each segment's warm-up (``harness.experiments.accuracy.frames.warmup_range``), run on the
    warm-up frames with their outputs dropped, and take over at the segment's start, as live."""
    from harness.experiments.accuracy.frames import warmup_range

    runners = sets["current"]
    from harness.common.progress import progress_bar

    k_per = session.get("candidates_per_camera", {})
    records = {kind: TrackRecord.empty(n) for kind in config.trackers}
    gt_world, gt_present = np.full((n, 3), np.nan), np.zeros(n, bool)
    topics = ["/tracker/*/ball", "/ground_truth/ball"]
    topics.append("/camera/*/image" if src == "images" else "/camera/*/detections")
    starts = {a for a, _ in config.segments()}
    seg_of = np.searchsorted(sorted(starts), np.arange(n), side="right")
    warm_of = {k: (a, k == w[0]) for a in starts for w in [warmup_range(config, a)] for k in w}  # frame -> (segment, first?)
    cam_index = {c: i for i, c in enumerate(names)}
    det_cams = {c + DETECTION_SUFFIX[k]: (k, cam_index[c]) for k in runners if k in DETECTION_SUFFIX for c in names}
    state = {"k": None, "images": {}, "dets": {}, "obs": {}, "gt": None, "segment": None, "last_image_frame": -1}
    bar = progress_bar(total=n, desc="reevaluate", unit="frame", file=sys.stderr, disable=not progress)

    def flush():
        k = state["k"]
        if k is None or not 0 <= k < n:
            return
        bar.update(1)
        if state["gt"] is not None:
            gt_world[k], gt_present[k] = state["gt"], True
        logged = state["obs"]
        t_cam = next(iter(logged.values())).t_s if logged else float(state["gt_t"] or 0.0)
        if seg_of[k] != state["segment"]:
            first = state["segment"] is None
            state["segment"] = seg_of[k]
            if sets["spare"] and not first and k in starts:  # the warmed-up trackers take over
                sets["current"], sets["spare"] = sets["spare"], sets["current"]
            else:
                for r in sets["current"].values():
                    if hasattr(r, "reset"):
                        r.reset(clear_stats=True)
        runners = sets["current"]
        if src == "images" and state["images"]:
            state["last_image_frame"] = k
            fs = FrameSet(t_cam, tuple(state["images"].get(c) for c in names), k)
            if sets["spare"] and k in warm_of:  # warm-up of the next segment's trackers: outputs dropped
                if warm_of[k][1]:
                    for r in sets["spare"].values():
                        r.reset(clear_stats=True)
                for tr in sets["spare"].values():
                    tr.process(fs)
            for kind, tr in runners.items():
                records[kind].put(k, tr.process(fs))
        elif src == "detections":
            for kind, est in runners.items():
                uv = np.full((len(names), k_per.get(kind, 1), 2), np.nan)
                areas = np.full(uv.shape[:2], np.nan)
                have_areas = True
                for i, (cand, area) in state["dets"].get(kind, {}).items():
                    uv[i, : len(cand)] = cand
                    if area is None:
                        have_areas = False
                    else:
                        areas[i, : len(area)] = area
                if not have_areas and est.size_test.max_ratio is not None:
                    records["_no_areas"] = True
                # the hand-over's history spans segments, as the live tracker's (the warm-up saw the same frames)
                t_k = logged[kind].t_s if kind in logged else t_cam
                X, info = est.estimate(t_k, uv, areas if have_areas else None)
                r = records[kind]
                if X is not None:
                    r.position_m[k] = X
                r.ok[k] = info.status is Status.OK
                r.flagged[k] = bool(logged[kind].notes) if kind in logged else False
                r.present[k] = kind in logged
        for kind, obs in logged.items():  # trackers not re-run: as recorded
            if kind in records and (kind not in runners):
                records[kind].put(k, obs)

    for m in reader.messages(topics, workers=decode_workers):
        if m.sequence != state["k"]:
            flush()
            state.update(k=m.sequence, images={}, dets={}, obs={}, gt=None, gt_t=None)
        topic = m.topic
        if topic == "/ground_truth/ball":
            state["gt"], state["gt_t"] = m.data.position_m, m.data.t_s
        elif topic.startswith("/tracker/"):
            state["obs"][topic.split("/")[2]] = m.data
        elif topic.endswith("/image"):
            state["images"][topic.split("/")[2]] = m.data
        else:
            cam = topic.split("/")[2]
            if cam in det_cams:
                kind, i = det_cams[cam]
                state["dets"].setdefault(kind, {})[i] = (m.data.uv_px, m.data.areas_px)
    flush()
    bar.close()
    if not reader.data_complete:  # the last frame set of each lane may be cut in the middle
        last = [int(np.flatnonzero(gt_present)[-1])] if gt_present.any() else []
        if src == "images" and state["last_image_frame"] >= 0:
            last.append(state["last_image_frame"])
        for k in last:
            gt_present[k] = False
    records["_gt"] = (gt_world, gt_present)
    return records

