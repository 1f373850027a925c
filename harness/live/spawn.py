"""Start ``rt2 track`` as a separate process and wait for its ready line (the bound stream addresses).

Used by ``rt2 accuracy --live`` (the one-command local run: bridge, tracker and experiment as three
processes) and by its tests.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["TrackProcess"]

ROOT = Path(__file__).resolve().parents[2]


class TrackProcess:
    """A running ``rt2 track ... --ready-json`` process; ``streams`` maps ``tennicam`` / ``rt2`` to their addresses.

    args : ``rt2 track`` options (``--publish`` defaults to a free port on 127.0.0.1); ``timeout_s``: how long
    its start (rig, tracker warm-up, renderer) may take before it counts as failed.
    """

    def __init__(self, *args: str, timeout_s: float = 600.0):
        cmd = [sys.executable, "-m", "harness.cli", "track", "--ready-json", *args]
        if "--publish" not in args:
            cmd += ["--publish", "tcp://127.0.0.1:0"]
        self._log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        deadline = time.monotonic() + timeout_s
        line = ""
        try:
            while time.monotonic() < deadline and self.proc.poll() is None:
                ready, _, _ = select.select([self.proc.stdout], [], [], 0.5)
                if ready:
                    line = self.proc.stdout.readline()
                    break
        except BaseException:  # SIGINT while it starts: never leave it running
            self.stop()
            raise
        if not line.startswith("{"):
            self.stop()
            raise ValueError(f"rt2 track did not start within {timeout_s:.0f} s: "
                             f"{(line + self.log_text()).strip()[-1500:] or 'no output'}")
        self.ready = json.loads(line)
        self.streams = self.ready["streams"]
        # its status lines and summary go on stdout: drain them into the log file so a full pipe never blocks it
        import threading

        self._drain = threading.Thread(target=self._copy_stdout, daemon=True, name="rt2 track stdout")
        self._drain.start()

    def _copy_stdout(self) -> None:
        for line in self.proc.stdout:
            self._log.write(line)

    def stop(self) -> str:
        """SIGTERM (rt2 track finishes its log and prints its summary), wait; returns what it printed."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.log_text()

    def log_text(self) -> str:
        self._log.flush()
        self._log.seek(0)
        text = self._log.read()
        self._log.seek(0, 2)
        return text

    def __enter__(self) -> "TrackProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
