"""``genicam``: any GenICam / GenTL camera through harvesters (extra ``rt2[cameras]``).

``cti`` is the GenTL producer (.cti file) of the camera vendor; without one, the environment
variable ``GENICAM_GENTL64_PATH`` is searched, then the reference producer shipped inside the
``genicam`` package (simulated devices, for tests). Rig camera i is the i-th of ``serials`` (serial
numbers or device ids), or without them the i-th device found sorted by serial number (then the
count must equal the rig's). Images are converted to RGB (RGB8, RGBa8, BGR8, BGRa8, Mono8 and the
8-bit Bayer formats). ``frame_id`` is the buffer's frame id, ``t_device_s`` its timestamp where the
producer gives one (None otherwise: the host stamp carries the time). Cameras free-run; assemble
with ``match="time"`` unless they share a hardware trigger.
"""

from __future__ import annotations

import glob
import os
import time
from pathlib import Path

import numpy as np

from harness.live.frames import Frame, SourceError
from harness.live.sources.drivers import SourceUnavailable, require_driver

__all__ = ["GenICamCamera", "default_producers", "open_genicam"]

_BAYER = {"BayerRG8": "COLOR_BayerRG2RGB", "BayerGR8": "COLOR_BayerGR2RGB", "BayerBG8": "COLOR_BayerBG2RGB",
          "BayerGB8": "COLOR_BayerGB2RGB"}


def default_producers() -> list[str]:
    """GenTL producers to use without ``cti``: GENICAM_GENTL64_PATH's, else the genicam package's reference one."""
    found = []
    for folder in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if folder:
            found += sorted(glob.glob(os.path.join(folder, "*.cti")))
    if not found:
        try:
            import genicam
        except ImportError:
            return []
        found = sorted(glob.glob(os.path.join(os.path.dirname(genicam.__file__), "*.cti")))
    return found


def _to_rgb(data: np.ndarray, fmt: str, w: int, h: int) -> np.ndarray:
    import cv2

    if fmt in ("RGB8", "RGB8Packed"):
        return data.reshape(h, w, 3).copy()
    if fmt in ("RGBa8", "RGBA8"):
        return data.reshape(h, w, 4)[:, :, :3].copy()
    if fmt in ("BGR8", "BGR8Packed"):
        return cv2.cvtColor(data.reshape(h, w, 3), cv2.COLOR_BGR2RGB)
    if fmt in ("BGRa8", "BGRA8"):
        return cv2.cvtColor(data.reshape(h, w, 4), cv2.COLOR_BGRA2RGB)
    if fmt == "Mono8":
        return cv2.cvtColor(data.reshape(h, w), cv2.COLOR_GRAY2RGB)
    if fmt in _BAYER:
        return cv2.cvtColor(data.reshape(h, w), getattr(cv2, _BAYER[fmt]))
    raise SourceError(f"genicam: pixel format {fmt!r} is not supported; set the camera to RGB8, Mono8 or Bayer*8")


class GenICamCamera:
    """One harvesters ImageAcquirer as a :class:`~harness.live.frames.FrameSource`."""

    def __init__(self, acquirer, camera: int, serial: str, size: tuple):
        self.ia, self.camera, self.serial, self.size = acquirer, camera, serial, size
        self.name = f"genicam:{serial}"
        self.shared = None

    def start(self) -> None:
        if not self.ia.is_acquiring():
            self.ia.start()

    def read(self, timeout_s: float) -> Frame | None:
        from genicam.gentl import NotAvailableException, TimeoutException

        try:
            buffer = self.ia.fetch(timeout=max(1e-3, float(timeout_s)))
        except TimeoutException:
            return None
        except Exception as exc:  # noqa: BLE001 - the camera is gone
            raise SourceError(f"{self.name}: {type(exc).__name__}: {exc}") from None
        t_host = time.monotonic()
        with buffer:
            c = buffer.payload.components[0]
            w, h = int(c.width), int(c.height)
            if (w, h) != self.size:
                raise SourceError(f"{self.name}: delivers {w}x{h} images, the rig camera is "
                                  f"{self.size[0]}x{self.size[1]}")
            image = _to_rgb(c.data, str(c.data_format), w, h)
            try:
                stamp = buffer.timestamp_ns
            except NotAvailableException:
                stamp = 0
            return Frame(self.camera, int(buffer.frame_id), stamp * 1e-9 if stamp else None, t_host, image)

    @property
    def exhausted(self) -> bool:
        return False

    def close(self) -> None:
        if self.ia is None:
            return
        try:
            if self.ia.is_acquiring():
                self.ia.stop()
            self.ia.destroy()
        except Exception:  # noqa: BLE001 - closing must not raise
            pass
        self.ia = None
        shared = getattr(self, "shared", None)
        if shared is not None:
            shared["open"] -= 1
            if shared["open"] == 0:
                shared["harvester"].reset()


