"""The frames ``rt2 label`` shows: a folder of images, a video file, or the camera images of a session log.

Every frame gets a stable key (the same key on every start, so labels resume) and the image file the
COCO data set will name, inside the output folder ``OUT``:

* folder ``DIR``: the images directly in ``DIR`` (``IMAGE_SUFFIXES``) in time order (their names as time stamps:
  :func:`checks.time_order.time_key`, digits compared as numbers, labelling tools' split prefixes and hashes removed;
  ties by name); key = file name;
  a labelled image is copied to ``OUT/images/<file name>`` when its label is saved. An image that cannot
  be read (damaged, not an image, a truncated JPEG or PNG) is skipped and listed in ``FrameSet.skipped``.
* video ``FILE`` (anything ``cv2.VideoCapture`` opens): every ``every``-th frame, at most ``max_frames``;
  key ``<stem>_f<index>``; decoded once at start to ``OUT/images/<key>.png`` (lossless).
* session log ``LOG.mcap`` (``rt2 track --log``): the images on ``/camera/<name>/image`` of one camera
  (``camera=``) or all; key ``<camera>_s<sequence>`` (the frame-set index); written like video frames.

Images are (H, W, 3) uint8 RGB everywhere.
"""

from __future__ import annotations

import math
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from checks.time_order import time_key
from harness.common.outputs import atomic_path

