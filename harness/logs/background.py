"""BackgroundLogWriter: log from a real-time loop without ever blocking it.

A worker thread owns the :class:`~harness.logs.SessionLogWriter` and drains a bounded queue.
When the queue is full (the disk or the image encoder cannot keep up) the new item is dropped
and counted, never silently: the first drop raises a ``RuntimeWarning``, ``dropped`` says how many
per kind, and the counts are written into the log's ``session_end`` record. Images are dropped
first (they have their own, smaller bound), so state messages survive an image backlog.
"""

from __future__ import annotations

import queue
import threading
import warnings

from harness.logs.topics import LogError
from harness.logs.writer import SessionLogWriter

__all__ = ["BackgroundLogWriter"]

_STOP = object()


class BackgroundLogWriter:
    """Same ``write_*`` methods as :class:`SessionLogWriter`, run by a worker thread.

    writer : the SessionLogWriter to feed (closed by :meth:`close`)
    max_pending_images : images waiting at most; more are dropped (and counted)
    max_pending : messages of any kind waiting at most; more are dropped (and counted)

    Arrays passed in must not be modified afterwards (they are encoded later, not copied).
    An error raised by the writer in the worker thread is raised again by the next call.
    """

    def __init__(self, writer: SessionLogWriter, *, max_pending_images: int = 32, max_pending: int = 8192):
        if not isinstance(writer, SessionLogWriter):
            raise LogError(f"writer must be a SessionLogWriter, got {type(writer).__name__}")
        if max_pending_images < 1 or max_pending < max_pending_images:
            raise LogError(f"need 1 <= max_pending_images <= max_pending, got {max_pending_images} and {max_pending}")
        self.writer = writer
        self.max_pending_images = int(max_pending_images)
        self._queue: queue.Queue = queue.Queue(maxsize=int(max_pending))
        self._images_pending = 0
        self._lock = threading.Lock()
        self.dropped: dict[str, int] = {}
        self.submitted: dict[str, int] = {}
        self._error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="rt2-log-writer", daemon=True)
        self._thread.start()

    # -- worker ---------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            kind, fn, args, kwargs = item
            try:
                if self._error is None:
                    fn(*args, **kwargs)
            except BaseException as exc:  # re-raised in the caller's thread
                self._error = exc
            finally:
                if kind == "image":
                    with self._lock:
                        self._images_pending -= 1

    def _submit(self, kind: str, fn, args, kwargs=None) -> bool:
        if self._error is not None:
            raise LogError(f"the background log writer failed: {self._error}") from self._error
        if self._closed:
            raise LogError(f"log {str(self.writer.path)!r} is closed")
        self.submitted[kind] = self.submitted.get(kind, 0) + 1
        if kind == "image":
            with self._lock:
                full = self._images_pending >= self.max_pending_images
                if not full:
                    self._images_pending += 1
        else:
            full = False
        if not full:
            try:
                self._queue.put_nowait((kind, fn, args, kwargs or {}))
                return True
            except queue.Full:
                if kind == "image":
                    with self._lock:
                        self._images_pending -= 1
        if not self.dropped:
            warnings.warn(f"{self.writer.path}: the log writer cannot keep up; dropping {kind} messages "
                          "(counted in BackgroundLogWriter.dropped and in the log's session_end record)",
                          RuntimeWarning, stacklevel=3)
        self.dropped[kind] = self.dropped.get(kind, 0) + 1
        return False

    # -- the SessionLogWriter interface ---------------------------------------------------------
    def write_image(self, t_s, camera, image_rgb, frame_index: int = 0) -> bool:
        """Queue an image; False if ``log_images`` skips it or it was dropped (see ``dropped``)."""
        every = self.writer.image_every
        if every == 0 or frame_index % every:
            return False
        return self._submit("image", self.writer.write_image, (t_s, camera, image_rgb, frame_index))

    def write_detections(self, *args, **kwargs) -> bool:
        return self._submit("detections", self.writer.write_detections, args, kwargs)

    def write_observation(self, *args, **kwargs) -> bool:
        return self._submit("observation", self.writer.write_observation, args, kwargs)

    def write_ground_truth(self, *args, **kwargs) -> bool:
        return self._submit("ground_truth", self.writer.write_ground_truth, args, kwargs)

    def write_transforms(self, *args, **kwargs) -> bool:
        return self._submit("transforms", self.writer.write_transforms, args, kwargs)

    def write_scene_arm(self, *args, **kwargs) -> bool:
        return self._submit("scene", self.writer.write_scene_arm, args, kwargs)

    def write_scene_balls(self, *args, **kwargs) -> bool:
        return self._submit("scene", self.writer.write_scene_balls, args, kwargs)

    def write_scene_static(self, *args, **kwargs) -> bool:
        return self._submit("scene", self.writer.write_scene_static, args, kwargs)

    def write_figures(self, *args, **kwargs) -> bool:
        return self._submit("figures", self.writer.write_figures, args, kwargs)

    def write_metadata(self, *args, **kwargs) -> bool:
        return self._submit("metadata", self.writer.write_metadata, args, kwargs)

    def attach(self, *args, **kwargs) -> bool:
        return self._submit("attachment", self.writer.attach, args, kwargs)

    # -- lifetime -------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    @property
    def pending(self) -> int:
        return self._queue.qsize()

    def close(self, *, error: str | None = None) -> None:
        """Drain the queue, stop the worker and close the log (drop counts go into ``session_end``)."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)
        self._thread.join()
        failure = self._error
        err = error or (None if failure is None else f"{type(failure).__name__}: {failure}")
        self.writer.close(error=err, extra={"dropped": dict(self.dropped), "submitted": dict(self.submitted)})
        if failure is not None:
            raise LogError(f"the background log writer failed: {failure}") from failure

    def __enter__(self) -> "BackgroundLogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(error=None if exc is None else f"{exc_type.__name__}: {exc}")
