"""``pylon``: Basler cameras through pypylon (extra ``rt2[cameras]``).

Which camera is which rig camera: with ``serials`` (serial numbers or user-defined names, in rig
order) exactly those; without, every camera found, sorted by serial number, in rig order (then the
count must equal the rig's). Each camera is opened, set to the rig camera's image size, RGB output
(RGB8 where the camera offers it, else converted from Bayer / mono by pylon's converter), and to
one of three triggers:

* ``"free"``: free run at ``rate_hz`` (``AcquisitionFrameRate``);
* ``"software"``: a host thread fires ``TriggerSoftware`` on every camera each ``1 / rate_hz`` (a lab
  without a trigger line); frame ids stay aligned unless a camera is not ready for a trigger
  (counted in ``group.trigger_misses``; the emulator streaming VGA files keeps up with ~20 Hz here);
* ``"hardware"``: ``TriggerSource = trigger_line`` (default Line1), the lab's trigger generator.

``frame_id`` is the grab's ``BlockID`` (counts from 0 per camera when grabbing starts, so with a
trigger all cameras share it); ``t_device_s`` is ``TimeStamp / tick_hz`` (``GevTimestampTickFrequency``
on GigE cameras, 1 GHz on USB3) or None where the camera reports 0, as the emulator does.

The pylon camera emulator (``PYLON_CAMEMU=4`` in the environment: four devices) can stream your own
images: ``emulator_images=[dir0, dir1, ...]`` sets ``ImageFileMode = On`` and ``ImageFilename`` per
camera (tests/harness/live/test_live_pylon.py drives rendered frames through it to a 3D position).
"""

from __future__ import annotations

import threading
import time

from harness.live.frames import Frame, SourceError
from harness.live.sources.drivers import SourceUnavailable, require_driver

__all__ = ["TRIGGERS", "PylonCamera", "open_pylon"]

TRIGGERS = ("free", "software", "hardware")


def _set(cam, name: str, value) -> bool:
    """Set a camera parameter where the camera has it and it is writable; True if set."""
    node = getattr(cam, name, None)
    try:
        if node is None or not node.IsWritable():
            return False
        node.SetValue(value)
        return True
    except Exception:  # noqa: BLE001 - pylon raises its own types for out-of-range values
        return False


class _Group:
    """The opened cameras of one ``open_pylon`` call and, for ``trigger="software"``, the trigger thread."""

    def __init__(self, pylon, cameras, trigger: str, rate_hz: float):
        self.pylon, self.cameras, self.trigger, self.rate_hz = pylon, cameras, trigger, rate_hz
        self._started = False
        self._open = len(cameras)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = None
        self.triggers_sent = 0
        self.trigger_misses = [0] * len(cameras)

    def start(self) -> None:
        with self._lock:
            if self._started:
                return
            self._started = True
            for cam in self.cameras:
                cam.StartGrabbing(self.pylon.GrabStrategy_OneByOne)
            if self.trigger == "software":
                self._thread = threading.Thread(target=self._fire, name="pylon software trigger", daemon=True)
                self._thread.start()

    def _fire(self) -> None:
        period = 1.0 / self.rate_hz
        t_next = time.monotonic()
        while not self._stop.is_set():
            for j, cam in enumerate(self.cameras):
                if cam.WaitForFrameTriggerReady(100, self.pylon.TimeoutHandling_Return):
                    cam.ExecuteSoftwareTrigger()
                else:  # that camera misses this trigger: its frame ids fall one behind (use match="time")
                    self.trigger_misses[j] += 1
            self.triggers_sent += 1
            t_next += period
            self._stop.wait(max(0.0, t_next - time.monotonic()))

    def release(self) -> None:
        with self._lock:
            self._open -= 1
            if self._open > 0:
                return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for cam in self.cameras:
            try:
                cam.StopGrabbing()
                cam.Close()
            except Exception:  # noqa: BLE001 - closing must reach every camera
                pass


class PylonCamera:
    """One Basler camera of a :class:`_Group` as a :class:`~harness.live.frames.FrameSource`."""

    def __init__(self, group: _Group, index: int, serial: str, tick_hz: float):
        self.group, self.camera, self.serial, self.tick_hz = group, index, serial, tick_hz
        self.cam = group.cameras[index]
        self.name = f"pylon:{serial}"
        self.grab_errors = 0
        pylon = group.pylon
        self._converter = None
        if self.cam.PixelFormat.GetValue() not in ("RGB8", "RGB8Packed"):
            self._converter = pylon.ImageFormatConverter()
            self._converter.OutputPixelFormat = pylon.PixelType_RGB8packed
        self._closed = False

    def start(self) -> None:
        self.group.start()

    def read(self, timeout_s: float) -> Frame | None:
        pylon = self.group.pylon
        if not self.cam.IsGrabbing():
            raise SourceError(f"{self.name}: not grabbing (camera removed or closed)")
        res = self.cam.RetrieveResult(max(1, int(timeout_s * 1000)), pylon.TimeoutHandling_Return)
        t_host = time.monotonic()
        if res is None or not res.IsValid():
            return None
        try:
            if not res.GrabSucceeded():
                self.grab_errors += 1
                return None
            image = (self._converter.Convert(res).GetArray() if self._converter is not None else res.GetArray()).copy()
            stamp = res.TimeStamp
            return Frame(self.camera, int(res.BlockID), stamp / self.tick_hz if stamp else None, t_host, image)
        finally:
            res.Release()

    @property
    def exhausted(self) -> bool:
        return False  # a camera never runs out; it fails (SourceError) or stops delivering

    def stats(self) -> dict:
        """grab_errors : grabs the camera reported failed; trigger_misses : software triggers it was not ready for."""
        return {"grab_errors": self.grab_errors, "trigger_misses": self.group.trigger_misses[self.camera]}

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.group.release()