__all__ = ["IMAGE_SUFFIXES", "Frame", "FrameSet", "check_complete", "open_frames"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
IMAGES_DIR = "images"


@dataclass(frozen=True)
class Frame:
    """One frame to label.

    key : stable name of the frame in its source (resume matches on it)
    image_path : the image file the COCO data set names (inside the output folder)
    source_path : where the pixels are read from (the original image, or the extracted PNG)
    width, height : image size, px
    """

    key: str
    image_path: Path
    source_path: Path
    width: int
    height: int


@dataclass(frozen=True)
class FrameSet:
    """The frames of one source, in source order (time order for videos and logs)."""

    kind: str  # "folder", "video" or "log"
    spec: str  # the source as the user named it
    frames: tuple
    skipped: tuple = ()  # (file name, why) of the images that could not be read (folders), in the folder's time order

    def __len__(self) -> int:
        return len(self.frames)

    def image(self, i: int) -> np.ndarray:
        """Frame ``i`` as (H, W, 3) uint8 RGB."""
        return _read_rgb(self.frames[i].source_path)

    def materialise(self, i: int) -> Path:
        """Make sure frame ``i``'s image file exists inside the output folder (copy a folder image); returns it."""
        f = self.frames[i]
        if not f.image_path.is_file():
            with atomic_path(f.image_path, "label image") as tmp:
                shutil.copyfile(f.source_path, tmp)
        return f.image_path


def _read_rgb(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{path}: cannot read the image (missing, or not an image format OpenCV reads)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def open_frames(source, out_dir, *, camera: str | None = None, every: int = 1, max_frames: int = 500, progress=None) -> FrameSet:
    """Open ``source`` (a folder of images, a video file or a ``.mcap`` session log) for labelling into ``out_dir``.

    camera : session logs only: label this camera's images (default: every camera's)
    every, max_frames : videos and logs: take every ``every``-th frame (per camera), at most ``max_frames`` in all
    progress : optional callable ``(done, total_or_None)`` while frames are extracted

    Raises ``ValueError`` naming the path for a missing source, an empty folder, a file OpenCV cannot
    decode, a log without camera images or without ``camera``.
    """
    src = Path(source)
    out_dir = Path(out_dir)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"--every must be a positive integer, got {every!r}")
    if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
        raise ValueError(f"--max-frames must be a positive integer, got {max_frames!r}")
    if camera is not None and src.suffix.lower() != ".mcap":
        raise ValueError(f"--camera is for session logs (.mcap); {str(src)!r} is not one")
    if not src.exists():
        raise ValueError(f"{str(src)!r}: no such folder, video or session log")
    if src.is_dir():
        return _folder(src, out_dir)
    if src.suffix.lower() == ".mcap":
        return _log(src, out_dir, camera, every, max_frames, progress)
    return _video(src, out_dir, every, max_frames, progress)


def _folder(src: Path, out_dir: Path) -> FrameSet:
    files = sorted((p for p in src.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: (time_key(p), p.name))
    if not files:
        raise ValueError(f"{str(src)!r}: no images ({', '.join(IMAGE_SUFFIXES)}) directly in this folder")
    frames, skipped = [], []
    for p in files:
        try:
            size = _image_size(p)
        except ValueError as exc:  # one bad file does not stop the others: skipped and listed
            skipped.append((p.name, str(exc)))
            continue
        frames.append(Frame(p.name, out_dir / IMAGES_DIR / p.name, p, *size))
    if not frames:
        raise ValueError(f"{str(src)!r}: none of its {len(files)} images can be read; the first: {skipped[0][1]}")
    return FrameSet("folder", str(src), tuple(frames), tuple(skipped))


def check_complete(path: Path) -> None:
    """ValueError naming ``path`` when a JPEG or PNG file ends before its end marker (a truncated copy or upload).

    Files without the format's signature are left to OpenCV (which refuses what is not an image).

    OpenCV decodes a truncated JPEG without an error, the missing part grey: labelled, such a frame
    teaches the detector a grey background. JPEG ends with EOI (FF D9; trailing padding allowed), PNG with IEND.
    """
    suffix = path.suffix.lower()
    if suffix not in (".jpg", ".jpeg", ".png"):
        return
    with open(path, "rb") as fh:
        head = fh.read(8)
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(0, size - 4096))
        tail = fh.read()
    if head == b"\x89PNG\r\n\x1a\n":
        if b"IEND" not in tail[-16:]:
            raise ValueError(f"{path}: the PNG file is truncated (no IEND chunk at its end)")
    elif head[:2] == b"\xff\xd8" and not tail.rstrip(b"\x00\r\n\t ").endswith(b"\xff\xd9"):
        raise ValueError(f"{path}: the JPEG file is truncated (no end-of-image marker)")


def _image_size(path: Path) -> tuple[int, int]:
    check_complete(path)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: cannot read the image (not an image format OpenCV reads, or damaged)")
    return image.shape[1], image.shape[0]


def _write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an extracted frame once (kept from an earlier run: the same key is the same frame)."""
    if path.is_file():
        return
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"{path}: cannot encode the frame as PNG")
    with atomic_path(path, "extracted frame") as tmp:
        tmp.write_bytes(buf.tobytes())


def _video(src: Path, out_dir: Path, every: int, max_frames: int, progress) -> FrameSet:
    cap = cv2.VideoCapture(str(src))
    try:
        if not cap.isOpened():
            raise ValueError(f"{str(src)!r}: OpenCV cannot open this file as a video (and it is not a folder or a .mcap session log)")
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or None
        frames, index = [], 0
        while len(frames) < max_frames and cap.grab():
            if index % every == 0:
                ok, bgr = cap.retrieve()
                if not ok or bgr is None or bgr.ndim != 3:
                    raise ValueError(f"{str(src)!r}: frame {index} cannot be decoded")
                key = f"{src.stem}_f{index:06d}"
                path = out_dir / IMAGES_DIR / f"{key}.png"
                _write_png(path, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
                frames.append(Frame(key, path, path, bgr.shape[1], bgr.shape[0]))
                if progress is not None:
                    progress(len(frames), None if total is None else min(max_frames, math.ceil(total / every)))
            index += 1
    finally:
        cap.release()
    if not frames:
        raise ValueError(f"{str(src)!r}: no frame could be decoded (not a video OpenCV reads, or empty)")
    return FrameSet("video", str(src), tuple(frames))


def _log(src: Path, out_dir: Path, camera, every: int, max_frames: int, progress) -> FrameSet:
    from harness.logs import LogError, SessionLogReader

    try:
        with warnings.catch_warnings():  # damage is reported in the one-line error below, or read around
            warnings.simplefilter("ignore", RuntimeWarning)
            reader = SessionLogReader(src)
    except (LogError, OSError) as exc:
        raise ValueError(f"{str(src)!r}: not a readable session log: {exc}") from None
    with reader:
        cams = [t[len("/camera/"):-len("/image")] for t in reader.topics() if t.startswith("/camera/") and t.endswith("/image")]
        if not cams:
            damage = f" (damaged: {reader.problems[0]})" if reader.problems else " (recorded with --log-images none?)"
            raise ValueError(f"{str(src)!r}: the session log holds no camera images{damage}")
        if camera is not None and camera not in cams:
            raise ValueError(f"--camera {camera!r}: {str(src)!r} has images of {sorted(cams)} only")
        wanted = [camera] if camera is not None else sorted(cams)
        seen = {c: 0 for c in wanted}
        frames = []
        try:
            for m in reader.messages([f"/camera/{c}/image" for c in wanted]):
                cam = m.topic[len("/camera/"):-len("/image")]
                n, seen[cam] = seen[cam], seen[cam] + 1
                if n % every:
                    continue
                key = f"{cam}_s{m.sequence:06d}"
                path = out_dir / IMAGES_DIR / f"{key}.png"
                rgb = np.asarray(m.data)
                _write_png(path, rgb)
                frames.append(Frame(key, path, path, rgb.shape[1], rgb.shape[0]))
                if progress is not None:
                    progress(len(frames), None)
                if len(frames) >= max_frames:
                    break
        except LogError as exc:
            raise ValueError(f"{str(src)!r}: {exc}") from None
    keys = [f.key for f in frames]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{str(src)!r}: two images of one camera share a frame-set sequence number; cannot key them")
    return FrameSet("log", str(src), tuple(frames))
