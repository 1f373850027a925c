"""Message encodings of session logs: the types that cross into logs, their schemas, encoders, decoders.

Foxglove types (images, transforms, scene, joint states, calibration, annotations) are protobuf
with the official precompiled schemas (``foxglove-schemas-protobuf``); the schema record holds the
FileDescriptorSet, so any reader can decode them. Our own types are JSON with a JSON Schema in the
file (``rt2.*``). Non-finite floats are written as ``null`` (Foxglove's JSON parser rejects NaN)
and read back as NaN where an array was expected.
"""

from __future__ import annotations

import dataclasses

import json
from dataclasses import dataclass

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates as _PbJointStates
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.timestamp_pb2 import Timestamp
from mcap_protobuf.schema import build_file_descriptor_set
from scipy.spatial.transform import Rotation

from harness.logs.topics import LogError
from tracker.observation import BallObservation, Status

__all__ = [
    "Detections",
    "GroundTruthBall",
    "JointStates",
    "IMAGE_FORMATS",
    "json_schema",
    "protobuf_schema",
    "timestamp",
    "encode_json",
    "to_json_value",
    "encode_image",
    "decode_image",
    "encode_detections",
    "decode_detections",
    "encode_observation",
    "decode_observation",
    "encode_ground_truth",
    "decode_ground_truth",
    "encode_joint_states",
    "decode_joint_states",
    "encode_transforms",
    "decode_transforms",
]

#: image_format -> foxglove schema of the image messages
IMAGE_FORMATS = {"jpeg": "foxglove.CompressedImage", "png": "foxglove.CompressedImage", "raw": "foxglove.RawImage"}


@dataclass(frozen=True)
class Detections:
    """Ball candidates of one camera image.

    uv_px : (k, 2) distorted pixel centres; scores : (k,) detector scores (higher = more ball-like)
    areas_px : (k,) blob areas, pixels (the 3D size test's input), or None (not logged: RTBlob, older logs)
    """

    t_s: float
    camera: str
    uv_px: np.ndarray
    scores: np.ndarray
    frame_index: int = 0
    areas_px: np.ndarray | None = None


@dataclass(frozen=True)
class GroundTruthBall:
    """Ball centre from the simulator's kinematics. position_m : (3,) world frame, metres."""

    t_s: float
    position_m: np.ndarray
    frame_index: int = 0


@dataclass(frozen=True)
class JointStates:
    """Joint positions (rad) and velocities (rad/s) of the arm; velocity_rad_s is None for commands."""

    t_s: float
    names: tuple
    position_rad: np.ndarray
    velocity_rad_s: np.ndarray | None = None


# -- schemas --------------------------------------------------------------------------------------
_NUM = {"type": ["number", "null"]}
_VEC = {"type": "array", "items": _NUM}
_JSON_SCHEMAS = {
    "rt2.Detections": {
        "title": "rt2.Detections", "description": "Ball candidates of one camera image (distorted pixels).",
        "type": "object",
        "properties": {"t_s": {"type": "number"}, "camera": {"type": "string"}, "frame_index": {"type": "integer"},
                       "uv_px": {"type": "array", "items": _VEC}, "scores": _VEC, "areas_px": _VEC},
        "required": ["t_s", "camera", "frame_index", "uv_px", "scores"],
    },
    "rt2.BallObservation": {
        "title": "rt2.BallObservation",
        "description": "One tracker output per frame set (tracker.BallObservation); world frame, metres.",
        "type": "object",
        "properties": {
            "t_s": {"type": "number"}, "tracker": {"type": "string"},
            "status": {"type": "string", "enum": [s.value for s in Status]},
            "position_m": {"oneOf": [_VEC, {"type": "null"}]},
            "covariance_m2": {"oneOf": [{"type": "array", "items": _VEC}, {"type": "null"}]},
            "support": {"type": "integer"}, "inliers": {"type": "array", "items": {"type": "boolean"}},
            "latency_s": {"type": "number"},
            "uv_px": {"oneOf": [{"type": "array", "items": _VEC}, {"type": "null"}]},
            "notes": {"type": "array", "items": {"type": "string"}},
        },
        "required": ["t_s", "tracker", "status", "position_m", "covariance_m2", "support", "inliers", "latency_s"],
    },
    "rt2.GroundTruthBall": {
        "title": "rt2.GroundTruthBall", "description": "Ball centre from kinematics; world frame, metres.",
        "type": "object",
        "properties": {"t_s": {"type": "number"}, "frame_index": {"type": "integer"}, "position_m": _VEC},
        "required": ["t_s", "position_m"],
    },
    "rt2.Figures": {
        "title": "rt2.Figures", "description": "Final figures of an experiment (free-form JSON object).",
        "type": "object", "properties": {"name": {"type": "string"}, "figures": {"type": "object"}},
        "required": ["name", "figures"],
    },
}