def _choose(devices, serials, n: int) -> list:
    found = {d.GetSerialNumber(): d for d in devices}
    if serials is None:
        if len(found) != n:
            raise ValueError(f"pylon: found {len(found)} camera(s) {sorted(found)} but the rig has {n}; connect {n} "
                             "or list the serial numbers to use, in rig order (--source pylon SER0,SER1,...)")
        return [found[s] for s in sorted(found)]
    by_name = {d.GetUserDefinedName(): d for d in devices if d.GetUserDefinedName()}
    chosen = []
    for s in map(str, serials):
        d = found.get(s) or by_name.get(s)
        if d is None:
            raise SourceUnavailable(f"pylon: no camera with serial number or user id {s!r}; found {sorted(found)}")
        chosen.append(d)
    return chosen


def open_pylon(rig, *, serials=None, rate_hz: float = 200.0, trigger: str = "free", trigger_line: str = "Line1",
               emulator_images=None) -> list:
    """Open one :class:`PylonCamera` per rig camera (see the module docstring)."""
    if trigger not in TRIGGERS:
        raise ValueError(f"pylon: trigger must be one of {TRIGGERS}, got {trigger!r}")
    n = len(rig.cameras)
    if emulator_images is not None and len(emulator_images) != n:
        raise ValueError(f"pylon: emulator_images needs one folder per rig camera ({n}), got {len(emulator_images)}")
    pylon = require_driver("pypylon.pylon", "pylon")
    tlf = pylon.TlFactory.GetInstance()
    devices = list(tlf.EnumerateDevices())
    if not devices:
        raise SourceUnavailable("pylon: no Basler camera found (check cables and power; for the pylon camera "
                                "emulator set PYLON_CAMEMU=4 in the environment)")
    chosen = _choose(devices, serials, n)
    cameras = []
    try:
        for i, (dev, rc) in enumerate(zip(chosen, rig.cameras)):
            cam = pylon.InstantCamera(tlf.CreateDevice(dev))
            cameras.append(cam)
            cam.Open()
            _configure(cam, rc, i, rate_hz, trigger, trigger_line, emulator_images)
        group = _Group(pylon, cameras, trigger, float(rate_hz))
        out = []
        for i, (dev, cam) in enumerate(zip(chosen, cameras)):
            tick = getattr(cam, "GevTimestampTickFrequency", None)
            tick_hz = float(tick.GetValue()) if tick is not None and tick.IsReadable() else 1e9
            out.append(PylonCamera(group, i, dev.GetSerialNumber(), tick_hz))
        return out
    except BaseException as exc:
        for cam in cameras:
            try:
                cam.Close()
            except Exception:  # noqa: BLE001
                pass
        if isinstance(exc, (ValueError, SourceError)):
            raise
        raise SourceUnavailable(f"pylon: cannot open or configure the cameras: {type(exc).__name__}: {exc}") from None


def _configure(cam, rc, i: int, rate_hz: float, trigger: str, trigger_line: str, emulator_images) -> None:
    name = f"pylon camera {cam.GetDeviceInfo().GetSerialNumber()} (rig camera {rc.name})"
    if emulator_images is not None:
        if not _set(cam, "ImageFilename", str(emulator_images[i])) or not _set(cam, "ImageFileMode", "On"):
            raise ValueError(f"{name}: emulator_images given but the camera has no ImageFileMode (not the emulator?)")
        _set(cam, "TestImageSelector", "Off")
    w, h = rc.image_size
    for param, value in (("Width", w), ("Height", h)):
        node = getattr(cam, param)
        if value > node.GetMax() or not _set(cam, param, value):
            raise ValueError(f"{name}: cannot set {param} = {value} (the camera allows up to {node.GetMax()})")
    for fmt in ("RGB8", "RGB8Packed"):
        if _set(cam, "PixelFormat", fmt):
            break
    if trigger == "free":
        _set(cam, "TriggerMode", "Off")
        _set(cam, "AcquisitionFrameRateEnable", True)
        rate = float(rate_hz)
        if not (_set(cam, "AcquisitionFrameRate", rate) or _set(cam, "AcquisitionFrameRateAbs", rate)):
            raise ValueError(f"{name}: cannot set the frame rate to {rate_hz} Hz")
    else:
        _set(cam, "TriggerSelector", "FrameStart")
        source = "Software" if trigger == "software" else trigger_line
        if not (_set(cam, "TriggerMode", "On") and _set(cam, "TriggerSource", source)):
            raise ValueError(f"{name}: cannot set TriggerMode On with TriggerSource {source}")
