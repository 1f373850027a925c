"""``rt2 train`` on the labels so far, as a child process the page starts and watches.

The child is ``python -m harness.cli train --data OUT --out OUT/<model> ...``: the same command a user
types, so its checks, its atomic model write and its messages are the ones documented for ``rt2 train``.
Its stdout and stderr go to ``OUT/train.log``; :meth:`TrainingJob.status` reports the state, the last
lines (tqdm's carriage-return updates split into lines), the held-out figures ``rt2 train`` printed
(its cross-validated or validation-split recall and outliers, and the base model's on the same images),
and, when it ends, the exit code and, for a failure, the last line the child wrote on stderr (``rt2
train``'s one-line reason: too few balls of the colour, a model too weak to write, ...).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path

__all__ = ["TrainingJob"]

LOG_FILE = "train.log"
TAIL_CHARS = 4000
#: a line of rt2 train's held-out figures (not an epoch's progress line)
_FIGURES = re.compile(r"^(?!epoch ).*\b(ours|top-[0-9]+) recall [0-9.]+%")
#: rt2 train's line on labelled balls left out for their measured colour (trained as background): the page shows it
_COLOUR_NOTE = re.compile(r"^[0-9]+ of the [0-9]+ labelled balls measure as not ")


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
        self._stderr_thread: threading.Thread | None = None
        self._last_err = ""
        self._lock = threading.Lock()
        self.runs = 0
        self.ball_colour: str | None = None

    def start(self, ball_colour: str) -> None:
        """Start training on balls of ``ball_colour`` (``rt2 train --ball-colour``); ValueError if a run is still going."""
        with self._lock:
            if self._proc is not None and self._proc.poll() is None:
                raise ValueError("training is already running; wait for it to end")
            self._close_log()
            cmd = [sys.executable, "-m", "harness.cli", "train", "--data", str(self.out_dir), "--out", str(self.model_path),
                   "--ball-colour", ball_colour, *self.extra_args]
            with open(self.log_path, "w") as fh:
                fh.write("$ rt2 " + " ".join(cmd[3:]) + "\n")
            self._log = open(self.log_path, "a")  # O_APPEND: the child's stdout and the stderr copy below never overwrite each other
            self._last_err = ""
            self._proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                          env={**os.environ, "PYTHONUNBUFFERED": "1"})
            self._stderr_thread = threading.Thread(target=self._copy_stderr, args=(self._proc, self._log), daemon=True,
                                                   name="rt2 train stderr")
            self._stderr_thread.start()
            self.ball_colour = ball_colour
            self.runs += 1

    def _copy_stderr(self, proc: subprocess.Popen, log) -> None:
        """The child's stderr into the log, remembering its last line (the reason of a failure)."""
        pending = ""
        for chunk in iter(lambda: proc.stderr.read1(4096), b""):
            text = chunk.decode(errors="replace")
            try:
                log.write(text)
                log.flush()
            except (OSError, ValueError):  # the log was closed (server stopping)
                pass
            pending = (pending + text)[-TAIL_CHARS:]
            lines = [ln.strip() for ln in pending.replace("\r", "\n").split("\n") if ln.strip()]
            if lines:
                self._last_err = lines[-1]
        proc.stderr.close()

    def status(self) -> dict:
        """``{"state": "idle"|"running"|"done"|"failed", "returncode", "log_tail", "model", "figures", "notes", "error", "ball_colour"}``.

        figures : rt2 train's held-out figure lines so far (list of str); notes : its line on labelled balls it trains
        as background for their measured colour, if any (list of str; it scrolls out of the log's tail); error : a
        failed run's last stderr line
        """
        with self._lock:
            proc, thread = self._proc, self._stderr_thread
        if proc is None:
            return {"state": "idle", "returncode": None, "log_tail": "", "model": None, "figures": [], "notes": [], "error": None,
                    "ball_colour": None}
        rc = proc.poll()
        if rc is not None and thread is not None:
            thread.join(timeout=5)  # the last stderr line is in before the run is reported as ended
        state = "running" if rc is None else ("done" if rc == 0 else "failed")
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            text = ""
        lines = [ln.rstrip() for ln in text.replace("\r", "\n").split("\n") if ln.strip()]
        figures = [ln.strip() for ln in lines if _FIGURES.match(ln.strip())][-2:]
        notes = [ln.strip() for ln in lines if _COLOUR_NOTE.match(ln.strip())][-1:]
        model = str(self.model_path) if state == "done" and self.model_path.is_file() else None
        error = (self._last_err or f"rt2 train ended with exit code {rc}") if state == "failed" else None
        return {"state": state, "returncode": rc, "log_tail": "\n".join(lines[-12:]), "model": model, "figures": figures,
                "notes": notes, "error": error, "ball_colour": self.ball_colour}

    def _close_log(self) -> None:
        if self._stderr_thread is not None:
            self._stderr_thread.join(timeout=5)
            self._stderr_thread = None
        if self._log is not None:
            self._log.close()
            self._log = None

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
        self._close_log()
