"""The ZeroMQ streams of ``rt2 track``: the tennicam-compatible one and rt2's own richer one.

Two PUB sockets, each bound to its own TCP address (docs/live.md, "Output streams"):

* **tennicam** (default ``tcp://127.0.0.1:7660``): one single-part JSON text message per frame set,
  ``{"num": int, "time": int, "proc_time": float, "obs": [x, y, z] | null}``, exactly what the
  paper's own system (MPI-IS tennicam) sends and what its public client subscribes to unchanged
  (intelligent-soft-robots/tennicam_client, ``src/driver.cpp``: a SUB socket connected to
  ``tcp://HOST:PORT``, subscribed to ``""``, each message parsed whole as JSON; ``obs`` null means
  "no ball", ``time`` is used as nanoseconds in its finite-difference velocity).
* **rt2** (default: the tennicam port + 1): one single-part JSON message per frame set with
  everything rt2 knows (status, support, covariance, inliers, notes, frame id, host and device
  stamps, latency): :func:`rich_message`.

Separate ports, not topics on one socket: the tennicam client subscribes to everything on its
socket and would try to read rt2's messages as its own.

A subscriber that connects late or reads slowly never stalls the tracker: sends are non-blocking
and ZeroMQ drops messages for a subscriber whose queue (``sndhwm`` messages) is full.
"""

from __future__ import annotations

import ipaddress
import json
import math
import re
import time

import numpy as np

__all__ = ["LATENCY", "TENNICAM_PORT", "Publisher", "parse_address", "rich_message", "tennicam_message"]

#: tennicam's port (tennicam_client ``config/config.toml``: ``[server] port = 7660``)
TENNICAM_PORT = 7660

_ADDR = re.compile(r"^(?:tcp://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-*]*)(?::(?P<port>[0-9]+))?$")


