"""Run ``make test`` N times in a row and report every test that failed at least once (``make flaky``).

    python tests/flaky_runs.py --runs 5                       # what `make flaky` does
    python tests/flaky_runs.py --runs 2 --tests tests/harness/common/test_progress.py   # a subset
    python tests/flaky_runs.py --runs 5 --cold                # `make flaky COLD=1`: every cache emptied before each run

Each run is ``make -i test JUNIT=DIR/run-K TESTS=...``: both of ``make test``'s pytest invocations (the
parallel suite, then the ``realtime`` tests alone) write a JUnit XML report, and ``-i`` lets the second run
even when the first had a failure; ``--cold`` runs ``make clean-cache`` before each run, so that every run
starts as a fresh clone's first ``make test`` does, with no compiled kernel and no disk cache. The reports are read back: a test that failed or errored in any run is
listed with the runs it failed in and its first failure message; a run whose reports are missing (pytest
crashed, the setup failed) counts as failed. The slowest tests (median time over the runs) are listed too.
Exit code: 0 when every run passed every test, 1 otherwise, 2 for bad arguments. Not a pytest test module
(its name does not start with ``test_``).
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REPORTS = ("parallel.xml", "realtime.xml")  #: the JUnit files of `make test`'s two pytest invocations


def read_report(path: Path) -> list[tuple[str, str, float, str]]:
    """(test id, outcome in passed/failed/error/skipped, seconds, message) of each test case in a JUnit XML."""
    rows = []
    for case in ET.parse(path).getroot().iter("testcase"):
        name = f"{case.get('classname', '')}::{case.get('name', '')}"
        outcome, message = "passed", ""
        for tag in ("failure", "error", "skipped"):
            node = case.find(tag)
            if node is not None:
                outcome = "failed" if tag == "failure" else tag
                message = (node.get("message") or "").strip().splitlines()[0][:200] if node.get("message") else ""
                break
        rows.append((name, outcome, float(case.get("time") or 0.0), message))
    return rows


def summarise(run_dirs: list[Path]) -> dict:
    """{"failures": {test: [(run, message)]}, "missing": [(run, file)], "times": {test: [s]}} over the runs."""
    failures, times, missing = defaultdict(list), defaultdict(list), []
    for k, run_dir in enumerate(run_dirs, 1):
        for name in REPORTS:
            path = run_dir / name
            if not path.is_file():
                missing.append((k, name))
                continue
            try:
                rows = read_report(path)
            except ET.ParseError as exc:
                missing.append((k, f"{name} (not valid XML: {exc})"))
                continue
            for test, outcome, seconds, message in rows:
                times[test].append(seconds)
                if outcome in ("failed", "error"):
                    failures[test].append((k, f"{outcome}: {message}"))
    return {"failures": dict(failures), "missing": missing, "times": dict(times)}


def report(summary: dict, runs: int, slowest: int = 20) -> str:
    lines = []
    if summary["failures"]:
        lines.append(f"{len(summary['failures'])} test(s) failed at least once in {runs} run(s):")
        for test, fails in sorted(summary["failures"].items(), key=lambda kv: (-len(kv[1]), kv[0])):
            lines.append(f"  {len(fails)}/{runs}  {test}")
            lines.append(f"        run {fails[0][0]}: {fails[0][1]}")
    for k, name in summary["missing"]:
        lines.append(f"run {k}: no report {name} (pytest did not finish)")
    if not summary["failures"] and not summary["missing"]:
        lines.append(f"no test failed in {runs} run(s)")
    ranked = sorted(summary["times"].items(), key=lambda kv: -statistics.median(kv[1]))[:slowest]
    if ranked:
        lines.append(f"slowest {len(ranked)} tests (median seconds over the runs):")
        lines += [f"  {statistics.median(ts):7.1f}  {test}" for test, ts in ranked]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="make flaky", description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="how many times to run `make test` (default 5)")
    parser.add_argument("--tests", default="", help="pytest arguments narrowing the suite (default: all of it)")
    parser.add_argument("--out", type=Path, default=ROOT / ".flaky", help="folder of the JUnit reports (default .flaky)")
    parser.add_argument("--make", default="make", help="the make program (default make)")
    parser.add_argument("--cold", action="store_true", help="empty numba's kernel cache and the tests' disk cache (make clean-cache) before each run")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs must be >= 1, got {args.runs}")
    run_dirs = []
    for k in range(1, args.runs + 1):
        run_dir = args.out / f"run-{k}"
        run_dir.mkdir(parents=True, exist_ok=True)
        for name in REPORTS:
            (run_dir / name).unlink(missing_ok=True)
        if args.cold:
            print(f"flaky: run {k}/{args.runs}: {args.make} clean-cache (cold caches)", flush=True)
            if subprocess.call([args.make, "clean-cache"], cwd=ROOT) != 0:
                print(f"flaky: {args.make} clean-cache failed", file=sys.stderr)
                return 1
        cmd = [args.make, "-i", "test", f"JUNIT={run_dir}", f"TESTS={args.tests}"]
        print(f"flaky: run {k}/{args.runs}: {shlex.join(cmd)}", flush=True)
        t0 = time.monotonic()
        code = subprocess.call(cmd, cwd=ROOT)
        print(f"flaky: run {k}/{args.runs} ended with code {code} after {time.monotonic() - t0:.0f} s", flush=True)
        run_dirs.append(run_dir)
    summary = summarise(run_dirs)
    print(report(summary, args.runs))
    return 1 if summary["failures"] or summary["missing"] else 0


if __name__ == "__main__":
    sys.exit(main())
