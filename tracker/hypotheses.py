"""Several balls in view: 3D hypotheses across frame sets, and which one is the ball in play.

A real lab has more than one ball: spare balls in a hand, on the floor, in a basket. Each is a
consistent set of candidates across the cameras, so the robust estimator alone cannot tell the ball in
play from the others, and once the ``rt2`` window search has locked onto a held ball it follows it.
:class:`BallHypotheses` keeps up to ``max_hypotheses`` 3D tracks and decides which one is reported:

* **hypotheses**: every position of a frame set (on a full-frame search: the estimator's best
  consistent set, then the next best after dropping its candidates, and so on; on a window search
  the one set the windows hold) joins the hypothesis whose constant-velocity prediction (over at most
  ``speed_window_s`` past its newest position) is nearest, within ``gate_m`` plus ``gate_growth_mps``
  times the time since it was seen (each position one hypothesis, each hypothesis one position,
  nearest pairs first), else starts a new one (the one seen longest ago makes room when all are
  taken). A hypothesis not seen for ``forget_s`` is dropped, a known other ball (below) after
  ``forget_other_s`` (the window search follows the ball in play and does not see the others);
* **in play**: a hypothesis with ``min_samples`` positions within the last ``speed_window_s`` whose
  least-squares velocity has a horizontal speed of at least ``min_speed_mps`` and whose newest
  position is at least ``min_height_m`` above the world's ``z = 0`` (the floor): a served ball crosses
  the table at metres per second; a ball held in a hand, lying on the table or in a basket is slow, a
  ball rolling on the floor is low, a ball tossed straight up by a person moves vertically;
* **the lead** (the reported hypothesis), per frame set, among the hypotheses seen in it:
  (a) one in play (the lead itself if it is, else the one with most positions);
  (b) else the lead, if seen (a static ball stays reported while nothing is in play: one ball, or the
  ball on a robot's end effector, works as before);
  (c) else, leaving out *known other balls* (hypotheses seen beside a lead in play: the held ball
  once the served one was chosen), the only hypothesis seen; none: nothing is reported;
  (d) else (several seen, none in play) nothing is reported for at most ``max_withhold_s`` (long
  enough for a served ball to show its speed: 3 frame sets at 180 Hz), then the best of them (the
  estimator's order: the behaviour without hypotheses).

:meth:`BallHypotheses.wants_full_frame` asks for a full-frame search while the lead is not in play:
every ``full_frame_period_s``, and at every frame set while a choice is withheld or another
hypothesis seen within ``speed_window_s`` has fewer than ``min_samples`` positions (not classified
yet). The window search follows the lead, so a lock-in on a static ball lasts at most
``full_frame_period_s`` plus the frames a ball needs to show it is in play.

At most ``max_hypotheses x history`` numbers, arrays allocated once; the per-frame-set steps are
compiled (:mod:`tracker._hypotheses_kernels`, ``backend="numba"``) with these numpy methods as the
reference (``backend="numpy"``). Pure: nothing outside ``tracker`` is imported. See docs/pipeline.md, step 10.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker._hypotheses_kernels import OPTION_FIELDS, update_kernel, wants_full_frame_kernel

__all__ = ["BACKENDS", "BallHypotheses", "HypothesisOptions"]


@dataclass(frozen=True)
class HypothesisOptions:
    """Options of :class:`BallHypotheses` (module docstring); ``TrackerOptions.hypotheses``.

    max_hypotheses : 3D tracks kept at once (>= 2; one track is the plain ``rt2`` tracker)
    history : positions kept per hypothesis
    gate_m : a position joins a hypothesis predicted at most this far from it, metres
    gate_growth_mps : the gate grows by this much per second the hypothesis was not seen, m/s
    forget_s : a hypothesis not seen for this long is dropped, seconds
    forget_other_s : the same for a known other ball, seconds
    speed_window_s : the velocity is fitted on the positions this recent, seconds
    min_samples : positions in that window needed to call a hypothesis in play
    min_speed_mps : horizontal speed of a ball in play, at least, m/s
    min_height_m : height of a ball in play above the world's z = 0 (the floor), at least, metres
    full_frame_period_s : full-frame search at least this often while the lead is not in play, seconds
    max_withhold_s : longest wait for a hypothesis in play when several are seen, seconds
    """

    max_hypotheses: int = 4
    history: int = 8
    gate_m: float = 0.15
    gate_growth_mps: float = 0.5
    forget_s: float = 0.5
    forget_other_s: float = 5.0
    speed_window_s: float = 0.05
    min_samples: int = 3
    min_speed_mps: float = 1.5
    min_height_m: float = 0.3
    full_frame_period_s: float = 0.1
    max_withhold_s: float = 0.05

    def __post_init__(self):
        for name, lo in (("max_hypotheses", 2), ("history", 2), ("min_samples", 2)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"HypothesisOptions.{name} must be an integer >= {lo}, got {v!r}")
        if self.min_samples > self.history:
            raise ValueError(f"HypothesisOptions.min_samples ({self.min_samples}) must not exceed history ({self.history})")
        for name in ("gate_m", "gate_growth_mps", "forget_s", "forget_other_s", "speed_window_s", "min_speed_mps", "full_frame_period_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"HypothesisOptions.{name} must be a positive number, got {v!r}")
        for name in ("min_height_m", "max_withhold_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"HypothesisOptions.{name} must be a number >= 0, got {v!r}")


#: implementations of the per-frame-set steps: "numba" (compiled, :mod:`tracker._hypotheses_kernels`) and
#: "numpy" (the reference)
BACKENDS = ("numba", "numpy")


class BallHypotheses:
    """The hypotheses of one tracker (module docstring). Not thread-safe; :meth:`reset` forgets all.

    backend : "numba" (default: the compiled steps, ~100x less overhead per frame set) or "numpy" (the
    reference); both give the same results (tests/tracker/test_hypotheses.py)
    """

    def __init__(self, options: HypothesisOptions | None = None, backend: str = "numba"):
        o = HypothesisOptions() if options is None else options
        if not isinstance(o, HypothesisOptions):
            raise ValueError(f"options must be a HypothesisOptions, got {type(o).__name__}")
        if backend not in BACKENDS:
            raise ValueError(f"unknown BallHypotheses backend {backend!r}; valid: {list(BACKENDS)}")
        self.options = o
        self.backend = backend
        self._o = np.array([float(getattr(o, f)) for f in OPTION_FIELDS])
        m, h = o.max_hypotheses, o.history
        self._t_s = np.full((m, h), np.nan)  # per hypothesis, newest position in column 0
        self._X_m = np.full((m, h, 3), np.nan)
        self._count = np.zeros(m, np.int64)  # positions ever joined (0: slot free)
        self._in_play = np.zeros(m, bool)
        self._other = np.zeros(m, bool)  # seen beside a lead in play: a known other ball
        self.reset()

    def reset(self) -> None:
        """Forget every hypothesis, the lead and the full-frame schedule (a new rally or recording)."""
        self._t_s.fill(np.nan)
        self._X_m.fill(np.nan)
        self._count.fill(0)
        self._in_play.fill(False)
        self._other.fill(False)
        self.lead = -1  #: slot of the reported hypothesis, -1 = none
        self.switched = False  #: the last update moved the lead to a ball in play from another kept one
        self._last_full_s = -math.inf
        self._withhold_since_s = math.nan

    # -- queries -------------------------------------------------------------------------------
    @property
    def n_hypotheses(self) -> int:
        """Hypotheses currently kept."""
        return int((self._count > 0).sum())

    @property
    def lead_in_play(self) -> bool:
        return self.lead >= 0 and bool(self._in_play[self.lead])

    def in_play(self) -> np.ndarray:
        """(n_hypotheses,) bool, in slot order of the kept hypotheses (for reports and tests)."""
        return self._in_play[self._count > 0].copy()

    def positions(self) -> np.ndarray:
        """(n_hypotheses, 3) newest position of each kept hypothesis, world frame, metres."""
        return self._X_m[self._count > 0, 0].copy()

    def wants_full_frame(self, t_s: float) -> bool:
        """Whether the frame set at ``t_s`` should be searched on the full frame (module docstring)."""
        if self.backend == "numba":
            return bool(wants_full_frame_kernel(float(t_s), self._t_s, self._count, self._in_play, self._other, self.lead,
                                                self._withhold_since_s, self._last_full_s, self._o))
        return self._wants_full_frame_numpy(t_s)

    def _wants_full_frame_numpy(self, t_s: float) -> bool:
        if not math.isnan(self._withhold_since_s):
            return True
        if self.lead_in_play:
            return False
        o = self.options
        young = (self._count > 0) & (self._count < o.min_samples) & ~self._other & (t_s - self._t_s[:, 0] <= o.speed_window_s)
        if self.lead >= 0:
            young[self.lead] = False
        return bool(young.any()) or t_s - self._last_full_s >= o.full_frame_period_s

    def searched_full_frame(self, t_s: float) -> None:
        """Note a full-frame search at ``t_s`` (restarts the period of :meth:`wants_full_frame`)."""
        self._last_full_s = t_s

    # -- per frame set ---------------------------------------------------------------------------
    def update(self, t_s: float, X_m: np.ndarray) -> int:
        """Join the positions ``X_m`` (n, 3) of the frame set at ``t_s`` (world frame, metres; row 0 the
        estimator's best set) to the hypotheses and choose the lead.

        Returns the row of ``X_m`` to report, or -1: nothing to report (a choice withheld, or n = 0).
        """
        if self.backend == "numba":
            X = np.ascontiguousarray(X_m, dtype=np.float64).reshape(-1, 3)
            row, self.lead, self.switched, self._withhold_since_s = update_kernel(
                float(t_s), X, self._t_s, self._X_m, self._count, self._in_play, self._other, self.lead,
                self._withhold_since_s, self._o)
            return int(row)
        return self._update_numpy(t_s, X_m)

    def _update_numpy(self, t_s: float, X_m: np.ndarray) -> int:
        o = self.options
        self.switched = False
        self._drop_old(t_s)
        n = len(X_m)
        if n == 0:
            return -1
        slots = self._associate(t_s, X_m)
        self._push(slots, t_s, X_m)
        self._classify(t_s, slots)
        seen_in_play = self._in_play[slots]
        if seen_in_play.any():  # (a)
            if self.lead in slots and self._in_play[self.lead]:
                row = int(np.flatnonzero(slots == self.lead)[0])
            else:
                cand = np.flatnonzero(seen_in_play)
                row = int(cand[np.argmax(self._count[slots[cand]])])
                self.switched = self.lead >= 0
            self._other[slots] = True  # the others seen now are known other balls
            self._other[slots[row]] = False
        elif self.lead in slots:  # (b)
            row = int(np.flatnonzero(slots == self.lead)[0])
        else:
            rows = np.flatnonzero(~self._other[slots])
            if len(rows) == 0:  # (c) only known other balls
                self.lead, self._withhold_since_s = -1, math.nan
                return -1
            if len(rows) == 1:  # (c)
                row = int(rows[0])
            else:  # (d)
                if math.isnan(self._withhold_since_s):
                    self._withhold_since_s = t_s
                if t_s - self._withhold_since_s < o.max_withhold_s:
                    self.lead = -1
                    return -1
                row = int(rows[0])
        self._withhold_since_s = math.nan
        self.lead = int(slots[row])
        return row

    def _drop_old(self, t_s: float) -> None:
        o = self.options
        old = (self._count > 0) & ~(t_s - self._t_s[:, 0] <= np.where(self._other, o.forget_other_s, o.forget_s))
        if old.any():
            self._count[old] = 0
            self._in_play[old] = False
            self._other[old] = False
            self._t_s[old] = np.nan
            self._X_m[old] = np.nan
            if self.lead >= 0 and old[self.lead]:
                self.lead = -1

    def _predict(self, t_s: float) -> np.ndarray:
        """(m, 3) constant-velocity prediction of each slot at ``t_s`` (NaN rows: free slots)."""
        X0, X1 = self._X_m[:, 0], self._X_m[:, 1]
        dt = self._t_s[:, 0] - self._t_s[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where((self._count >= 2)[:, None] & (dt > 0)[:, None], (X0 - X1) / dt[:, None], 0.0)
        return X0 + v * np.minimum(t_s - self._t_s[:, 0], self.options.speed_window_s)[:, None]

    def _associate(self, t_s: float, X_m: np.ndarray) -> np.ndarray:
        """(n,) slot of each position: nearest pairs within the gate first, then free or oldest slots."""
        m, n = len(self._count), len(X_m)
        d = np.linalg.norm(self._predict(t_s)[:, None, :] - X_m[None, :, :], axis=2)  # (m, n)
        gate = self.options.gate_m + self.options.gate_growth_mps * (t_s - self._t_s[:, 0])
        d[~(d <= gate[:, None])] = np.inf
        slots = np.full(n, -1, np.int64)
        taken = np.zeros(m, bool)
        for _ in range(min(m, n)):  # at most 4 rounds on a 4 x 4 table
            k = int(np.argmin(d))
            i, j = divmod(k, n)
            if not np.isfinite(d[i, j]):
                break
            slots[j], taken[i] = i, True
            d[i, :] = np.inf
            d[:, j] = np.inf
        for j in np.flatnonzero(slots < 0):
            free = np.flatnonzero((self._count == 0) & ~taken)
            if len(free):
                i = int(free[0])
            else:  # the hypothesis seen longest ago (never the lead while another can go) makes room
                age = np.where(taken, -np.inf, t_s - self._t_s[:, 0])
                if self.lead >= 0 and (~taken).sum() > 1:
                    age[self.lead] = -np.inf
                i = int(np.argmax(age))
            self._count[i] = 0
            self._in_play[i] = False
            self._other[i] = False
            self._t_s[i] = np.nan
            self._X_m[i] = np.nan
            if i == self.lead:
                self.lead = -1
            slots[j], taken[i] = i, True
        return slots

    def _push(self, slots: np.ndarray, t_s: float, X_m: np.ndarray) -> None:
        self._t_s[slots, 1:] = self._t_s[slots, :-1]
        self._X_m[slots, 1:] = self._X_m[slots, :-1]
        self._t_s[slots, 0] = t_s
        self._X_m[slots, 0] = X_m
        self._count[slots] += 1

    def _classify(self, t_s: float, slots: np.ndarray) -> None:
        """In play or not, for the hypotheses in ``slots`` (module docstring): a least-squares line
        through their recent positions, all slots in one batched computation."""
        o = self.options
        t = self._t_s[slots]  # (s, h)
        X = self._X_m[slots]  # (s, h, 3)
        w = (t_s - t <= o.speed_window_s).astype(float)  # NaN times compare False
        nw = w.sum(axis=1)
        tc = np.where(w > 0, t - t_s, 0.0)
        t_mean = (w * tc).sum(axis=1) / np.maximum(nw, 1)
        dt = (tc - t_mean[:, None]) * w
        Xz = np.where(w[:, :, None] > 0, X, 0.0)
        X_mean = (w[:, :, None] * Xz).sum(axis=1) / np.maximum(nw, 1)[:, None]
        sxx = (dt * dt).sum(axis=1)
        sxy = (dt[:, :, None] * (Xz - X_mean[:, None, :]) * w[:, :, None]).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            v = sxy / sxx[:, None]  # (s, 3) m/s
        fast = np.hypot(v[:, 0], v[:, 1]) >= o.min_speed_mps
        high = X[:, 0, 2] >= o.min_height_m
        self._in_play[slots] = (nw >= o.min_samples) & (sxx > 0) & fast & high
