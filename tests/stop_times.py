"""How fast every long-running ``rt2`` command stops on SIGINT / SIGTERM, measured as a user meets it
(``make stop-times``).

    python tests/stop_times.py                                   # every command, SIGINT and SIGTERM, 20 tries each
    python tests/stop_times.py --tries 3 --commands play play-live   # a few (names without spaces)
    python tests/stop_times.py --load tests/tracker --parallel 2 --json out/stop_times.json   # beside `pytest -n 2`

For each command and signal, each try starts the real CLI (``python -m harness.cli ...``, small seeded
arguments, its own session and temporary folder), waits until it is doing work -- its progress bar shows a
finished task, its ready line or first status line is printed (an event on its output, never a blind sleep)
-- takes a snapshot of its descendant processes and of the TCP ports they listen on (/proc), sends the signal
to the main process alone (as ``kill PID`` or systemd would; a Ctrl-C in a terminal reaches the whole group,
an easier case: workers ignore SIGINT) and times signal -> exit. Then it checks what docs/reliability.md
promises: the exit code (128 + signal; 0 for the services ``rt2 track`` and ``rt2 robot serve``, which were
asked to stop and did), no descendant left (5 s after the exit at most; the time until the last one is gone is
reported as well), every port they listened on bindable again, and the outputs: written and marked partial
(``"partial": true``, ``PARTIAL (interrupted by SIGTERM)``), session logs closed with the reason, a data set
left out (all or nothing), no traceback on stderr. A try fails when the exit takes longer than ``--limit`` (2 s)
or any check fails; the tail of its output is kept in the JSON.

``--load "PYTEST ARGS"`` loops ``pytest -q -n 2 -m "not slow and not realtime" PYTEST ARGS`` in the
background for the whole measurement (the load under which the 2 s promise must hold), stops it after, and
reports the 1-minute load average seen (median and max of a sample every 5 s) and the load runs' results.

Prints a table (command, signal, tries, p50, p99, p100 of signal -> exit, p100 of signal -> last descendant gone,
failures) and writes every try to ``--json``. Exit code 0 when no try failed, 1 otherwise, 2 for bad
arguments. Not a pytest test module (its name does not start with ``test_``): it is a measurement, and it
runs from a checkout (the load is the checkout's own test suite), so it is a Makefile target, not an ``rt2``
command.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # rt2's own harness package, not tests/harness (this script's folder comes first)
LIMIT_S = 2.0  #: docs/reliability.md: every command stops within 2 s of SIGINT / SIGTERM
CHILDREN_GONE_S = 5.0  #: descendants still alive this long after the main process exited: a failure
READY_TIMEOUT_S = 600.0  #: a command that shows no work within this long fails the try (a cold numba cache, load)
SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}


# -- the processes: /proc, no psutil ---------------------------------------------------------------------------
def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of ``pid`` from /proc/PID/stat, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (children, their children, ...), zombies left out."""
    parent_of = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None and st[0] != "Z":
                parent_of[int(d.name)] = st[1]
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent_of.items() if pp == p]
        out += kids
        todo += kids
    return out


def alive(pid: int) -> bool:
    st = _stat(pid)
    return st is not None and st[0] != "Z"


def wait_gone(pids: list[int], timeout_s: float) -> list[int]:
    """Wait until every process of ``pids`` has exited (or ``timeout_s``); the ones still running. Waits on
    pidfds (Linux >= 5.3: readable once the process has exited, no polling); elsewhere polls /proc."""
    import select

    fds, left = {}, []
    try:
        for pid in pids:
            try:
                fds[os.pidfd_open(pid)] = pid
            except ProcessLookupError:
                continue  # gone already
            except (AttributeError, OSError):  # no pidfd here: poll
                left.append(pid)
        t_end = time.monotonic() + max(timeout_s, 0.0)
        poller = select.poll()
        for fd in fds:
            poller.register(fd, select.POLLIN)
        waiting = dict(fds)
        while waiting and time.monotonic() < t_end:
            for fd, _ in poller.poll(max(0.0, t_end - time.monotonic()) * 1e3):
                poller.unregister(fd)
                waiting.pop(fd, None)
        while any(alive(p) for p in left) and time.monotonic() < t_end:
            time.sleep(0.01)
        return [p for p in waiting.values() if alive(p)] + [p for p in left if alive(p)]
    finally:
        for fd in fds:
            os.close(fd)


