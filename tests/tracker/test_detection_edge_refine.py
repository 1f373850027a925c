"""tracker.detection.edge_refine: a candidate's centre and diameter from a circle fitted to its edge. Balls drawn
with a known centre (anti-aliased, on noise and texture, smeared): the fit finds them to a fraction of a pixel from a
centre a few pixels off and a diameter too wide; the compiled kernel agrees with the numpy reference; candidates it
cannot fit (no edge, NaN, outside the image, too small or too large) keep what they had; the detector uses it for a
learned stage whose filter does not see its ball (the white model) and not otherwise."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from tracker.detection.edge_refine import refine_edges, refine_edges_reference


def _ball_image(rng, size_hw=(120, 160), diameter=16.0, center=None, ball=235, background=70, noise=4.0, smear_px=0.0):
    """A bright disc (anti-aliased: drawn at 8x and averaged down) on a textured, noisy background; (image, centre)."""
    h, w = size_hw
    m = max(30.0, 1.5 * diameter)  # the whole ball and the rays around it inside the image
    c = np.array(center if center is not None else rng.uniform([m, m], [w - m, h - m]), float)
    s = 8
    big = np.zeros((h * s, w * s), np.float32)
    n = max(1, int(round(smear_px)) + 1)
    for t in np.linspace(-smear_px / 2, smear_px / 2, n):  # a smear along x: the disc at several times, averaged
        one = np.zeros_like(big)
        cv2.circle(one, (int(round(((c[0] + t) + 0.5) * s * 16)), int(round((c[1] + 0.5) * s * 16))), int(round(diameter / 2 * s * 16)),
                   1.0, -1, cv2.LINE_AA, shift=4)
        big += one / n
    cover = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    texture = cv2.GaussianBlur(rng.normal(0, 12, (h, w)).astype(np.float32), (0, 0), 3)
    grey = background + texture + cover * (ball - background - texture) + rng.normal(0, noise, (h, w))
    img = np.clip(np.repeat(grey[:, :, None], 3, axis=2) * [1.0, 0.97, 0.93], 0, 255).astype(np.uint8)
    return img, c


@pytest.mark.parametrize("diameter", [8.0, 14.0, 24.0, 40.0, 80.0])
def test_the_fit_finds_a_ball_from_a_centre_a_few_pixels_off(diameter):
    rng = np.random.default_rng(int(diameter))
    errors, ratios = [], []
    for _ in range(12):
        img, c = _ball_image(rng, size_hw=(max(120, int(4 * diameter)), max(160, int(5 * diameter))), diameter=diameter,
                             center=None)
        off = rng.uniform(-0.25, 0.25, 2) * diameter  # the network's centre, up to a quarter diameter off
        uv, d, ok = refine_edges(img, (c + off)[None, :], np.array([1.35 * diameter]))  # and its diameter too wide
        assert ok[0]
        errors.append(np.linalg.norm(uv[0] - c))
        ratios.append(d[0] / diameter)
    assert np.median(errors) <= 0.25 and max(errors) <= 0.6, errors
    assert 0.9 <= np.median(ratios) <= 1.12, ratios  # the edge at the steepest fall: about the disc's own diameter


def test_a_smeared_ball_is_centred_on_its_middle():
    rng = np.random.default_rng(5)
    for smear in (4.0, 8.0):
        img, c = _ball_image(rng, diameter=16.0, smear_px=smear)
        uv, _, ok = refine_edges(img, (c + [2.0, -2.0])[None, :], np.array([20.0]))
        assert ok[0] and np.linalg.norm(uv[0] - c) <= 0.5


def test_a_dark_ball_on_a_bright_background_too():
    rng = np.random.default_rng(6)
    img, c = _ball_image(rng, diameter=18.0, ball=40, background=200)
    uv, _, ok = refine_edges(img, (c + [2.5, 1.5])[None, :], np.array([24.0]))
    assert ok[0] and np.linalg.norm(uv[0] - c) <= 0.4


@pytest.mark.parametrize("chroma", [False, True])
def test_the_compiled_kernel_agrees_with_the_numpy_reference(chroma):
    """Balls, near misses and empty places at random: the same refined flags, centres and diameters to 1e-9 px, on
    grey and on chroma (orange balls there)."""
    rng = np.random.default_rng(7)
    n_ok = 0
    for trial in range(40):
        diameter = float(rng.uniform(5, 60))
        if chroma:
            img, c = _orange_ball_image(rng, size_hw=(200, 240), diameter=min(diameter, 50), center=(120 + rng.uniform(-20, 20), 100),
                                        light=rng.normal(size=2))
        else:
            img, c = _ball_image(rng, size_hw=(200, 240), diameter=min(diameter, 50), center=(120 + rng.uniform(-20, 20), 100))
        uv = np.vstack([c + rng.normal(0, 0.2 * diameter, 2), rng.uniform([0, 0], [240, 200], (3, 2)), [[-5.0, 3.0], [239.4, 199.6]]])
        d = np.concatenate([[diameter * rng.uniform(0.8, 1.6)], rng.uniform(3, 70, 5)])
        a, b = refine_edges(img, uv, d, chroma), refine_edges_reference(img, uv, d, chroma)
        np.testing.assert_array_equal(a[2], b[2])
        np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(a[1], b[1], rtol=0, atol=1e-9)
        n_ok += int(a[2].sum())
    assert n_ok >= 40  # the comparison covers fits, not only refusals


def _orange_ball_image(rng, size_hw=(120, 160), diameter=24.0, center=None, light=(1.0, 0.0), dark=0.12, background=(45, 45, 50)):
    """An orange disc lit from one side (its brightness falling linearly along ``light`` from 1 to ``dark`` across it,
    as a ball's shaded side does) on a dark, textured, noisy grey background; (image, centre)."""
    h, w = size_hw
    m = max(30.0, 1.5 * diameter)
    c = np.array(center if center is not None else rng.uniform([m, m], [w - m, h - m]), float)
    s = 8
    big = np.zeros((h * s, w * s), np.float32)
    cv2.circle(big, (int(round((c[0] + 0.5) * s * 16)), int(round((c[1] + 0.5) * s * 16))), int(round(diameter / 2 * s * 16)), 1.0, -1,
               cv2.LINE_AA, shift=4)
    cover = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)[..., None]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    ld = np.asarray(light, float) / max(np.hypot(*light), 1e-9)
    t = np.clip(0.5 - ((xx - c[0]) * ld[0] + (yy - c[1]) * ld[1]) / diameter, 0.0, 1.0)  # 1 on the lit side, 0 on the far one
    shade = (dark + (1.0 - dark) * t)[..., None]
    ball = shade * np.array([235.0, 115.0, 25.0], np.float32)
    texture = cv2.GaussianBlur(rng.normal(0, 10, (h, w)).astype(np.float32), (0, 0), 3)[..., None]
    bg = np.array(background, np.float32) + texture
    img = bg * (1.0 - cover) + ball * cover + rng.normal(0, 3.0, (h, w, 3))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), c


