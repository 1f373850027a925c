"""The streams side of the live accuracy run (:mod:`harness.experiments.accuracy.live`): rt2's tracker stream read as
observations and candidates, the clocks seen in it, and the latency budget.

* :class:`TrackerStream` subscribes to ``rt2 track``'s rt2 stream (docs/live.md, "rt2"); a stream that sends
  nothing, or a tracker process that stopped, is a one-line error naming it (:class:`StreamSilent`);
* :func:`observation_from_message` / :func:`candidates_from_message` turn a message back into the tracker's
  ``BallObservation`` and the estimator's candidates (what the session log and ``rt2 reevaluate`` need);
* :func:`camera_offsets` is what one-way stamps vs arrival say of each camera's clock;
* :func:`latency_budget` / :func:`format_budget`: camera exposure -> observation here, observation -> command,
  command -> motion.
"""

from __future__ import annotations

import json
import time

import numpy as np

from tracker import BallObservation, Status

__all__ = ["StreamSilent", "TrackerStream", "camera_offsets", "candidates_from_message", "format_budget",
           "latency_budget", "motion_onset_ms", "observation_from_message", "wait_first"]


class StreamSilent(ValueError):
    """The tracker stream sent nothing (in time): the message names the address and the wait."""

def observation_from_message(m: dict) -> BallObservation:
    """A ``tracker.BallObservation`` from one message of rt2's stream (docs/live.md, "rt2")."""
    pos = None if m["position_m"] is None else np.asarray(m["position_m"], float)
    cov = None if m["covariance_m2"] is None else np.asarray(m["covariance_m2"], float)
    uv = None if m["uv_px"] is None else np.array([[np.nan if v is None else v for v in row] for row in m["uv_px"]], float)
    return BallObservation(float(m["t_s"]), pos, cov, int(m["support"]), np.asarray(m["inliers"], bool),
                           Status(m["status"]), float(m["tracker_latency_s"]), str(m["tracker"]), uv,
                           tuple(m.get("notes") or ()))


def candidates_from_message(m: dict, n_cams: int, k: int):
    """(uv (n_cams, k, 2), scores (n_cams, k), areas (n_cams, k)) from the message's per-camera candidate rows."""
    uv = np.full((n_cams, k, 2), np.nan)
    scores = np.full((n_cams, k), np.nan)
    areas = np.full((n_cams, k), np.nan)
    for i, rows in enumerate(m.get("candidates") or ()):
        r = np.asarray(rows, float).reshape(-1, 4)[:k]
        uv[i, : len(r)] = r[:, :2]
        scores[i, : len(r)] = r[:, 2]
        areas[i, : len(r)] = r[:, 3]
    return uv, scores, areas


class TrackerStream:
    """SUB to rt2's stream; ``get(timeout_s)`` -> (message, receipt time) or None."""

    def __init__(self, address: str, alive=None):
        import zmq

        self._alive = alive  # None, or a callable: None while the publisher lives, else why it is gone

        if not isinstance(address, str) or not address.startswith(("tcp://", "ipc://")):
            raise ValueError(f"--tracker-stream must be rt2's stream address like tcp://127.0.0.1:7661, got {address!r}")
        self.address = address
        self._sock = zmq.Context.instance().socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.RCVHWM, 100000)
        self._sock.setsockopt(zmq.SUBSCRIBE, b"")
        self._sock.connect(address)

    def _poll(self, timeout_s: float) -> bool:
        """Wait for a message; in slices, so that a publisher process that died is reported at once."""
        t_end = time.monotonic() + timeout_s
        while True:
            left = t_end - time.monotonic()
            if self._sock.poll(max(0, int(min(left, 0.5) * 1000))):
                return True
            gone = None if self._alive is None else self._alive()
            if gone:
                raise ValueError(gone)
            if left <= 0.5:
                return False

    def latest(self, timeout_s: float):
        """The newest message waiting (older ones are dropped unparsed), or None after ``timeout_s``."""
        import zmq

        if not self._poll(timeout_s):
            return None
        raw = self._sock.recv()
        while True:
            try:
                raw = self._sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
        return self._parse(raw, time.monotonic())

    def get(self, timeout_s: float):
        if not self._poll(timeout_s):
            return None
        return self._parse(self._sock.recv(), time.monotonic())

    def _parse(self, raw: bytes, t: float):
        try:
            m = json.loads(raw)
        except ValueError:
            raise ValueError(f"the tracker stream at {self.address} sent something that is not rt2's JSON message "
                             f"({raw[:60]!r}...): is that the rt2 stream (the tennicam port + 1)?") from None
        if not isinstance(m, dict) or "frame_id" not in m or "candidates" not in m:
            raise ValueError(f"the tracker stream at {self.address} is not rt2's stream with candidates (fields "
                             f"{sorted(m) if isinstance(m, dict) else type(m).__name__}): connect to `rt2 track`'s "
                             "rt2 stream (--publish-rt2, default the tennicam port + 1)")
        return m, t

    def close(self) -> None:
        self._sock.close(linger=0)