def listening_ports(pids: list[int]) -> list[int]:
    """The TCP ports the processes ``pids`` listen on (their socket inodes matched in /proc/net/tcp{,6})."""
    inodes = set()
    for pid in pids:
        try:
            fds = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # state LISTEN
                ports.add(int(f[1].rsplit(":", 1)[1], 16))
    return sorted(ports)


def bindable(port: int) -> bool:
    """Whether 127.0.0.1:``port`` can be bound again, as a server would (SO_REUSEADDR: TIME_WAIT does not count)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- one command as a user runs it -----------------------------------------------------------------------------
class Run:
    """``rt2 ARGV`` in its own session; stdout and stderr read line by line by threads, ``ready`` set once
    ``ready_pattern`` matched ``ready_count`` times (progress bars: its first group >= ``ready_count``)."""

    def __init__(self, argv: list[str], ready_pattern: str, ready_count: int, cwd: Path, ready_stream: str = "stderr"):
        env = dict(os.environ, PYTHONUNBUFFERED="1", TQDM_MININTERVAL="0")  # a progress line per finished task
        self.proc = subprocess.Popen([sys.executable, "-m", "harness.cli", *argv], cwd=cwd, env=env, text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
        self.out: list[str] = []
        self.err: list[str] = []
        self.ready = threading.Event()
        self.exited_at: float | None = None
        self._exited = threading.Event()
        self._pattern, self._count, self._hits = re.compile(ready_pattern), ready_count, 0
        self._lock = threading.Lock()
        self._readers = [threading.Thread(target=self._read, args=(s, b, name == ready_stream), daemon=True)
                         for name, s, b in (("stdout", self.proc.stdout, self.out), ("stderr", self.proc.stderr, self.err))]
        for t in self._readers:
            t.start()
        threading.Thread(target=self._wait, daemon=True).start()

    def _read(self, stream, into: list[str], match: bool) -> None:
        for line in iter(stream.readline, ""):
            into.append(line)
            for piece in (line.split("\r") if match else ()):  # a terminal-style bar redraws with \r
                for m in self._pattern.finditer(piece):
                    with self._lock:
                        self._hits = max(self._hits, int(m.group(1))) if m.groups() else self._hits + 1
                        if self._hits >= self._count:
                            self.ready.set()
        self._exited.wait(1.0)

    def _wait(self) -> None:
        self.proc.wait()
        self.exited_at = time.monotonic()
        self._exited.set()
        self.ready.set()  # wake a waiter: it ended before it was ready

    def wait_exit(self, timeout_s: float) -> bool:
        return self._exited.wait(timeout_s)

    def finish(self) -> None:
        for t in self._readers:
            t.join(5.0)

    def kill_all(self) -> None:
        """Whatever is left of this run (its own session only): SIGKILL."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def text(self) -> str:
        return "".join(self.out) + "".join(self.err)


@dataclass(frozen=True)
class Command:
    """One command to stop: its arguments in a scratch folder, what 'doing work' looks like, the exit code a
    stop gives, and what its outputs must show afterwards."""

    name: str
    argv: Callable[[Path], list[str]]
    ready_pattern: str  #: a regex on stdout/stderr; with a group: a progress count that must reach ready_count
    ready_count: int
    service: bool = False  #: a service asked to stop exits 0; a study stopped early exits 128 + signal
    check: Callable[[Path, str, str, str], list[str]] = field(default=lambda d, sig, out, err: [])
    slow: bool = False  #: starts slowly (renders, compiles): fewer tries when --slow-tries is given
    ready_stream: str = "stderr"  #: where ready_pattern is looked for: progress bars write to stderr, ready lines to stdout

    def expected_code(self, signum: int) -> int:
        return 0 if self.service else 128 + signum


