"""The full-frame search's reusable buffers: the same bytes as fresh arrays, per thread, picklable."""

from __future__ import annotations

import pickle
import threading

import numpy as np
import pytest

from tracker import BallDetector, BallSegmentationModel
from tracker.detection.blobs import find_blobs
from tracker.detection.model import LogitWorkspace
from tracker.detection.synthetic import ORANGE_RGB, hand_made_model, synthetic_scene


def _model(input_transform):
    rng = np.random.default_rng(3)
    return BallSegmentationModel(kernel=rng.normal(size=(5, 5, 3)), bias=float(rng.normal()), input_transform=input_transform,
                                 input_scale=rng.uniform(0.002, 0.01, 3), input_offset=rng.normal(size=3), t_high=0.6, t_low=0.3)


@pytest.mark.parametrize("transform", ["linear", "log"])
def test_workspace_logits_are_the_same_bytes_as_fresh_arrays(transform):
    model = _model(transform)
    rng = np.random.default_rng(0)
    work = LogitWorkspace()
    for shape in [(48, 64, 3), (48, 64, 3), (31, 17, 3), (1, 1, 3), (48, 64, 3)]:  # reuse, then new sizes, then back
        image = rng.integers(0, 256, shape, dtype=np.uint8)
        want = model.logits_trusted(image)
        got = model.logits_trusted(image, work)
        assert got.dtype == np.float32 and got.shape == shape[:2]
        assert got.tobytes() == want.tobytes()


def test_workspace_is_reused_and_resized():
    work = LogitWorkspace()
    a = work.buffers((10, 20))
    assert work.buffers((10, 20))[1] is a[1]
    b = work.buffers((11, 20))
    assert b[1] is not a[1] and b[1].shape == (11, 20) and b[0].shape == (3, 5, 24) and b[0].dtype == b[1].dtype == np.float32


def test_find_blobs_with_given_queues_equals_fresh_queues():
    rng = np.random.default_rng(1)
    image, _, _ = synthetic_scene(rng, n_balls=3, diameter_px=(6, 20))
    model = hand_made_model(ORANGE_RGB)
    logits = model.logits(image)
    kw = dict(max_blobs=4, max_seeds=16)
    want = find_blobs(logits, 0.0, -1.0, **kw)
    small = (np.empty(5, np.int64), np.empty(5, np.int64))  # too small: ignored, fresh ones are made
    for queues in [(np.empty(logits.size, np.int64), np.empty(logits.size, np.int64)), small]:
        got = find_blobs(logits, 0.0, -1.0, queues=queues, **kw)
        for f in ("centers_px", "peak_logits", "boxes", "areas_px"):
            assert getattr(got, f).tobytes() == getattr(want, f).tobytes()


def _same(a, b):
    return all(getattr(a, f).tobytes() == getattr(b, f).tobytes() for f in ("uv_px", "scores", "boxes_xywh", "areas_px"))


def test_one_detector_on_two_threads_gives_the_sequential_answers():
    rng = np.random.default_rng(2)
    images = [synthetic_scene(rng, n_balls=2, diameter_px=(8, 16))[0] for _ in range(6)]
    det = BallDetector(hand_made_model(ORANGE_RGB))
    want = [det.detect(im) for im in images]
    assert sum(len(d) for d in want) > 0
    got = [[None] * len(images) for _ in range(2)]
    barrier = threading.Barrier(2)

    def run(j):
        barrier.wait()
        for _ in range(5):
            for i, im in enumerate(images):
                got[j][i] = det.detect(im)
                assert _same(got[j][i], want[i])

    threads = [threading.Thread(target=run, args=(j,)) for j in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(_same(g, w) for row in got for g, w in zip(row, want))


def test_detector_pickles_without_its_buffers():
    det = BallDetector(hand_made_model(ORANGE_RGB))
    image = synthetic_scene(np.random.default_rng(4), diameter_px=(12, 12))[0]
    want = det.detect(image)
    det2 = pickle.loads(pickle.dumps(det))
    assert _same(det2.detect(image), want)