def open_genicam(rig, *, cti=None, serials=None, rate_hz: float = 200.0) -> list:
    """Open one :class:`GenICamCamera` per rig camera (see the module docstring). The shared
    ``Harvester`` is reset when the last source is closed."""
    core = require_driver("harvesters.core", "genicam")
    require_driver("genicam.gentl", "genicam")
    producers = [str(cti)] if cti else default_producers()
    if cti and not Path(cti).is_file():
        raise FileNotFoundError(f"genicam: no GenTL producer file {cti}")
    if not producers:
        raise SourceUnavailable("genicam: no GenTL producer (.cti): give one (--source genicam PRODUCER.cti) or set "
                                "GENICAM_GENTL64_PATH")
    h = core.Harvester()
    for p in producers:
        h.add_file(p)
    h.update()
    infos = list(h.device_info_list)
    n = len(rig.cameras)

    def serial_of(info) -> str:
        try:
            return str(info.serial_number)
        except Exception:  # noqa: BLE001 - some producers do not give one
            return str(info.id_)

    found = {serial_of(d): k for k, d in enumerate(infos)}
    ids = {str(d.id_): k for k, d in enumerate(infos)}
    if serials is None:
        if len(found) != n:
            h.reset()
            raise ValueError(f"genicam: found {len(found)} device(s) {sorted(found)} but the rig has {n}; connect {n} "
                             "or list the serial numbers to use, in rig order (--source genicam PRODUCER.cti SER0,...)")
        chosen = [found[s] for s in sorted(found)]
    else:
        chosen = []
        for s in map(str, serials):
            k = found.get(s, ids.get(s))
            if k is None:
                h.reset()
                raise SourceUnavailable(f"genicam: no device with serial number or id {s!r}; found {sorted(found)}")
            chosen.append(k)
    sources = []
    try:
        for i, (k, rc) in enumerate(zip(chosen, rig.cameras)):
            ia = h.create(k)
            node_map = ia.remote_device.node_map
            for param, value in (("Width", rc.image_size[0]), ("Height", rc.image_size[1])):
                node = getattr(node_map, param, None)
                if node is not None and node.value != value:
                    try:
                        node.value = value
                    except Exception:  # noqa: BLE001 - checked on the first frame, with a clear message
                        pass
            rate = getattr(node_map, "AcquisitionFrameRate", None)
            if rate is not None:
                try:
                    rate.value = float(rate_hz)
                except Exception:  # noqa: BLE001 - not writable on this device: it runs at its own rate
                    pass
            src = GenICamCamera(ia, i, serial_of(infos[k]), tuple(rc.image_size))
            sources.append(src)
    except Exception as exc:
        for src in sources:
            src.close()
        h.reset()
        raise SourceUnavailable(f"genicam: cannot open device for rig camera {rig.names[len(sources)]}: "
                                f"{type(exc).__name__}: {exc}") from None
    shared = {"harvester": h, "open": len(sources)}
    for src in sources:
        src.shared = shared
    return sources