def _json(path: Path):
    return json.loads(path.read_text())


def _log_closed(path: Path, sig: str, reason: bool = True) -> list[str]:
    """A session log closed cleanly (and, with ``reason``, whose session_end names the signal: a study cut
    short; a service asked to stop ends its log as it always does)."""
    from harness.logs import SessionLogReader

    with SessionLogReader(path) as log:
        if not log.finished_cleanly:
            return [f"{path.name} not finished cleanly"]
        end = json.dumps(log.summary().session_end)
    return [] if (not reason or sig in end or "signal" in end) else [f"{path.name}: session_end does not name the stop: {end[:200]}"]


def _partial_rows(path: Path, what: str, out: str, sig: str) -> list[str]:
    problems = []
    if f"PARTIAL (interrupted by {sig})" not in out:
        problems.append(f"stdout does not say PARTIAL (interrupted by {sig})")
    if not path.is_file():
        return problems + [f"{path.name} not written"]
    rows = _json(path)
    if not rows or not all(r.get("partial") is True for r in rows):
        problems.append(f"{what} rows not marked partial")
    return problems


def _check_play(d: Path, sig: str, out: str, err: str) -> list[str]:
    problems = _partial_rows(d / "play.json", "play", out, sig)
    if not problems:
        (row,) = _json(d / "play.json")
        problems += [] if 1 <= row["balls"] < 60 else [f"{row['balls']} balls kept (1..59 expected)"]
        problems += _log_closed(Path(row["log"]), sig)
    return problems


def _check_compare(d: Path, sig: str, out: str, err: str) -> list[str]:
    path = d / "compare.json"
    problems = [] if f"PARTIAL (interrupted by {sig})" in out else [f"stdout does not say PARTIAL (interrupted by {sig})"]
    if not path.is_file():
        return problems + ["compare.json not written"]
    rows = _json(path)
    return problems + ([] if rows and rows[-1]["partial"] is True else ["the last configuration is not marked partial"])


def _check_accuracy(d: Path, sig: str, out: str, err: str) -> list[str]:
    """Scored and marked partial, or (too few frame sets to score) one line saying so; the log closed either way."""
    if f"accuracy: interrupted by {sig} " in err and "the finished frames are in the session log" in err:
        return _log_closed(d / "session.mcap", sig)
    if f"accuracy: interrupted by {sig} before any frame set finished" in err:
        return []  # nothing finished: nothing to keep
    problems = [] if out.startswith("PARTIAL") else ["stdout does not start with PARTIAL"]
    if not (d / "summary.json").is_file():
        return problems + ["summary.json not written"]
    part = _json(d / "summary.json")["figures"].get("partial") or {}
    problems += [] if part.get("reason") == f"interrupted by {sig}" else [f"summary.json partial: {part}"]
    return problems + _log_closed(d / "session.mcap", sig)


def _check_dataset(d: Path, sig: str, out: str, err: str) -> list[str]:
    left = list((d / "set").iterdir()) if (d / "set").exists() else []
    return [f"--out not left as it was: {[p.name for p in left]}"] if left else []


def _check_track(d: Path, sig: str, out: str, err: str) -> list[str]:
    if not (d / "stats.json").is_file():
        return ["stats.json not written"]
    s = _json(d / "stats.json")
    problems = [] if s.get("stopped_by") == sig else [f"stats.json stopped_by {s.get('stopped_by')!r}"]
    return problems + _log_closed(d / "track.mcap", sig, reason=False)


