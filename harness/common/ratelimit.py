"""Rate limits of repeated reports: a flood of bad messages or clients costs a few log lines a second, not one
per message (docs/reliability.md). Standard library only (the ROS bridge runs it under a system Python)."""

from __future__ import annotations

import collections
import logging
import re
import threading
import time

__all__ = ["RateLimit", "RateLimitedLogs"]


class RateLimit:
    """Rate limit of repeated reports (rejected messages, dropped clients): :meth:`note` says whether this one is
    reported on its own (the first ``burst`` of each ``period_s``); the others are counted per reason (numbers
    and quoted values folded) and :meth:`summary` returns them once per period. Thread-safe."""

    def __init__(self, burst: int = 10, period_s: float = 1.0, clock=time.monotonic,
                 what: str = "messages rejected"):
        self.what = what
        self.burst, self.period_s, self._clock = int(burst), float(period_s), clock
        self._lock = threading.Lock()
        self._window = clock()
        self._in_window = 0
        self._counts: collections.Counter = collections.Counter()
        self._ready: str | None = None
        self.total = 0  #: every rejection noted

    @staticmethod
    def kind(reason: str) -> str:
        """The reason without its numbers and quoted values (what rejections are counted by)."""
        short = re.sub(r"'[^']*'|\"[^\"]*\"|\[[^\]]*\]|\([^)]*\)", "...", reason)
        return re.sub(r"[-+]?\d[\d.e+-]*", "N", short)[:80]

    def note(self, reason: str) -> bool:
        with self._lock:
            self.total += 1
            self._roll()
            self._in_window += 1
            if self._in_window <= self.burst:
                return True
            self._counts[self.kind(reason)] += 1
            return False

    def _roll(self, force: bool = False) -> None:
        """At the end of a period (or now, ``force``): the summary of its suppressed reports waits for :meth:`summary`."""
        now = self._clock()
        if not force and now - self._window < self.period_s:
            return
        counts, elapsed = self._counts, now - self._window
        self._counts, self._window, self._in_window = collections.Counter(), now, 0
        if counts:
            parts = "; ".join(f"{n} x {k}" for k, n in counts.most_common(5))
            more = f" (and {len(counts) - 5} more kinds)" if len(counts) > 5 else ""
            text = f"{sum(counts.values())} more {self.what} in {elapsed:.1f} s: {parts}{more}"
            self._ready = text if self._ready is None else f"{self._ready}; {text}"

    def summary(self) -> str | None:
        """The summary of the suppressed reports once their period has passed (then None until the next)."""
        return self._take(force=False)

    def flush(self) -> str | None:
        """The summary of every suppressed report not summarised yet, its period over or not (at shutdown: none
        counted goes unreported); None when there is none."""
        return self._take(force=True)

    def _take(self, force: bool) -> str | None:
        with self._lock:
            self._roll(force)
            out, self._ready = self._ready, None
            return out


class RateLimitedLogs(logging.Filter):
    """A logging filter: the first ``burst`` records of a second pass, the rest are counted per kind and the
    summary is appended to the next record that passes."""

    def __init__(self, burst: int = 5, period_s: float = 1.0, what: str = "similar messages"):
        super().__init__()
        self.limit = RateLimit(burst, period_s, what=what)

    def filter(self, record: logging.LogRecord) -> bool:
        summary = self.limit.summary()
        if not self.limit.note(record.getMessage()):
            return False
        if summary:
            record.msg, record.args = f"{record.getMessage()} ({summary})", ()
        return True
