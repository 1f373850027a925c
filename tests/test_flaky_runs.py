"""`make flaky`'s report: tests that failed in any run, runs without a report, the slowest tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import flaky_runs  # noqa: E402  (tests/flaky_runs.py, a script beside the tests)

PASSED = '<testcase classname="tests.test_a" name="test_ok" time="{t}"/>'
FAILED = ('<testcase classname="tests.test_a" name="test_sometimes" time="2.5">'
          '<failure message="assert 26.0 &lt; 2.0&#10;more">trace</failure></testcase>')
ERROR = '<testcase classname="tests.test_b" name="test_setup" time="0.1"><error message="fixture broke"/></testcase>'
SKIPPED = '<testcase classname="tests.test_b" name="test_ray" time="0.0"><skipped message="no ray"/></testcase>'


def junit(path: Path, *cases: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'<?xml version="1.0"?><testsuites><testsuite name="pytest">{"".join(cases)}</testsuite></testsuites>')


def test_a_test_failing_in_one_run_of_three_is_listed_with_its_message(tmp_path):
    runs = [tmp_path / f"run-{k}" for k in (1, 2, 3)]
    junit(runs[0] / "parallel.xml", PASSED.format(t=1.0), FAILED, SKIPPED)
    junit(runs[1] / "parallel.xml", PASSED.format(t=3.0), SKIPPED,
          '<testcase classname="tests.test_a" name="test_sometimes" time="2.0"/>')
    junit(runs[2] / "parallel.xml", PASSED.format(t=2.0), ERROR)
    for r in runs:
        junit(r / "realtime.xml")
    summary = flaky_runs.summarise(runs)
    assert summary["failures"] == {"tests.test_a::test_sometimes": [(1, "failed: assert 26.0 < 2.0")],
                                   "tests.test_b::test_setup": [(3, "error: fixture broke")]}
    assert summary["missing"] == []
    text = flaky_runs.report(summary, 3)
    assert "2 test(s) failed at least once in 3 run(s)" in text
    assert "1/3  tests.test_a::test_sometimes" in text and "run 1: failed: assert 26.0 < 2.0" in text
    slowest = text.split("slowest 4 tests (median seconds over the runs):\n")[1].splitlines()
    assert [ln.split() for ln in slowest] == [["2.2", "tests.test_a::test_sometimes"], ["2.0", "tests.test_a::test_ok"],
                                              ["0.1", "tests.test_b::test_setup"], ["0.0", "tests.test_b::test_ray"]]


def test_a_run_without_its_report_counts_as_failed(tmp_path):
    run = tmp_path / "run-1"
    junit(run / "parallel.xml", PASSED.format(t=1.0))
    (run / "realtime.xml").write_text("<testsuites><testsuite")  # cut short
    summary = flaky_runs.summarise([run, tmp_path / "run-2"])
    assert [k for k, _ in summary["missing"]] == [1, 2, 2]
    assert "run 2: no report parallel.xml (pytest did not finish)" in flaky_runs.report(summary, 2)


def test_all_passing_runs_say_so(tmp_path):
    run = tmp_path / "run-1"
    junit(run / "parallel.xml", PASSED.format(t=1.0))
    junit(run / "realtime.xml")
    assert flaky_runs.report(flaky_runs.summarise([run]), 1).startswith("no test failed in 1 run(s)")


def test_bad_runs_argument_is_exit_2():
    proc = subprocess.run([sys.executable, str(Path(flaky_runs.__file__)), "--runs", "0"], capture_output=True, text=True)
    assert proc.returncode == 2 and "--runs must be >= 1, got 0" in proc.stderr


def test_cold_runs_empty_the_kernel_cache_before_each_run(tmp_path):
    """--cold: `make clean-cache` before every `make test` (a fake make records what it was asked)."""
    log = tmp_path / "make.log"
    fake = tmp_path / "make"
    fake.write_text(f"#!/bin/sh\necho \"$*\" >> {log}\n")
    fake.chmod(0o755)
    proc = subprocess.run([sys.executable, str(Path(flaky_runs.__file__)), "--runs", "2", "--cold", "--make", str(fake),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True)
    calls = [line.split()[0] if line.split()[0] == "clean-cache" else line.split()[1] for line in log.read_text().splitlines()]
    assert calls == ["clean-cache", "test", "clean-cache", "test"]
    assert proc.returncode == 1 and "no report parallel.xml" in proc.stdout  # the fake make wrote no report