def _check_play_live(d: Path, sig: str, out: str, err: str) -> list[str]:
    if not (d / "live.json").is_file():
        return ["live.json not written"]
    (row,) = _json(d / "live.json")
    problems = [] if row["partial"] is True and 1 <= row["balls"] < 20 else [f"live.json: partial {row['partial']}, "
                                                                              f"{row['balls']} balls"]
    return problems + _log_closed(d / "play_live_rt2_raw_synthetic_s0.mcap", sig)


def _check_accuracy_live(d: Path, sig: str, out: str, err: str) -> list[str]:
    logs = list((d / "out").glob("*.mcap"))
    return [p for log in logs for p in _log_closed(log, sig)]


def _track_argv(d: Path) -> list[str]:
    return ["track", "--source", "sim", "--prerender", "0.1", "--publish", f"tcp://127.0.0.1:{free_port()}",
            "--publish-rt2", f"tcp://127.0.0.1:{free_port()}", "--status-period", "0.5", "--log", str(d / "track.mcap"),
            "--log-images", "none", "--json", str(d / "stats.json")]


COMMANDS: dict[str, Command] = {c.name: c for c in [
    Command("play", lambda d: ["play", "--tracker", "rt2", "--filter", "raw", "--balls", "60", "--seed", "0",
                               "--workers", "2", "--out", str(d), "--no-figure", "--json", str(d / "play.json")],
            r"(\d+)/60", 1, check=_check_play),
    Command("play compare", lambda d: ["play", "compare", "--trackers", "rt2", "--filters", "raw", "ransac_kalman",
                                       "--balls", "30", "--seed", "0", "--workers", "2", "--out", str(d),
                                       "--no-figure", "--no-log", "--json", str(d / "compare.json")],
            r"(\d+)/30", 1, check=_check_compare),
    Command("accuracy", lambda d: ["accuracy", "--frames", "1000", "--rate-hz", "50", "--seed", "3", "--workers", "2",
                                   "--trackers", "rt2", "--log-images", "none", "--out", str(d),
                                   "--json", str(d / "accuracy.json")],
            r"(\d+)/1000", 1, check=_check_accuracy, slow=True),
    Command("sim table1", lambda d: ["sim", "table1", "--trials", "4000", "--cameras", "4", "8", "15", "30",
                                     "--workers", "2", "--seed", "0", "--json", str(d / "table1.json")],
            r"(\d+)/160", 2, check=lambda d, sig, out, err: _partial_rows(d / "table1.json", "table1", out, sig)),
    Command("eval framesets", lambda d: ["eval", "framesets", "--frames", "400", "--seed", "0", "--workers", "2",
                                         "--trackers", "rt2", "--json", str(d / "framesets.json")],
            r"(\d+)/400", 20, check=lambda d, sig, out, err: _partial_rows(d / "framesets.json", "framesets", out, sig)),
    Command("sim dataset", lambda d: ["sim", "dataset", "--frames", "200", "--seed", "1", "--workers", "2",
                                      "--out", str(d / "set")],
            r"(\d+)/200", 8, check=_check_dataset),
    Command("track", _track_argv, r"frame sets,", 2, service=True, check=_check_track, ready_stream="stdout"),
    Command("robot serve", lambda d: ["robot", "serve", "--sim", "--bind", "tcp://127.0.0.1:*", "--batch", "4",
                                      "--ready-json"],
            r'^\{"command"', 1, service=True, ready_stream="stdout"),
    Command("play --live", lambda d: ["play", "--live", "--balls", "20", "--seed", "0", "--out", str(d),
                                      "--json", str(d / "live.json")],
            # stdout: a warning on stderr may start with "ball 0:" too, before that ball has finished
            r"^ball 0:", 1, check=_check_play_live, slow=True, ready_stream="stdout"),
    Command("accuracy --live", lambda d: ["accuracy", "--live", "--frames", "40", "--rate-hz", "100", "--trackers",
                                          "rt2", "--out", str(d / "out")],
            r"^motion commanded:", 1, check=_check_accuracy_live, slow=True, ready_stream="stdout"),
]}


