"""``rt2 play observe``: the synthetic tracker of ``rt2 play --live`` as its own process.

It subscribes to the world's lab truth stream and serve events (harness/experiments/play/world.py) and publishes,
exactly as ``rt2 track`` does (harness/live/publish.py: rt2's rich JSON stream, optionally the
tennicam one), what the in-process ``--source synthetic`` gives the filter: for ball i of a session of
seed S it captures frame sets at ``t_serve + phase + k / rate_hz`` (the in-process phase), draws each
observation with :class:`harness.experiments.play.sources.SyntheticSource` from the in-process noise stream of
that ball (same seeds, so frame k of ball i has the same noise, miss or outlier live and in process),
and publishes it ``latency_s`` (the tracker profile's) after the capture. The true ball at a capture
time is interpolated linearly between the two truth samples around it (2 ms apart).

Message times are host ``CLOCK_MONOTONIC``: ``t_s`` is the capture time, ``t_first_host_s`` too (a
synthetic tracker has no camera transfer), ``t_publish_s`` the send. Frame sets are captured from a
ball's serve until the world reports its end (before the first serve and between balls nothing is
published).
"""

from __future__ import annotations

import heapq
import json
import time

import numpy as np
import zmq

from harness.sim.lab import coverage
from harness.live.frames import AssembledFrameSet
from harness.sim.lab_truth import TruthError, decode_truth
from harness.live.publish import Publisher, rich_message, tennicam_message
from harness.experiments.play.profiles import TrackerProfile
from harness.experiments.play.sources import SyntheticSource
from tracker import FrameSet

__all__ = ["ObservationService", "ball_observation_seeds"]


def ball_observation_seeds(seed: int, ball: int):
    """(noise seed, frame-phase seed) of ball ``ball``: the in-process session's (``PlaySession.run``)."""
    from harness.experiments.play.experiment import ball_seeds

    ss_source, _, ss_phase = ball_seeds(seed, ball + 1)[ball][1].spawn(3)
    return ss_source, ss_phase


