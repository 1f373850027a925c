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


@pytest.fixture(scope="session")
def synthetic_ball_coco(tmp_path_factory):
    """Factory ``(n_images, seed) -> folder`` of a small COCO ball set (96x128 synthetic scenes, every
    5th image without a ball), written once per arguments; see ``tracker.detection.synthetic``."""
    import cv2
    import numpy as np

    from harness.experiments.detector.coco import LabelledImage, write_coco
    from tracker.detection.synthetic import synthetic_scene

    made = {}

    def make(n_images: int = 30, seed: int = 0) -> Path:
        if (n_images, seed) in made:
            return made[n_images, seed]
        out = tmp_path_factory.mktemp(f"balls_{n_images}_{seed}")
        rng = np.random.default_rng(seed)
        labelled = []
        for i in range(n_images):
            image, centers, diams = synthetic_scene(rng, size_hw=(96, 128), n_balls=0 if i % 5 == 4 else 1, diameter_px=(6, 14))
            path = out / f"f{i:06d}_cam0.png"
            cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            boxes = np.array([[c[0] + 0.5 - d / 2, c[1] + 0.5 - d / 2, d, d] for c, d in zip(centers, diams)]).reshape(-1, 4)
            labelled.append(LabelledImage(path, 128, 96, boxes, centers))
        write_coco(out, labelled)
        made[n_images, seed] = out
        return out

    return make


@pytest.fixture(scope="session")
def accuracy_session(tmp_path_factory):
    """A tiny accuracy run (48 frame sets at 50 Hz, two 24-frame segments, faults injected, every image
    logged as PNG, flushed every 0.05 s) with the hand-made colour model; returns ``(result, out_dir)``.
    Shared by tests/harness/experiments/test_accuracy_run.py and tests/harness/experiments/test_reevaluate.py (harness.experiments.accuracy)."""
    from harness.experiments.accuracy import AccuracyConfig, run_accuracy
    from tracker.detection.synthetic import hand_made_model

    out = tmp_path_factory.mktemp("accuracy_session")
    model = hand_made_model().save(out / "model.npz")
    config = AccuracyConfig(seed=3, n_frames=48, rate_hz=50.0, segment_frames=24, register_fraction=0.5,
                            inject_faults=True, model=str(model))
    result = run_accuracy(config, out, workers=1, log_images="all", log_flush_s=0.05, progress=False)
    return result, out
