"""docs/architecture.md stays true: every file and module it names exists, and its command counts are the
``COMMANDS`` table's (a file renamed or removed without its line in the docs fails here)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from tests.test_architecture import OURS, ROOT, command_table, modules, top_level_names

DOC = ROOT / "docs" / "architecture.md"
FILE = re.compile(r"`([\w./*-]+\.(?:py|md|yaml|urdf|npz|msg|srv|toml))`")
MODULE = re.compile(r"\b((?:" + "|".join(OURS) + r")(?:\.\w+)+)")
SKIP_DIRS = {".git", ".venv", "__pycache__", "node_modules"}


def repo_files() -> list[str]:
    return [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
            if p.is_file() and not SKIP_DIRS & set(p.relative_to(ROOT).parts)]


def missing_files(text: str, files: list[str]) -> list[str]:
    """Backticked file names in ``text`` that no file of the repository is (or ends with, after a folder)."""
    bad = []
    for name in sorted(set(FILE.findall(text))):
        rx = re.compile(r"(^|/)" + re.escape(name).replace(r"\*", r"[^/]*") + "$")
        if not any(rx.search(f) for f in files):
            bad.append(name)
    return bad


def missing_modules(text: str) -> list[str]:
    """Dotted names of ours in ``text`` that are neither a module nor a name defined at the top of one."""
    mods, bad = modules(), []
    for name in sorted(set(MODULE.findall(text))):
        if name in mods:
            continue
        module, _, attr = name.rpartition(".")
        if module not in mods or attr not in top_level_names(mods[module]) | {"py"}:
            bad.append(name)
    return bad


def test_every_file_and_module_architecture_md_names_exists():
    text = DOC.read_text()
    assert not missing_files(text, repo_files()), f"docs/architecture.md names files that do not exist: {missing_files(text, repo_files())}"
    assert not missing_modules(text), f"docs/architecture.md names modules that do not exist: {missing_modules(text)}"


def test_the_checks_catch_a_stale_line():
    files = ["harness/sim/study_rigs.py", "policies/_hitting_motion.py", "harness/cli/calib_wand.py"]
    text = "`sim/study_rigs.py`, `policies/_promp_checks.py`, `_hitting_*.py`, `cli/calib_*.py`, `rigs.py`"
    assert missing_files(text, files) == ["policies/_promp_checks.py", "rigs.py"]
    assert missing_modules("harness.live.reevaluate_track, harness.experiments.reevaluate_live, tracker.rtblob.RTBlobTracker") == \
        ["harness.experiments.reevaluate_live"]


def test_the_command_counts_are_the_tables():
    text = " ".join(DOC.read_text().split())
    study = re.search(r"The (\d+) commands whose module is a study \((\d+) in `experiments/studies/`", text)
    other = re.search(r"The other (\d+) commands have their module in `cli/`", text)
    assert study and other, "docs/architecture.md lost its command-count sentences"
    table = command_table()
    in_cli = sum(m.startswith("harness.cli.") for m in table.values())
    in_studies = sum(m.startswith("harness.experiments.studies.") for m in table.values())
    assert (int(study[1]), int(study[2]), int(other[1])) == (len(table) - in_cli, in_studies, in_cli)