def json_schema(name: str) -> bytes:
    """JSON Schema document of our message type ``name`` (``rt2.*``)."""
    try:
        return json.dumps(_JSON_SCHEMAS[name], sort_keys=True).encode()
    except KeyError:
        raise LogError(f"unknown rt2 message type {name!r}; valid: {sorted(_JSON_SCHEMAS)}") from None


def protobuf_schema(message_class) -> tuple[str, bytes]:
    """(full name, serialized FileDescriptorSet) of a protobuf message class."""
    return message_class.DESCRIPTOR.full_name, build_file_descriptor_set(message_class).SerializeToString()


def timestamp(log_time_ns: int) -> Timestamp:
    return Timestamp(seconds=log_time_ns // 1_000_000_000, nanos=log_time_ns % 1_000_000_000)


# -- JSON helpers -----------------------------------------------------------------------------------
def _nan_to_none(arr: np.ndarray) -> list:
    """Array -> nested list with non-finite entries as None."""
    arr = np.asarray(arr, float)
    if np.isfinite(arr).all():
        return arr.tolist()
    return np.where(np.isfinite(arr), arr, None).tolist()


def _none_to_nan(value) -> np.ndarray:
    return np.array(value, dtype=float)  # None -> nan under dtype=float


def to_json_value(value, where: str, *, lenient: bool = False):
    """Convert numpy values, tuples, dataclasses and nested containers to plain JSON values
    (non-finite -> None).

    Strict by default (what a log stores): a non-string key or a value of another type raises
    :class:`LogError` naming ``where``. ``lenient=True`` is for figures that must never cost the
    caller its log or summary (a camera source's own counters): keys become strings and values of
    other types pass through unchanged.
    """
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                if not lenient:
                    raise LogError(f"{where}: keys must be strings, got {k!r}")
                k = str(k)
            out[k] = to_json_value(v, f"{where}.{k}", lenient=lenient)
        return out
    if isinstance(value, (list, tuple)):
        return [to_json_value(v, f"{where}[{i}]", lenient=lenient) for i, v in enumerate(value)]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_json_value(dataclasses.asdict(value), where, lenient=lenient)
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            return _nan_to_none(value)
        if value.dtype.kind in "biu":
            return value.tolist()
        if value.dtype.kind == "U":
            return value.tolist()
        raise LogError(f"{where}: cannot store an array of dtype {value.dtype}")
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    if hasattr(value, "value") and isinstance(value.value, str):  # enums such as Status
        return value.value
    if lenient:
        return value
    raise LogError(f"{where}: cannot store a value of type {type(value).__name__} in a log")


def encode_json(obj: dict) -> bytes:
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()


# -- images -----------------------------------------------------------------------------------------
def encode_image(image_rgb: np.ndarray, fmt: str, log_time_ns: int, frame_id: str, *,
                 jpeg_quality: int = 95, png_compression: int = 1) -> bytes:
    """(H, W, 3) uint8 RGB -> serialized foxglove.CompressedImage (jpeg, png) or foxglove.RawImage (raw)."""
    h, w = image_rgb.shape[:2]
    if fmt == "raw":
        return RawImage(timestamp=timestamp(log_time_ns), frame_id=frame_id, width=w, height=h, encoding="rgb8",
                        step=3 * w, data=np.ascontiguousarray(image_rgb).tobytes()).SerializeToString()
    bgr = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR)
    if fmt == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    else:
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)])
    if not ok:
        raise LogError(f"OpenCV could not encode a {w}x{h} image as {fmt}")
    return CompressedImage(timestamp=timestamp(log_time_ns), frame_id=frame_id, data=buf.tobytes(),
                           format=fmt).SerializeToString()


def decode_image(msg) -> np.ndarray:
    """Decoded foxglove.CompressedImage / foxglove.RawImage message -> (H, W, 3) uint8 RGB."""
    if hasattr(msg, "format"):  # CompressedImage
        bgr = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise LogError(f"image data is not a valid {msg.format or 'compressed'} image ({len(msg.data)} bytes)")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(msg.encoding)
    if channels is None or msg.step < msg.width * channels or len(msg.data) < msg.step * msg.height:
        raise LogError(f"unsupported raw image: encoding {msg.encoding!r}, {msg.width}x{msg.height}, step {msg.step}, "
                       f"{len(msg.data)} bytes")
    rows = np.frombuffer(msg.data, np.uint8, count=msg.step * msg.height).reshape(msg.height, msg.step)
    img = rows[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    if msg.encoding == "bgr8":
        img = img[:, :, ::-1]
    elif msg.encoding == "mono8":
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img)


# -- rt2 JSON types ---------------------------------------------------------------------------------
def encode_detections(t_s: float, camera: str, uv_px: np.ndarray, scores: np.ndarray, frame_index: int, areas_px=None) -> bytes:
    doc = {"t_s": t_s, "camera": camera, "frame_index": frame_index, "uv_px": _nan_to_none(uv_px), "scores": _nan_to_none(scores)}
    if areas_px is not None:
        doc["areas_px"] = _nan_to_none(areas_px)
    return encode_json(doc)


