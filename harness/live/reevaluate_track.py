"""``rt2 reevaluate`` of an ``rt2 track`` session log: re-run the tracker on what was recorded.

A live session has no ground truth, so its figures are what the tracker made of the frame sets:
statuses, positions, and whether the re-run reproduces the live observations. Two sources
(``--from``, ``auto`` picks the first that applies):

* ``images`` (every frame set's images logged, ``--log-images all``): a new tracker of the logged
  kind, rig and weights runs on the logged images with the logged frame-set times. PNG/raw images
  are lossless, so the observations are the live ones; JPEG re-runs on the compressed images and
  differs a little.
* ``detections``: rt2's robust estimator, 3D size test and support hand-over re-run on the logged
  candidates (exactly what the live estimator saw), so with the same settings every status and position is reproduced;
  ``--eps-px`` shows what another threshold would have made of the same session.

A live tracker that searched full frames after reporting the frame set (``defer_full_frame``) reported
that frame set without a position and the frame sets that came during the search unsearched: both
re-runs do the same (the images re-run defers as live did, waits for each search where live's had
ended, and leaves unsearched what live left unsearched), so those frame sets are reproduced too.

RTBlob sessions log no detections: their observations are counted as recorded.

Images the log's writer dropped (an encoder that could not keep up: counted in the log's ``session_end``)
are missing from the images re-run: ``auto`` then re-runs on the detections, and ``--from images`` says
so in a note.
"""

from __future__ import annotations

import json
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from tracker import BallDetector, BallSegmentationModel, CandidateEstimator, FrameSet, Status

__all__ = ["reevaluate_track", "run_reevaluate"]