def key(name: str) -> str:
    """A command's name without spaces, for a shell or make: 'play --live' -> 'play-live'."""
    return name.replace(" --", "-").replace(" ", "-")


def try_once(cmd: Command, sig: str, limit_s: float = LIMIT_S) -> dict:
    """One start - work - signal - exit of ``cmd``: a row with the times (s) and the problems found."""
    signum = SIGNALS[sig]
    with tempfile.TemporaryDirectory(prefix="rt2-stop-") as tmp:
        d = Path(tmp)
        run = Run(cmd.argv(d), cmd.ready_pattern, cmd.ready_count, ROOT, cmd.ready_stream)
        row = {"command": cmd.name, "signal": sig, "exit_s": None, "gone_s": None, "code": None, "problems": []}
        try:
            t_start = time.monotonic()
            run.ready.wait(READY_TIMEOUT_S)
            row["ready_s"] = round(time.monotonic() - t_start, 3)
            if run.proc.poll() is not None or not run.ready.is_set():
                why = "ended" if run.proc.poll() is not None else f"showed no work within {READY_TIMEOUT_S:g} s"
                row["problems"].append(f"it {why} before the signal (code {run.proc.returncode}): {run.text()[-600:]}")
                return row
            tree = descendants(run.proc.pid)
            ports = listening_ports([run.proc.pid, *tree])
            t0 = time.monotonic()
            os.kill(run.proc.pid, signum)
            if not run.wait_exit(30.0):
                row["problems"].append(f"still running 30 s after {sig}")
                return row
            row["exit_s"] = round(run.exited_at - t0, 3)
            left = wait_gone(tree, run.exited_at + CHILDREN_GONE_S - time.monotonic())
            row["gone_s"] = None if left else round(max(time.monotonic() - t0, row["exit_s"]) if tree else row["exit_s"], 3)
            row.update(code=run.proc.returncode, children=len(tree), ports=ports)
            run.finish()
            if row["exit_s"] > limit_s:
                row["problems"].append(f"exit {row['exit_s']:.2f} s after {sig} (limit {limit_s:g} s)")
            if run.proc.returncode != cmd.expected_code(signum):
                row["problems"].append(f"exit code {run.proc.returncode}, expected {cmd.expected_code(signum)}: "
                                       f"{''.join(run.err)[-600:]}")
            if left:
                row["problems"].append(f"{len(left)} descendant(s) alive {CHILDREN_GONE_S:g} s after the exit")
            if "Traceback (most recent call last)" in "".join(run.err):  # an exit code a fast exit may have masked
                row["problems"].append("a traceback on stderr")
            busy = [p for p in ports if not bindable(p)]
            if busy:
                row["problems"].append(f"ports {busy} not bindable after the exit")
            try:
                row["problems"] += cmd.check(d, sig, "".join(run.out), "".join(run.err))
            except Exception as exc:  # a damaged output is a finding of this try, not a crash of the measurement
                row["problems"].append(f"outputs unreadable: {type(exc).__name__}: {exc}")
            return row
        finally:
            if row["problems"]:  # what it said, to find the cause
                row["stdout_tail"], row["stderr_tail"] = "".join(run.out)[-1500:], "".join(run.err)[-1500:]
            run.kill_all()
            run.finish()