def test_a_shaded_orange_ball_is_centred_by_its_chroma_not_by_its_grey():
    """An orange ball whose far side is shaded into a dark background: grey's edge there is the shading's (the fit
    leans to the lit side, over a pixel off on 24-40 px balls), the chroma's the ball's own (a fraction of a pixel)."""
    rng = np.random.default_rng(12)
    grey_err, chroma_err = [], []
    for _ in range(12):
        diameter = float(rng.uniform(24, 40))
        img, c = _orange_ball_image(rng, size_hw=(160, 200), diameter=diameter, light=rng.normal(size=2))
        start = (c + rng.uniform(-0.2, 0.2, 2) * diameter)[None, :]
        uv, _, ok = refine_edges(img, start, np.array([1.2 * diameter]), chroma=True)
        assert ok[0]
        chroma_err.append(np.linalg.norm(uv[0] - c))
        uv, _, ok = refine_edges(img, start, np.array([1.2 * diameter]))
        grey_err.append(np.linalg.norm(uv[0] - c) if ok[0] else np.inf)
    assert np.median(chroma_err) <= 0.5 and max(chroma_err) <= 1.0, chroma_err
    assert np.median(grey_err) >= 1.0, grey_err


def test_the_chroma_window_is_the_integer_chroma():
    """``window_of(chroma=True)`` before smoothing: ``255 max(R - B, 0) // (R + G + B + CHROMA_DARK)`` (0 on grey and on
    blue, up to 255 R / (R + 30) on pure red); the compiled window is the reference's."""
    from tracker.detection.edge_refine import CHROMA_DARK, _window_nb, window_of

    rng = np.random.default_rng(13)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    img[0, 0], img[0, 1], img[0, 2] = (255, 0, 0), (90, 90, 90), (0, 0, 255)
    r, g, b = (img[..., i].astype(np.int64) for i in range(3))
    want = np.maximum(r - b, 0) * 255 // (r + g + b + CHROMA_DARK)
    assert want[0, 0] == 255 * 255 // 285 and want[0, 1] == 0 and want[0, 2] == 0
    ref = window_of(img, 10.0, 10.0, 5.0, chroma=True)  # a 5-px ball: no pyramid; the smallest smoothing
    x0, y0 = ref[1], ref[2]
    from tracker.detection.edge_refine import _blur_reference, _gauss_taps

    sub = want[y0:y0 + ref[0].shape[0], x0:x0 + ref[0].shape[1]]
    np.testing.assert_array_equal(ref[0], _blur_reference(sub.astype(np.float64), _gauss_taps(0.6)))
    has, gray, *_ = _window_nb(img, 10.0, 10.0, 5.0, True)
    assert has
    np.testing.assert_array_equal(gray, ref[0])


