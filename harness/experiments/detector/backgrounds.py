"""Ball-free training images from real scenes (``rt2 train --backgrounds``): frames of videos without a
ball, and labelled frames with their balls painted out (:mod:`harness.experiments.detector.ballfree`).

Each source is one of

* a video file (``.mp4``, ``.avi``, ``.mov``, ``.mkv``, ``.webm``): ``frames_per_video`` frames spread
  evenly over it, read with ``cv2.VideoCapture``;
* a COCO set (a folder with ``annotations.json`` or a ``.json`` file), optionally followed by
  ``@START:STOP`` to take only those images in time order (:mod:`harness.experiments.detector.subsets`):
  every image with its labelled balls inpainted;
* a folder of images (``.png``, ``.jpg``, ``.jpeg``, ``.bmp``) taken as they are (they must show no ball).

They join every training fit as background (never the validation or cross-validation scores).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["VIDEO_SUFFIXES", "read_backgrounds"]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def _empty(name: str, image: np.ndarray):
    from harness.experiments.detector.coco import LabelledImage

    return LabelledImage(name, image.shape[1], image.shape[0], np.zeros((0, 4)), np.zeros((0, 2)))


def _video_frames(path: Path, n: int) -> list:
    cap = cv2.VideoCapture(str(path))
    try:
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if not cap.isOpened() or total <= 0:
            raise ValueError(f"--backgrounds {str(path)!r}: OpenCV cannot read this video (or it has no frames)")
        out = []
        for k in np.unique(np.linspace(0, total - 1, min(n, total)).round().astype(int)):
            cap.set(cv2.CAP_PROP_POS_FRAMES, int(k))
            ok, frame = cap.read()
            if ok:
                rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
                out.append((rgb, _empty(f"{path}#frame{k}", rgb)))
        if not out:
            raise ValueError(f"--backgrounds {str(path)!r}: no frame could be decoded")
        return out
    finally:
        cap.release()


def read_backgrounds(sources, frames_per_video: int = 8, *, load_image) -> list:
    """``[(image (H, W, 3) uint8 RGB, LabelledImage without boxes)]`` from the sources (module docstring).

    load_image : ``LabelledImage -> (H, W, 3) uint8 RGB`` for COCO sets (training's
        :func:`harness.experiments.detector.train.load_image`, which checks the size against the label)
    """
    from harness.experiments.detector.ballfree import ball_free
    from harness.experiments.detector.coco import read_coco
    from harness.experiments.detector.subsets import take_range

    if isinstance(frames_per_video, bool) or not isinstance(frames_per_video, int) or frames_per_video < 1:
        raise ValueError(f"--background-frames must be a positive integer, got {frames_per_video!r}")
    out = []
    for source in sources:
        text, _, time_range = str(source).partition("@")
        path = Path(text)
        if not path.exists():
            raise ValueError(f"--backgrounds {source!r}: no such file or folder")
        if path.suffix.lower() in VIDEO_SUFFIXES:
            if time_range:
                raise ValueError(f"--backgrounds {source!r}: @START:STOP applies to COCO sets, not videos")
            out += _video_frames(path, frames_per_video)
        elif path.suffix.lower() == ".json" or (path / "annotations.json").is_file():
            for li in take_range(read_coco(path), time_range or None, f"--backgrounds {text}@"):
                out.append(ball_free(load_image(li), li))
        elif path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not files:
                raise ValueError(f"--backgrounds {source!r}: the folder holds no image ({', '.join(IMAGE_SUFFIXES)})")
            for p in files:
                bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
                if bgr is None:
                    raise ValueError(f"--backgrounds {str(p)!r}: cannot read the image")
                rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                out.append((rgb, _empty(str(p), rgb)))
        else:
            raise ValueError(f"--backgrounds {source!r}: expected a video ({', '.join(VIDEO_SUFFIXES)}), a COCO set or a folder of images")
    return out
