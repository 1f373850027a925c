"""Start an ``rt2`` service (``python -m harness.cli ARGS...``) as a separate process and wait for the one
JSON line it prints on stdout when it serves (its ready line: the bound endpoints, pid, ...).

The one-command local runs use it (``rt2 accuracy --robot sim`` / ``--live``, ``rt2 play --live``: the
simulated robot bridge, ``rt2 track``, the observation process), as do the tests of the robot link and of
the live experiments.

No orphans: a child dies with its parent however the parent ends (SIGKILL included) and so releases its
ports. ``ReadyProcess`` passes its pid in :data:`PARENT_PID_ENV`; the child's ``rt2`` entry point calls
:func:`die_with_parent_from_env`, which asks the kernel for SIGTERM when the parent dies
(``PR_SET_PDEATHSIG``: the child shuts down cleanly) and starts a thread that watches the parent's pid and
ends the process :data:`PARENT_GONE_GRACE_S` after the parent is gone, whatever its SIGTERM handler does
(also where ``prctl`` does not exist). Children of the child (``rt2 track``'s renderer) go the same way:
the renderer ends when its parent's pipe closes. Create a ``ReadyProcess`` from a thread that lives as long
as the child should (the main thread): the kernel's signal follows the creating thread.
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

__all__ = ["PARENT_PID_ENV", "STOP_GRACE_S", "ReadyProcess", "die_with_parent", "die_with_parent_from_env",
           "stop_together"]

ROOT = Path(__file__).resolve().parents[2]
PARENT_PID_ENV = "RT2_DIE_WITH_PARENT"  #: the parent's pid, for a child started by ReadyProcess
PARENT_GONE_GRACE_S = 1.0  #: a child still alive this long after its parent died exits at once
_WATCH_S = 0.1
#: after SIGINT / SIGTERM reached the parent, how long its children get to leave after their SIGTERM before SIGKILL:
#: the parent has 2 s in all (docs/reliability.md), and a child service that stops cleanly takes 0.03-0.5 s even
#: on the loaded 2-core machine (make stop-times)
STOP_GRACE_S = 1.0


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM, grace_s: float = PARENT_GONE_GRACE_S) -> None:
    """In a child: get ``sig`` when the parent dies (Linux ``PR_SET_PDEATHSIG``), and exit (status 1)
    ``grace_s`` after the parent is gone in any case; exit at once if it is gone already. Child services take
    SIGTERM and a grace for a clean shutdown; the sweep workers (``executor.py``) SIGKILL and none."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, int(sig), 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass  # the watcher below still works
    if os.getppid() != parent_pid:  # the parent died before we got here
        os._exit(1)

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(_WATCH_S)
        time.sleep(grace_s)  # time for a clean shutdown on the signal
        os._exit(1)

    threading.Thread(target=watch, name="rt2-parent-watch", daemon=True).start()


def die_with_parent_from_env() -> None:
    """:func:`die_with_parent` for the pid in :data:`PARENT_PID_ENV` (removed from the environment, so that the
    child's own children do not watch their grandparent); nothing when it is not set."""
    value = os.environ.pop(PARENT_PID_ENV, None)
    if value is None:
        return
    try:
        parent = int(value)
    except ValueError:
        return
    die_with_parent(parent)


class ReadyProcess:
    """A child process ``python -m harness.cli *args`` whose first stdout line is a JSON object (``ready``).

    what : names the child in errors; timeout_s : how long its start may take (it counts as failed when it
    exits or prints nothing by then); stop_timeout_s : how long :meth:`stop` waits after SIGTERM before
    SIGKILL. Its stderr, and whatever it prints on stdout after the ready line (drained by a thread so a
    full pipe never blocks it), go to a temporary file (:meth:`log_text`). A SIGINT while it starts never
    leaves it running.
    """

    def __init__(self, args, *, what: str, timeout_s: float = 60.0, stop_timeout_s: float = 10.0):
        cmd = [sys.executable, "-m", "harness.cli", *args]
        self.what, self.stop_timeout_s = what, float(stop_timeout_s)
        self._log = tempfile.TemporaryFile(mode="w+")
        self._lock = threading.Lock()
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1", PARENT_PID_ENV: str(os.getpid())})
        deadline = time.monotonic() + timeout_s
        line = ""
        try:
            while time.monotonic() < deadline and self.proc.poll() is None:
                if select.select([self.proc.stdout], [], [], 0.5)[0]:
                    line = self.proc.stdout.readline()
                    break
        except BaseException:  # SIGINT while it starts: never leave it running
            self.stop()
            raise
        if not line.startswith("{"):
            self.stop()
            raise ValueError(f"{what} did not start within {timeout_s:.0f} s: "
                             f"{(line + self.log_text()).strip()[-2000:] or 'no output'}")
        self.ready = json.loads(line)
        self._drain = threading.Thread(target=self._copy_stdout, daemon=True, name=f"{what} stdout")
        self._drain.start()

    def _copy_stdout(self) -> None:
        for line in self.proc.stdout:
            with self._lock:
                self._log.seek(0, 2)
                self._log.write(line)

    def kill(self) -> None:
        """SIGKILL (a crash, for tests of link loss)."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self, timeout_s: float | None = None) -> str:
        """SIGTERM, wait (SIGKILL after ``timeout_s``, default ``stop_timeout_s``); returns what the child logged
        and printed."""
        stop_together([self], timeout_s)
        return self.log_text()

    def log_text(self) -> str:
        """What the child has logged (stderr) and printed after its ready line so far."""
        with self._lock:
            self._log.flush()
            self._log.seek(0)
            return self._log.read()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def stop_together(children, timeout_s: float | None = None) -> None:
    """Stop ``children`` (:class:`ReadyProcess` or anything with ``proc``, a :class:`subprocess.Popen`, and
    ``stop_timeout_s``) side by side: SIGTERM to every one first, then wait for all of them until one deadline
    (``timeout_s``, default the largest ``stop_timeout_s``), then SIGKILL the ones still running and reap them.
    So n children take as long as the slowest, not the sum; a parent stopped by a signal passes
    :data:`STOP_GRACE_S`, so that a child that does not leave never holds it past its 2 s."""
    children = list(children)
    for child in children:
        if child.proc.poll() is None:
            try:
                child.proc.terminate()
            except ProcessLookupError:
                pass
    if timeout_s is None:
        timeout_s = max((float(c.stop_timeout_s) for c in children), default=0.0)
    deadline = time.monotonic() + max(0.0, float(timeout_s))
    for child in children:
        try:
            child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.proc.kill()
            child.proc.wait()