def reevaluate_track(reader, *, eps_px=None, source: str = "auto", decode_workers: int = 0) -> dict:
    """Figures of a re-run on a ``track`` log (a :class:`~harness.logs.SessionLogReader`); decode_workers :
    threads decoding the images ahead of the tracker (``SessionLogReader.messages(workers=)``: same figures)."""
    where = str(reader.path)
    session = reader.metadata("session")
    kind = session.get("tracker")
    names = session.get("camera_names")
    rig = reader.rig()
    if rig.names != names:
        raise ValueError(f"{where}: the attached rig's cameras {rig.names} differ from the session's {names}")
    every = reader.metadata("environment").get("writer", {}).get("log_images_every", 0)
    end = reader.metadata("session_end") if reader.finished_cleanly else None
    dropped = int(((end or {}).get("dropped") or {}).get("image", 0) or 0)  # images the writer could not encode in time
    notes = []
    lost = f"the writer dropped {dropped} images (the encoder could not keep up; the log's session_end): "
    if source == "auto":
        source = "images" if every == 1 and (not dropped or kind == "rtblob") else "detections"  # (RTBlob logs no detections)
        if source == "detections" and every == 1:
            notes.append(lost + "re-running the estimator on the logged detections, which every frame set has (--from images "
                         "re-runs the tracker without the dropped images)")
    elif source == "images" and dropped:
        notes.append(lost + "the frame sets that lost some are re-run without them, so their observations can differ from "
                     "live (--from detections re-runs every frame set on its logged candidates)")
    if source == "images" and every != 1:
        raise ValueError(f"{where}: cannot re-run on images: the log keeps every {every}th frame set's images "
                         "(0 = none); record with --log-images all, or use --from detections")
    if source == "detections" and kind == "rtblob":
        source = "recorded"
    if not reader.finished_cleanly:
        notes.append("the log was not finished cleanly: re-evaluating the frame sets recovered")
    k_per = int(session.get("candidates_per_camera") or 1)
    tracker = est = None
    tmp = tempfile.TemporaryDirectory()
    try:
        if source == "images":
            from tracker import Tracker

            model = None
            if kind != "rtblob":
                model = Path(tmp.name) / "model.npz"
                model.write_bytes(reader.attachment("model.npz"))
            defer = bool(session.get("defer_full_frame", False))
            tracker = Tracker(rig, kind, model=model, defer_full_frame=defer,
                              **({} if eps_px is None else {"eps_px": float(eps_px)}))
            topics = [f"/tracker/{kind}/ball", "/camera/*/image"]
        elif source == "detections":
            model = Path(tmp.name) / "model.npz"
            model.write_bytes(reader.attachment("model.npz"))
            det = BallDetector(BallSegmentationModel.load(model))  # as the tracker made them: its edge loss and size record
            est = CandidateEstimator(rig, kind, eps_px=eps_px, edge_px=det.edge_loss_px, size_ratio=det.size_ratio)
            topics = [f"/tracker/{kind}/ball", "/camera/*/detections"]
        else:
            topics = [f"/tracker/{kind}/ball"]
        cam = {c: i for i, c in enumerate(names)}
        live, rerun = Counter(), Counter()
        counts = {"frame_sets": 0, "identical": 0, "with_position_live": 0, "with_position_rerun": 0,
                  "deferred_live": 0, "not_searched_live": 0}
        state = {"seq": None, "obs": None, "items": {}, "max_diff": 0.0}

        def flush():
            obs = state["obs"]
            if obs is None:
                return
            counts["frame_sets"] += 1
            live[str(obs.status)] += 1
            counts["with_position_live"] += obs.position_m is not None
            counts["deferred_live"] += obs.full_frames_deferred
            counts["not_searched_live"] += obs.not_searched
            if source == "images" and obs.not_searched and tracker.options.defer_full_frame:
                status, pos = obs.status, obs.position_m  # live's search still ran: nothing was searched, nor is it now
            elif source == "images":
                tracker.settle()  # live's deferred search had ended before this frame set (else it was not searched)
                imgs = tuple(state["items"].get(i) for i in range(len(names)))
                new = tracker.process(FrameSet(obs.t_s, imgs, state["seq"]))
                status, pos = new.status, new.position_m
            elif source == "detections":
                uv = np.full((len(names), k_per, 2), np.nan)
                areas = np.full(uv.shape[:2], np.nan)
                have_areas = True
                for i, (cand, area) in state["items"].items():
                    uv[i, : len(cand)] = cand[:k_per]
                    if area is None:
                        have_areas = False
                    else:
                        areas[i, : len(area)] = area[:k_per]
                X, info = est.estimate(obs.t_s, uv, areas if have_areas else None)  # as the live tracker
                status, pos = info.status, X
                if obs.full_frames_deferred:  # reported before its full frames were searched: no position, as live
                    status, pos = status.unreported(), None
            else:
                status, pos = obs.status, obs.position_m
            rerun[str(status)] += 1
            counts["with_position_rerun"] += pos is not None
            same = status == obs.status and ((pos is None) == (obs.position_m is None))
            if same and pos is not None:
                d = float(np.abs(np.asarray(pos) - obs.position_m).max())
                state["max_diff"] = max(state["max_diff"], d)
                same = d <= 1e-9
            counts["identical"] += bool(same)

        for m in reader.messages(topics, workers=decode_workers):
            if m.sequence != state["seq"]:
                flush()
                state.update(seq=m.sequence, obs=None, items={})
            if m.topic.startswith("/tracker/"):
                state["obs"] = m.data
            elif m.topic.endswith("/image"):
                state["items"][cam[m.topic.split("/")[2]]] = m.data
            else:
                c = m.topic.split("/")[2]
                if c in cam:
                    state["items"][cam[c]] = (np.asarray(m.data.uv_px, float).reshape(-1, 2), m.data.areas_px)
        flush()
        if counts["deferred_live"] or counts["not_searched_live"]:
            notes.append(f"{counts['deferred_live']} frame set(s) had their full frames searched after they were reported and "
                         f"{counts['not_searched_live']} came while such a search ran: re-run as live reported them (no position)")
    finally:
        if tracker is not None:
            tracker.close()
        tmp.cleanup()
    how = {"images": "tracker re-run on the logged images", "detections": "estimator and size test re-run on the logged detections",
           "recorded": "observations counted as recorded (RTBlob logs no detections to re-run)"}[source]
    return {"tracker": kind, "source": source, "how": how, "eps_px": eps_px, **counts,
            "max_position_difference_m": state["max_diff"],
            "status_live": dict(live), "status_rerun": dict(rerun), "notes": notes,
            "live_figures": reader.figures().get("track")}


def run_reevaluate(reader, args) -> int:
    """``rt2 reevaluate`` for ``track`` logs: print the comparison, ``--json`` writes it."""
    if args.tracker and any(t != reader.metadata("session").get("tracker") for t in args.tracker):
        raise ValueError(f"{reader.path}: this session ran tracker {reader.metadata('session').get('tracker')!r} only, "
                         f"got --tracker {args.tracker}")
    src = args.source if args.source != "auto" else "auto"
    r = reevaluate_track(reader, eps_px=args.eps_px, source=src, decode_workers=getattr(args, "decode_workers", 0))
    n = r["frame_sets"]
    print(f"rt2 reevaluate {reader.path}: live tracking session ({r['tracker']}), {n} frame sets; {r['how']}"
          + (f", eps_px {r['eps_px']:g}" if r["eps_px"] is not None else ""))
    for note in r["notes"]:
        print(f"note: {note}")
    statuses = [str(s) for s in Status]
    print(f"{'status':<22}{'live':>10}{'re-run':>10}")
    for s in statuses:
        print(f"{s:<22}{r['status_live'].get(s, 0):>10}{r['status_rerun'].get(s, 0):>10}")
    print(f"identical observations (status and position): {r['identical']} of {n}"
          f" (largest position difference {r['max_position_difference_m'] * 1e3:.3g} mm)")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(r, indent=1, default=str) + "\n")
        print(f"wrote {args.json}")
    if getattr(args, "plot", None):
        print("note: --plot: a live session has no ground truth, so there is no error histogram to plot")
    return 0
