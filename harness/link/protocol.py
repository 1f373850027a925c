"""The robot link's wire protocol: message schema, encoding (msgpack) and validation (docs/robot_link.md).

Two ZeroMQ sockets on the robot side (the *bridge*):

* ``ROUTER`` at the command address (``tcp://HOST:PORT``): the harness sends requests from a ``DEALER``
  and gets one reply per request: ``hello``, ``trajectory``, ``hold``, ``heartbeat``, ``clock``;
* ``PUB`` at the state address (told in the ``hello`` reply): ``state`` at the robot's rate and ``event``.

Every message is one msgpack map with ``v`` (protocol version, :data:`VERSION`) and ``type``. Robot
times are integer nanoseconds ``t_ns`` on the robot's own clock (0 at the bridge's session start);
joint vectors are lists of n floats (rad, rad/s, N m), one per joint of the arm in the order of the
``welcome``'s ``joint_names`` (the URDF's: the WAM's 7 ``joint_1 .. joint_7``, a UR10's 6): the ``welcome``
sets n for the session (1 .. :data:`MAX_JOINTS`), and every vector of a session has n entries.
:func:`decode` checks a frame against :data:`SCHEMA` and raises :class:`ProtocolError` quoting what
was received; nothing malformed gets further on either side.
"""

from __future__ import annotations

import array
import gc
import itertools
import math
import time

import msgpack
import numpy as np

from robot_models.limits import MAX_JOINTS  # an arm's joints: at most this many (its URDF is refused beyond)

__all__ = ["MAX_JOINTS", "MAX_MESSAGE_BYTES", "MAX_TRAJECTORY_SAMPLES", "MODES", "ProtocolError", "SCHEMA", "VERSION", "decode",
           "decode_request", "encode", "request_id"]

VERSION = 1
MAX_MESSAGE_BYTES = 4 << 20  #: larger frames are rejected before unpacking
MAX_TRAJECTORY_SAMPLES = 20000  #: 40 s at 500 Hz
MODES = ("idle", "track", "hold", "watchdog")  #: what the robot is doing, in every ``state``
EVENTS = ("watchdog_hold", "rejected", "started", "stopping")

_VEC = "vec"  # list of n_joints finite floats
_VEC_OR_NIL = "vec|nil"
_MAT = "mat"  # list of N lists of n_joints finite floats
_MAT_OR_NIL = "mat|nil"
_INT = "int"
_INTS = "ints"  # list of N ints
_STR = "str"
_FLOAT = "float"
_FLOAT_OR_NIL = "float|nil"
_INT_OR_NIL = "int|nil"
_DICT_OR_NIL = "dict|nil"
_STRS = "strs"

#: type -> {field: kind}; every field is required (nil where allowed), unknown fields are rejected
SCHEMA: dict[str, dict[str, str]] = {
    # requests, harness -> robot (DEALER -> ROUTER); ``id`` is echoed in the reply
    "hello": {"id": _INT, "client": _STR},
    "trajectory": {"id": _INT, "t_ns": _INTS, "q": _MAT, "qdot": _MAT_OR_NIL},
    "hold": {"id": _INT},
    "heartbeat": {"id": _INT},
    "clock": {"id": _INT, "t0_ns": _INT},
    # replies, robot -> harness
    "welcome": {"id": _INT, "robot": _STR, "bridge_id": _STR, "joint_names": _STRS, "control_rate_hz": _FLOAT,
                "q_min": _VEC, "q_max": _VEC, "qdot_max": _VEC, "state_endpoint": _STR, "watchdog_s": _FLOAT,
                "t_ns": _INT},
    "ok": {"id": _INT, "t_ns": _INT},
    "error": {"id": _INT_OR_NIL, "reason": _STR},
    "clock_reply": {"id": _INT, "t0_ns": _INT, "t1_ns": _INT, "t2_ns": _INT},
    # stream, robot -> harness (PUB -> SUB)
    "state": {"seq": _INT, "t_ns": _INT, "q": _VEC, "qdot": _VEC, "effort": _VEC_OR_NIL, "mode": _STR,
              "cmd_id": _INT, "sim": _DICT_OR_NIL},
    "event": {"t_ns": _INT, "event": _STR, "reason": _STR},
}



class ProtocolError(ValueError):
    """A frame that is not a valid robot-link message; the text says which field and what was received."""


def encode(msg_type: str, *, n_joints: int | None = None, **fields) -> bytes:
    """One message as bytes, checked against :data:`SCHEMA` (a sender never emits what a receiver would reject).
    ``n_joints``: the session's joint count (every joint vector must have it); None: the message's own
    (a ``welcome``'s from its ``joint_names``, another's from its first joint vector, the others alike)."""
    msg = {"v": VERSION, "type": msg_type, **fields}
    _check(msg, n_joints)
    return msgpack.packb(msg, use_bin_type=True)


