"""One reusable object per thread (work buffers of a per-frame step), that pickles as a fresh, empty one.

A detector or a renderer may serve several threads at once and is sent to worker processes; its
buffers must be neither shared between threads nor pickled. Hold ``PerThread(factory)`` and call
``get()`` where the buffers are needed: each thread gets its own ``factory()`` on first use.
"""

from __future__ import annotations

import threading

__all__ = ["PerThread"]


class PerThread:
    """``get()`` returns this thread's ``factory()`` (made once per thread); pickling keeps only ``factory``
    (a module-level callable), so the copy starts with no buffers."""

    def __init__(self, factory):
        self._factory = factory
        self._local = threading.local()

    def get(self):
        obj = getattr(self._local, "obj", None)
        if obj is None:
            obj = self._local.obj = self._factory()
        return obj

    def __reduce__(self):
        return PerThread, (self._factory,)
