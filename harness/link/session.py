"""``LinkSession``: one session log (MCAP) of a robot over the link, in segments -- one per connection.

The session clock is the harness clock (``time.monotonic_ns``) from the session's start. Each segment
connects a :class:`WamClient`, estimates the robot clock's offset (recorded with its uncertainty in the
``link_segment_<i>`` metadata) and maps every joint state's robot stamp onto the session clock with
it (``/robot/joint_states``). A link loss ends the segment: the states received up to the loss are
written, the reason goes into ``link_segment_<i>_end``, and :class:`LinkLostError` reaches the caller,
who may :meth:`LinkSession.connect` again (a restarted bridge: a new segment of the same session).
:meth:`LinkSession.close` always finishes the file cleanly.
"""

from __future__ import annotations

import time

import numpy as np

from harness.logs import SessionLogWriter
from harness.link.client import LinkLostError, WamClient
from robot_models.robot_interface import JointSamples

__all__ = ["LinkSession"]


class LinkSession:
    """Record the joint states of a robot over the link to ``path`` (see the module docstring).

    metadata : extra session metadata (``kind`` defaults to ``"robot_link"``); ``overwrite``: replace ``path``.
    """

    def __init__(self, path, *, metadata: dict | None = None, overwrite: bool = False):
        self.writer = SessionLogWriter(path, metadata={"kind": "robot_link", **(metadata or {})}, log_images="none",
                                       overwrite=overwrite)
        self.t0_ns = time.monotonic_ns()
        self.client: WamClient | None = None
        self.segments: list[dict] = []
        self.loss: str | None = None  #: why the latest segment ended, None while it runs or after a clean end

    def now_s(self) -> float:
        """The session clock, s."""
        return (time.monotonic_ns() - self.t0_ns) * 1e-9

    def connect(self, address: str, **client_options) -> WamClient:
        """Start a new segment on the robot at ``address`` (options: :class:`WamClient`'s)."""
        if self.client is not None and self.client.lost is None:
            raise ValueError(f"segment {len(self.segments) - 1} is still connected; close it first")
        client = WamClient(address, **client_options)
        est = client.clock.estimate()
        seg = {"index": len(self.segments), "address": address, "bridge_id": client.bridge_id,
               "robot": client.robot_info["robot"], "control_rate_hz": client.control_rate_hz,
               "start_s": self.now_s(), "clock": est.to_dict(), "states": 0}
        self.writer.write_metadata(f"link_segment_{seg['index']}", seg)
        self.segments.append(seg)
        self.client, self.loss = client, None
        return client

    def to_session_s(self, t_robot_s) -> np.ndarray:
        """Robot times (s) of the present segment -> session clock (s), with the segment's offset estimate."""
        est = self.client.clock.estimate()
        return (est.to_harness_ns(np.asarray(t_robot_s, float) * 1e9) - self.t0_ns) * 1e-9

    def record(self, samples: JointSamples) -> None:
        """Write joint states of the present segment (robot clock) to the log on the session clock."""
        if len(samples) == 0:
            return
        t = self.to_session_s(samples.t_s)
        for i in np.flatnonzero(t >= 0):  # states from before the session started are not part of it
            self.writer.write_ground_truth(float(t[i]), None, samples.q[i], samples.qdot[i])
        self.segments[-1]["states"] += int((t >= 0).sum())

    def advance_to(self, t_robot_s: float) -> JointSamples:
        """``client.advance_to`` plus recording; on a link loss records what arrived, ends the segment, re-raises."""
        try:
            samples = self.client.advance_to(t_robot_s)
        except LinkLostError as exc:
            self.end_segment(str(exc))
            raise
        self.record(samples)
        return samples

    def end_segment(self, reason: str | None = None) -> None:
        """Write what is buffered, the segment's end record, and close its client."""
        client, seg = self.client, self.segments[-1]
        self.record(client.take_buffered())
        events = [{"event": e["event"], "reason": e["reason"], "t_robot_s": e["t_ns"] * 1e-9} for e in client.events]
        self.writer.write_metadata(f"link_segment_{seg['index']}_end", {
            "end_s": self.now_s(), "reason": reason or "closed", "states": seg["states"], "events": events,
            "dropped_messages": client.dropped, "clock": client.clock.estimate().to_dict()})
        client.close()
        seg["ended"] = True
        self.loss = reason

    def close(self) -> None:
        """End the open segment (if any) and finish the log file cleanly."""
        if self.segments and not self.segments[-1].get("ended"):
            self.end_segment(None)
        self.writer.close(error=self.loss, extra={"segments": len(self.segments)})

    def __enter__(self) -> "LinkSession":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