def parse_address(text, *, default_port: int = TENNICAM_PORT, default_host: str = "127.0.0.1") -> str:
    """``tcp://HOST:PORT`` from ``HOST:PORT``, ``HOST``, ``:PORT``, ``PORT`` or ``tcp://HOST:PORT``.

    HOST is an IPv4/IPv6 address, ``*`` (every interface), ``localhost`` or an interface name;
    PORT is 0..65535 (0: a free port the system picks). Raises ``ValueError`` quoting the text.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"publish address must be text like tcp://127.0.0.1:{default_port}, got {text!r}")
    s = text.strip()
    if s.isdigit():
        s = f":{s}"
    if "://" in s and not s.startswith("tcp://"):
        raise ValueError(f"publish address {text!r}: only tcp:// addresses are supported")
    m = _ADDR.match(s)
    if m is None:
        raise ValueError(f"publish address {text!r} is not HOST:PORT (e.g. tcp://127.0.0.1:{default_port})")
    host = m.group("host") or default_host
    port = int(m.group("port")) if m.group("port") is not None else int(default_port)
    if not 0 <= port <= 65535:
        raise ValueError(f"publish address {text!r}: port must be 0..65535, got {port}")
    if host not in ("*", "localhost") and not host.startswith("["):
        try:
            ipaddress.ip_address(host)
        except ValueError:
            if not re.match(r"^[A-Za-z][A-Za-z0-9_.\-]*$", host):
                raise ValueError(f"publish address {text!r}: host {host!r} is not an IP address, '*' or an interface name") from None
    return f"tcp://{host}:{port}"


def _num(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


#: what both streams call latency (docs/live.md, "Output streams"): seconds from the first frame's
#: arrival on this host (``t_first_host_s``) to the publication stamp ``t_publish_s``, taken once per
#: frame set when the service has its observation and builds the messages, just before they are encoded
#: and sent; tennicam's ``proc_time`` and rt2's ``latency_s`` are this same number
LATENCY = "t_publish_s - t_first_host_s"


def tennicam_message(num: int, time_ns: int, proc_time_s: float, position_m) -> dict:
    """The tennicam message (docs/live.md): ``position_m`` (3,) world frame metres, or None (no ball).

    num : running frame-set number; time_ns : the frame set's capture time on the host's
    CLOCK_MONOTONIC, nanoseconds (tennicam stamps with ``o80::time_now()``, a steady clock in ns);
    proc_time_s : the latency (:data:`LATENCY`), seconds
    """
    obs = None if position_m is None else [float(v) for v in np.asarray(position_m, float).reshape(3)]
    return {"num": int(num), "time": int(time_ns), "proc_time": float(proc_time_s), "obs": obs}


def _stamps(values) -> list:
    return [_num(v) for v in np.asarray(values, float).ravel().tolist()]


def _candidates(info) -> list | None:
    """Per camera ``[[u, v, score, area_px], ...]``: every candidate the estimator saw (None without them)."""
    uv = getattr(info, "uv_candidates_px", None)
    if uv is None:
        return None
    uv = np.asarray(uv, float)
    cols = [uv, np.asarray(info.scores, float)[..., None]]
    if info.areas_px is not None:  # rtblob has no blob areas: its rows end in null
        cols.append(np.asarray(info.areas_px, float)[..., None])
    rows = np.concatenate(cols, axis=-1)
    have = np.isfinite(uv[..., 0])
    out = [rows[i][have[i]].tolist() for i in range(rows.shape[0])]
    if info.areas_px is None:
        for row in (r for cam in out for r in cam):
            row.append(None)
    return out


def rich_message(num: int, afs, obs, *, t_first_host_s: float, camera_names, t_publish_s: float | None = None,
                 info=None) -> dict:
    """rt2's own message for one frame set (every field documented in docs/live.md).

    afs : the :class:`~harness.live.frames.AssembledFrameSet`; obs : its ``tracker.BallObservation``;
    t_first_host_s / t_publish_s : ``time.monotonic()`` seconds of the first frame's arrival and of
    the publication, the one stamp both streams carry (:data:`LATENCY`; None: not stamped, ``latency_s`` null)
    info : the tracker's ``PipelineInfo`` (``candidates``: what the estimator saw; None: not sent)
    """
    pos = None if obs.position_m is None else [float(v) for v in obs.position_m]
    cov = None if obs.covariance_m2 is None else np.asarray(obs.covariance_m2, float).tolist()
    uv = None if obs.uv_px is None else [[_num(a), _num(b)] for a, b in np.asarray(obs.uv_px, float).tolist()]
    return {
        "num": int(num),
        "frame_id": int(afs.frame_id),
        "tracker": obs.tracker,
        "status": str(obs.status),
        "position_m": pos,
        "covariance_m2": cov,
        "support": int(obs.support),
        "inliers": [bool(v) for v in np.asarray(obs.inliers).tolist()],
        "cameras": list(camera_names),
        "uv_px": uv,
        "t_s": float(afs.frameset.t_s),
        "t_host_s": _stamps(afs.t_host_s),
        "t_device_s": _stamps(afs.t_device_s),
        "t_first_host_s": float(t_first_host_s),
        "t_assembled_s": float(afs.t_assembled_s),
        "t_publish_s": None if t_publish_s is None else float(t_publish_s),
        "tracker_latency_s": float(obs.latency_s),
        "latency_s": None if t_publish_s is None else float(t_publish_s - t_first_host_s),
        "notes": [str(n) for n in (*afs.notes, *obs.notes)],
        "candidates": None if info is None else _candidates(info),
    }


class Publisher:
    """The two PUB sockets (module docstring). ``tennicam_addr`` / ``rich_addr``: ``tcp://HOST:PORT``
    (see :func:`parse_address`), either may be None (not published).

    sndhwm : messages queued per subscriber at most; beyond it ZeroMQ drops (never blocks)
    A bind that fails (port in use, address not on this host) raises ``ValueError`` naming the address.
    """

    def __init__(self, tennicam_addr: str | None, rich_addr: str | None = None, *, sndhwm: int = 1000):
        import zmq

        if isinstance(sndhwm, bool) or not isinstance(sndhwm, int) or sndhwm < 1:
            raise ValueError(f"sndhwm must be a positive number of messages, got {sndhwm!r}")
        self._zmq = zmq
        self._ctx = zmq.Context()
        self._sockets: dict[str, object] = {}
        self.addresses: dict[str, str] = {}
        self.sent = {"tennicam": 0, "rt2": 0}
        self.failed = {"tennicam": 0, "rt2": 0}
        try:
            for name, addr in (("tennicam", tennicam_addr), ("rt2", rich_addr)):
                if addr is None:
                    continue
                sock = self._ctx.socket(zmq.PUB)
                sock.setsockopt(zmq.SNDHWM, sndhwm)
                sock.setsockopt(zmq.LINGER, 0)
                self._sockets[name] = sock
                try:
                    sock.bind(addr)
                except zmq.ZMQError as exc:
                    raise ValueError(f"cannot publish the {name} stream on {addr}: {exc.strerror}") from None
                self.addresses[name] = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        except BaseException:
            self.close()
            raise

    def publish(self, tennicam: dict | None, rich: dict | None = None) -> None:
        """Send one frame set's messages, as they are (JSON), without blocking; a stream that is off or a
        message that is None is skipped. The messages are complete when they come here (the service
        stamps them): the transport neither stamps nor changes them."""
        zmq = self._zmq
        for name, msg in (("tennicam", tennicam), ("rt2", rich)):
            sock = self._sockets.get(name)
            if sock is None or msg is None:
                continue
            try:
                sock.send(json.dumps(msg, allow_nan=False).encode(), zmq.NOBLOCK)
                self.sent[name] += 1
            except zmq.Again:
                self.failed[name] += 1

    def close(self) -> None:
        for sock in self._sockets.values():
            sock.close(linger=0)
        self._sockets = {}
        self._ctx.term()

    def __enter__(self) -> "Publisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
