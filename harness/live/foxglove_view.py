"""Live view of ``rt2 track`` in Foxglove / Lichtblick, through the foxglove-sdk WebSocket server.

Open Foxglove (or Lichtblick), "Open connection", ``ws://127.0.0.1:8765``. The port takes both
WebSocket subprotocols, ``foxglove.sdk.v1`` (Foxglove's current apps) and the classic
``foxglove.websocket.v1`` (Lichtblick, older Foxglove apps, Foxglove's ``ws-protocol`` clients): a
front (:class:`~harness.live.ws_subprotocols.SubprotocolFront`) listens there and hands each
connection to the SDK server on a loopback port. Topics (the session
log's names and schemas, docs/logging.md, so a layout made for logs works live):

    /camera/<camera>/image        foxglove.CompressedImage (JPEG), throttled to ``image_rate_hz``
    /camera/<camera>/annotations  foxglove.ImageAnnotations: the detector's candidates, green = used
    /camera/<camera>/calibration  foxglove.CameraCalibration (repeated every second for late clients)
    /tf_static                    foxglove.FrameTransforms: the camera frames
    /scene/static                 foxglove.SceneUpdate: table, net, camera frustums
    /scene/balls                  foxglove.SceneUpdate: the ball and its recent track (``trail`` positions)
    /tracker/<kind>/ball          JSON: status, position, support, notes of every frame set

The tracking loop only hands its latest result over (:meth:`LiveView.update`, a few microseconds);
a thread of the view encodes and sends at its own rates, and only what a client subscribed to, so
the view never slows the tracker down. The server binds to 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from harness.live.ws_subprotocols import SubprotocolFront
from harness.common.ratelimit import RateLimitedLogs
from harness.logs import codecs, foxglove_scene, topics

__all__ = ["LiveView", "ViewOptions", "ball_scene"]

_JSON_OBS = {"type": "object", "properties": {"num": {"type": "integer"}, "status": {"type": "string"},
                                               "position_m": {"type": ["array", "null"]}, "support": {"type": "integer"},
                                               "notes": {"type": "array"}}}


def ball_scene(log_ns: int, kind: str, position_m, trail_m: np.ndarray, *, diameter_m: float = 0.04) -> bytes:
    """SceneUpdate: the ball (sphere, deleted when there is no position) and its recent track
    ``trail_m`` (n, 3) world frame metres as a line strip."""
    msg = SceneUpdate.FromString(foxglove_scene.scene_balls(log_ns, None, [(kind, position_m)], diameter_m=diameter_m))
    e = msg.entities.add(frame_id=topics.WORLD_FRAME, id=f"track/{kind}")
    e.timestamp.CopyFrom(codecs.timestamp(log_ns))
    if len(trail_m) >= 2:
        ln = e.lines.add(type=LinePrimitive.LINE_STRIP, thickness=2.0, scale_invariant=True)
        ln.pose.orientation.w = 1.0
        for x, y, z in np.asarray(trail_m, float).tolist():
            ln.points.add(x=x, y=y, z=z)
        ln.color.r, ln.color.g, ln.color.b, ln.color.a = (*foxglove_scene.tracker_color(0), 0.8)
    return msg.SerializeToString()


@dataclass(frozen=True)
class ViewOptions:
    """host/port : where the WebSocket server listens (port 0: a free one, see ``LiveView.port``);
    image_rate_hz : camera images per second per camera at most; scene_rate_hz : ball updates per
    second at most; trail : positions in the drawn track; jpeg_quality : 1..100"""

    host: str = "127.0.0.1"
    port: int = 8765
    image_rate_hz: float = 10.0
    scene_rate_hz: float = 30.0
    trail: int = 100
    jpeg_quality: int = 80

    def __post_init__(self):
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ValueError(f"--foxglove port must be 0..65535, got {self.port!r}")
        for name in ("image_rate_hz", "scene_rate_hz"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 1000):
                raise ValueError(f"{name} must be in (0, 1000] per second, got {v!r}")
        if not 1 <= int(self.jpeg_quality) <= 100 or int(self.trail) < 0:
            raise ValueError(f"jpeg_quality must be 1..100 and trail >= 0, got {self.jpeg_quality!r}, {self.trail!r}")


def _proto_channel(foxglove, ctx, topic: str, cls):
    name, data = codecs.protobuf_schema(cls)
    return foxglove.Channel(topic, schema=foxglove.Schema(name=name, encoding="protobuf", data=data),
                            message_encoding="protobuf", context=ctx)


class _StderrHandler(logging.Handler):
    """Writes to whatever ``sys.stderr`` is when a record comes."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def _quiet_foxglove_logs() -> None:
    """The Foxglove SDK logs each client it drops (``Dropping client ...: handshake failed``) through Python's
    logging; without a handler each became an unprefixed stderr line. Once per process: prefixed
    (``rt2 live view: ...``) and rate-limited (5 a second, the rest counted)."""
    logger = logging.getLogger("foxglove")
    if any(isinstance(h, _StderrHandler) for h in logger.handlers):
        return
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("rt2 live view: %(levelname)s %(message)s"))
    handler.addFilter(RateLimitedLogs(5, what="Foxglove messages"))  # on the handler: the SDK logs on child loggers
    logger.addHandler(handler)
    logger.propagate = False


