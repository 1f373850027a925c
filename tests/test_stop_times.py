"""`make stop-times` (tests/stop_times.py): one real try of `rt2 robot serve` per signal beside a small
`pytest -n 2` load, a limit it cannot meet (the failure path, and only that check failing), the summary and
table, the /proc helpers against a real child, bad arguments."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import stop_times  # noqa: E402  (tests/stop_times.py, a script beside the tests)

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the process checks read /proc")
ROOT = Path(__file__).resolve().parents[1]


def test_a_real_stop_is_timed_checked_and_a_missed_limit_fails(tmp_path):
    out = tmp_path / "stops.json"
    proc = subprocess.run([sys.executable, "tests/stop_times.py", "--tries", "1", "--commands", "robot-serve",
                           "--limit", "0.000001", "--load", "tests/test_flaky_runs.py", "--json", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1, proc.stdout + proc.stderr  # no stop takes a microsecond
    data = json.loads(out.read_text())
    assert [(s["command"], s["signal"], s["tries"], s["failures"]) for s in data["summary"]] == [
        ("robot serve", "SIGINT", 1, 1), ("robot serve", "SIGTERM", 1, 1)]
    for row in data["tries"]:
        assert row["code"] == 0 and 0 < row["exit_s"] <= row["gone_s"] < 30  # a service asked to stop exits 0
        assert len(row["ports"]) == 2  # commands and state stream, both found listening, both bindable again
        assert len(row["problems"]) == 1 and "limit" in row["problems"][0]  # only the limit failed
    assert data["load"]["command"].endswith("tests/test_flaky_runs.py") and data["load"]["loadavg_1min_max"] >= 0
    assert "robot serve      SIGTERM     1" in proc.stdout and "load: " in proc.stdout


def test_summary_and_table():
    rows = [{"command": "play", "signal": "SIGINT", "exit_s": e, "gone_s": g, "problems": p}
            for e, g, p in [(0.5, 0.6, []), (1.5, 1.5, []), (2.5, None, ["slow"])]]
    (s,) = stop_times.summarise(rows)
    assert s == {"command": "play", "signal": "SIGINT", "tries": 3, "exit_p50_s": 1.5, "exit_p99_s": 2.48, "exit_p100_s": 2.5,
                 "gone_p100_s": None, "failures": 1}  # a try whose children outlived it: no gone p100
    assert stop_times.table([s]).splitlines()[1].split() == ["play", "SIGINT", "3", "1.50", "2.48", "2.50", "-", "1"]


def test_descendants_and_ports_of_a_real_child():
    port = stop_times.free_port()
    code = f"import socket, time; s = socket.socket(); s.bind(('127.0.0.1', {port})); s.listen(); time.sleep(60)"
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        t_end = time.monotonic() + 30
        while port not in stop_times.listening_ports([proc.pid]) and time.monotonic() < t_end:
            time.sleep(0.05)
        assert stop_times.listening_ports([proc.pid]) == [port]
        assert not stop_times.bindable(port)
        assert any(p == proc.pid for p in stop_times.descendants(os.getpid()))
    finally:
        proc.kill()
        proc.wait()
    assert not stop_times.alive(proc.pid) and stop_times.bindable(port)


@pytest.mark.parametrize("argv, says", [
    (["--commands", "bogus"], "unknown command(s) ['bogus']"),
    (["--tries", "0"], "--tries and --slow-tries must be at least 1"),
    (["--parallel", "0"], "--parallel must be at least 1"),
    (["--limit", "-1"], "--limit must be positive"),
    (["--limit", "nan"], "--limit must be positive"),
    (["--signals", "SIGKILL"], "invalid choice: 'SIGKILL'"),
])
def test_bad_arguments_are_one_line_and_exit_2(argv, says, capsys):
    with pytest.raises(SystemExit) as exc:
        stop_times.parse_args(argv)
    assert exc.value.code == 2 and says in capsys.readouterr().err


def test_report_merges_the_tries_of_runs_made_side_by_side(tmp_path, capsys):
    rows = [{"command": "track", "signal": "SIGTERM", "exit_s": e, "gone_s": e, "problems": p} for e, p in
            [(0.2, []), (0.4, []), (2.4, ["exit 2.40 s after SIGTERM (limit 2 s)"])]]
    (tmp_path / "a.json").write_text(json.dumps({"tries": rows[:2]}))
    (tmp_path / "b.json").write_text(json.dumps({"tries": rows[2:]}))
    assert stop_times.main(["--report", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 1  # one failure
    assert capsys.readouterr().out.splitlines()[1].split() == ["track", "SIGTERM", "3", "0.40", "2.36", "2.40", "2.40", "1"]
    assert stop_times.main(["--report", str(tmp_path / "a.json"), str(tmp_path / "b.json"), "--json", str(tmp_path / "m.json")]) == 1
    merged = json.loads((tmp_path / "m.json").read_text())
    assert len(merged["tries"]) == 3 and merged["summary"][0]["exit_p100_s"] == 2.4 and len(merged["merged_from"]) == 2
    capsys.readouterr()
    (tmp_path / "c.json").write_text("{")
    assert stop_times.main(["--report", str(tmp_path / "c.json")]) == 2
    assert "--report" in capsys.readouterr().err
