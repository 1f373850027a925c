"""Shared fixtures: paths to the real recordings in ../shared/data/real and the project's data/."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
REAL = ROOT.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Folder of the real recordings (ewand rig, launcher flights); skips if absent."""
    if not REAL.is_dir():
        pytest.skip(f"real recordings not found at {REAL}")
    return REAL


@pytest.fixture(scope="session")
def ewand_dir(real_data) -> Path:
    return real_data / "ewand"


@pytest.fixture(scope="session")
def ewand_rig(ewand_dir):
    from tracker import Rig

    return Rig.from_opencv_files(sorted(ewand_dir.glob("frame_*.yaml")), length_unit_m=0.001)
