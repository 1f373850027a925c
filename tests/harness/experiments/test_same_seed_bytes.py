"""Same seed, same bytes: each study's output files, written by the CLI in a fresh process with a cold numba
cache (every kernel compiled there, none loaded), an empty disk cache (the simulated lab ray-cast there, not read
back: harness/common/disk_cache.py) and one worker, are byte-identical to those written in this
(warm) process with two worker processes that load the cached kernels. One comparison covers four axes at
once: 1 vs 2 workers, cold vs warm numba cache, a fresh vs a warm interpreter, a separate CLI process vs the
in-process call. Local vs Ray: tests/harness/common/test_executor.py.

Each test starts its own cold process (numba compiles that study's kernels there). accuracy, dataset and framesets render
images and take minutes on a loaded 2-core machine: they are `slow` (`make test-all`); their worker-count
tests in test_accuracy_run.py and test_sim_dataset.py stay in `make test`. play is `slow` too (27 s alone, 75-97 s
in the parallel suite: compiling every policy kernel cold): its worker-count test is
test_play.py::test_session_json_deterministic_and_independent_of_workers, and table1 below keeps the cold-cache,
fresh-process and CLI axes in `make test`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from harness.cli import main

ROOT = Path(__file__).resolve().parents[3]

#: study -> (rt2 arguments, files under its output folder to compare); "{out}" is the study's output folder
STUDIES = {
    "table1": (["sim", "table1", "--trials", "200", "--cameras", "4", "--outlier-rates", "5", "--seed", "1",
                "--no-progress", "--json", "{out}/table1.json"], ["table1.json"]),
    "play": (["play", "--balls", "3", "--seed", "4", "--out", "{out}", "--json", "{out}/play.json", "--quiet",
              "--no-figure", "--no-log"], ["play.json"]),
    "framesets": (["eval", "framesets", "--frames", "3", "--seed", "0", "--trackers", "rt2", "rt2-paper",
                   "--json", "{out}/framesets.json"], ["framesets.json"]),
    "accuracy": (["accuracy", "--frames", "40", "--rate-hz", "50", "--seed", "3", "--no-log", "--out", "{out}"],
                 ["accuracy.json"]),
    "dataset": (["sim", "dataset", "--frames", "4", "--seed", "1", "--out", "{out}"], ["annotations.json"]),
}

def _argv(study: str, out: Path) -> list[str]:
    return [a.replace("{out}", str(out)) for a in STUDIES[study][0]]


def _cold_run(study: str, base: Path) -> Path:
    """The study's outputs from a fresh process with an empty numba cache, an empty disk cache and --workers 1."""
    out = base / "cold"
    argv = [*_argv(study, out), "--workers", "1"]
    code = f"import sys; from harness.cli import main; sys.exit(main({argv!r}))"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(base / "numba-cache"), RT2_CACHE_DIR=str(base / "disk-cache"))
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert any((base / "numba-cache").rglob("*.nbi")), "the cold run should have compiled into its own cache"
    return out


def _differences(a: Path, b: Path) -> list[str]:
    return [f.name for f in sorted(a.rglob("*")) if f.is_file() and f.read_bytes() != (b / f.relative_to(a)).read_bytes()]


SLOW = {"accuracy", "dataset", "framesets", "play"}  # render images / compile the policies cold: minutes on a loaded 2-core machine


@pytest.mark.parametrize("study", [pytest.param(s, marks=[pytest.mark.slow] if s in SLOW else []) for s in STUDIES])
def test_same_seed_same_bytes_cold_cache_one_worker_vs_warm_two_workers(study, tmp_path, capsys):
    cold = _cold_run(study, tmp_path)
    out = tmp_path / "warm"
    assert main([*_argv(study, out), "--workers", "2"]) == 0
    for name in STUDIES[study][1]:
        warm, fresh = (out / name).read_bytes(), (cold / name).read_bytes()
        assert warm == fresh, (f"{study}: {name} differs between a warm run with 2 workers and a fresh process "
                               f"with a cold numba cache and 1 worker:\n{warm[:600]!r}\n{fresh[:600]!r}")
    if study == "dataset":  # every image too
        assert sorted(p.name for p in out.rglob("*.png")) == sorted(p.name for p in cold.rglob("*.png"))
        assert _differences(out, cold) == []
    if study == "accuracy":  # the figures of summary.json (its timing differs by nature)
        figures = [json.loads((d / "summary.json").read_text())["figures"] for d in (out, cold)]
        assert figures[0] == figures[1]
