"""Start ``rt2 robot serve --sim`` (or another ``rt2`` service) as a separate process on free ports and wait
for its ready line.

Used by ``rt2 accuracy --robot sim`` and ``rt2 play --live`` (the one-command local runs) and by the tests.
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["ReadyProcess", "SimBridgeProcess"]

ROOT = Path(__file__).resolve().parents[2]


class ReadyProcess:
    """A child process (``python -m harness.cli ARGS...``) that prints one JSON ready line on stdout when it
    serves; ``ready`` is that line, ``what`` names the child in errors. Its stderr goes to a temporary file
    (:meth:`log_text`)."""

    def __init__(self, args, *, what: str, timeout_s: float = 60.0):
        cmd = [sys.executable, "-m", "harness.cli", *args]
        self.what = what
        self._log = tempfile.TemporaryFile(mode="w+")  # the child's log; a pipe nobody reads could fill and block it
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
            line = self.proc.stdout.readline() if ready else ""
        except BaseException:  # SIGINT while it starts: never leave it running
            self.proc.kill()
            self.proc.wait()
            raise
        if not line:
            self.proc.kill()
            self.proc.wait()
            raise ValueError(f"{what} did not start: {self.log_text()[-2000:]}")
        self.ready = json.loads(line)


    def kill(self) -> None:
        """SIGKILL (a crash, for tests of link loss)."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> str:
        """SIGTERM, wait; returns what the bridge logged."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.log_text()

    def log_text(self) -> str:
        """What the bridge has logged so far (stderr)."""
        self._log.seek(0)
        return self._log.read()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class SimBridgeProcess(ReadyProcess):
    """A running simulated-WAM bridge process; ``ready`` is its ready line (endpoints, pid, clock epoch),
    ``address`` its command endpoint. ``extra``: more ``rt2 robot serve`` options (``--seed 3`` ...)."""

    def __init__(self, *extra: str, bind: str = "tcp://127.0.0.1:*", state_bind: str | None = None,
                 timeout_s: float = 60.0):
        args = ["robot", "serve", "--sim", "--bind", bind, "--ready-json", *extra]
        if state_bind:
            args += ["--state-bind", state_bind]
        super().__init__(args, what="the simulated robot bridge", timeout_s=timeout_s)
        self.address = self.ready["command"]
