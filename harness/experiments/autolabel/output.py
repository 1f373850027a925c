"""``rt2 label --auto``'s data set: the kept frame sets' labels as COCO in ``OUT`` (what ``rt2 train --data OUT`` reads).

One image per camera of a kept frame set that can hold a label, ``OUT/images/<camera>_s<frame id>.png``
(``_f`` for a video source), written losslessly. Its image entry carries ``camera`` (the rig camera's name),
``frame_id`` (the source's), ``t_s``, ``rt2_frame`` (its key, as ``rt2 label`` on the log keys it) and
``hard_negatives`` (COCO boxes of the candidates the consensus rejected in that image). Its ball annotation
carries ``source: "auto"``, ``support``, ``rms_reprojection_px`` (the frame set's), ``reprojection_px`` (this
camera's, null where its detector had no candidate), ``detected`` (the camera was in the consistent set;
false = a hard positive) and ``confidence``. ``info`` says how the labels were made, and its description
begins like ``rt2 label``'s, so ``rt2 label`` continues the folder and shows the labels as proposals.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from harness.common.outputs import atomic_path
from harness.experiments.detector.coco import LabelledImage, write_coco

__all__ = ["AUTO_DESCRIPTION", "auto_support", "image_key", "keep_supported", "per_camera_counts", "write_auto_labels"]

AUTO_DESCRIPTION = "ball labels made with rt2 label --auto"


def image_key(kind: str, camera: str, frame_id: int) -> str:
    """The key (and image stem) of one camera's frame: ``cam2_s000123`` (log) or ``cam2_f000123`` (video)."""
    return f"{camera}_{'s' if kind == 'replay' else 'f'}{int(frame_id):06d}"


def per_camera_counts(rig, kept) -> dict:
    """camera name -> {"labels", "hard_positives" (its detector missed), "hard_negatives"} over ``kept``."""
    out = {name: {"labels": 0, "hard_positives": 0, "hard_negatives": 0} for name in rig.names}
    for fs in kept:
        for j, name in enumerate(rig.names):
            if np.isfinite(fs.diameter_px[j]):
                out[name]["labels"] += 1
                out[name]["hard_positives"] += int(not fs.inliers[j])
                out[name]["hard_negatives"] += len(fs.negatives[j])
    return out


def write_auto_labels(out_dir, kind: str, rig, kept, framesets, info: dict) -> Path:
    """Write the images of ``kept`` (read again from ``framesets``, the same recording in the same order) and the COCO file.

    kind : the source kind ("replay" or "video"); info : more ``info`` fields (the command, options, counts)
    """
    out_dir = Path(out_dir)
    by_index = {fs.index: fs for fs in kept}
    images, extra, image_extra = [], [], []
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    for rs in framesets:
        fs = by_index.get(rs.index)
        if fs is None:
            continue
        for j, cam in enumerate(rig):
            if not np.isfinite(fs.diameter_px[j]):
                continue
            key = image_key(kind, cam.name, fs.frame_id)
            path = out_dir / "images" / f"{key}.png"
            ok, buf = cv2.imencode(".png", cv2.cvtColor(rs.images[j], cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
            if not ok:
                raise ValueError(f"{path}: cannot encode the frame as PNG")
            with atomic_path(path, "auto label image") as tmp:
                tmp.write_bytes(buf.tobytes())
            w, h = cam.image_size
            box = fs.box_xywh(j)
            x0, y0 = max(0.0, box[0]), max(0.0, box[1])
            x1, y1 = min(float(w), box[0] + box[2]), min(float(h), box[1] + box[3])
            images.append(LabelledImage(path.resolve(), int(w), int(h), np.array([[x0, y0, x1 - x0, y1 - y0]]), fs.center_px[j][None, :]))
            err = float(fs.reprojection_px[j])
            extra.append([{"source": "auto", "support": fs.support, "rms_reprojection_px": round(fs.rms_reprojection_px, 4),
                           "reprojection_px": round(err, 4) if math.isfinite(err) else None, "detected": bool(fs.inliers[j]),
                           "confidence": round(fs.confidence, 4)}])
            image_extra.append({"rt2_frame": key, "camera": cam.name, "frame_id": int(fs.frame_id), "t_s": float(fs.t_s),
                                "hard_negatives": np.round(fs.negatives[j], 2).tolist()})
    return write_coco(out_dir, images, extra, image_extra=image_extra,
                      info={"description": f"{AUTO_DESCRIPTION} from {info.get('source', '')}".strip(), **info,
                            "no_ball_images": "an image without annotations shows no ball"})


def auto_support(data) -> dict:
    """Resolved image path -> the smallest ``support`` of its auto labels, for every COCO file among ``data``
    (folders or JSON files; other label formats and hand-labelled images have none)."""
    import json

    from harness.experiments.detector.coco import ANNOTATIONS_FILE

    out = {}
    for d in data:
        path = Path(d)
        path = path / ANNOTATIONS_FILE if path.is_dir() else path
        if path.suffix.lower() != ".json" or not path.is_file():
            continue
        try:
            doc = json.loads(path.read_text())
            files = {im["id"]: (path.parent / im["file_name"]).resolve() for im in doc["images"]}
            for ann in doc["annotations"]:
                if ann.get("source") == "auto" and isinstance(ann.get("support"), int) and ann.get("image_id") in files:
                    f = files[ann["image_id"]]
                    out[f] = min(out.get(f, ann["support"]), ann["support"])
        except (ValueError, KeyError, TypeError, OSError):
            continue  # not a COCO file of ours: its reader reports what is wrong with it
    return out


def keep_supported(labelled, data, min_support: int) -> list:
    """``labelled`` without the images whose auto labels have a support below ``min_support`` (hand labels are kept)."""
    if isinstance(min_support, bool) or not isinstance(min_support, int) or min_support < 2:
        raise ValueError(f"--min-support must be an integer >= 2, got {min_support!r}")
    support = auto_support(data)
    return [li for li in labelled if support.get(Path(li.path).resolve(), min_support) >= min_support]
