"""``stop_on_signals`` (harness/common/signal_stop.py), each case in a process of its own (a stop ends the
process with 128 + signal): SIGTERM raises ``Interrupted``; a stop whose exception is dropped by a ``__del__``
is raised again within a re-delivery period instead of letting the run go on; re-deliveries never interrupt
the cleanup the first stop started (children stopped, logs closed in ``finally`` / ``__exit__``)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pthread_kill, POSIX signals")

ROOT = Path(__file__).resolve().parents[3]

SCRIPT = """
import os, signal, sys, time
from harness.common.signal_stop import Interrupted, stop_on_signals


class DropsWhatItRaises:  # Python prints and drops an exception raised in __del__ (numba, llvmlite free objects so)
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        t_end = time.monotonic() + 0.2
        while time.monotonic() < t_end:  # the handler runs (and raises) here
            pass


mode = sys.argv[1]
try:
    with stop_on_signals():
        if mode == "plain":
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5.0)
        elif mode == "dropped":
            DropsWhatItRaises()
            time.sleep(5.0)  # the run going on after its stop was dropped
        elif mode == "cleanup":
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5.0)
            finally:  # stopping children, closing a log: 1 s, over three re-delivery periods
                t_end = time.monotonic() + 1.0
                while time.monotonic() < t_end:
                    time.sleep(0.01)
                print("CLEANUP DONE", flush=True)
        print("RAN TO THE END", flush=True)
except Interrupted as stop:
    print("STOPPED", stop.exit_code, stop, flush=True)
    sys.exit(stop.exit_code)
"""


def _run(mode: str) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", SCRIPT, mode], cwd=ROOT, capture_output=True, text=True, timeout=120)
    return proc, time.monotonic() - t0


def test_sigterm_raises_interrupted_with_its_exit_code():
    proc, _ = _run("plain")
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert "STOPPED 143 interrupted by SIGTERM" in proc.stdout and "RAN TO THE END" not in proc.stdout


def test_a_stop_dropped_by_a_del_is_raised_again():
    """Without the re-delivery the run went on for its 5 s and ran to its end (exit 0)."""
    proc, dt = _run("dropped")
    assert "Exception ignored" in proc.stderr  # the first exception was indeed dropped
    assert proc.returncode == 128 + signal.SIGTERM, proc.stdout + proc.stderr[-2000:]
    assert "RAN TO THE END" not in proc.stdout
    assert dt < 4.5  # the interpreter's start included; the sleep it cut was 5 s


def test_redeliveries_do_not_interrupt_the_cleanup():
    proc, _ = _run("cleanup")
    assert proc.returncode == 128 + signal.SIGINT, proc.stdout + proc.stderr[-2000:]
    assert "CLEANUP DONE" in proc.stdout and "Traceback" not in proc.stderr
    assert "STOPPED 130 interrupted by SIGINT" in proc.stdout
