"""Stop a command on SIGINT / SIGTERM within 2 s, even where the code the signal lands in drops the exception
(docs/reliability.md, "Worker processes" and "Child services stop fast").

    with stop_on_signals():     # SIGINT / SIGTERM raise Interrupted(signum) in the main thread
        run_the_experiment()    # its `with` blocks and `finally` clauses stop children and close logs
    # rt2's main turns Interrupted into exit code 128 + signal; the process then leaves at once

Python drops an exception raised in a signal handler when it lands in a ``__del__`` method or a weakref
callback (numba and llvmlite free compiler objects that way), and the run then goes on to its end. So after
the first signal a watchdog thread sends it to the main thread again every ``redeliver_s`` until the block is
left; the handler raises again only while the main thread is not already unwinding with :class:`Interrupted`
(a re-delivery never interrupts the ``finally`` clauses and ``__exit__`` methods that stop children and close
logs). The sweeps' executor does the same for its tasks (harness/common/executor.py).
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

from harness.common.fast_exit import exit_at_once_when_done

__all__ = ["Interrupted", "stop_on_signals"]

REDELIVER_S = 0.3  #: the watchdog's period: a dropped stop is raised again at most this much later


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM reached the main thread; ``exit_code`` = 128 + signal number."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        super().__init__(f"interrupted by {signal.Signals(self.signum).name}")


@contextmanager
def stop_on_signals(signals=(signal.SIGINT, signal.SIGTERM), redeliver_s: float = REDELIVER_S):
    """While the block runs, ``signals`` raise :class:`Interrupted` in the main thread (again every
    ``redeliver_s`` until the block is left, module docstring); the process's exit code becomes 128 + signal
    and it leaves without the interpreter's slow teardown once the command has returned
    (:func:`~harness.common.fast_exit.exit_at_once_when_done`). Outside the main thread: no effect."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    left = threading.Event()
    first: list[int] = []

    def redeliver() -> None:
        main = threading.main_thread()
        while not left.wait(redeliver_s) and main.is_alive():
            signal.pthread_kill(main.ident, first[0])

    def on_signal(signum, _frame) -> None:
        if not first:
            first.append(signum)
            exit_at_once_when_done(128 + signum)
            threading.Thread(target=redeliver, name="rt2-stop-redeliver", daemon=True).start()
        if left.is_set() or isinstance(sys.exc_info()[1], Interrupted):
            return  # already on its way out: let the cleanup run
        raise Interrupted(first[0])

    old = {s: signal.signal(s, on_signal) for s in signals}
    try:
        yield
    finally:
        left.set()
        for s, h in old.items():
            signal.signal(s, h)
