"""Reading what the ``rt2 calib`` commands take: board specs, images or videos, intrinsics, 2D detections.

Every problem raises a ``ValueError`` naming the file and what is wrong (the CLI prints it on one line).
"""

from __future__ import annotations

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


def iter_frames(source, *, every: int = 1, max_frames: int | None = None):
    """Yield ``(index, name, image BGR uint8)`` from a video file or a folder of images (sorted by name).

    every : keep every n-th frame; max_frames : stop after this many kept frames.
    """
    src = Path(source)
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    kept = 0
    if src.is_dir():
        files = sorted(p for p in src.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"{src}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        for i, p in enumerate(files):
            if i % every:
                continue
            img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{p}: not a readable image")
            yield i, p.name, img
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
        rows = []
        for k, ln in enumerate(lines):
            parts = ln.replace(",", ";").split(";")
            try:
                vals = [float(x) if x.strip() not in ("", "nan", "NaN") else np.nan for x in parts]
            except ValueError:
                if k == 0:
                    continue  # header
                raise ValueError(f"{p}: line {k + 1} is not numbers: {ln[:60]!r}") from None
            rows.append(vals)
        if not rows:
            raise ValueError(f"{p}: no detection rows")
        widths = {len(r) for r in rows}
        if len(widths) != 1 or (next(iter(widths)) - 1) % 2 or next(iter(widths)) < 3:
            raise ValueError(f"{p}: rows must be 'timestamp;u1;v1[;u2;v2...]' with the same width, got widths {sorted(widths)}")
        arr = np.asarray(rows)
        tables.append((p, arr))
    n_balls = {(a.shape[1] - 1) // 2 for _, a in tables}
    if len(n_balls) != 1:
        raise ValueError(f"detection files disagree on the number of balls: {[(str(p), (a.shape[1] - 1) // 2) for p, a in tables]}")
    common = tables[0][1][:, 0].astype(np.int64)
    for _, a in tables[1:]:
        common = np.intersect1d(common, a[:, 0].astype(np.int64))
    if len(common) == 0:
        raise ValueError(f"detection files share no timestamp: {[str(p) for p, _ in tables]}")
    nb = n_balls.pop()
    uv = np.full((len(tables), len(common), nb, 2), np.nan)
    for c, (_, a) in enumerate(tables):
        ts = a[:, 0].astype(np.int64)
        _, first = np.unique(ts, return_index=True)
        a = a[first]
        idx = np.searchsorted(a[:, 0].astype(np.int64), common)
        pts = a[idx, 1:].reshape(len(common), nb, 2)
        pts[(pts < 0).any(axis=2)] = np.nan
        uv[c] = pts
    return common, uv
