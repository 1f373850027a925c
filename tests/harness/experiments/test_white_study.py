"""Drawn white balls (exact centres, boxes, seeded) and the white-ball study's numpy CNN against torch; the
study itself on the real rally frames (skipped, with the reason, where the shared data is absent)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.experiments.detector.white_balls import WhiteBall, draw_white_ball, random_ball
from tests.conftest import REAL

RALLY = REAL / "phone_rally"


def _ball(**kw) -> WhiteBall:
    base = dict(center_px=(40.3, 30.7), diameter_px=16.0, blur_px=(0.0, 0.0), tint=(1.0, 0.95, 0.85), brightness=1.0,
                light=(0.0, 0.0, 1.0), specular=0.0, defocus_px=0.5, noise_dn=0.0)
    return WhiteBall(**{**base, **kw})


def test_drawn_ball_is_centred_where_asked():
    bg = np.full((64, 96, 3), 40, np.uint8)
    for blur in ((0.0, 0.0), (14.0, -6.0)):
        out, box = draw_white_ball(bg, _ball(blur_px=blur), np.random.default_rng(0))
        a = out.astype(float).sum(2) - bg.astype(float).sum(2)
        vv, uu = np.mgrid[: a.shape[0], : a.shape[1]]
        centroid = np.array([(a * uu).sum(), (a * vv).sum()]) / a.sum()
        np.testing.assert_allclose(centroid, (40.3, 30.7), atol=0.15)  # rt2 pixel centres
        np.testing.assert_allclose(box[:2] + box[2:] / 2 - 0.5, (40.3, 30.7), atol=1e-9)  # COCO box around it
        np.testing.assert_allclose(box[2:], (16.0 + abs(blur[0]), 16.0 + abs(blur[1])), atol=1e-9)
        ys, xs = np.nonzero(a > 3)
        assert xs.min() >= box[0] - 3 and xs.max() <= box[0] + box[2] + 2
    assert (out[0, 0] == bg[0, 0]).all()  # nothing drawn away from the ball


def test_drawn_ball_is_cream_and_brighter_than_a_dark_background():
    bg = np.zeros((64, 64, 3), np.uint8)
    bg[::7] = 230  # white lines set the frame's white level
    out, _ = draw_white_ball(bg, _ball(center_px=(32.0, 32.0)), np.random.default_rng(0))
    r, g, b = out[30:35, 30:35].reshape(-1, 3).mean(0)
    assert r > 180 and r >= g >= b


def test_random_balls_are_seeded_and_in_the_rally_range():
    a = [random_ball(np.random.default_rng(5), (10, 10)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(1)
    balls = [random_ball(rng, (0, 0)) for _ in range(200)]
    assert all(18 <= b.diameter_px <= 34 and np.hypot(*b.blur_px) <= 1.4 * b.diameter_px for b in balls)
    bg = np.full((50, 50, 3), 90, np.uint8)
    one = draw_white_ball(bg, balls[0], np.random.default_rng(2))[0]
    np.testing.assert_array_equal(one, draw_white_ball(bg, balls[0], np.random.default_rng(2))[0])


def test_numpy_cnn_matches_torch():
    torch = pytest.importorskip("torch")
    from harness.experiments.detector.white_study import _params, _torch_cnn, cnn_forward

    torch.manual_seed(0)
    net = _torch_cnn(32).eval()
    x = np.random.default_rng(0).normal(0, 1, (5, 32, 32, 3)).astype(np.float32)
    with torch.no_grad():
        ref = net(torch.as_tensor(x.transpose(0, 3, 1, 2).copy())).numpy()
    np.testing.assert_allclose(cnn_forward(_params(net), x), ref, rtol=1e-4, atol=1e-5)


@pytest.mark.skipif(not (RALLY / "annotations.json").is_file(), reason=f"real rally frames not found at {RALLY}")
def test_white_study_is_seeded_on_real_frames():
    from harness.experiments.detector.white_study import run_white_study

    kw = dict(train_range="40:46", test_range="50:53", seed=3, synthetic_per_frame=1, synthetic_crops=40, epochs=1)
    a, b = run_white_study(RALLY, **kw), run_white_study(RALLY, **kw)
    pa, pb = a.pop("params"), b.pop("params")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert all(np.array_equal(pa[k], pb[k]) for k in pa)
    assert a["n_train"] == 6 and a["n_test"] == 3 and a["n_synthetic_frames"] == 6 and len(a["verifier"]) == 10


@pytest.mark.skipif(not (RALLY / "annotations.json").is_file(), reason=f"real rally frames not found at {RALLY}")
@pytest.mark.parametrize("argv, message", [
    (["--train-range", "0-58"], "--train-range must be START:STOP"),
    (["--test-range", "90:"], "--test-range 90:: selects no image of the 83 given"),
    (["--backgrounds", "/nonexistent.mp4"], "--backgrounds '/nonexistent.mp4': no such file or folder"),
])
def test_white_study_hostile_options(argv, message, capsys):
    from harness.experiments.detector.white_study import main as study

    assert study(["--data", str(RALLY), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_numpy_proposer_response_matches_the_torch_expansion():
    torch = pytest.importorskip("torch")
    from harness.experiments.detector.shape_study import _Proposer
    from harness.experiments.detector.white_study import _NumpyProposer

    rng = np.random.default_rng(0)
    feats = rng.normal(0, 1, (7, 9, 24)).astype(np.float32)
    ref, fast = _Proposer(4.0, 9), _NumpyProposer(4.0, 9)
    w = torch.as_tensor(rng.normal(0, 0.1, 24 + 300).astype(np.float32))  # linear terms, then the 300 products i <= j
    for p in (ref, fast):
        p.mu, p.sd = np.full(24, 0.1, np.float32), np.full(24, 1.3, np.float32)
        p.w, p.b = w, torch.tensor([0.2])
    np.testing.assert_allclose(fast.response(feats), ref.response(feats), rtol=1e-4, atol=1e-4)
