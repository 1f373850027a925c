"""``replay``: the camera images of a session log (MCAP, :mod:`harness.logs`, docs/logging.md) as live cameras.

Images are matched to rig cameras by name (topic ``/camera/<name>/image``). Frames of one frame set
share the MCAP ``sequence`` (the writer's ``frame_index``), which becomes the frame id; the recorded
``t_s`` becomes the device stamp. ``speed=1.0`` replays at the recorded timing, ``speed=None`` as fast
as the readers take frames (lossless: nothing is dropped). Logs written with ``log_images=N`` replay
only the frame sets that were recorded.
"""

from __future__ import annotations

import os
from pathlib import Path

from harness.live.sources._feed import FeedItem, PacedFeed

__all__ = ["open_replay"]


def _log_cameras(reader) -> list[str]:
    return [t[len("/camera/"):-len("/image")] for t in reader.topics()
            if t.startswith("/camera/") and t.endswith("/image")]


def open_replay(path, rig, *, speed: float | None = 1.0, queue_len: int = 8, decode_workers: int | None = None):
    """One :class:`~._feed.FeedCamera` per rig camera replaying ``path``. Returns ``(sources, feed)``.

    decode_workers : threads decoding the images ahead (``SessionLogReader.messages(workers=)``: the
    same images in the same order); None = one per core, 0 = in the feed's own thread

    Raises FileNotFoundError if the log is missing, ValueError if it is not a session log or lacks
    images of a rig camera.
    """
    from harness.logs import SessionLogReader

    from harness.logs.reader import MAX_DECODE_WORKERS

    workers = (os.cpu_count() or 1) if decode_workers is None else decode_workers
    if isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= MAX_DECODE_WORKERS:
        raise ValueError(f"replay: decode_workers must be a whole number in [0, {MAX_DECODE_WORKERS}], got {workers!r}")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"replay: no session log at {path}")
    with SessionLogReader(path) as reader:
        have = _log_cameras(reader)
    missing = [n for n in rig.names if n not in have]
    if missing:
        raise ValueError(f"replay: {path} has no images of rig camera(s) {missing}; its image topics are for "
                         f"{have or 'no camera (recorded with --log-images none?)'}")
    column = {name: j for j, name in enumerate(rig.names)}
    n = len(rig.names)
    topics = [f"/camera/{name}/image" for name in rig.names]

    def produce():
        t0 = None
        with SessionLogReader(path) as reader:
            pending, seq, t_set = [None] * n, None, 0.0
            for m in reader.messages(topics, workers=workers):
                if seq is not None and m.sequence != seq:
                    yield FeedItem((seq,) * n, t_set - t0, (t_set,) * n, tuple(pending))
                    pending = [None] * n
                if t0 is None:
                    t0 = m.t_s
                seq, t_set = m.sequence, m.t_s
                pending[column[m.topic[len("/camera/"):-len("/image")]]] = m.data
            if seq is not None:
                yield FeedItem((seq,) * n, t_set - t0, (t_set,) * n, tuple(pending))

    feed = PacedFeed(f"replay {path.name}", range(n), rig.names, produce, speed=speed, queue_len=queue_len,
                     prefetch=8)
    return feed.views(), feed
