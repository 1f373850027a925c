"""Start an ``rt2`` service (``python -m harness.cli ARGS...``) as a separate process and wait for the one
JSON line it prints on stdout when it serves (its ready line: the bound endpoints, pid, ...).

The one-command local runs use it (``rt2 accuracy --robot sim`` / ``--live``, ``rt2 play --live``: the
simulated robot bridge, ``rt2 track``, the observation process), as do the tests of the robot link and of
the live experiments.
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

__all__ = ["ReadyProcess"]

ROOT = Path(__file__).resolve().parents[2]


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
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
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

    def stop(self) -> str:
        """SIGTERM, wait (SIGKILL after ``stop_timeout_s``); returns what the child logged and printed."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
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
