"""``import tracker`` for a type stays cheap: the package's names load on first use (tracker/__init__.py),
so a type does not bring in the pipeline, the detector, RTBlob, OpenCV or numba."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import tracker

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("numba", "cv2", "scipy", "tracker.pipeline", "tracker.detection", "tracker.rtblob", "tracker.camera")


def loaded_after(statement: str) -> set[str]:
    code = f"import sys\n{statement}\nprint(' '.join(sorted(sys.modules)))"
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    return set(run.stdout.split())


@pytest.mark.parametrize("statement, allowed", [
    ("import tracker", ()),
    ("from tracker import FrameSet, BallObservation, Status", ()),
    ("from tracker import Camera", ("numba", "scipy", "tracker.camera")),  # the lens model's numba twin (numba loads part of scipy)
])
def test_a_type_does_not_import_the_pipeline(statement, allowed):
    heavy = {m for m in loaded_after(statement) if m.split(".")[0] in HEAVY or m in HEAVY}
    assert {m for m in heavy if m not in allowed and m.split(".")[0] not in allowed} == set(), statement


def test_every_name_of_the_package_resolves_and_unknown_names_fail():
    for name in tracker.__all__:
        assert getattr(tracker, name).__name__ == name
    assert set(tracker.__all__) <= set(dir(tracker))
    with pytest.raises(AttributeError, match="module 'tracker' has no attribute 'Trackr'"):
        tracker.Trackr