def decode(frame: bytes, expect: tuple[str, ...] | None = None, n_joints: int | None = None) -> dict:
    """Unpack and validate one frame; ``expect``: the message types allowed here; ``n_joints``: the session's
    joint count (the ``welcome``'s; None: any consistent count, as :func:`encode`). Raises ProtocolError."""
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"a message must be bytes, got {type(frame).__name__}")
    if len(frame) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {len(frame)} bytes exceeds the limit of {MAX_MESSAGE_BYTES}")
    try:
        msg = msgpack.unpackb(frame, raw=False, strict_map_key=True, max_array_len=MAX_TRAJECTORY_SAMPLES + 16)
    except Exception as exc:  # msgpack raises several types (ExtraData, FormatError, ValueError, ...)
        raise ProtocolError(f"not a msgpack message ({type(exc).__name__}: {str(exc)[:80]})") from None
    _check(msg, n_joints)
    if expect is not None and msg["type"] not in expect:
        raise ProtocolError(f"message type {msg['type']!r} not expected here; expected one of {list(expect)}")
    return msg


_YIELD_S = 0.001  #: unpacking offers the GIL to other threads at least this often (checked every _CHECK_ROWS rows)
_CHECK_ROWS = 32


class _RequestShape:
    """Hooks that abort unpacking a request as soon as its shape is one no request has, and keep its joint
    vectors (lists of ``n_joints`` numbers, one a float at least) as floats in one buffer (a list of them
    becomes an (N, n_joints) float64 array): the numbers of a vector are freed as soon as it is buffered,
    so a hostile frame costs no more than the largest valid request and its refusal frees no large
    structure. A list of ``n_joints`` integers (a short ``t_ns``, or a joint vector of whole numbers) is kept
    as it is and placed among the rows when its list of rows comes. Every :data:`_YIELD_S` the GIL is
    offered to other threads (a bridge's control loop keeps its schedule while its intake thread decodes)."""

    def __init__(self, n_joints: int):
        self.n = n_joints
        self.rows = self.lists = self.maps = 0
        self._buf = array.array("d")
        self._pending = 0  # rows in the buffer not yet claimed by a list of rows
        self._next_yield = time.perf_counter() + _YIELD_S

    def list_hook(self, lst: list):
        if len(lst) == self.n and _NUMBER_TYPES.issuperset(map(type, lst)):  # a joint vector (or a short t_ns)
            self.rows += 1
            if self.rows > 2 * MAX_TRAJECTORY_SAMPLES:
                raise ProtocolError(f"more than {2 * MAX_TRAJECTORY_SAMPLES} joint vectors: no request is that large")
            if not self.rows % _CHECK_ROWS and time.perf_counter() > self._next_yield:
                time.sleep(0)  # hand the GIL over: a hook call alone does not (CPython 3.11)
                self._next_yield = time.perf_counter() + _YIELD_S
            if type(lst[0]) is not float and float not in map(type, lst):  # integers only: maybe not a joint vector
                return lst  # kept as it is
            self._buf.extend(lst)
            self._pending += 1
            return None
        nones = lst.count(None) if lst else -1
        if nones == self._pending and (nones == len(lst) or self._rows_only(lst)):  # the list of those rows
            buffered = np.frombuffer(self._buf, dtype=np.float64).reshape(-1, self.n)
            if nones == len(lst):
                rows = buffered.copy()
            else:  # some rows were integers only, kept as lists
                rows = np.empty((len(lst), self.n))
                is_buffered = np.fromiter((x is None for x in lst), bool, len(lst))
                rows[is_buffered] = buffered
                kept = np.flatnonzero(~is_buffered)
                rows[kept] = np.array([lst[i] for i in kept], dtype=np.float64)  # one conversion, not a row at a time
            self._buf, self._pending = array.array("d"), 0
            return rows
        self.lists += 1
        if self.lists > 3:
            raise ProtocolError(f"nested lists of a shape no request has (this arm's joint vectors have {self.n} numbers)")
        return lst

    def _rows_only(self, lst: list) -> bool:
        """Every item a buffered row (None) or a kept list of ``n`` integers."""
        return all(x is None or (type(x) is list and len(x) == self.n and all(type(v) is int for v in x)) for x in lst)

    def object_hook(self, obj: dict) -> dict:
        self.maps += 1
        if self.maps > 1:
            raise ProtocolError("a map inside the message: no request has one")
        return obj


