"""The house stays a tree: checks/ imports nothing of ours, tracker/ and robot_models/ only checks/,
policies/ never imports harness/, and inference code in tracker/ never imports torch (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"checks", "tracker", "robot_models", "policies", "harness"}
ALLOWED = {
    "checks": {"checks"},
    "tracker": {"tracker", "checks"},
    "robot_models": {"robot_models", "checks"},
    "policies": {"policies", "robot_models", "tracker", "checks"},
    "harness": OURS,
}


def imported_top_levels(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_import_direction(package):
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        wrong = (imported_top_levels(path) & OURS) - ALLOWED[package]
        if wrong:
            bad.append(f"{path.relative_to(ROOT)} imports {sorted(wrong)}")
    assert not bad, "\n".join(bad)


def test_inference_never_imports_torch():
    bad = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "tracker").rglob("*.py")) if "torch" in imported_top_levels(p)]
    assert not bad, f"tracker/ must not import torch: {bad}"
