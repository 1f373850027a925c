"""The robot clock's offset from the harness clock, estimated online with its uncertainty, and pairing.

The harness clock is ``time.monotonic_ns()`` (the clock of ``harness.live`` frame arrival stamps).

* **Robot** (:class:`RoundTripClock`): NTP-style. The harness stamps a ``clock`` request ``t0`` (its
  clock), the robot stamps its receipt ``t1`` and its reply ``t2`` (robot clock), the harness stamps the
  reply's arrival ``t3``. Then ``offset = ((t1 - t0) + (t2 - t3)) / 2`` (robot minus harness) and the
  round trip ``delay = (t3 - t0) - (t2 - t1)``; whatever the split of the delay between the two ways,
  the true offset lies within ``offset +- delay / 2``. The estimate keeps the last ``window`` samples,
  takes the ``best`` of them with the smallest delays (queueing only ever adds delay) and reports
  their median offset; the uncertainty is half the smallest delay plus the spread of those offsets.
* **Camera** clocks are estimated from frame stamps vs arrival by
  :class:`harness.live.sources.clock.ClockOffsetEstimator` (one way: the offset plus the smallest
  transfer latency, which host-side stamps cannot separate).

Drift is not modelled: over a session of minutes two quartz clocks drift by well under 0.1 ms,
and the window keeps the estimate current.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["ClockEstimate", "RoundTripClock", "pair_joint_states"]


@dataclass(frozen=True)
class ClockEstimate:
    """offset_ns : robot clock minus harness clock, ns; uncertainty_ns : bound on its error, ns;
    n_samples : exchanges in the window; delay_ns : smallest round trip, ns."""

    offset_ns: float
    uncertainty_ns: float
    n_samples: int
    delay_ns: float

    def to_harness_ns(self, t_other_ns):
        """Times on the robot clock (ns) -> harness clock (ns), scalar or array."""
        return np.asarray(t_other_ns, dtype=np.float64) - self.offset_ns

    def to_dict(self) -> dict:
        return {"offset_ms": self.offset_ns / 1e6, "uncertainty_ms": self.uncertainty_ns / 1e6,
                "n_samples": self.n_samples, "min_delay_ms": self.delay_ns / 1e6}


def _check_window(window: int, best: int) -> None:
    if not (isinstance(window, int) and isinstance(best, int) and 1 <= best <= window <= 100000):
        raise ValueError(f"need integers 1 <= best <= window <= 100000, got best={best!r}, window={window!r}")


class RoundTripClock:
    """NTP-style offset of a robot clock (see the module docstring). ``add(t0, t1, t2, t3)`` in ns."""

    def __init__(self, window: int = 64, best: int = 8):
        _check_window(window, best)
        self.best = best
        self._samples: deque = deque(maxlen=window)
        self._estimate: ClockEstimate | None = None  # of the present samples (read every control tick)

    def add(self, t0_ns: int, t1_ns: int, t2_ns: int, t3_ns: int) -> None:
        """One exchange: t0, t3 on the harness clock, t1, t2 on the robot clock (ints, ns)."""
        t0, t1, t2, t3 = (int(v) for v in (t0_ns, t1_ns, t2_ns, t3_ns))
        if t3 < t0 or t2 < t1:
            raise ValueError(f"clock exchange out of order: t0={t0} t1={t1} t2={t2} t3={t3} "
                             "(need t3 >= t0 and t2 >= t1)")
        delay = (t3 - t0) - (t2 - t1)
        offset = ((t1 - t0) + (t2 - t3)) / 2
        self._samples.append((max(delay, 0), offset))
        self._estimate = None

    def estimate(self) -> ClockEstimate:
        """The present estimate; ValueError before the first sample."""
        if self._estimate is not None:
            return self._estimate
        if not self._samples:
            raise ValueError("no clock exchange yet: cannot estimate the robot clock offset")
        s = np.array(self._samples, dtype=np.float64)
        keep = s[np.argsort(s[:, 0], kind="stable")[: self.best]]
        offset = float(np.median(keep[:, 1]))
        spread = float(np.max(np.abs(keep[:, 1] - offset)))
        self._estimate = ClockEstimate(offset, float(keep[0, 0] / 2 + spread), len(s), float(keep[0, 0]))
        return self._estimate


def pair_joint_states(t_harness_s, t_robot_s, q, estimate: ClockEstimate) -> np.ndarray:
    """Joint angles at harness times, from states stamped on the robot clock, through the offset estimate.

    t_harness_s : (m,) harness clock, s (e.g. when a camera exposed a frame); t_robot_s : (n,) increasing
    robot clock, s; q : (n, n_joints) rad. Returns (m, n_joints): linear interpolation at ``t_harness + offset``; NaN rows
    for times outside the states (never extrapolated).
    """
    th = np.asarray(t_harness_s, dtype=np.float64)
    tr = np.asarray(t_robot_s, dtype=np.float64)
    Q = np.asarray(q, dtype=np.float64)
    if th.ndim != 1 or tr.ndim != 1 or Q.shape != (tr.shape[0], Q.shape[-1]) or Q.ndim != 2:
        raise ValueError(f"need t_harness_s (m,), t_robot_s (n,), q (n, n_joints); got shapes {th.shape}, "
                         f"{tr.shape}, {Q.shape}")
    if tr.size < 2 or (np.diff(tr) <= 0).any():
        raise ValueError("t_robot_s must hold at least two strictly increasing times")
    t_on_robot = th + estimate.offset_ns * 1e-9
    out = np.stack([np.interp(t_on_robot, tr, Q[:, j]) for j in range(Q.shape[1])], axis=1)
    out[(t_on_robot < tr[0]) | (t_on_robot > tr[-1])] = np.nan
    return out
