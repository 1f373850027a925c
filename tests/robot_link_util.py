"""Start ``rt2 robot serve --sim`` as a separate process on free 127.0.0.1 ports (shared by the robot-link tests)."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


class BridgeProcess:
    """A running simulated-WAM bridge; ``ready`` is its ready line (endpoints, pid, clock epoch)."""

    def __init__(self, *extra: str, bind: str = "tcp://127.0.0.1:*", state_bind: str | None = None,
                 timeout_s: float = 60.0):
        cmd = [sys.executable, "-m", "harness.cli", "robot", "serve", "--sim", "--bind", bind, "--ready-json", *extra]
        if state_bind:
            cmd += ["--state-bind", state_bind]
        self._log = tempfile.TemporaryFile(mode="w+")  # the bridge's log; a pipe nobody reads could fill and block it
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.proc.kill()
            raise RuntimeError(f"bridge did not start: {self.log_text()[-2000:]}")
        self.ready = json.loads(line)
        self.address = self.ready["command"]

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> str:
        """SIGTERM, wait, return stderr (the bridge's log)."""
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
