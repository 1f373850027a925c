"""Per-camera clock offset: where a camera stamps its frames on its own clock, estimate
``offset_s`` so that ``t_device_s + offset_s`` is the frame's capture time on the host's monotonic clock
(plus the smallest transfer latency, which no host-side measurement can separate from the offset).

Every arrival gives ``d = t_host_s - t_device_s`` = offset + transfer latency (>= its minimum). The
estimate is a low quantile (default 5 %) of ``d`` over the last ``window`` frames: the frames that
arrived fastest, robust to a single early outlier unlike the plain minimum, and following slow clock
drift because the window slides. ``spread_s`` (95 % - 5 % quantile of ``d``) is the arrival jitter.
A device stamp that runs backwards (the camera restarted its clock) clears the window.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["ClockOffset", "ClockOffsetEstimator"]


@dataclass(frozen=True)
class ClockOffset:
    """offset_s : host time minus device time at capture (s); spread_s : 5-95 % range of the arrival
    delays in the window (s); n_samples : frames in the window; resets : clock restarts seen."""

    offset_s: float
    spread_s: float
    n_samples: int
    resets: int = 0


class ClockOffsetEstimator:
    """Sliding-window low-quantile estimate of one camera's clock offset (see the module docstring).

    window : frames kept; quantile : in [0, 0.5]; min_samples : frames before an estimate is given;
    update_every : the quantile is recomputed every this many frames (cheap on a 200 Hz path).
    """

    def __init__(self, window: int = 400, *, quantile: float = 0.05, min_samples: int = 10, update_every: int = 10):
        if int(window) < 2 or not (0.0 <= quantile <= 0.5) or int(min_samples) < 1 or int(update_every) < 1:
            raise ValueError(f"ClockOffsetEstimator needs window >= 2, 0 <= quantile <= 0.5, min_samples >= 1, "
                             f"update_every >= 1, got {window!r}, {quantile!r}, {min_samples!r}, {update_every!r}")
        self.window = int(window)
        self.quantile = float(quantile)
        self.min_samples = int(min(min_samples, window))
        self.update_every = int(update_every)
        self._d: deque = deque(maxlen=self.window)
        self._last_device: float | None = None
        self._since = 0
        self._resets = 0
        self._estimate: ClockOffset | None = None

    def add(self, t_host_s: float, t_device_s: float) -> None:
        """One arrival: host monotonic seconds, device seconds."""
        if self._last_device is not None and t_device_s < self._last_device:
            self._d.clear()
            self._resets += 1
            self._estimate = None
            self._since = 0
        self._last_device = t_device_s
        self._d.append(t_host_s - t_device_s)
        self._since += 1
        if len(self._d) >= self.min_samples and (self._estimate is None or self._since >= self.update_every):
            self._update()

    def _update(self) -> None:
        d = np.fromiter(self._d, float, len(self._d))
        lo, hi = np.quantile(d, [self.quantile, 1.0 - self.quantile])
        self._estimate = ClockOffset(float(lo), float(hi - lo), len(d), self._resets)
        self._since = 0

    def estimate(self) -> ClockOffset | None:
        """The current estimate, or None before ``min_samples`` frames."""
        return self._estimate

    def to_host(self, t_device_s: float) -> float | None:
        """``t_device_s`` mapped to the host clock, or None while there is no estimate."""
        e = self._estimate
        return None if e is None else t_device_s + e.offset_s
