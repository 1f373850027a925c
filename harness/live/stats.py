"""Running figures of the tracking service: rate, latency percentiles, per-camera missing frames.

Latency of a frame set = from the first host arrival stamp of its frames (``time.monotonic()``)
to the moment its messages were handed to the sockets. Everything is kept in preallocated
arrays (no growth per frame set beyond a fixed ring), so a long run's memory stays flat.

The latency budget splits each frame set's latency into stages (:data:`STAGES`, seconds between
consecutive stamps on the host's monotonic clock): ``assembly`` (first frame's arrival -> the set is
complete or timed out), ``backlog`` (-> the service takes it), ``tracker`` (-> the observation),
``publish`` (-> the messages handed to the sockets); ``after`` is the work of the loop after the
messages left (the log's and the view's hand-over, the figures): not part of this set's latency, it
delays the next one. Where some frame sets searched a camera's full frame (a new ball, a lost one) and
others only windows, the budget also gives the tracker stage and the whole latency of the former alone
(``tracker_full``, ``total_full``): what a window-mode run's tail is made of.
"""

from __future__ import annotations

import heapq
import math
import re
import time
from collections import Counter

import numpy as np

__all__ = ["LiveStats", "STAGES", "format_budget"]

#: the stages of the latency budget, in order (the module docstring)
STAGES = ("assembly", "backlog", "tracker", "publish", "after")
#: the slowest frame sets a run keeps with their stages and notes (``LiveStats.slowest``)
SLOWEST_KEPT = 5

_NUMBER = re.compile(r"(?<![A-Za-z_])[-+]?\d[\d.e+-]*")


def _percentiles_ms(values_s: np.ndarray) -> dict:
    """n, p50, p99, max in ms of the finite ``values_s`` (seconds); only n when there is none."""
    v = values_s[np.isfinite(values_s)] * 1e3
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)), "max": float(v.max())}


def _pct_ms(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q) * 1e3) if len(values) else math.nan


