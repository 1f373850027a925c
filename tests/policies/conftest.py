"""Fixtures of the policies tests: the WAM's kinematics, the shipped hitting primitive, the fitted ball model."""

from __future__ import annotations

from pathlib import Path

import pytest

from policies import BallParams
from policies.promp import ProMP

SHIPPED = Path(__file__).resolve().parents[2] / "data" / "promp" / "wam_hitting.npz"


@pytest.fixture(scope="module")
def kin():
    from robot_models import WamKinematics

    return WamKinematics.default()


@pytest.fixture(scope="module")
def promp(kin):
    return ProMP.load(SHIPPED, robot_id="wam7", joint_names=kin.joint_names)


@pytest.fixture(scope="module")
def params():
    return BallParams.load()