class ObservationService:
    """Truth in, tracker stream out (module docstring).

    truth_addr / world_addr : the world's endpoints; profile : the tracker's profile (rate, latency, errors);
    seed : the session's seed; publish_addr : rt2's stream (``tcp://HOST:PORT``, port 0 or ``*``: a free one);
    tennicam_addr : the tennicam stream too (None: not published)
    """

    def __init__(self, truth_addr: str, world_addr: str, profile: TrackerProfile, *, seed: int, publish_addr: str,
                 tennicam_addr: str | None = None, rig: str = "lab4_vga"):
        from tracker.rig_files import resolve_rig

        self.profile, self.seed = profile, int(seed)
        self.rig = resolve_rig(rig)
        self.source = SyntheticSource(self.rig, profile)
        self.malformed_truth = 0  #: truth samples skipped as malformed
        self._ctx = zmq.Context()
        self._truth = self._ctx.socket(zmq.SUB)
        self._world = self._ctx.socket(zmq.SUB)
        for sock, addr in ((self._truth, truth_addr), (self._world, world_addr)):
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.SUBSCRIBE, b"")
            sock.setsockopt(zmq.RCVHWM, 100_000)
            sock.connect(addr)
        self.publisher = Publisher(tennicam_addr, publish_addr)
        self.address = self.publisher.addresses["rt2"]
        self._queue: list = []  # (due ns, num, rich, tennicam)
        self._captures: list = []  # (capture ns, frame index, ball position, velocity, q) not yet observed
        self._num = 0
        self._ball = None  # the ball being observed: dict
        self.finished = False
        self.stats = {"published": 0, "late_ms_max": 0.0, "balls": 0}

    def close(self) -> None:
        for sock in (self._truth, self._world):
            sock.close(linger=0)
        self.publisher.close()
        self._ctx.term()

    # -- world events and truth -------------------------------------------------------------------
    def _on_world(self, doc: dict) -> None:
        kind = doc.get("type")
        if kind == "ball":
            if self._ball is not None and self._ball["index"] == int(doc["ball"]):
                return  # the world repeats an announcement until the serve
            self._observe_captures()  # the previous ball's last frame sets, before its noise stream is replaced
            ss_source, ss_phase = ball_observation_seeds(self.seed, int(doc["ball"]))
            self.source.reset(ss_source)
            period_ns = 1e9 / self.profile.rate_hz
            phase_ns = float(np.random.default_rng(ss_phase).uniform(0.0, 1.0 / self.profile.rate_hz)) * 1e9
            t0 = int(doc["t_serve_ns"])
            self._ball = {"index": int(doc["ball"]), "t_serve_ns": t0, "phase_ns": phase_ns, "period_ns": period_ns,
                          "k": 0, "prev": (t0, np.asarray(doc["serve"]["state"][:3], float), None), "live": True}
            self.stats["balls"] += 1
        elif kind == "outcome" and self._ball is not None and int(doc["ball"]) == self._ball["index"]:
            self._ball["live"] = False
        elif kind == "end":
            self.finished = True

    def _on_truth(self, frame: bytes) -> None:
        b = self._ball
        if b is None or not b["live"]:
            return
        try:
            sample = decode_truth(frame)
        except TruthError:  # a malformed sample is skipped and counted, never observed
            self.malformed_truth += 1
            return
        t_ns, q = sample.t_ns, sample.q
        if t_ns <= b["prev"][0]:
            return
        if not len(sample.balls):
            b["live"] = False  # the world has ended this ball
            return
        x1 = sample.balls[0]
        t0, x0, q0 = b["prev"]
        q0 = q if q0 is None else q0
        while True:
            t_cap = b["t_serve_ns"] + b["phase_ns"] + b["k"] * b["period_ns"]
            if t_cap > t_ns:
                break
            w = (t_cap - t0) / (t_ns - t0)
            pos, vel = x0 + w * (x1 - x0), (x1 - x0) / ((t_ns - t0) * 1e-9)
            self._captures.append((int(round(t_cap)), b["k"], pos, vel, q0 + w * (q - q0)))
            b["k"] += 1
        b["prev"] = (t_ns, x1, q)

    def _observe_captures(self) -> None:
        """The observations of the frame sets captured since the last call: one coverage count for all of them
        (the expensive part), then the source's draws in capture order."""
        if not self._captures:
            return
        seen = coverage(self.rig, np.array([c[2] for c in self._captures])).n_seeing
        for (t_cap_ns, k, pos, vel, q), n in zip(self._captures, seen):
            self._enqueue(t_cap_ns, k, self.source.observe(k, t_cap_ns * 1e-9, pos, vel, q, n_seeing=int(n)))
        self._captures.clear()

    def _enqueue(self, t_cap_ns: int, k: int, obs) -> None:
        n = len(self.rig)
        t_s = t_cap_ns * 1e-9
        afs = AssembledFrameSet(FrameSet(t_s, (None,) * n, k), k, np.full(n, t_s), np.full(n, np.nan), t_s)
        rich = rich_message(self._num, afs, obs, t_first_host_s=t_s, camera_names=self.rig.names)
        ten = tennicam_message(self._num, t_cap_ns, self.profile.latency_s, obs.position_m)
        heapq.heappush(self._queue, (t_cap_ns + int(round(self.profile.latency_s * 1e9)), self._num, rich, ten))
        self._num += 1

    # -- loop -------------------------------------------------------------------------------------
    def run(self, stop=lambda: False, idle_timeout_s: float | None = None) -> dict:
        """Serve until the world's ``end`` (and everything queued is out), ``stop()`` or ``idle_timeout_s``
        without any message; returns the counts (published, balls, late_ms_max)."""
        poller = zmq.Poller()
        poller.register(self._truth, zmq.POLLIN)
        poller.register(self._world, zmq.POLLIN)
        last_msg = time.monotonic()
        while not stop() and not (self.finished and not self._queue):
            now = time.monotonic_ns()
            while self._queue and self._queue[0][0] <= now:
                due, _, rich, ten = heapq.heappop(self._queue)
                t_publish = time.monotonic()  # the message is completed here; the publisher only sends
                rich["t_publish_s"], rich["latency_s"] = t_publish, t_publish - rich["t_first_host_s"]
                self.publisher.publish(ten, rich)
                self.stats["published"] += 1
                self.stats["late_ms_max"] = max(self.stats["late_ms_max"], (time.monotonic_ns() - due) / 1e6)
            wait_ms = 5 if not self._queue else max(0, int((self._queue[0][0] - time.monotonic_ns()) / 1e6))
            events = dict(poller.poll(min(wait_ms, 5)))
            if self._world in events:
                while self._world.poll(0):
                    self._on_world(json.loads(self._world.recv()))
                last_msg = time.monotonic()
            if self._truth in events:
                while self._truth.poll(0):
                    self._on_truth(self._truth.recv())
                self._observe_captures()
                last_msg = time.monotonic()
            if idle_timeout_s is not None and time.monotonic() - last_msg > idle_timeout_s:
                break
        return dict(self.stats)
