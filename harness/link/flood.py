"""A hostile peer against a bridge: what a flood of bad and huge frames does to a good client (``rt2 bench link-flood``).

One peer sends ``n_big`` frames of :data:`protocol.MAX_MESSAGE_BYTES` (each a trajectory of the largest
size the protocol allows, malformed only in its last sample, so the bridge pays the full cost of unpacking
it), ``n_small`` small malformed frames, and ``n_oversize`` frames far over the limit (refused by ZeroMQ
unread, ``ZMQ_MAXMSGSIZE``), while a good :class:`WamClient` reads joint states. Figures: the good client's
state rate against the nominal rate, its largest gap between states, whether it lost the link, and the
bridge's resident memory (peak over idle, from ``/proc/PID/status``).
"""

from __future__ import annotations

import subprocess
import sys
import time

import msgpack
import numpy as np
import zmq

from harness.link import protocol
from harness.link.client import WamClient

__all__ = ["flood_frames", "measure_flood"]


def flood_frames(n_big: int, n_small: int, seed: int) -> tuple[bytes, list[bytes]]:
    """``(big, small)``: one frame of exactly MAX_MESSAGE_BYTES (sent ``n_big`` times) and ``n_small`` small bad frames."""
    rng = np.random.default_rng(seed)
    n = protocol.MAX_TRAJECTORY_SAMPLES
    q = rng.uniform(-1, 1, (n, 7)).tolist()
    qdot = [row[:] for row in q]
    qdot[-1] = qdot[-1][:6]  # the last row one joint short: found only at the very end
    msg = {"v": protocol.VERSION, "type": "trajectory", "id": 1, "t_ns": list(range(n)), "q": q, "qdot": qdot}
    msg["pad"] = b""  # an unknown field after the arrays, sized to bring the frame to the limit exactly
    base = len(msgpack.packb(msg, use_bin_type=True)) - 2  # without the pad's 2-byte bin8 header
    msg["pad"] = b"\0" * (protocol.MAX_MESSAGE_BYTES - base - 5)  # a bin32: 5-byte header
    big = msgpack.packb(msg, use_bin_type=True)
    if len(big) != protocol.MAX_MESSAGE_BYTES:  # pragma: no cover - msgpack's header sizes are fixed
        raise AssertionError(f"the big frame has {len(big)} bytes, not {protocol.MAX_MESSAGE_BYTES}")
    kinds = [lambda i: rng.bytes(int(rng.integers(1, 200))),
             lambda i: msgpack.packb({"v": 9, "type": "hold", "id": i}),
             lambda i: msgpack.packb({"v": 1, "type": "launch", "id": i}),
             lambda i: msgpack.packb({"v": 1, "type": "trajectory", "id": i, "t_ns": [0, 1], "q": [[0.0] * 7] * 2,
                                      "qdot": [[float("nan")] * 7] * 2})]
    small = [kinds[i % len(kinds)](i) for i in range(n_small)]
    return big, small


def _rss_bytes(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise ValueError(f"no VmRSS for process {pid}")


def flood(address: str, n_big: int, n_small: int, n_oversize: int, oversize_bytes: int, seed: int,
          timeout_s: float) -> int:
    """Send the flood from one peer (``n_oversize`` frames over the limit on a second socket first); returns the
    replies received. Bounded: every send and the wait for replies give up after ``timeout_s``."""
    big, small = flood_frames(n_big, n_small, seed)
    huge = b"\x01" * int(oversize_bytes)
    ctx = zmq.Context.instance()
    peer, giant = ctx.socket(zmq.DEALER), ctx.socket(zmq.DEALER)
    for s in (peer, giant):
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDTIMEO, int(timeout_s * 1000))
        s.connect(address)
    replies = 0
    try:
        for _ in range(n_oversize):
            giant.send(huge, copy=False)  # refused by ZeroMQ unread: the peer is disconnected and reconnects
        for i in range(max(n_big, len(small))):
            if i < n_big:
                peer.send(big, copy=False)
            if i < len(small):
                peer.send(small[i])
            while peer.poll(0):
                peer.recv()
                replies += 1
        deadline = time.monotonic() + timeout_s
        while replies < n_big + len(small) and time.monotonic() < deadline and peer.poll(1000):
            peer.recv()
            replies += 1
    finally:
        peer.close(0)
        giant.close(0)
    return replies


def measure_flood(address: str, pid: int, *, n_big: int = 64, n_small: int = 2000, n_oversize: int = 8,
                  oversize_bytes: int = 50 << 20, seed: int = 0, idle_s: float = 1.0, timeout_s: float = 120.0,
                  client_timeout_s: float = 0.25) -> dict:
    """Flood the bridge at ``address`` (process ``pid``) from one peer -- a separate process, so that it takes no
    CPU from the good client -- while a good client here (``WamClient(timeout_s=client_timeout_s)``, default
    the client's own) reads states; the figures of the module docstring."""
    cmd = [sys.executable, "-c", "import sys; from harness.link.flood import flood; "
           f"print(flood({address!r}, {int(n_big)}, {int(n_small)}, {int(n_oversize)}, {int(oversize_bytes)}, "
           f"{int(seed)}, {float(timeout_s)}))"]
    with WamClient(address, timeout_s=client_timeout_s) as good:
        nominal_hz = good.control_rate_hz
        rss = []
        t_end = time.monotonic() + idle_s
        while time.monotonic() < t_end:
            rss.append(_rss_bytes(pid))
            time.sleep(0.01)
        idle_rss = float(np.median(rss))
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        try:
            first = time.monotonic()
            good.take_arrivals()
            peak = idle_rss
            while proc.poll() is None and time.monotonic() - first < 2 * timeout_s + 30:
                peak = max(peak, _rss_bytes(pid))
                time.sleep(0.005)
        finally:
            if proc.poll() is None:
                proc.kill()
            out = proc.communicate()[0]
        flood_s = time.monotonic() - first
        arrivals = good.take_arrivals()
        lost = good.lost
    rx = arrivals[:, 2] * 1e-9 - (time.monotonic_ns() * 1e-9 - time.monotonic())  # harness clock, s
    rx = rx[(rx >= first) & (rx <= first + flood_s)]
    gaps = np.diff(rx) if rx.size > 1 else np.array([flood_s])
    return {"n_big": n_big, "big_bytes": protocol.MAX_MESSAGE_BYTES, "n_small": n_small, "n_oversize": n_oversize,
            "oversize_bytes": int(oversize_bytes), "replies": int(out.strip() or -1), "flood_s": round(flood_s, 3),
            "states": int(rx.size), "nominal_hz": nominal_hz,
            "rate_share": round(float(rx.size / (flood_s * nominal_hz)), 4),
            "max_gap_ms": round(float(gaps.max() * 1e3), 2), "p99_gap_ms": round(float(np.percentile(gaps, 99) * 1e3), 2),
            "link_lost": lost, "idle_rss_mb": round(idle_rss / 2**20, 1),
            "rss_peak_over_idle_mb": round((peak - idle_rss) / 2**20, 1)}