@pytest.mark.parametrize("uv, d, why", [
    ([[np.nan, 50.0]], [16.0], "a NaN centre"),
    ([[50.0, 50.0]], [np.nan], "a NaN diameter"),
    ([[50.0, 50.0]], [np.inf], "an infinite diameter"),
    ([[50.0, 50.0]], [2.0], "a diameter below the smallest fitted"),
    ([[50.0, 50.0]], [1000.0], "a diameter above the largest fitted"),
    ([[-500.0, 50.0]], [16.0], "a centre far outside the image"),
    ([[50.0, 1e12]], [16.0], "a centre beyond any image"),
])
def test_what_cannot_be_fitted_keeps_its_centre_and_diameter(uv, d, why):
    img, _ = _ball_image(np.random.default_rng(8), diameter=16.0, center=(50, 50))
    out_uv, out_d, ok = refine_edges(img, np.array(uv), np.array(d))
    assert not ok[0], why
    np.testing.assert_array_equal(out_uv, np.array(uv, float))
    np.testing.assert_array_equal(out_d, np.array(d, float))
    np.testing.assert_array_equal(refine_edges_reference(img, np.array(uv), np.array(d))[2], ok)


def test_a_flat_image_has_no_edge_to_fit():
    for img in (np.full((100, 120, 3), 128, np.uint8), np.zeros((1, 1, 3), np.uint8), np.zeros((3, 200, 3), np.uint8)):
        uv, d, ok = refine_edges(img, np.array([[1.0, 1.0], [50.0, 40.0]]), np.array([16.0, 20.0]))
        assert not ok.any()
    uv, d, ok = refine_edges(np.zeros((10, 10, 3), np.uint8), np.zeros((0, 2)), np.zeros(0))
    assert uv.shape == (0, 2) and d.shape == (0,) and ok.shape == (0,)


def test_the_inputs_are_not_changed():
    img, c = _ball_image(np.random.default_rng(9), diameter=16.0)
    uv, d = (c + [2.0, 0.0])[None, :], np.array([20.0])
    before = (img.copy(), uv.copy(), d.copy())
    refine_edges(img, uv, d)
    for x, y in zip((img, uv, d), before):
        np.testing.assert_array_equal(x, y)


def test_the_detector_refines_by_the_edge_only_where_its_filter_does_not_see_the_ball():
    """A learned stage 2 px off a white ball: with ``filter_refines`` False (the white model) the edge fit centres it
    (its diameter stays the network's);
    ``refine_edges=False`` keeps the network's centre; with ``filter_refines`` True the filter's rule applies (an
    orange filter sees no white ball: the centre stays)."""
    from tracker import BallDetector, DetectorOptions
    from tracker.detection.learned import LearnedStage
    from tracker.detection.synthetic import hand_made_model

    img, c = _ball_image(np.random.default_rng(10), diameter=16.0)

    class Off(LearnedStage):
        def candidates(self, image, window=None, k=4, threshold=None, frame_shape=None, confirm=True):
            return (c + [2.0, -1.0])[None, :], np.array([0.9]), np.array([21.0])

    torch = pytest.importorskip("torch")  # (a network for the stage's file; its answer is replaced above)
    from harness.experiments.detector.learned_train import build_net, export_onnx

    onnx = export_onnx(torch, build_net(torch))
    base = hand_made_model()
    white = dataclasses.replace(base, learned=Off(onnx, filter_refines=False))
    det = BallDetector(white).detect(img)
    assert np.linalg.norm(det.uv_px[0] - c) <= 0.4
    assert det.boxes_xywh[0, 2] == 21.0  # the network's diameter: the 3D size test is calibrated on it (edge_refine's docstring)
    raw = BallDetector(white, DetectorOptions(refine_edges=False)).detect(img)
    np.testing.assert_allclose(raw.uv_px[0], c + [2.0, -1.0])
    orange = dataclasses.replace(base, learned=Off(onnx, filter_refines=True))
    np.testing.assert_allclose(BallDetector(orange).detect(img).uv_px[0], c + [2.0, -1.0])


