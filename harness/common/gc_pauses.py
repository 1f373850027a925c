"""The garbage collector in a real-time loop: freeze what is alive before it starts, count the pauses while it runs.

A full collection traverses every object of the process (in one with numba's compiled kernels, SciPy and Pinocchio
loaded: hundreds of thousands), and every thread waits for it. ``frozen_gc()`` collects once and ``gc.freeze()``s
what exists when a loop starts (its model, kernels, sockets), so that later collections traverse only what the loop
itself makes, and counts the collections and their pauses (``GcPauses``) until the loop ends; it then unfreezes
(when it froze) and stops counting. Used by the tracking service (``harness.live.service``) and the live hitting
policy (``harness.experiments.play.live``).
"""

from __future__ import annotations

import contextlib
import gc
import time

__all__ = ["GcPauses", "frozen_gc"]


class GcPauses:
    """The garbage collector's runs (``gc.callbacks``, any thread): count per generation and the pauses."""

    def __init__(self):
        self.runs = [0, 0, 0]
        self.total_s = self.max_s = 0.0
        self._t0 = None

    def on_gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        elif self._t0 is not None:
            dt = time.perf_counter() - self._t0
            self._t0 = None
            self.runs[min(int(info.get("generation", 0)), 2)] += 1
            self.total_s += dt
            self.max_s = max(self.max_s, dt)

    def summary(self) -> dict:
        return {"collections_per_generation": list(self.runs), "pause_total_ms": self.total_s * 1e3,
                "pause_max_ms": self.max_s * 1e3}


@contextlib.contextmanager
def frozen_gc(pauses: GcPauses, *, freeze: bool = True):
    """Within the block: ``pauses`` counts the collections; with ``freeze`` (and nothing frozen yet) what is alive at
    its start is collected once and frozen, unfrozen at its end."""
    froze = freeze and not gc.get_freeze_count()
    if froze:
        gc.collect()
        gc.freeze()
    gc.callbacks.append(pauses.on_gc)
    try:
        yield pauses
    finally:
        gc.callbacks.remove(pauses.on_gc)
        if froze:
            gc.unfreeze()
