"""A warning during a command prints one line naming the command, not Python's two (the second is the source line
the warning came from: ``return int(importlib.import_module(...).run(args) or 0)`` said nothing to a user of
``RT2_CACHE_MAX_MB=abc rt2 cache info``). Run as a user runs it: a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from harness.cli import _warning_line, main

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("value", ["abc", "-5", "0", "nan"])
def test_a_bad_cache_limit_warns_in_one_line_naming_the_command(tmp_path, value):
    env = dict(os.environ, RT2_CACHE_DIR=str(tmp_path / "cache"), RT2_CACHE_MAX_MB=value)
    done = subprocess.run([sys.executable, "-m", "harness.cli", "cache", "info"], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [
        f"rt2 cache info: warning: RT2_CACHE_MAX_MB={value!r} is not a positive number of megabytes; using 2048"]
    assert "at most 2048.0 MB" in done.stdout


def test_a_librarys_other_categories_keep_their_name_and_origin():
    line = _warning_line("sim wam")
    lib = "/usr/lib/python3/site-packages/numpy/core/x.py"
    assert line("overflow", RuntimeWarning, lib, 12) == f"rt2 sim wam: RuntimeWarning: overflow ({lib}:12)\n"
    assert line("slow", UserWarning, lib, 12) == "rt2 sim wam: warning: slow\n"
    # rt2's own code speaks to the user whatever the category (a damaged log's chunk is a RuntimeWarning)
    own = str(ROOT / "harness" / "logs" / "reader.py")
    assert line("damaged chunk at offset 9 skipped", RuntimeWarning, own, 3) == "rt2 sim wam: warning: damaged chunk at offset 9 skipped\n"


def test_the_format_is_the_commands_only_while_it_runs(tmp_path, monkeypatch, capsys):
    before = warnings.formatwarning
    monkeypatch.setenv("RT2_CACHE_DIR", str(tmp_path))
    assert main(["cache", "info"]) == 0
    assert warnings.formatwarning is before