# -- the load: pytest -n 2 looping beside the measurement --------------------------------------------------------
class Load:
    """``pytest -q -n 2 -m "not slow and not realtime" ARGS`` run again and again in the background until
    :meth:`stop`; the 1-minute load average sampled every 5 s."""

    def __init__(self, pytest_args: str):
        self.argv = [sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "no:cacheprovider",
                     "-m", "not slow and not realtime", *shlex.split(pytest_args)]
        self.runs: list[int] = []  #: each finished load run's exit code
        self.loadavg: list[float] = []
        self._stop = threading.Event()
        self._proc: subprocess.Popen | None = None
        self._threads = [threading.Thread(target=self._loop, daemon=True),
                         threading.Thread(target=self._sample, daemon=True)]

    def start(self) -> "Load":
        for t in self._threads:
            t.start()
        return self

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._proc = subprocess.Popen(self.argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          start_new_session=True)
            code = self._proc.wait()
            if not self._stop.is_set():
                self.runs.append(code)

    def _sample(self) -> None:
        while not self._stop.wait(5.0):
            self.loadavg.append(os.getloadavg()[0])

    def stop(self) -> dict:
        self._stop.set()
        if self._proc is not None and self._proc.poll() is None:
            try:
                os.killpg(self._proc.pid, signal.SIGKILL)  # the load's own session: pytest and its xdist workers
            except ProcessLookupError:
                pass
        for t in self._threads:
            t.join(30.0)
        la = self.loadavg or [os.getloadavg()[0]]
        return {"command": " ".join(self.argv[1:]), "runs_finished": len(self.runs),
                "runs_failed": sum(c != 0 for c in self.runs),
                "loadavg_1min_median": round(statistics.median(la), 2), "loadavg_1min_max": round(max(la), 2)}


# -- the report ------------------------------------------------------------------------------------------------
def summarise(rows: list[dict]) -> list[dict]:
    """Per (command, signal): tries, p50, p99 and p100 of signal -> exit, p100 of signal -> last descendant gone,
    failures."""
    out = []
    for key in dict.fromkeys((r["command"], r["signal"]) for r in rows):
        mine = [r for r in rows if (r["command"], r["signal"]) == key]
        exits = [r["exit_s"] for r in mine if r["exit_s"] is not None]
        gones = [r["gone_s"] for r in mine if r["gone_s"] is not None]
        out.append({"command": key[0], "signal": key[1], "tries": len(mine),
                    "exit_p50_s": round(statistics.median(exits), 3) if exits else None,
                    "exit_p99_s": round(float(np.percentile(exits, 99)), 3) if exits else None,  # linear between ranks
                    "exit_p100_s": max(exits) if exits else None,
                    "gone_p100_s": max(gones) if len(gones) == len(mine) else None,
                    "failures": sum(bool(r["problems"]) for r in mine)})
    return out


def table(summary: list[dict]) -> str:
    f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    lines = [f"{'command':<16} {'signal':<7} {'tries':>5} {'p50 s':>6} {'p99 s':>6} {'p100 s':>6} {'gone p100':>9} "
             f"{'failures':>8}"]
    lines += [f"{s['command']:<16} {s['signal']:<7} {s['tries']:>5} {f(s['exit_p50_s']):>6} {f(s['exit_p99_s']):>6} "
              f"{f(s['exit_p100_s']):>6} "
              f"{f(s['gone_p100_s']):>9} {s['failures']:>8}" for s in summary]
    return "\n".join(lines)