class LiveView:
    """The Foxglove WebSocket server and the thread that feeds it (module docstring).

    rig : the cameras (names, calibration, frustums); kind : the tracker kind (topic name)
    A port that cannot be bound raises ``ValueError`` naming it.
    """

    def __init__(self, rig, kind: str, options: ViewOptions | None = None):
        import foxglove

        self.options = o = options if options is not None else ViewOptions()
        self.rig, self.kind, self.names = rig, kind, rig.names
        _quiet_foxglove_logs()
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(name="rt2 track", host="127.0.0.1", port=0, context=self._ctx)
        except RuntimeError as exc:
            raise ValueError(f"cannot start the Foxglove live view's server on 127.0.0.1: {exc}") from None
        try:  # the user's port takes both subprotocols (ws_subprotocols.py); the SDK server stays on loopback
            self._front = SubprotocolFront(o.host, o.port, self._server.port)
        except OSError as exc:
            self._server.stop()
            raise ValueError(f"cannot start the Foxglove live view on {o.host}:{o.port}: {exc}") from None
        self.port = self._front.port
        ch = lambda topic, cls: _proto_channel(foxglove, self._ctx, topic, cls)  # noqa: E731
        self._img = [ch(topics.image_topic(c), CompressedImage) for c in self.names]
        self._ann = [ch(topics.annotations_topic(c), ImageAnnotations) for c in self.names]
        self._cal = [ch(topics.calibration_topic(c), CameraCalibration) for c in self.names]
        self._tf_static = ch(topics.TF_STATIC, FrameTransforms)
        self._static = ch(topics.SCENE_STATIC, SceneUpdate)
        self._balls = ch(topics.SCENE_BALLS, SceneUpdate)
        self._obs = foxglove.Channel(topics.tracker_topic(kind), schema=_JSON_OBS, context=self._ctx)
        self._trail: deque = deque(maxlen=max(o.trail, 1))
        self._latest = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.sent = {"images": 0, "scenes": 0, "observations": 0}
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="rt2-live-view", daemon=True)
        self._thread.start()

    # -- called by the tracking loop ------------------------------------------------------------
    def update(self, num: int, afs, obs, info) -> None:
        """Hand over the newest frame set's result (keeps a reference; the loop moves on at once)."""
        if obs.position_m is not None:
            self._trail.append(np.asarray(obs.position_m, float))
        with self._lock:
            self._latest = (num, afs, obs, info)
        self._wake.set()

    # -- the view's thread ----------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # the view stops; the tracker never notices (error reported in ``error``)
            self.error = f"{type(exc).__name__}: {exc}"

    def _loop(self) -> None:
        o = self.options
        next_static = next_image = next_scene = 0.0
        while not self._stop.is_set():
            self._wake.wait(0.2)
            self._wake.clear()
            now = time.monotonic()
            if now >= next_static:
                next_static = now + 1.0
                self._send_static()
            with self._lock:
                latest = self._latest
            if latest is None:
                continue
            num, afs, obs, info = latest
            ns = time.time_ns()
            if now >= next_scene:
                next_scene = now + 1.0 / o.scene_rate_hz
                self._send_scene(ns, num, obs)
            if now >= next_image:
                next_image = now + 1.0 / o.image_rate_hz
                self._send_images(ns, afs, obs, info)
            time.sleep(min(1.0 / o.scene_rate_hz, 1.0 / o.image_rate_hz) / 2)

    def _send_static(self) -> None:
        ns = time.time_ns()
        if self._static.has_sinks():
            self._static.log(foxglove_scene.scene_static(ns, self.rig), log_time=ns)
        if self._tf_static.has_sinks():
            T = [c.cam_to_world for c in self.rig]
            self._tf_static.log(codecs.encode_transforms(ns, [topics.WORLD_FRAME] * len(T), list(self.names), np.stack(T)),
                                log_time=ns)
        for chan, cam in zip(self._cal, self.rig):
            if chan.has_sinks():
                chan.log(foxglove_scene.camera_calibration(ns, cam), log_time=ns)

    def _send_scene(self, ns: int, num: int, obs) -> None:
        if self._balls.has_sinks():
            trail = np.array(list(self._trail)) if self._trail else np.zeros((0, 3))
            self._balls.log(ball_scene(ns, self.kind, obs.position_m, trail), log_time=ns)
            self.sent["scenes"] += 1
        if self._obs.has_sinks():
            self._obs.log({"num": num, "status": str(obs.status), "support": int(obs.support), "notes": list(obs.notes),
                           "position_m": None if obs.position_m is None else [float(v) for v in obs.position_m]},
                          log_time=ns)
            self.sent["observations"] += 1

    def _send_images(self, ns: int, afs, obs, info) -> None:
        for i, cam in enumerate(self.names):
            img = afs.frameset.images[i]
            if img is not None and self._img[i].has_sinks():
                self._img[i].log(codecs.encode_image(img, "jpeg", ns, cam, jpeg_quality=self.options.jpeg_quality),
                                 log_time=ns)
                self.sent["images"] += 1
            if info is not None and self._ann[i].has_sinks():
                self._ann[i].log(_annotations(ns, info.uv_candidates_px[i], obs.uv_px, i), log_time=ns)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=2.0)
        self._server.stop()  # its close frames still pass the front
        self._front.close()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _annotations(ns: int, uv_candidates_px: np.ndarray, uv_used_px, i: int) -> bytes:
    """Circles on camera ``i``'s image: every candidate (k, 2) px, green where the estimate used it."""
    msg = ImageAnnotations()
    ts = codecs.timestamp(ns)
    used = None if uv_used_px is None else np.asarray(uv_used_px, float)[i]
    for u, v in np.asarray(uv_candidates_px, float).reshape(-1, 2).tolist():
        if u != u:  # NaN padding
            continue
        c = msg.circles.add(diameter=14.0, thickness=2.0)
        c.timestamp.CopyFrom(ts)
        c.position.x, c.position.y = u, v
        hit = used is not None and abs(used[0] - u) < 1e-6 and abs(used[1] - v) < 1e-6
        c.outline_color.r, c.outline_color.g, c.outline_color.b, c.outline_color.a = (0.1, 1.0, 0.2, 1.0) if hit else (1.0, 0.3, 0.1, 1.0)
    return msg.SerializeToString()
