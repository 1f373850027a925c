"""Fixtures most tracker tests share: the lab rig and the hand-made detector model (a test module
that needs another rig or model defines its own fixture of the same name, which takes precedence)."""

import pytest

from tests.tracker._tracker_scenes import shipped_rig
from tracker.detection.synthetic import hand_made_model


@pytest.fixture(scope="module")
def rig():
    """The four-camera lab rig (data/rigs/lab4_vga.yaml)."""
    return shipped_rig("lab4_vga")


@pytest.fixture(scope="module")
def model():
    """The hand-made 5x5 model, whose blobs cover the whole disk (tracker.detection.synthetic)."""
    return hand_made_model()
