"""``rt2 train`` on the labels so far, as a child process the page starts and watches.

The child is ``python -m harness.cli train --data OUT --out OUT/<model> ...``: the same command a user
types, so its checks, its atomic model write and its messages are the ones documented for ``rt2 train``.
Its stdout and stderr go to ``OUT/train.log``; :meth:`TrainingJob.status` reports the state, the last
lines (tqdm's carriage-return updates split into lines) and, when it ends, the exit code.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

__all__ = ["TrainingJob"]

LOG_FILE = "train.log"
TAIL_CHARS = 4000


class TrainingJob:
    """At most one ``rt2 train`` child at a time for one output folder.

    out_dir : the data set folder (``--data``); model_name : the weights file written inside it
    extra_args : more ``rt2 train`` options (e.g. ``["--epochs", "2"]``)
    """

    def __init__(self, out_dir, model_name: str = "model.npz", extra_args=()):
        self.out_dir = Path(out_dir)
        self.model_path = self.out_dir / model_name
        self.log_path = self.out_dir / LOG_FILE
        self.extra_args = [str(a) for a in extra_args]
        self._proc: subprocess.Popen | None = None
        self._log = None
        self._lock = threading.Lock()
        self.runs = 0

    def start(self) -> None:
        """Start training; ValueError if a run is still going."""
        with self._lock:
            if self._proc is not None and self._proc.poll() is None:
                raise ValueError("training is already running; wait for it to end")
            if self._log is not None:
                self._log.close()
            cmd = [sys.executable, "-m", "harness.cli", "train", "--data", str(self.out_dir), "--out", str(self.model_path), *self.extra_args]
            self._log = open(self.log_path, "w")
            self._log.write("$ rt2 " + " ".join(cmd[3:]) + "\n")
            self._log.flush()
            self._proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                          env={**os.environ, "PYTHONUNBUFFERED": "1"})
            self.runs += 1

    def status(self) -> dict:
        """``{"state": "idle"|"running"|"done"|"failed", "returncode", "log_tail", "model"}``."""
        with self._lock:
            proc = self._proc
        if proc is None:
            return {"state": "idle", "returncode": None, "log_tail": "", "model": None}
        rc = proc.poll()
        state = "running" if rc is None else ("done" if rc == 0 else "failed")
        try:
            text = self.log_path.read_text(errors="replace")[-TAIL_CHARS:]
        except OSError:
            text = ""
        lines = [ln.rstrip() for ln in text.replace("\r", "\n").split("\n") if ln.strip()]
        model = str(self.model_path) if state == "done" and self.model_path.is_file() else None
        return {"state": state, "returncode": rc, "log_tail": "\n".join(lines[-12:]), "model": model}

    def stop(self) -> None:
        """End a running child (the server is shutting down)."""
        with self._lock:
            proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._log is not None:
            self._log.close()
            self._log = None
