"""Leave at once after a stop by a signal: once a command has written its output and returned, flush and exit
without the interpreter's teardown of native libraries (numba, llvmlite, ZeroMQ, BLAS), which alone took
1.2-2.7 s on the loaded 2-core development machine (measured on ``rt2 robot serve --sim``: SIGTERM to the
end of its ``atexit`` handlers 1 ms, to the end of the process 1.6 s). A parent that stops its child services
waits for exactly that, and has 2 s to stop (docs/reliability.md).

    signal.signal(signal.SIGTERM, lambda s, _f: (stop_serving(), exit_at_once_when_done(128 + s)))
"""

from __future__ import annotations

import atexit
import os
import sys
import threading

__all__ = ["exit_at_once", "exit_at_once_when_done"]


def exit_at_once(code: int) -> None:
    """Flush logging and stdio, then ``os._exit(code)``: no further teardown."""
    import logging

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def exit_at_once_when_done(code: int) -> None:
    """Have :func:`exit_at_once` run when the main thread is done (the command returned, its output written),
    before the interpreter joins threads: threading's own exit hooks run before that join (and before
    :mod:`atexit`), last registered first, so this one precedes e.g. concurrent.futures' join of its manager
    threads. Falls back to :mod:`atexit`. Safe to call from a signal handler, and more than once (the first
    registration to run exits)."""
    register = getattr(threading, "_register_atexit", None)
    try:
        if register is None:
            raise RuntimeError("no threading exit hooks")
        register(exit_at_once, code)
    except RuntimeError:  # already shutting down, or another Python
        atexit.register(exit_at_once, code)
