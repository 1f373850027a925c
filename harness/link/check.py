"""Measure a robot link (``rt2 robot check``): state rate, gaps, delivery delay, clock offset, round trips,
and the time from a command to the first motion."""

from __future__ import annotations

import time

import numpy as np

from harness.link.client import WamClient

__all__ = ["check_link"]


def _q(values_ms) -> dict:
    v = np.asarray(values_ms, float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"p50": None, "p99": None, "max": None}
    return {"p50": round(float(np.median(v)), 3), "p99": round(float(np.percentile(v, 99)), 3),
            "max": round(float(v.max()), 3)}


def _move(wam: WamClient, move_rad: float) -> dict:
    """Command the last joint (the WAM's joint_7) out by move_rad and back (1 s); the acknowledgement and the
    onset of motion."""
    st = wam.read_state()
    j = wam.n_joints - 1
    q0 = st.q.copy()
    q1 = q0.copy()
    q1[j] = np.clip(q0[j] + move_rad, wam.kinematics.q_min[j] + 0.05, wam.kinematics.q_max[j] - 0.05)
    lead_s = 0.05
    t_start = st.t_s + lead_s
    wam.advance_to(st.t_s)
    t_send = time.monotonic_ns()
    wam.command_trajectory([t_start, t_start + 0.5, t_start + 1.0], np.stack([q0, q1, q0]), np.zeros((3, wam.n_joints)))
    ack_ms = (time.monotonic_ns() - t_send) / 1e6
    s = wam.advance_to(t_start + 1.3)
    before = s.t_s < t_start
    noise = float(np.std(s.q[before, j])) if before.sum() > 5 else 0.0
    threshold = max(4 * noise, 2e-4)  # well above encoder noise and quantisation
    moved = (s.t_s >= t_start) & (np.abs(s.q[:, j] - q0[j]) > threshold)
    onset_ms = float((s.t_s[np.argmax(moved)] - t_start) * 1e3) if moved.any() else float("nan")
    return {"command_ack_ms": round(ack_ms, 3), "motion_onset_after_start_ms": round(onset_ms, 3),
            "onset_threshold_rad": threshold, "lead_s": lead_s, "joint": wam.kinematics.joint_names[j],
            "amplitude_rad": float(q1[j] - q0[j]), "returned_within_rad": round(float(abs(s.q[-1, j] - q0[j])), 5)}


def check_link(address: str, *, duration_s: float = 3.0, move_rad: float | None = None, kinematics=None) -> dict:
    """Measure the link at ``address`` (see the module docstring); returns the figures as a dict.
    ``kinematics``: the arm's (:class:`robot_models.ArmKinematics`; default the WAM's)."""
    if not 0.2 <= float(duration_s) <= 3600:
        raise ValueError(f"--duration must be in [0.2, 3600] s, got {duration_s!r}")
    with WamClient(address, kinematics=kinematics, heartbeat_s=None if move_rad is None else 0.1) as wam:
        wam.sync_clock(32)
        wam.take_arrivals()
        rtt = []
        t_end = time.monotonic() + float(duration_s)
        while time.monotonic() < t_end:
            t0 = time.monotonic_ns()
            wam.sync_clock(1)  # a clock exchange is a request like any other
            rtt.append((time.monotonic_ns() - t0) / 1e6)
            time.sleep(0.05)
        arr = wam.take_arrivals()
        est = wam.clock.estimate()
        motion = _move(wam, float(move_rad)) if move_rad is not None else None
        info = wam.robot_info
        seq, t_ns, rx_ns = arr[:, 0], arr[:, 1], arr[:, 2]
        span_s = (t_ns[-1] - t_ns[0]) * 1e-9 if len(arr) > 1 else float("nan")
        lost = int(np.maximum(np.diff(seq) - 1, 0).sum()) if len(arr) > 1 else 0
        return {
            "robot": info["robot"], "address": address, "bridge_id": wam.bridge_id,
            "control_rate_hz": wam.control_rate_hz, "watchdog_s": info["watchdog_s"],
            "states": int(len(arr)), "state_rate_hz": round(float((len(arr) - 1) / span_s), 2) if len(arr) > 1 else None,
            "states_lost": lost, "dropped_malformed": wam.dropped,
            "stamp_interval_ms": _q(np.diff(t_ns) / 1e6), "arrival_interval_ms": _q(np.diff(rx_ns) / 1e6),
            "delivery_ms": _q((rx_ns - est.to_harness_ns(t_ns)) / 1e6),
            "clock": est.to_dict(), "request_round_trip_ms": _q(rtt), "move": motion,
        }
