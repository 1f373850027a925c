"""``opencv``: live cameras through ``cv2.VideoCapture``: USB / V4L2 devices by index (``0,1,2,3``)
or path (``/dev/video2``), and anything else VideoCapture opens (a stream URL, a video file).

Camera i of the list is rig camera i. The requested size is the rig camera's image size and the
requested rate ``rate_hz``; a device that delivers another size is an error naming it (a rig
calibrated at one resolution is wrong at another). ``t_device_s`` is the driver's buffer timestamp
(``CAP_PROP_POS_MSEC``) where it is positive, else None; the frame id is the source's count.
``read`` blocks in the driver until a frame comes (V4L2 gives up after ~10 s): USB cameras are not
hardware-triggered, so assemble them with ``match="time"``.
"""

from __future__ import annotations

import time

from harness.live.frames import Frame, SourceError
from harness.live.sources.drivers import SourceUnavailable

__all__ = ["OpenCVCamera", "open_opencv"]


class OpenCVCamera:
    """One ``cv2.VideoCapture`` as a :class:`~harness.live.frames.FrameSource`."""

    def __init__(self, device, camera: int, rig_camera, *, rate_hz: float):
        import cv2

        self.cv2 = cv2
        self.device, self.camera = device, camera
        self.name = f"opencv:{device}"
        self.size = tuple(rig_camera.image_size)
        self.cap = cv2.VideoCapture(device)
        if not self.cap.isOpened():
            self.cap.release()
            raise SourceUnavailable(f"opencv camera {device!r} (rig camera {rig_camera.name}) does not open: no such "
                                    "device, no permission, or it is in use by another program")
        if isinstance(device, int):  # devices only: files and streams have their own size and rate
            self.cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
            self.cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
            self.cap.set(cv2.CAP_PROP_FPS, float(rate_hz))
        self.k = 0
        self._ended = False

    def start(self) -> None:
        pass

    def read(self, timeout_s: float) -> Frame | None:
        if self._ended:
            return None
        ok, bgr = self.cap.read()
        t_host = time.monotonic()
        if not ok:
            if self.k == 0 or not isinstance(self.device, int):
                self._ended = True  # a file or stream ended (or never gave a frame)
                return None
            raise SourceError(f"{self.name}: the camera stopped delivering frames after {self.k}")
        h, w = bgr.shape[:2]
        if (w, h) != self.size:
            raise SourceError(f"{self.name}: delivers {w}x{h} images, the rig camera is {self.size[0]}x{self.size[1]}")
        ms = self.cap.get(self.cv2.CAP_PROP_POS_MSEC)
        frame = Frame(self.camera, self.k, ms * 1e-3 if ms > 0 else None, t_host,
                      self.cv2.cvtColor(bgr, self.cv2.COLOR_BGR2RGB))
        self.k += 1
        return frame

    @property
    def exhausted(self) -> bool:
        return self._ended

    def close(self) -> None:
        self.cap.release()


def open_opencv(devices, rig, *, rate_hz: float = 200.0) -> list:
    """One :class:`OpenCVCamera` per rig camera; ``devices`` in rig order (ints or paths / URLs)."""
    if len(devices) != len(rig.cameras):
        raise ValueError(f"opencv: {len(devices)} device(s) {list(devices)} for a rig of {len(rig.cameras)} cameras")
    opened: list = []
    try:
        for i, (device, cam) in enumerate(zip(devices, rig.cameras)):
            opened.append(OpenCVCamera(device, i, cam, rate_hz=rate_hz))
    except BaseException:
        for c in opened:
            c.close()
        raise
    return opened
