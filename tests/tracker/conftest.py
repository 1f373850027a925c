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


@pytest.fixture(scope="module")
def bright_spot_onnx():
    """A learned stage's heatmap network whose heat is the brightness of each 4x4 cell (a bright spot peaks where it
    is: white high, pink lower, black 0.27), offsets 0, diameter e^2 (exported from torch: rt2[train])."""
    torch = pytest.importorskip("torch", reason="the test network is exported from torch (rt2[train])")
    from harness.experiments.detector.learned_train import build_net, export_onnx

    net = build_net(torch)
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net.a.weight[0] = 1.0 / 16  # channel 0 of the stride-4 features: the cell's mean of (x/255 - 0.5) over RGB
        net.head.weight[0, 0, 0, 0] = 10.0  # heat = 10 * relu(mean)
        net.head.bias[:] = torch.tensor([-1.0, 0.0, 0.0, 2.0])
    return export_onnx(torch, net)