def decode_request(frame: bytes, expect: tuple[str, ...], n_joints: int) -> dict:
    """:func:`decode` for requests arriving at a bridge from any peer: the same checks, with the unpacking
    aborted as soon as the frame cannot be a request (:class:`_RequestShape`), and string/binary lengths capped.
    ``n_joints``: the bridge's arm's. Lists of joint vectors (``q``, ``qdot`` of a trajectory) come back as
    (N, n_joints) float64 arrays."""
    _check_n(n_joints)
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"a message must be bytes, got {type(frame).__name__}")
    if len(frame) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {len(frame)} bytes exceeds the limit of {MAX_MESSAGE_BYTES}")
    shape = _RequestShape(n_joints)
    collecting = gc.isenabled()
    gc.disable()  # a message holds no cycles: no collection pass (which holds the GIL) for each thousand rows
    try:
        msg = msgpack.unpackb(frame, raw=False, strict_map_key=True, max_array_len=MAX_TRAJECTORY_SAMPLES + 16,
                              max_map_len=64, max_str_len=4096, max_bin_len=4096, max_ext_len=0,
                              list_hook=shape.list_hook, object_hook=shape.object_hook)
    except ProtocolError:
        raise
    except Exception as exc:  # msgpack raises several types (ExtraData, FormatError, ValueError, ...)
        raise ProtocolError(f"not a msgpack message ({type(exc).__name__}: {str(exc)[:80]})") from None
    finally:
        if collecting:
            gc.enable()
    _check(msg, n_joints)
    if msg["type"] not in expect:
        raise ProtocolError(f"message type {msg['type']!r} not expected here; expected one of {list(expect)}")
    return msg


def request_id(frame: bytes) -> int | None:
    """The ``id`` of a frame that failed :func:`decode`, when it can still be read (for the ``error`` reply), else None."""
    try:
        msg = msgpack.unpackb(frame, raw=False, max_array_len=MAX_TRAJECTORY_SAMPLES + 16) if len(frame) <= MAX_MESSAGE_BYTES else None
    except Exception:  # the frame is not msgpack: no id to echo
        return None
    rid = msg.get("id") if isinstance(msg, dict) else None
    return rid if _is_int(rid) else None


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_n(n_joints) -> None:
    if not _is_int(n_joints) or not 1 <= n_joints <= MAX_JOINTS:
        raise ValueError(f"n_joints must be an integer in 1..{MAX_JOINTS}, got {n_joints!r}")


def _session_n(kind: str, msg: dict, spec: dict, n_joints: int | None) -> int:
    """The joint count the vectors of this message must have: a ``welcome``'s from its ``joint_names``,
    else ``n_joints`` or (None) the first joint vector's length."""
    if kind == "welcome":
        names = msg.get("joint_names")
        if isinstance(names, (list, tuple)) and not 1 <= len(names) <= MAX_JOINTS:
            raise ProtocolError(f"welcome: joint_names must name 1..{MAX_JOINTS} joints, got {len(names)}")
        if n_joints is not None and isinstance(names, (list, tuple)) and len(names) != n_joints:
            raise ProtocolError(f"welcome: {len(names)} joint_names, this side expects {n_joints} joints")
        return len(names) if isinstance(names, (list, tuple)) else 0
    if n_joints is not None:
        _check_n(n_joints)
        return n_joints
    for name, field_kind in spec.items():  # the first vector present decides; the others must agree
        value = msg.get(name)
        if value is None or field_kind.split("|")[0] not in (_VEC, _MAT):
            continue
        row = value[0] if field_kind.startswith(_MAT) and isinstance(value, (list, tuple, np.ndarray)) and len(value) else value
        if isinstance(row, (list, tuple, np.ndarray)) and 1 <= len(row) <= MAX_JOINTS:
            return len(row)
        raise ProtocolError(f"{kind}: {name} must hold joint vectors of 1..{MAX_JOINTS} finite numbers, got {_short(value)}")
    return 0