class LiveStats:
    """Figures of one service run.

    camera_names : rig order; window : frame sets in the status line's rolling percentiles;
    keep : latencies kept for the summary's percentiles (a ring of the last ``keep``)
    """

    def __init__(self, camera_names, *, window: int = 1000, keep: int = 1 << 20):
        self.names = list(camera_names)
        self.n = 0
        self.t_start = time.monotonic()
        self.t_first: float | None = None
        self.t_last: float | None = None
        self._lat = np.zeros(keep)
        self._proc = np.zeros(keep)
        self._stages = np.full((keep, len(STAGES)), np.nan)
        self._full = np.zeros(keep, bool)  # the frame set searched a camera's full frame
        self.window = int(window)
        self.missing = np.zeros(len(self.names), np.int64)  # frame sets without this camera's frame
        self.status = Counter()
        self.with_position = 0
        self.notes = Counter()  # assembly and tracker notes, numbers replaced by '#' (bounded key count)
        self.max_latency_s = 0.0
        self.last_frame_id: int | None = None
        self.frame_id_gaps = 0  # frame ids skipped between consecutive frame sets (lost before rt2)
        self._mark = (self.t_start, 0)
        self.first_missing_after: dict[str, int] = {}
        self._slowest: list = []  # a min-heap of (latency_s, n, frame_id, status, notes) of the SLOWEST_KEPT slowest sets

    def add(self, afs, obs, latency_s: float, t_done_s: float, stages_s=None, *, full_frame: bool = False) -> None:
        """One frame set: its assembled set, observation, host-stamp-to-publication latency (s), and
        optionally its stage durations in the order of :data:`STAGES` (s; NaN = not measured) and whether
        the tracker searched a camera's full frame in it."""
        i = self.n % len(self._lat)
        self._lat[i] = latency_s
        self._proc[i] = obs.latency_s
        self._full[i] = bool(full_frame)
        if stages_s is not None:
            self._stages[i] = stages_s
        if len(self._slowest) < SLOWEST_KEPT or latency_s > self._slowest[0][0]:  # (two comparisons per set)
            item = (latency_s, self.n, int(afs.frame_id), str(obs.status), (*afs.notes, *obs.notes))
            (heapq.heappush if len(self._slowest) < SLOWEST_KEPT else heapq.heapreplace)(self._slowest, item)
        self.n += 1
        self.max_latency_s = max(self.max_latency_s, latency_s)
        if self.t_first is None:
            self.t_first = t_done_s
        self.t_last = t_done_s
        for c, img in enumerate(afs.frameset.images):
            if img is None:
                self.missing[c] += 1
        self.status[str(obs.status)] += 1
        self.with_position += obs.position_m is not None
        for note in (*afs.notes, *obs.notes):
            key = _NUMBER.sub("#", str(note))[:120]  # one key per kind of note, whatever its numbers
            if key in self.notes or len(self.notes) < 200:
                self.notes[key] += 1
        fid = int(afs.frame_id)
        if self.last_frame_id is not None and fid > self.last_frame_id + 1:
            self.frame_id_gaps += fid - self.last_frame_id - 1
        self.last_frame_id = fid

    def latencies_s(self) -> np.ndarray:
        return self._lat[: min(self.n, len(self._lat))]

    def stages_s(self) -> np.ndarray:
        """(n, len(STAGES)) stage durations in seconds of the frame sets kept, in the order they were added
        (NaN = not measured)."""
        return self._stages[: min(self.n, len(self._lat))]

    def stage(self, name: str, value_s: float) -> None:
        """Set one stage of the frame set last added (seconds), e.g. ``after``, known only once it is done."""
        if self.n:
            self._stages[(self.n - 1) % len(self._lat), STAGES.index(name)] = value_s

    def budget_ms(self, first: int = 0) -> dict:
        """The latency budget: per stage of :data:`STAGES` (and ``total``) n, p50, p99, max in ms, over the
        frame sets from the ``first``-th on (a benchmark leaves its warm-up out)."""
        k = min(self.n, len(self._lat))
        first = min(max(int(first), 0), k)
        out = {}
        for j, name in enumerate((*STAGES, "total")):
            out[name] = _percentiles_ms(self._lat[first:k] if name == "total" else self._stages[first:k, j])
        full = self._full[first:k]
        if full.any() and not full.all():  # window sets and full-frame sets: the latter's share of the tail
            out["tracker_full"] = _percentiles_ms(self._stages[first:k, STAGES.index("tracker")][full])
            out["total_full"] = _percentiles_ms(self._lat[first:k][full])
        return out

    def slowest(self) -> list[dict]:
        """The slowest frame sets of the run (at most :data:`SLOWEST_KEPT`), slowest first: frame id, latency, each
        stage (ms; while the set is still among the kept latencies), status and the assembly's and tracker's notes:
        where a run's max came from."""
        out = []
        for lat, n, fid, status, notes in sorted(self._slowest, reverse=True):
            row = {"frame_id": fid, "latency_ms": lat * 1e3, "status": status, "notes": [str(x) for x in notes]}
            if n >= self.n - len(self._lat):
                row["stages_ms"] = {name: (None if math.isnan(v) else float(v) * 1e3)
                                    for name, v in zip(STAGES, self._stages[n % len(self._lat)])}
            out.append(row)
        return out

    def status_line(self) -> str:
        """One line: rate since the last call, latency p50/p99 over the last ``window`` frame sets,
        frame sets without each camera's frame so far."""
        now = time.monotonic()
        t0, n0 = self._mark
        rate = (self.n - n0) / max(now - t0, 1e-9)
        self._mark = (now, self.n)
        k = min(self.n, self.window, len(self._lat))
        idx = (np.arange(self.n - k, self.n) % len(self._lat)) if k else np.zeros(0, int)
        lat = self._lat[idx]
        miss = " ".join(f"{n}:{m}" for n, m in zip(self.names, self.missing.tolist()))
        ok = self.status.get("ok", 0)
        return (f"{self.n} frame sets, {rate:6.1f}/s, latency p50 {_pct_ms(lat, 50):5.2f} ms p99 {_pct_ms(lat, 99):5.2f} ms, "
                f"ok {100.0 * ok / max(self.n, 1):5.1f} %, missing frames {miss}")

    def summary(self) -> dict:
        """The end-of-run figures (``--json``): counts, rates, latency percentiles in ms."""
        lat = self.latencies_s()
        span = (self.t_last - self.t_first) if self.n > 1 else 0.0
        return {
            "frame_sets": self.n,
            "duration_s": time.monotonic() - self.t_start,
            "rate_hz": (self.n - 1) / span if span > 0 else math.nan,
            "latency_ms": {"p50": _pct_ms(lat, 50), "p99": _pct_ms(lat, 99), "max": self.max_latency_s * 1e3,
                           "what": "first frame's host arrival stamp to the messages handed to the sockets"},
            "tracker_ms": {"p50": _pct_ms(self._proc[: len(lat)], 50), "p99": _pct_ms(self._proc[: len(lat)], 99)},
            "latency_budget_ms": self.budget_ms(),
            "status": dict(self.status),
            "with_position": self.with_position,
            "missing_frames": dict(zip(self.names, self.missing.tolist())),
            "frame_id_gaps": self.frame_id_gaps,
            "notes": dict(self.notes.most_common(20)),
            "slowest_frame_sets": self.slowest(),
        }


def process_per_set(use0, use1, n_sets: int) -> dict:
    """This process's CPU time (ms), page faults and context switches per frame set between two
    ``resource.getrusage(RUSAGE_SELF)`` readings: what a frame set costs the service's process (its
    cameras, assembly, tracker and sockets; not a render child), whatever the load."""
    n = max(int(n_sets), 1)
    cpu_s = (use1.ru_utime - use0.ru_utime) + (use1.ru_stime - use0.ru_stime)
    return {"cpu_ms": 1e3 * cpu_s / n, "page_faults": (use1.ru_minflt - use0.ru_minflt) / n,
            "context_switches": ((use1.ru_nvcsw - use0.ru_nvcsw) + (use1.ru_nivcsw - use0.ru_nivcsw)) / n}


_STAGE_WHAT = {"assembly": "first frame -> set assembled", "backlog": "assembled -> taken by the tracker",
               "tracker": "tracker", "publish": "messages encoded and sent",
               "after": "log, view, figures (before the next set)", "total": "first frame -> messages sent",
               "tracker_full": "tracker, sets with a full-frame search", "total_full": "first frame -> sent, those sets"}


def format_budget(budget: dict, what: str = "") -> list[str]:
    """:meth:`LiveStats.budget_ms` as lines of text: per stage p50 / p99 / max ms and the count."""
    out = [f"{'latency budget' + (', ' + what if what else '') + ' (ms)':<42}{'p50':>8}{'p99':>9}{'max':>9}{'n':>9}"]
    for name, b in budget.items():
        if b.get("n"):
            out.append(f"  {_STAGE_WHAT.get(name, name):<40}{b['p50']:>8.2f}{b['p99']:>9.2f}{b['max']:>9.2f}{b['n']:>9d}")
    return out
