"""``video``: recorded cameras from a folder, one video file or image folder per rig camera (OpenCV).

Layout of ``DIR`` (names are the rig's camera names):

* ``DIR/<camera>.<ext>`` : a video file (any container OpenCV reads: .avi, .mp4, .mkv, ...), or
* ``DIR/<camera>/`` : a folder of images (.png, .jpg, .jpeg, .bmp, .tif, .tiff), in name order;
* timestamps (optional): ``DIR/<camera>.csv`` or ``DIR/<camera>/timestamps.csv`` with a header and
  the columns ``frame_id,t_s`` (one row per frame, in frame order; ``t_s`` = capture time in
  seconds on the camera's clock). Without it frame k has id k, no device stamp, and is played at
  ``k / rate_hz`` (the file's own frame rate is not trusted: containers often store a nominal one).

Frame k of every camera is emitted together at the earliest recorded time of the set; each
camera's ``t_s`` is its device stamp. A camera whose file ends earlier simply has no more frames.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from harness.live.sources._feed import FeedItem, PacedFeed

__all__ = ["IMAGE_SUFFIXES", "open_video", "read_timestamps"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def read_timestamps(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``frame_id,t_s`` CSV -> (ids (n,) int, t_s (n,) float). ValueError naming the file and row."""
    ids, ts = [], []
    with open(path, newline="") as f:
        rows = csv.reader(f)
        header = next(rows, None)
        if header is None or [h.strip() for h in header[:2]] != ["frame_id", "t_s"]:
            raise ValueError(f"{path}: the first row must be the header 'frame_id,t_s', got {header!r}")
        for n, row in enumerate(rows, start=2):
            if not row:
                continue
            try:
                ids.append(int(row[0]))
                ts.append(float(row[1]))
            except (ValueError, IndexError):
                raise ValueError(f"{path}: row {n} must be an integer frame id and a time in seconds, "
                                 f"got {row!r}") from None
    ids_a, ts_a = np.asarray(ids, int), np.asarray(ts, float)
    if ids_a.size == 0 or not np.isfinite(ts_a).all() or np.any(np.diff(ts_a) < 0):
        raise ValueError(f"{path}: needs at least one row, finite times, not decreasing")
    return ids_a, ts_a


class _Reader:
    """Frames of one camera: a video file or an image folder -> RGB images."""

    def __init__(self, path: Path, name: str):
        import cv2

        self.cv2, self.path = cv2, path
        if path.is_dir():
            self.files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self.files:
                raise ValueError(f"video: camera {name}: no images ({', '.join(IMAGE_SUFFIXES)}) in {path}")
            self.cap = None
        else:
            self.files = None
            self.cap = cv2.VideoCapture(str(path))
            if not self.cap.isOpened():
                raise ValueError(f"video: camera {name}: OpenCV cannot read the video file {path}")
        self.k = 0

    def next(self) -> np.ndarray | None:
        cv2 = self.cv2
        if self.files is not None:
            if self.k >= len(self.files):
                return None
            bgr = cv2.imread(str(self.files[self.k]), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"video: cannot read the image {self.files[self.k]}")
        else:
            ok, bgr = self.cap.read()
            if not ok:
                return None
        self.k += 1
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()


def _find(folder: Path, name: str) -> tuple[Path, Path | None]:
    media = folder / name
    if not media.is_dir():
        files = sorted(p for p in folder.glob(f"{name}.*") if p.suffix.lower() != ".csv")
        if not files:
            have = sorted(p.name for p in folder.iterdir())
            raise ValueError(f"video: no video file '{name}.<ext>' or image folder '{name}/' for rig camera {name} "
                             f"in {folder}; it holds {have[:12]}")
        media = files[0]
    for stamps in (folder / f"{name}.csv", media / "timestamps.csv"):
        if stamps.is_file():
            return media, stamps
    return media, None


def open_video(folder, rig, *, rate_hz: float = 200.0, speed: float | None = 1.0, queue_len: int = 8):
    """One :class:`~._feed.FeedCamera` per rig camera from ``folder`` (see the module docstring).
    Returns ``(sources, feed)``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"video: no folder {folder}")
    found = [_find(folder, name) for name in rig.names]
    stamps = [read_timestamps(s) if s is not None else None for _, s in found]
    n = len(found)
    period = 1.0 / float(rate_hz)

    def produce():
        readers = [_Reader(media, name) for (media, _), name in zip(found, rig.names)]
        try:
            k, t_first = 0, None
            while True:
                images = [r.next() for r in readers]
                if all(img is None for img in images):
                    return
                ids, t_dev = [], []
                for j, img in enumerate(images):
                    st = stamps[j]
                    if st is not None and img is not None and k >= len(st[0]):
                        raise ValueError(f"video: {found[j][1]} has {len(st[0])} rows but camera "
                                         f"{rig.names[j]} has more frames")
                    with_stamp = st is not None and img is not None
                    ids.append(int(st[0][k]) if with_stamp else k)
                    t_dev.append(float(st[1][k]) if with_stamp else None)
                stamped = [t for t in t_dev if t is not None]
                if stamped and t_first is None:
                    t_first = min(stamped)
                t_sched = min(stamped) - t_first if stamped else k * period
                yield FeedItem(tuple(ids), t_sched, tuple(t_dev), tuple(images))
                k += 1
        finally:
            for r in readers:
                r.close()

    feed = PacedFeed(f"video {folder.name}", range(n), rig.names, produce, speed=speed, queue_len=queue_len,
                     prefetch=8)
    return feed.views(), feed
