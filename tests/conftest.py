"""Shared fixtures: paths to the real recordings in ../shared/data/real and the project's data/."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# One BLAS / OpenMP thread in each xdist worker of `make test` (and in the processes it starts: the variables are
# inherited). torch (rt2 train's L-BFGS fit) and OpenBLAS start a thread per core and spin while they wait for each
# other: with the other worker busy on the second core they got 2-12 times slower (test_selection.py's multi-camera
# test took 101 s in the parallel suite, 9 s alone, 16 s beside a busy core with one thread). A run without xdist
# keeps the defaults; sweeps give their tasks one BLAS thread anyway (harness/common/executor.py).
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_name, "1")
    if "numpy" in sys.modules or "torch" in sys.modules:  # loaded before this file: limit them now as well
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
        if "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(1)

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


def run_once_per_run(tmp_path_factory, name: str, build):
    """``build(folder)`` once per test run, whatever the number of xdist workers: the first worker to ask builds
    into a folder the workers share (under an exclusive lock); the others wait for it and read its pickled result.
    Returns ``(result, folder)``. For session fixtures whose build is an experiment worth seconds."""
    import fcntl
    import pickle
    import shutil

    base = tmp_path_factory.getbasetemp()
    if base.name.startswith("popen-gw"):  # an xdist worker: its parent folder is this run's, shared by the workers
        base = base.parent
    folder, done = base / name, base / f"{name}.pickle"
    with open(base / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.is_file():
            shutil.rmtree(folder, ignore_errors=True)  # what a failed build of another worker left
            folder.mkdir()
            result = build(folder)
            done.write_bytes(pickle.dumps(result))
            return result, folder
    return pickle.loads(done.read_bytes()), folder


@pytest.fixture(scope="session")
def accuracy_session(tmp_path_factory):
    """A tiny accuracy run (48 frame sets at 50 Hz, two 24-frame segments, faults injected, every image
    logged as PNG, flushed every 0.05 s) with the hand-made colour model; returns ``(result, out_dir)``.
    Shared by tests/harness/experiments/test_accuracy_run.py and tests/harness/experiments/test_reevaluate.py (harness.experiments.accuracy),
    tests/harness/calib/test_calib_robot.py and tests/harness/logs/test_logs_damage.py; built once per run (not once per
    xdist worker: it took 25 s warm, 70 s with a cold numba cache); its users only read ``out_dir``."""

    def build(out):
        from harness.experiments.accuracy import AccuracyConfig, run_accuracy
        from tracker.detection.synthetic import hand_made_model

        model = hand_made_model().save(out / "model.npz")
        config = AccuracyConfig(seed=3, n_frames=48, rate_hz=50.0, segment_frames=24, register_fraction=0.5,
                                inject_faults=True, model=str(model))
        return run_accuracy(config, out, workers=1, log_images="all", log_flush_s=0.05, progress=False)

    return run_once_per_run(tmp_path_factory, "accuracy_session", build)
