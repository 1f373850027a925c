"""SessionLogWriter: record one session (images, detections, tracker output, ground truth, scene) to one MCAP file.

Times ``t_s`` are the session clock in seconds (>= 0); the MCAP log time is ``round(t_s * 1e9)`` ns,
and ``frame_index`` is stored as the message sequence number. Images go to their own chunks
(no compression for png/jpeg, lz4 for raw), everything else to zstd chunks; see
:mod:`harness.logs._mcap_writer` for the chunking and crash safety, docs/logging.md for topics.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates as PbJointStates
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from harness.logs import codecs, foxglove_scene, topics
from harness.logs._mcap_writer import LaneSpec, LaneWriter
from harness.logs._provenance import environment, utc_now
from harness.logs.topics import LogError
from tracker.observation import BallObservation

__all__ = ["SessionLogWriter", "LogWriterOptions", "WAM_JOINT_NAMES", "check_log_images"]

#: joint names of robot_models.WamKinematics (pass LogWriterOptions(joint_names=...) for another arm)
WAM_JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 8))
_PROTO = {c.DESCRIPTOR.full_name: c for c in (CompressedImage, RawImage, FrameTransforms, SceneUpdate,
                                               PbJointStates, CameraCalibration, ImageAnnotations)}


@dataclass(frozen=True)
class LogWriterOptions:
    """Knobs of :class:`SessionLogWriter` that rarely change.

    jpeg_quality : 1..100; png_compression : zlib level 0..9 (1 = fastest that still compresses)
    state_chunk_bytes / image_chunk_bytes : chunk size limits (uncompressed), bound the reader's memory
    raw_image_compression : chunk compression of raw images, ``"lz4"`` or ``""`` (png/jpeg chunks are never compressed)
    joint_names : names of the arm's joints, in the order of ``q``
    annotate_detections : also write each camera's candidates as foxglove.ImageAnnotations (drawn on the image)
    ball_diameter_m : size of the ball spheres in the 3D scene
    """

    jpeg_quality: int = 95
    png_compression: int = 1
    state_chunk_bytes: int = 1 << 20
    image_chunk_bytes: int = 8 << 20
    raw_image_compression: str = "lz4"
    joint_names: tuple = WAM_JOINT_NAMES
    annotate_detections: bool = True
    ball_diameter_m: float = 0.04

    def __post_init__(self):
        if not 1 <= self.jpeg_quality <= 100:
            raise LogError(f"jpeg_quality must be in 1..100, got {self.jpeg_quality!r}")
        if not 0 <= self.png_compression <= 9:
            raise LogError(f"png_compression must be in 0..9, got {self.png_compression!r}")
        if self.raw_image_compression not in ("", "lz4"):
            raise LogError(f"raw_image_compression must be 'lz4' or '', got {self.raw_image_compression!r}")
        for n in self.joint_names:
            topics.check_name(n, "joint name")


def check_log_images(value) -> int:
    """``"all"`` -> 1, ``"none"`` -> 0, a positive int N (or its text) -> N: keep every N-th frame."""
    if value in ("all", 1):
        return 1
    if value == "none":
        return 0
    try:
        n = int(value)
    except (TypeError, ValueError):
        n = -1
    if isinstance(value, bool) or n < 1 or (isinstance(value, float) and not value.is_integer()):
        raise LogError(f"log_images must be 'all', 'none' or a positive integer N (every N-th frame), got {value!r}")
    return n


class SessionLogWriter:
    """Write one session to ``path`` (an MCAP file). Use as a context manager; see docs/logging.md.

    metadata : what the session is; must hold ``kind`` (e.g. ``"accuracy"``); put ``seed`` and
        ``config`` here too. Stored as the MCAP metadata record ``session``.
    log_images : ``"all"``, ``"none"`` or N (keep frames whose ``frame_index % N == 0``)
    image_format : ``"jpeg"`` (default: the only one fast enough for 4 VGA cameras at 200 Hz),
        ``"png"`` (lossless, slow) or ``"raw"`` (lossless, lz4 chunks, large files)
    flush_period_s : a crash loses at most this much wall-clock time of messages (a timer thread
        hands open chunks to the operating system even when no new message arrives; it is stopped by
        :meth:`close`), and at most about this much log time
    """

    def __init__(self, path, *, metadata: dict, log_images="all", image_format: str = "jpeg",
                 flush_period_s: float = 1.0, options: LogWriterOptions | None = None, overwrite: bool = False):
        self.path = Path(path)
        self.options = options if options is not None else LogWriterOptions()
        if not isinstance(self.options, LogWriterOptions):
            raise LogError(f"options must be a LogWriterOptions, got {type(self.options).__name__}")
        if not isinstance(metadata, dict) or not isinstance(metadata.get("kind"), str) or not metadata["kind"]:
            raise LogError(f"metadata must be a dict with a non-empty string 'kind' (what the session is), got {metadata!r}"[:300])
        if image_format not in codecs.IMAGE_FORMATS:
            raise LogError(f"unknown image_format {image_format!r}; valid: {sorted(codecs.IMAGE_FORMATS)}")
        if not (isinstance(flush_period_s, (int, float)) and 0 < flush_period_s < math.inf):
            raise LogError(f"flush_period_s must be a positive number of seconds, got {flush_period_s!r}")
        self.image_every = check_log_images(log_images)
        self.image_format = image_format
        session = codecs.to_json_value(metadata, "metadata")
        if self.path.exists() and not overwrite:
            raise LogError(f"log file {str(self.path)!r} exists; pass overwrite=True to replace it")
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise LogError(f"cannot create log file {str(self.path)!r}: {exc.strerror}") from None
        o = self.options
        image_comp = o.raw_image_compression if image_format == "raw" else ""
        self._mcap = LaneWriter(self._file, {"state": LaneSpec("zstd", o.state_chunk_bytes),
                                             "image": LaneSpec(image_comp, o.image_chunk_bytes)},
                                flush_period_s=float(flush_period_s), profile="", library="rt2.harness.logs",
                                flush_timer=True)
        self._channels: dict[str, tuple[int, str]] = {}
        self._schemas: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self._last_ns = 0
        self._closed = False
        self.write_metadata("session", session)
        self.write_metadata("environment", {
            **environment(), "created_utc": utc_now(),
            "writer": {"image_format": image_format, "log_images_every": self.image_every,
                       "flush_period_s": float(flush_period_s), **asdict(o)},
        })

    # -- plumbing -------------------------------------------------------------------------------
    def _channel(self, topic: str, schema_name: str, lane: str = "state") -> int:
        hit = self._channels.get(topic)
        if hit is not None:
            return hit[0]
        sid = self._schemas.get(schema_name)
        if sid is None:
            if schema_name in _PROTO:
                name, data = codecs.protobuf_schema(_PROTO[schema_name])
                sid = self._mcap.register_schema(name, "protobuf", data)
            else:
                sid = self._mcap.register_schema(schema_name, "jsonschema", codecs.json_schema(schema_name))
            self._schemas[schema_name] = sid
        encoding = "protobuf" if schema_name in _PROTO else "json"
        cid = self._mcap.register_channel(topic, encoding, sid)
        self._channels[topic] = (cid, lane)
        return cid

    def _put(self, topic: str, schema_name: str, log_ns: int, data: bytes, sequence: int = 0, lane: str = "state"):
        cid = self._channel(topic, schema_name, lane)
        self._mcap.add_message(lane, cid, log_ns, data, sequence)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self._last_ns = max(self._last_ns, log_ns)

    def _time(self, t_s) -> int:
        if self._closed:
            raise LogError(f"log {str(self.path)!r} is closed")
        if isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.floating, np.integer)) or not (0 <= t_s < 1e9):
            raise LogError(f"t_s must be a finite time in seconds >= 0, got {t_s!r}")
        return int(round(float(t_s) * 1e9))

    @staticmethod
    def _index(frame_index) -> int:
        if isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer)) or frame_index < 0:
            raise LogError(f"frame_index must be an int >= 0, got {frame_index!r}")
        return int(frame_index)

    def _vector(self, value, name: str, n: int) -> np.ndarray:
        arr = np.asarray(value, float) if value is not None else None
        if arr is None or arr.shape != (n,) or not np.isfinite(arr).all():
            got = "None" if arr is None else f"shape {arr.shape}" + ("" if arr.shape != (n,) else " with NaN/inf")
            raise LogError(f"{name} must be a finite array of shape ({n},), got {got}")
        return arr

    # -- per frame ------------------------------------------------------------------------------
    def write_image(self, t_s: float, camera: str, image_rgb: np.ndarray, frame_index: int = 0) -> bool:
        """image_rgb : (H, W, 3) uint8 RGB. Returns False where ``log_images`` skips this frame."""
        log_ns, frame_index = self._time(t_s), self._index(frame_index)
        topics.check_name(camera, "camera")
        if not (isinstance(image_rgb, np.ndarray) and image_rgb.ndim == 3 and image_rgb.shape[2] == 3 and image_rgb.dtype == np.uint8):
            got = f"shape {image_rgb.shape} dtype {image_rgb.dtype}" if isinstance(image_rgb, np.ndarray) else type(image_rgb).__name__
            raise LogError(f"image of camera {camera!r} must be an (H, W, 3) uint8 RGB array, got {got}")
        if self.image_every == 0 or frame_index % self.image_every:
            return False
        o = self.options
        data = codecs.encode_image(image_rgb, self.image_format, log_ns, camera, jpeg_quality=o.jpeg_quality,
                                   png_compression=o.png_compression)
        self._put(topics.image_topic(camera), codecs.IMAGE_FORMATS[self.image_format], log_ns, data, frame_index, lane="image")
        return True

    def write_detections(self, t_s: float, camera: str, uv_px, scores, frame_index: int = 0, areas_px=None) -> None:
        """uv_px : (k, 2) distorted pixels of the candidates; scores : (k,) their detector scores;
        areas_px : (k,) their blob areas in pixels (optional; re-evaluation needs them for the 3D size test)."""
        log_ns, frame_index = self._time(t_s), self._index(frame_index)
        topics.check_name(camera, "camera")
        try:
            uv, sc = np.asarray(uv_px, float), np.asarray(scores, float)
            ar = None if areas_px is None else np.asarray(areas_px, float)
        except (TypeError, ValueError):
            raise LogError(f"detections of camera {camera!r}: uv_px, scores and areas_px must be numeric arrays") from None
        if uv.size == 0:
            uv = uv.reshape(0, 2)
        if uv.ndim != 2 or uv.shape[1] != 2 or sc.shape != (len(uv),) or (ar is not None and ar.shape != (len(uv),)):
            raise LogError(f"detections of camera {camera!r}: uv_px must be (k, 2) and scores and areas_px (k,), "
                           f"got shapes {uv.shape}, {sc.shape} and {None if ar is None else ar.shape}")
        self._put(topics.detections_topic(camera), "rt2.Detections", log_ns,
                  codecs.encode_detections(float(t_s), camera, uv, sc, frame_index, ar), frame_index)
        if self.options.annotate_detections:
            msg = ImageAnnotations()
            ts = codecs.timestamp(log_ns)
            for (u, v), s in zip(uv.tolist(), sc.tolist()):
                c = msg.circles.add(diameter=12.0, thickness=2.0)
                c.timestamp.CopyFrom(ts)
                c.position.x, c.position.y = u, v
                c.outline_color.r, c.outline_color.g, c.outline_color.a = 1.0, min(max(s, 0.0), 1.0), 1.0
            self._put(topics.annotations_topic(camera), "foxglove.ImageAnnotations", log_ns, msg.SerializeToString(), frame_index)

    def write_observation(self, t_s: float, tracker: str, obs: BallObservation, frame_index: int = 0) -> None:
        """One tracker output (``tracker.BallObservation``) on ``/tracker/<tracker>/ball``."""
        log_ns, frame_index = self._time(t_s), self._index(frame_index)
        topics.check_name(tracker, "tracker")
        if not isinstance(obs, BallObservation):
            raise LogError(f"obs must be a tracker.BallObservation, got {type(obs).__name__}")
        self._put(topics.tracker_topic(tracker), "rt2.BallObservation", log_ns, codecs.encode_observation(obs), frame_index)

    def write_ground_truth(self, t_s: float, ball_position_m, q, qdot, q_cmd=None, frame_index: int = 0) -> None:
        """ball_position_m : (3,) world frame, metres, or None (no ball); q, qdot, q_cmd : (n_joints,) rad, rad/s."""
        log_ns, frame_index = self._time(t_s), self._index(frame_index)
        names = self.options.joint_names
        if ball_position_m is not None:
            ball = self._vector(ball_position_m, "ball_position_m", 3)
            self._put(topics.GROUND_TRUTH_BALL, "rt2.GroundTruthBall", log_ns,
                      codecs.encode_ground_truth(float(t_s), ball, frame_index), frame_index)
        if q is not None:
            qa, qd = self._vector(q, "q", len(names)), self._vector(qdot, "qdot", len(names))
            self._put(topics.JOINT_STATES, "foxglove.JointStates", log_ns, codecs.encode_joint_states(log_ns, names, qa, qd), frame_index)
        if q_cmd is not None:
            qc = self._vector(q_cmd, "q_cmd", len(names))
            self._put(topics.COMMAND, "foxglove.JointStates", log_ns, codecs.encode_joint_states(log_ns, names, qc), frame_index)

    def write_transforms(self, t_s: float, transforms, *, topic: str = topics.TF) -> None:
        """transforms : [(parent_frame, child_frame, T (4, 4))], T the pose of child in parent (child -> parent)."""
        log_ns = self._time(t_s)
        try:
            parents, children, Ts = zip(*transforms) if len(transforms) else ((), (), ())
            T = np.asarray(Ts, float).reshape(-1, 4, 4)
        except (TypeError, ValueError):
            raise LogError("transforms must be a list of (parent_frame, child_frame, T (4, 4)) tuples") from None
        if not np.isfinite(T).all() or np.abs(T[:, :3, :3] @ T[:, :3, :3].transpose(0, 2, 1) - np.eye(3)).max(initial=0) > 1e-6:
            raise LogError("transforms: every T must be finite with an orthonormal rotation block")
        for f in parents + children:
            topics.check_name(f, "frame name")
        self._put(topic, "foxglove.FrameTransforms", log_ns, codecs.encode_transforms(log_ns, parents, children, T))

    # -- scene ----------------------------------------------------------------------------------
    def write_scene_static(self, t_s: float, rig=None) -> None:
        """Table and net; with a ``tracker.Rig`` also camera frustums, camera frames (/tf_static) and calibrations."""
        log_ns = self._time(t_s)
        self._put(topics.SCENE_STATIC, "foxglove.SceneUpdate", log_ns, foxglove_scene.scene_static(log_ns, rig))
        if rig is not None:
            T = np.stack([c.cam_to_world for c in rig])
            self.write_transforms(t_s, [(topics.WORLD_FRAME, c.name, T[i]) for i, c in enumerate(rig)], topic=topics.TF_STATIC)
            for cam in rig:
                self._put(topics.calibration_topic(cam.name), "foxglove.CameraCalibration", log_ns, foxglove_scene.camera_calibration(log_ns, cam))

    def write_scene_arm(self, t_s: float, X_world) -> None:
        """X_world : (n, 3) origins of the arm's link frames (base to racket), world frame, metres."""
        log_ns = self._time(t_s)
        X = np.asarray(X_world, float)
        if X.ndim != 2 or X.shape[1] != 3 or len(X) < 2 or not np.isfinite(X).all():
            raise LogError(f"X_world must be a finite (n >= 2, 3) array of link origins, got shape {X.shape}")
        self._put(topics.SCENE_ARM, "foxglove.SceneUpdate", log_ns, foxglove_scene.scene_arm(log_ns, X))

    def write_scene_balls(self, t_s: float, true_ball_m=None, tracked: dict | None = None) -> None:
        """Spheres for the true ball (3,) and for each tracker's ball {tracker: (3,) or None}."""
        log_ns = self._time(t_s)
        true = None if true_ball_m is None else self._vector(true_ball_m, "true_ball_m", 3)
        items = [(topics.check_name(k, "tracker"), None if v is None else self._vector(v, f"tracked[{k!r}]", 3))
                 for k, v in (tracked or {}).items()]
        self._put(topics.SCENE_BALLS, "foxglove.SceneUpdate", log_ns,
                  foxglove_scene.scene_balls(log_ns, true, items, diameter_m=self.options.ball_diameter_m))

    # -- once per session -----------------------------------------------------------------------
    def write_figures(self, name: str, figures: dict, t_s: float | None = None) -> None:
        """An experiment's final figures (JSON-able dict) on ``/figures/<name>``, at ``t_s`` or the last log time."""
        topics.check_name(name, "figures name")
        if not isinstance(figures, dict):
            raise LogError(f"figures must be a dict, got {type(figures).__name__}")
        log_ns = self._last_ns if t_s is None else self._time(t_s)
        doc = {"name": name, "figures": codecs.to_json_value(figures, f"figures {name!r}")}
        self._put(topics.figures_topic(name), "rt2.Figures", log_ns, codecs.encode_json(doc))

    def write_metadata(self, name: str, values: dict) -> None:
        """A named MCAP metadata record; each value is stored as JSON text (read back exactly by the reader)."""
        topics.check_name(name, "metadata name")
        if not isinstance(values, dict):
            raise LogError(f"metadata {name!r} must be a dict, got {type(values).__name__}")
        clean = codecs.to_json_value(values, f"metadata {name!r}")
        self._mcap.add_metadata(name, {k: json.dumps(v, allow_nan=False) for k, v in clean.items()})

    def attach(self, name: str, data: bytes, media_type: str = "application/octet-stream") -> None:
        """Store a file (rig YAML, model weights, config) in the log as an MCAP attachment."""
        if not isinstance(name, str) or not name:
            raise LogError(f"attachment name must be a non-empty string, got {name!r}")
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise LogError(f"attachment {name!r}: data must be bytes, got {type(data).__name__}")
        self._mcap.add_attachment(name, media_type, bytes(data), self._last_ns)

    def attach_rig(self, rig) -> None:
        """The rig as ``rig.yaml`` (our YAML format), so re-evaluation uses the same cameras."""
        import yaml

        self.attach("rig.yaml", yaml.safe_dump(rig.to_dict(), sort_keys=False).encode(), "application/yaml")

    # -- lifetime -------------------------------------------------------------------------------
    def flush(self) -> None:
        """Close the open chunks now and hand them to the operating system."""
        self._mcap.flush()

    def close(self, *, error: str | None = None, extra: dict | None = None) -> None:
        """Write the ``session_end`` record and the summary; the file is then finished cleanly."""
        if self._closed:
            return
        end = {"finished_utc": utc_now(), "error": error, "message_counts": dict(self.counts), **(extra or {})}
        try:
            self.write_metadata("session_end", end)
            self._closed = True
            self._mcap.finish()
        finally:  # even when the disk is full: no timer left running, no file left open
            self._closed = True
            self._mcap.stop_timer()
            self._file.close()

    @property
    def bytes_written(self) -> int:
        return self._mcap.bytes_written

    def __enter__(self) -> "SessionLogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(error=None if exc is None else f"{exc_type.__name__}: {exc}")
