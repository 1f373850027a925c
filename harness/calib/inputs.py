"""Reading what the ``rt2 calib`` commands take: board specs, images or videos, intrinsics, 2D detections.

Every problem raises a ``ValueError`` naming the file and what is wrong (the CLI prints it on one line).
"""

from __future__ import annotations

import math

import tomllib
from pathlib import Path

import cv2
import numpy as np

from tracker import Rig
from tracker.calibration.board import BoardSpec, board_from_dict
from checks.files import MAX_CONFIG_BYTES, MAX_DATA_BYTES, parse_yaml_checked, read_bytes_capped, read_text_capped

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "iter_frames", "load_board", "load_intrinsics", "read_detection_csvs"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm")


def load_board(path) -> BoardSpec:
    """Board spec from a YAML (rt2 keys) or TOML file (rt2 keys or caliscope's charuco.toml)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"board spec {str(path)!r}: no such file")
    text = read_text_capped(path, MAX_CONFIG_BYTES, "board spec")
    if path.suffix != ".toml":
        return board_from_dict(parse_yaml_checked(text, f"board spec {path}"), source=str(path))
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"board spec {path}: not valid toml: {exc}") from None
    return board_from_dict(data, source=str(path))


def read_image(path) -> np.ndarray:
    """One image file as BGR uint8; ValueError naming the file when it cannot be decoded or is a JPEG cut short
    (no end-of-image marker: OpenCV would return it with its missing part grey, and only warn on stderr)."""
    data = read_bytes_capped(path, MAX_DATA_BYTES, "image")
    if data[:2] == b"\xff\xd8" and b"\xff\xd9" not in data.rstrip(b"\x00\r\n\t ")[-2:]:
        raise ValueError(f"{path}: truncated JPEG ({len(data)} bytes, no end-of-image marker): not used")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    return img


def iter_frames(source, *, every: int = 1, max_frames: int | None = None):
    """Yield ``(index, name, image BGR uint8)`` from a video file or a folder of images (sorted by name).

    every : keep every n-th frame; max_frames : stop after this many kept frames.
    """
    src = Path(source)
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    if max_frames is not None and max_frames < 1:  # 0 read one frame before it stopped
        raise ValueError(f"--max-frames must be >= 1, got {max_frames}")
    kept = 0
    if src.is_dir():
        files = sorted(p for p in src.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"{src}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        for i, p in enumerate(files):
            if i % every:
                continue
            yield i, p.name, read_image(p)
            kept += 1
            if max_frames is not None and kept >= max_frames:
                return
        return
    if not src.is_file():
        raise ValueError(f"{src}: no such video file or image folder")
    if src.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"{src}: expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of images")
    cap = cv2.VideoCapture(str(src))
    if not cap.isOpened():
        raise ValueError(f"{src}: OpenCV cannot open this video")
    i = 0
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            if i % every == 0:
                yield i, f"{src.name}#{i}", img
                kept += 1
                if max_frames is not None and kept >= max_frames:
                    return
            i += 1
    finally:
        cap.release()
    if i == 0:
        raise ValueError(f"{src}: the video holds no readable frames")


def load_intrinsics(paths, names=None) -> list:
    """Cameras (``tracker.Camera``, extrinsics as stored) from rt2 rig files and/or OpenCV FileStorage files.

    An rt2 rig file contributes all its cameras; an OpenCV file (``camera_matrix`` ...) one camera,
    named after its file stem (or ``names``).
    """
    cams = []
    paths = [Path(p) for p in paths]
    for p in paths:
        if not p.is_file():
            raise ValueError(f"intrinsics {str(p)!r}: no such file")
        head = read_bytes_capped(p, MAX_CONFIG_BYTES, "intrinsics file")[:4000].decode(errors="replace")
        if "rt2.rig" in head:
            cams.extend(Rig.load(p).cameras)
        else:
            cams.extend(Rig.from_opencv_files([p], length_unit_m=0.001, names=[p.stem]).cameras)
    if names is not None:
        if len(names) != len(cams):
            raise ValueError(f"--names has {len(names)} entries for {len(cams)} cameras in {[str(p) for p in paths]}")
        from dataclasses import replace
        cams = [replace(c, name=n) for c, n in zip(cams, names)]
    return cams


def _timestamp_ns(path, line: int, text: str) -> int:
    """The timestamp column of one detections row: an integer number of ns (``1.5e9`` style allowed when it is
    whole) that fits int64; anything else (NaN, inf, 1e30, 12.5) is a ValueError naming the file and line."""
    text = text.strip()
    try:
        value = int(text)
    except ValueError:
        try:
            f = float(text)
        except ValueError:
            f = math.nan
        if not (math.isfinite(f) and f == int(f)):
            raise ValueError(f"{path}: line {line}: timestamp {text!r} is not a whole number of ns") from None
        value = int(f)
    if not -(1 << 63) <= value < (1 << 63):
        raise ValueError(f"{path}: line {line}: timestamp {text!r} does not fit a 64-bit time in ns")
    return value


def read_detection_csvs(paths) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera 2D detections of the wand balls, one CSV per camera (the ewand layout).

    Each row ``timestamp_ns;u1;v1;u2;v2;...`` (``;`` or ``,`` separated, optional header), distorted
    pixels, -1 (or empty / NaN) where a ball was not found. Rows are matched across cameras by timestamp.
    returns ``timestamps_ns (F,)`` (those present in every file) and ``uv (n_cams, F, n_balls, 2)`` with NaN gaps
    """
    tables = []
    for p in map(Path, paths):
        if not p.is_file():
            raise ValueError(f"detections {str(p)!r}: no such file")
        lines = [ln.strip() for ln in read_text_capped(p, MAX_DATA_BYTES, "detections file").splitlines() if ln.strip()]
        rows, stamps = [], []
        for k, ln in enumerate(lines):
            parts = ln.replace(",", ";").split(";")
            try:
                vals = [float(x) if x.strip() not in ("", "nan", "NaN") else np.nan for x in parts]
            except ValueError:
                if k == 0:
                    continue  # header
                raise ValueError(f"{p}: line {k + 1} is not numbers: {ln[:60]!r}") from None
            stamps.append(_timestamp_ns(p, k + 1, parts[0]))
            bad = [x for x in vals[1:] if math.isinf(x)]
            if bad:
                raise ValueError(f"{p}: line {k + 1}: pixel coordinate {bad[0]!r} is not finite (-1, empty or NaN "
                                 "mark a ball not found)")
            rows.append(vals)
        if not rows:
            raise ValueError(f"{p}: no detection rows")
        widths = {len(r) for r in rows}
        if len(widths) != 1 or (next(iter(widths)) - 1) % 2 or next(iter(widths)) < 3:
            raise ValueError(f"{p}: rows must be 'timestamp;u1;v1[;u2;v2...]' with the same width, got widths {sorted(widths)}")
        tables.append((p, np.asarray(stamps, dtype=np.int64), np.asarray(rows)[:, 1:]))
    n_balls = {a.shape[1] // 2 for _, _, a in tables}
    if len(n_balls) != 1:
        raise ValueError(f"detection files disagree on the number of balls: {[(str(p), a.shape[1] // 2) for p, _, a in tables]}")
    common = tables[0][1]
    for _, ts, _ in tables[1:]:
        common = np.intersect1d(common, ts)
    if len(common) == 0:
        raise ValueError(f"detection files share no timestamp: {[str(p) for p, _, _ in tables]}")
    common = np.unique(common)
    nb = n_balls.pop()
    uv = np.full((len(tables), len(common), nb, 2), np.nan)
    for c, (_, ts, a) in enumerate(tables):
        ts_u, first = np.unique(ts, return_index=True)
        idx = np.searchsorted(ts_u, common)
        pts = a[first][idx].reshape(len(common), nb, 2)
        pts[(pts < 0).any(axis=2)] = np.nan
        uv[c] = pts
    return common, uv