def _quantiles_ms(v) -> dict:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)] * 1e3
    if not v.size:
        return {"p50": None, "p99": None, "max": None}
    return {"p50": round(float(np.median(v)), 3), "p99": round(float(np.percentile(v, 99)), 3),
            "max": round(float(v.max()), 3)}


def motion_onset_ms(t_s, q, t_start_s: float) -> float:
    """Robot time from the trajectory's start to the first reported state that left the start pose by more
    than the encoder noise seen before it (all joints), ms; NaN when the states never moved."""
    before = t_s < t_start_s
    q0 = q[before][-1] if before.any() else q[0]
    noise = float(np.max(np.std(q[before], axis=0))) if before.sum() > 5 else 0.0
    dev = np.max(np.abs(q - q0), axis=1)
    moved = (t_s >= t_start_s) & (dev > max(4 * noise, 2e-4))
    return float((t_s[np.argmax(moved)] - t_start_s) * 1e3) if moved.any() else float("nan")


def latency_budget(messages: list, t_recv: np.ndarray, command: dict) -> dict:
    """The run's latency budget (printed and logged): camera exposure -> observation at this process (split into
    exposure -> first frame's arrival at the tracker, arrival -> publication, publication -> receipt here),
    observation -> command (none in this experiment) and command -> motion."""
    t_s = np.array([m["t_s"] for m in messages])
    first = np.array([m["t_first_host_s"] for m in messages])
    pub = np.array([np.nan if m["t_publish_s"] is None else m["t_publish_s"] for m in messages])
    return {
        "exposure_to_observation_ms": _quantiles_ms(t_recv - t_s),
        "exposure_to_arrival_ms": _quantiles_ms(first - t_s),
        "arrival_to_publish_ms": _quantiles_ms(pub - first),
        "publish_to_harness_ms": _quantiles_ms(t_recv - pub),
        "observation_to_command": "none: the accuracy motion is commanded once, ahead of its frames, and no command "
                                  "depends on an observation (a playing policy's budget has this step)",
        "command_to_motion": command,
    }


def format_budget(b: dict) -> str:
    def q(d):
        return "n/a" if d["p50"] is None else f"p50 {d['p50']:.1f} / p99 {d['p99']:.1f} / max {d['max']:.1f} ms"

    c = b["command_to_motion"]
    return "\n".join([
        "latency budget:",
        f"  camera exposure -> observation here: {q(b['exposure_to_observation_ms'])}",
        f"    exposure -> frame at the tracker {q(b['exposure_to_arrival_ms'])}; tracker (arrival -> published) "
        f"{q(b['arrival_to_publish_ms'])}; stream -> this process {q(b['publish_to_harness_ms'])}",
        f"  observation -> command: {b['observation_to_command']}",
        f"  command -> motion: trajectory acknowledged in {c['command_ack_ms']:.1f} ms (sent {c['lead_ms']:.0f} ms ahead "
        f"of its start); first reported motion {c['motion_onset_after_start_ms']:.1f} ms after the start (the motion "
        "starts from rest, so this includes its slow first millimetres)",
    ])


def wait_first(stream: TrackerStream, timeout_s: float):
    got = stream.get(timeout_s)
    if got is None:
        raise StreamSilent(f"the tracker stream at {stream.address} sent nothing in {timeout_s:g} s: is `rt2 track` "
                           "running and publishing its rt2 stream there?")
    return got

def camera_offsets(msgs: list, names) -> dict:
    """Per camera the offset of its stamps to the host clock from frame stamps vs arrival (the 5 % quantile
    of arrival - device stamp, as :class:`harness.live.sources.clock.ClockOffsetEstimator`) and its spread."""
    from harness.live.sources.clock import ClockOffsetEstimator

    out = {}
    for i, name in enumerate(names):
        est = ClockOffsetEstimator()
        for m in msgs:
            dev, host = m["t_device_s"][i], m["t_host_s"][i]
            if dev is not None and host is not None:
                est.add(float(host), float(dev))
        off = est.estimate()
        out[name] = None if off is None else {"offset_ms": round(off.offset_s * 1e3, 3),
                                              "spread_ms": round(off.spread_s * 1e3, 3), "frames": off.n_samples}
    return out