def decode_detections(doc: dict) -> Detections:
    uv = _none_to_nan(doc["uv_px"]).reshape(-1, 2)
    areas = doc.get("areas_px")
    return Detections(t_s=doc["t_s"], camera=doc["camera"], uv_px=uv, scores=_none_to_nan(doc["scores"]),
                      frame_index=doc.get("frame_index", 0), areas_px=None if areas is None else _none_to_nan(areas))


def encode_observation(obs: BallObservation) -> bytes:
    return encode_json({
        "t_s": float(obs.t_s), "tracker": obs.tracker, "status": Status(obs.status).value,
        "position_m": None if obs.position_m is None else _nan_to_none(obs.position_m),
        "covariance_m2": None if obs.covariance_m2 is None else _nan_to_none(obs.covariance_m2),
        "support": int(obs.support), "inliers": np.asarray(obs.inliers, bool).tolist(),
        "latency_s": float(obs.latency_s),
        "uv_px": None if obs.uv_px is None else _nan_to_none(obs.uv_px),
        "notes": [str(n) for n in obs.notes],
    })


def decode_observation(doc: dict) -> BallObservation:
    def arr(key, shape):
        v = doc.get(key)
        return None if v is None else _none_to_nan(v).reshape(shape)

    return BallObservation(
        t_s=doc["t_s"], position_m=arr("position_m", (3,)), covariance_m2=arr("covariance_m2", (3, 3)),
        support=doc["support"], inliers=np.array(doc["inliers"], bool), status=Status(doc["status"]),
        latency_s=doc["latency_s"], tracker=doc["tracker"], uv_px=arr("uv_px", (-1, 2)), notes=tuple(doc.get("notes", ())),
    )


def encode_ground_truth(t_s: float, position_m: np.ndarray, frame_index: int) -> bytes:
    return encode_json({"t_s": t_s, "frame_index": frame_index, "position_m": _nan_to_none(position_m)})


def decode_ground_truth(doc: dict) -> GroundTruthBall:
    return GroundTruthBall(t_s=doc["t_s"], position_m=_none_to_nan(doc["position_m"]), frame_index=doc.get("frame_index", 0))


# -- foxglove protobuf types ------------------------------------------------------------------------
def encode_joint_states(log_time_ns: int, names, position, velocity=None) -> bytes:
    msg = _PbJointStates(timestamp=timestamp(log_time_ns))
    vel = [None] * len(names) if velocity is None else velocity.tolist()
    for name, q, qd in zip(names, position.tolist(), vel):
        j = msg.joints.add(name=name, position=q)
        if qd is not None:
            j.velocity = qd
    return msg.SerializeToString()


def decode_joint_states(msg, t_s: float) -> JointStates:
    names = tuple(j.name for j in msg.joints)
    q = np.array([j.position for j in msg.joints], float)
    has_v = len(msg.joints) > 0 and all(j.HasField("velocity") for j in msg.joints)
    v = np.array([j.velocity for j in msg.joints], float) if has_v else None
    return JointStates(t_s=t_s, names=names, position_rad=q, velocity_rad_s=v)


def _quaternions_xyzw(R: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations (validated by the caller) -> (n, 4) unit quaternions, scalar last."""
    try:
        return Rotation.from_matrix(R, assume_valid=True).as_quat()  # skips re-orthonormalising (SciPy >= 1.16)
    except TypeError:
        return Rotation.from_matrix(R).as_quat()


def encode_transforms(log_time_ns: int, parents, children, T_parent_child: np.ndarray) -> bytes:
    """T_parent_child : (n, 4, 4) pose of each child frame in its parent frame (child -> parent)."""
    quat_xyzw = _quaternions_xyzw(T_parent_child[:, :3, :3])
    trans = T_parent_child[:, :3, 3].tolist()
    ts = timestamp(log_time_ns)
    msg = FrameTransforms()
    for parent, child, (x, y, z), (qx, qy, qz, qw) in zip(parents, children, trans, quat_xyzw.tolist()):
        tf = msg.transforms.add(parent_frame_id=parent, child_frame_id=child)
        tf.timestamp.CopyFrom(ts)
        tf.translation.x, tf.translation.y, tf.translation.z = x, y, z
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = qx, qy, qz, qw
    return msg.SerializeToString()


def decode_transforms(msg) -> list[tuple[str, str, np.ndarray]]:
    """Decoded foxglove.FrameTransforms -> [(parent, child, T (4, 4) child -> parent)]."""
    n = len(msg.transforms)
    if n == 0:
        return []
    q = np.array([[t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w] for t in msg.transforms])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_quat(q).as_matrix()
    T[:, :3, 3] = [[t.translation.x, t.translation.y, t.translation.z] for t in msg.transforms]
    return [(t.parent_frame_id, t.child_frame_id, T[i]) for i, t in enumerate(msg.transforms)]