def test_a_bad_refine_edges_option_is_refused():
    from tracker import DetectorOptions

    with pytest.raises(ValueError, match="refine_edges"):
        DetectorOptions(refine_edges="yes")


@pytest.mark.parametrize("value", ["gray", "", None, 1, "CHROMA"])
def test_a_bad_edge_channel_is_refused(value):
    from tracker import DetectorOptions

    with pytest.raises(ValueError, match=r"DetectorOptions.edge_channel must be one of \('auto', 'grey', 'chroma'\), got"):
        DetectorOptions(edge_channel=value)


def test_the_detector_fits_an_orange_models_edge_on_chroma():
    """``edge_channel`` "auto": an orange model's learned stage is centred on the chroma's edge (the shaded ball to a
    fraction of a pixel), a white model's on grey's (off towards the lit side); "grey" and "chroma" say which."""
    from tracker import BallDetector, DetectorOptions
    from tracker.detection.learned import LearnedStage
    from tracker.detection.synthetic import hand_made_model

    img, c = _orange_ball_image(np.random.default_rng(14), size_hw=(160, 200), diameter=32.0, light=(1.0, 0.3))

    class Off(LearnedStage):
        def candidates(self, image, window=None, k=4, threshold=None, frame_shape=None, confirm=True):
            return (c + [3.0, -2.0])[None, :], np.array([0.9]), np.array([38.0])

    torch = pytest.importorskip("torch")
    from harness.experiments.detector.learned_train import build_net, export_onnx

    stage = Off(export_onnx(torch, build_net(torch)), filter_refines=False)
    orange = dataclasses.replace(hand_made_model(), learned=stage, ball_colour="orange")
    white = dataclasses.replace(orange, ball_colour="white")
    err = lambda model, **kw: np.linalg.norm(BallDetector(model, DetectorOptions(**kw)).detect(img).uv_px[0] - c)
    assert err(orange) <= 0.5 and err(white) >= 1.0
    assert err(orange, edge_channel="grey") == err(white) and err(white, edge_channel="chroma") == err(orange)


def test_the_grey_window_is_opencvs_grey_pyramid_and_smoothing():
    """The window's grey and pyramid levels are OpenCV's to the bit (integer arithmetic), its smoothing OpenCV's
    Gaussian to float rounding; the compiled window is the reference's."""
    import cv2

    from tracker.detection.edge_refine import _gauss_taps, _pyr_down_reference, _window_nb, window_of

    rng = np.random.default_rng(11)
    for h, w in [(57, 43), (10, 11), (8, 8), (33, 64), (2, 5)]:
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        r, g, b = (rgb[..., i].astype(np.int64) for i in range(3))
        np.testing.assert_array_equal((r * 9798 + g * 19235 + b * 3735 + (1 << 14)) >> 15, gray)
        if min(h, w) >= 8:
            np.testing.assert_array_equal(_pyr_down_reference(gray.astype(np.int64)), cv2.pyrDown(gray))
    img, c = _ball_image(rng, size_hw=(200, 240), diameter=40.0, center=(120, 100))
    for d in (6.0, 20.0, 40.0, 90.0):  # no pyramid, no pyramid, one level, two levels
        ref = window_of(img, c[0], c[1], d)
        has, gray, x0, y0, scale = _window_nb(img, c[0], c[1], d, False)
        assert has and (x0, y0, scale) == ref[1:]
        np.testing.assert_array_equal(gray, ref[0])
        x0, y0 = ref[1], ref[2]
        r = int(np.ceil(2.5 * 0.5 * d + 3.0))
        level = cv2.cvtColor(np.ascontiguousarray(img[y0:int(c[1]) + r + 2, x0:int(c[0]) + r + 2]), cv2.COLOR_RGB2GRAY)
        for _ in range(int(np.log2(scale))):
            level = cv2.pyrDown(level)
        sigma = max(0.6, 0.08 * d / scale)
        k = len(_gauss_taps(sigma))
        np.testing.assert_allclose(ref[0], cv2.GaussianBlur(level.astype(np.float32), (k, k), sigma), atol=2e-3)