def write_json(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    tmp.replace(path)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="stop_times.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--tries", type=int, default=20, help="tries per command and signal (default 20)")
    p.add_argument("--slow-tries", type=int, default=None,
                   help="tries for the slow starters (accuracy, play --live, accuracy --live); default: --tries")
    p.add_argument("--commands", nargs="+", default=list(COMMANDS), metavar="NAME",
                   help=f"commands to measure (default all: {', '.join(map(key, COMMANDS))})")
    p.add_argument("--signals", nargs="+", default=list(SIGNALS), choices=list(SIGNALS))
    p.add_argument("--limit", type=float, default=LIMIT_S, help="the promise, s (default 2)")
    p.add_argument("--load", metavar="PYTEST_ARGS", default=None,
                   help='loop `pytest -n 2` over these (e.g. "tests/tracker") in the background while measuring')
    p.add_argument("--parallel", type=int, default=1, metavar="N",
                   help="N tries at a time (default 1); more load on the machine, fewer minutes")
    p.add_argument("--json", type=Path, default=None, help="write every try and the summary here")
    p.add_argument("--report", type=Path, nargs="+", default=None, metavar="JSON",
                   help="measure nothing: print the table of the tries in these --json files (runs made side by side); "
                        "with --json, write them merged there")
    args = p.parse_args(argv)
    keys = {key(c): c for c in COMMANDS}
    bad = [c for c in args.commands if c not in COMMANDS and c not in keys]
    if bad:
        p.error(f"unknown command(s) {bad}; valid: {', '.join(keys)} (or the names with spaces, e.g. 'play --live')")
    args.commands = [keys.get(c, c) for c in args.commands]
    if args.parallel < 1:
        p.error(f"--parallel must be at least 1, got {args.parallel}")
    if args.tries < 1 or (args.slow_tries is not None and args.slow_tries < 1):
        p.error("--tries and --slow-tries must be at least 1")
    if not (args.limit > 0):
        p.error(f"--limit must be positive, got {args.limit}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.report:
        try:
            rows = [r for path in args.report for r in json.loads(path.read_text())["tries"]]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"stop_times.py: error: --report: {exc}", file=sys.stderr)
            return 2
        print(table(summarise(rows)))
        if args.json:  # the merged runs as one measurement (their loads are in the files named)
            write_json(args.json, {"merged_from": [str(p) for p in args.report], "summary": summarise(rows), "tries": rows})
        return 1 if any(r["problems"] for r in rows) else 0
    if not sys.platform.startswith("linux"):
        print("stop_times.py: the process and port checks read /proc (Linux only)", file=sys.stderr)
        return 2
    load = Load(args.load).start() if args.load else None
    jobs = []
    for name in args.commands:
        cmd = COMMANDS[name]
        n = args.slow_tries if (cmd.slow and args.slow_tries is not None) else args.tries
        jobs += [(cmd, sig, k, n) for sig in args.signals for k in range(n)]
    printing = threading.Lock()
    done: list[dict] = []

    def one(job) -> dict:
        cmd, sig, k, n = job
        row = try_once(cmd, sig, args.limit)
        t = "-" if row["exit_s"] is None else f"{row['exit_s']:.2f} s"
        with printing:
            done.append(row)
            if args.json:  # every try as it comes: a measurement cut short keeps what it measured
                write_json(args.json, {"limit_s": args.limit, "parallel": args.parallel, "tries": done})
            print(f"{cmd.name} {sig} {k + 1}/{n}: exit {t}" + (f"  FAILED: {'; '.join(row['problems'])}"
                                                               if row["problems"] else ""), flush=True)
        return row

    t_begin = time.monotonic()
    pool = ThreadPoolExecutor(args.parallel)
    try:
        futures = [pool.submit(one, job) for job in jobs]
        rows = [f.result() for f in futures]
    except KeyboardInterrupt:  # Ctrl-C: the tries under way finish, the rest are dropped, the report covers those
        print("\ninterrupted: finishing the tries under way, then reporting what was measured", flush=True)
        pool.shutdown(wait=True, cancel_futures=True)
        rows = list(done)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        load_info = load.stop() if load else None
    summary = summarise(rows)
    print()
    print(table(summary))
    if load_info:
        print(f"\nload: {load_info['command']} looping ({load_info['runs_finished']} runs finished, "
              f"{load_info['runs_failed']} failed); 1-min load average median {load_info['loadavg_1min_median']}, "
              f"max {load_info['loadavg_1min_max']}")
    print(f"{len(rows)} tries in {time.monotonic() - t_begin:.0f} s, {args.parallel} at a time; limit {args.limit:g} s")
    if args.json:
        write_json(args.json, {"limit_s": args.limit, "parallel": args.parallel, "load": load_info, "summary": summary,
                               "tries": rows})
    return 1 if any(s["failures"] for s in summary) else 0


if __name__ == "__main__":
    sys.exit(main())