def _check(msg, n_joints: int | None = None) -> None:
    if not isinstance(msg, dict):
        raise ProtocolError(f"a message must be a map, got {type(msg).__name__}")
    if msg.get("v") != VERSION:
        raise ProtocolError(f"protocol version {_short(msg.get('v'))} not supported; this side speaks v={VERSION}")
    kind = msg.get("type")
    if kind not in SCHEMA:
        raise ProtocolError(f"unknown message type {_short(kind)}; valid: {sorted(SCHEMA)}")
    spec = SCHEMA[kind]
    extra = sorted(set(msg) - set(spec) - {"v", "type"})
    if extra:
        raise ProtocolError(f"{kind}: unknown field(s) {extra}")
    missing = [name for name in spec if name not in msg]
    if missing:
        raise ProtocolError(f"{kind}: missing field {missing[0]!r}")
    n = _session_n(kind, msg, spec, n_joints)
    for name, field_kind in spec.items():
        _check_field(kind, name, field_kind, msg[name], n)
    if kind == "trajectory":
        n = len(msg["t_ns"])
        if n < 2 or n > MAX_TRAJECTORY_SAMPLES:
            raise ProtocolError(f"trajectory: t_ns must hold 2..{MAX_TRAJECTORY_SAMPLES} samples, got {n}")
        for name in ("q", "qdot"):
            if msg[name] is not None and len(msg[name]) != n:
                raise ProtocolError(f"trajectory: {name} has {len(msg[name])} rows, t_ns has {n}")
    if kind == "state" and msg["mode"] not in MODES:
        raise ProtocolError(f"state: mode {_short(msg['mode'])} is not one of {list(MODES)}")
    if kind == "event" and msg["event"] not in EVENTS:
        raise ProtocolError(f"event: {_short(msg['event'])} is not one of {list(EVENTS)}")


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and -(1 << 63) <= x < (1 << 63)


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_vec(kind, name, value, n, where="") -> None:
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(_finite(x) for x in value):
        raise ProtocolError(f"{kind}: {name}{where} must be {n} finite numbers, got {_short(value)}")


_NUMBER_TYPES = frozenset((int, float))
_CHUNK_ROWS = 2048


def _plain_numbers(value, shape: tuple, kinds: str = "if") -> bool:
    """True if ``value`` is certainly valid: of ``shape``, finite numbers of numpy ``kinds`` ("i": all 64-bit
    integers; "if": integers and floats), every element a plain int or float (not a bool, which numpy would
    quietly take as a number). One array conversion instead of a Python call per element: a
    trajectory of 700 samples is ~10,000 numbers, checked on both sides of the link at every re-plan. False
    means "not sure": the per-element check decides and names the culprit."""
    if len(value) > _CHUNK_ROWS:  # in chunks: another thread may run between them (a bridge's control loop)
        return all(_plain_numbers(value[i:i + _CHUNK_ROWS], (len(value[i:i + _CHUNK_ROWS]),) + shape[1:], kinds)
                   for i in range(0, len(value), _CHUNK_ROWS))
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError, OverflowError):  # rows of different lengths, odd objects
        return False
    if arr.dtype.kind not in kinds or arr.shape != shape or not np.isfinite(arr).all():
        return False
    elements = itertools.chain.from_iterable(value) if arr.ndim == 2 else value
    return _NUMBER_TYPES.issuperset(map(type, elements))


def _check_field(kind: str, name: str, field_kind: str, value, n: int) -> None:
    if value is None and field_kind.endswith("|nil"):
        return
    base = field_kind.split("|")[0]
    if base == _INT:
        if not _is_int(value):
            raise ProtocolError(f"{kind}: {name} must be a 64-bit integer, got {_short(value)}")
    elif base == _FLOAT:
        if not _finite(value):
            raise ProtocolError(f"{kind}: {name} must be a finite number, got {_short(value)}")
    elif base == _STR:
        if not isinstance(value, str) or len(value) > 1000:
            raise ProtocolError(f"{kind}: {name} must be a string (<= 1000 characters), got {_short(value)}")
    elif base == _STRS:
        if not isinstance(value, (list, tuple)) or not all(isinstance(s, str) for s in value):
            raise ProtocolError(f"{kind}: {name} must be a list of strings, got {_short(value)}")
    elif base == "dict":
        if not isinstance(value, dict):
            raise ProtocolError(f"{kind}: {name} must be a map or nil, got {_short(value)}")
    elif base == _INTS:
        if isinstance(value, (list, tuple)) and _plain_numbers(value, (len(value),), "i"):
            return
        if not isinstance(value, (list, tuple)) or not all(_is_int(x) for x in value):
            raise ProtocolError(f"{kind}: {name} must be a list of integers, got {_short(value)}")
    elif base == _VEC:
        _check_vec(kind, name, value, n)
    elif base == _MAT:
        if isinstance(value, np.ndarray):  # from decode_request: already numbers, one row per joint vector
            if value.ndim == 2 and value.shape[1] == n and value.shape[0] and np.isfinite(value).all():
                return
            bad = np.argwhere(~np.isfinite(value))[:1]
            where = f"[{int(bad[0][0])}]" if bad.size else ""
            raise ProtocolError(f"{kind}: {name}{where} must be {n} finite numbers")
        if isinstance(value, (list, tuple)) and value and _plain_numbers(value, (len(value), n)):
            return
        if not isinstance(value, (list, tuple)):
            raise ProtocolError(f"{kind}: {name} must be a list of joint vectors, got {_short(value)}")
        for i, row in enumerate(value):
            _check_vec(kind, name, row, n, f"[{i}]")
    else:  # pragma: no cover - SCHEMA and this function are written together
        raise AssertionError(field_kind)
