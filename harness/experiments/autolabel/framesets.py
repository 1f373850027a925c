"""A recording's frame sets, every one and in order, for labelling offline: ``replay LOG.mcap`` or ``video DIR``.

The cameras come from :func:`harness.live.sources.open_sources` as ``rt2 track --source`` opens them,
paced as fast as they are read (``speed=None``: lossless, nothing dropped). Frames of one frame set share
their frame id (a log's frame-set sequence, a video's frame number or its ``timestamps.csv`` id); a frame
set that misses a camera's frame is skipped and counted. Before anything is read, the recording's cameras
must be the rig's cameras, the same number by the same names: a rig of 3 cameras on a recording of 4 is
refused, not labelled with one camera left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["AUTO_SOURCES", "RecordedSet", "check_cameras", "read_framesets", "source_cameras"]

#: the ``--source`` kinds ``rt2 label --auto`` reads (recordings; live cameras cannot be read twice)
AUTO_SOURCES = ("replay", "video")
READ_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class RecordedSet:
    """One frame set of a recording.

    index : its place among the frame sets read (0, 1, ...); frame_id : the source's frame id
    t_s : its time, seconds (the first camera's device stamp; else the frame id); images : per rig camera (H, W, 3) uint8 RGB
    """

    index: int
    frame_id: int
    t_s: float
    images: tuple


def source_cameras(spec) -> list[str]:
    """The camera names a recording holds (log image topics; a video folder's files and image folders), sorted.

    Raises ValueError naming the recording when it holds none (a log recorded with ``--log-images none``).
    """
    from harness.live.sources import parse_source_spec

    spec = parse_source_spec(spec)
    if spec.kind not in AUTO_SOURCES:
        raise ValueError(f"--source {spec}: rt2 label --auto reads a recording: {' or '.join(f'{k} ...' for k in AUTO_SOURCES)} "
                         "(record live cameras with rt2 track --log first)")
    target = Path(spec.target)
    if spec.kind == "replay":
        from harness.logs import LogError, SessionLogReader

        if not target.is_file():
            raise ValueError(f"--source replay {target}: no such session log")
        try:
            with SessionLogReader(target) as reader:
                topics = list(reader.topics())
        except (LogError, OSError) as exc:
            raise ValueError(f"--source replay {target}: not a readable session log: {exc}") from None
        names = sorted(t[len("/camera/"):-len("/image")] for t in topics if t.startswith("/camera/") and t.endswith("/image"))
        if not names:
            raise ValueError(f"--source replay {target}: the log holds no camera images (recorded with --log-images none?); "
                             "rt2 label --auto needs the images")
        return names
    if not target.is_dir():
        raise ValueError(f"--source video {target}: no such folder")
    names = sorted({p.stem for p in target.iterdir() if p.suffix.lower() != ".csv" and not p.name.startswith(".")})
    if not names:
        raise ValueError(f"--source video {target}: the folder holds no videos or image folders")
    return names


def check_cameras(spec, rig) -> None:
    """ValueError (one line) unless the recording ``spec`` holds images of exactly the cameras of ``rig``."""
    have = source_cameras(spec)
    if sorted(rig.names) != have:
        raise ValueError(f"--rig has {len(rig.names)} cameras {list(rig.names)} but --source {' '.join(map(str, spec))} "
                         f"has {len(have)} {have}: they must be the same cameras")


def read_framesets(spec, rig, *, every: int = 1, max_sets: int | None = None, counts: dict | None = None):
    """Yield :class:`RecordedSet` of ``spec`` (``["replay", "LOG.mcap"]`` or ``["video", "DIR"]``) in rig camera order.

    every : keep every N-th complete frame set; max_sets : stop after this many kept
    counts : optional dict, filled with ``read`` (complete frame sets) and ``incomplete`` (skipped: a camera's frame missing)
    Raises ValueError (one line) for a recording whose cameras are not the rig's.
    """
    from harness.live.sources import open_sources

    check_cameras(spec, rig)
    counts = {} if counts is None else counts
    counts.update(read=0, incomplete=0)
    sources = open_sources(spec, rig, speed=None)
    try:
        for s in sources:
            s.start()
        kept = 0
        heads = [s.read(READ_TIMEOUT_S) for s in sources]
        while all(h is not None for h in heads):
            target = max(h.frame_id for h in heads)
            if any(h.frame_id != target for h in heads):  # a camera lacks this frame set: skip to the newest id
                counts["incomplete"] += 1
                heads = [h if h.frame_id >= target else _read_until(s, target) for s, h in zip(sources, heads)]
                continue
            if counts["read"] % every == 0:
                t = heads[0].t_device_s
                yield RecordedSet(kept, int(target), float(target if t is None else t), tuple(np.asarray(h.image) for h in heads))
                kept += 1
                if max_sets is not None and kept >= max_sets:
                    return
            counts["read"] += 1
            heads = [s.read(READ_TIMEOUT_S) for s in sources]
    finally:
        for s in sources:
            s.close()


def _read_until(source, frame_id: int):
    frame = source.read(READ_TIMEOUT_S)
    while frame is not None and frame.frame_id < frame_id:
        frame = source.read(READ_TIMEOUT_S)
    return frame
