"""The confirmation network's training examples: the stage's own candidates labelled by the balls, jittered balls,
frames searched again with lamps drawn in; the fit's repeatability."""

from __future__ import annotations

import numpy as np
import pytest

from harness.experiments.detector.coco import LabelledImage
from harness.experiments.detector.confirm_train import (CONTEXT, CROP_PX, JITTER, confirm_examples, draw_glint, draw_lookalike, draw_skin, fit_confirm,
                                                         with_lights, with_lookalikes, with_skin)
from harness.experiments.detector.drawn import BALL_REFLECTANCE
from tracker.detection.confirm import confirm_crop


class _Stage:
    """Candidates as a learned stage gives them: on the ball, near it (neither ball nor not), far from it."""

    def __init__(self):
        self.calls = []

    def candidates(self, image, window=None, k=4, threshold=None, frame_shape=None, confirm=True):
        self.calls.append((image.copy(), k, threshold, confirm))
        uv = np.array([[80.0, 60.0], [88.0, 60.0], [20.0, 20.0]])
        return uv, np.array([0.9, 0.5, 0.3]), np.array([10.0, 10.0, 12.0])


def _frame():
    img = np.full((120, 160, 3), 60, np.uint8)
    li = LabelledImage("f.png", 160, 120, np.array([[75.5, 55.5, 10.0, 10.0]]), np.array([[80.0, 60.0]]))
    return img, li


def test_examples_are_the_stages_candidates_labelled_by_the_balls_and_jittered_balls():
    stage = _Stage()
    lines = []
    crops, labels = confirm_examples(stage, [_frame()], seed=0, log=lines.append)
    # the candidate on the ball, JITTER jittered crops of it (positives); the one 8 px off a 10-px ball is left out; the
    # far one; random places away from the ball until there are as many others as balls
    assert crops.shape == (2 * (1 + JITTER), CROP_PX, CROP_PX, 3) and crops.dtype == np.uint8
    assert labels.tolist() == [1.0, 0.0] + [1.0] * JITTER + [0.0] * JITTER
    assert lines[-1].endswith(f"{1 + JITTER} balls, {1 + JITTER} not, {JITTER} of them random places)")
    assert [c[1:] for c in stage.calls] == [(16, 0.05, False)]  # the heat alone, its best 16 at >= 0.05
    again, labels_again = confirm_examples(_Stage(), [_frame()], seed=0, log=lambda m: None)
    np.testing.assert_array_equal(again, crops)  # the same seed, the same examples


def test_frames_searched_again_with_lamps_drawn_in_add_their_candidates_not_their_jitter():
    stage = _Stage()
    crops, labels = confirm_examples(stage, [_frame()] * 4, seed=0, lit=1.0, log=lambda m: None)
    assert len(stage.calls) == 8 and sum(not np.array_equal(c[0], stage.calls[0][0]) for c in stage.calls) == 4
    assert labels.sum() == 4 * (1 + JITTER) + 4 and (labels == 0).sum() == labels.sum()  # 8 candidates, the rest random places


def test_lamps_are_drawn_away_from_the_balls():
    img, li = _frame()
    rng = np.random.default_rng(3)
    out = with_lights(img, li.centers_px, [10.0], rng, n=3)
    assert out.shape == img.shape and not np.array_equal(out, img) and np.array_equal(img, _frame()[0])  # a copy
    yy, xx = np.mgrid[0:120, 0:160]
    disc = np.hypot(xx - 80, yy - 60) <= 6
    np.testing.assert_array_equal(out[disc], img[disc])
    assert (out == 255).all(axis=-1).sum() >= 10  # saturated cores


def test_lookalikes_are_of_the_balls_colour_away_from_the_balls_and_flat_edged():
    """A look-alike: a thing of the ball's colour (orange: red over green over blue) drawn where no ball is, in a copy;
    its pixels cover a polygon's area, not a disc's outline alone; nowhere to put it leaves the image as it was."""
    img, li = _frame()
    img = np.full((120, 160, 3), 120, np.uint8)
    yy, xx = np.mgrid[0:120, 0:160]
    disc = np.hypot(xx - 80, yy - 60) <= 6
    drawn = 0
    for seed in range(20):
        out = with_lookalikes(img, li.centers_px, [10.0], np.random.default_rng(seed), BALL_REFLECTANCE["orange"], n=2)
        assert out.shape == img.shape and out.dtype == np.uint8 and (img == 120).all()  # a copy
        np.testing.assert_array_equal(out[disc], img[disc])
        changed = (out.astype(int) - img).any(axis=-1)
        if changed.sum() >= 20:
            drawn += 1
            core = out[changed & (np.abs(out.astype(int) - img).sum(-1) > 60)]
            if len(core):
                r, g, b = np.median(core, axis=0)
                assert r > g > b, (seed, r, g, b)
    assert drawn >= 15
    rng = np.random.default_rng(0)
    assert draw_lookalike(img, rng, np.array([[80.0, 60.0]]), np.array([1000.0]), BALL_REFLECTANCE["orange"]) is img


def test_frames_searched_again_with_lookalikes_add_their_candidates_and_need_the_colour():
    stage = _Stage()
    crops, labels = confirm_examples(stage, [_frame()] * 4, seed=0, lookalikes=1.0, reflectance=BALL_REFLECTANCE["orange"], log=lambda m: None)
    assert len(stage.calls) == 8 and labels.sum() == 4 * (1 + JITTER) + 4
    plain, plain_labels = confirm_examples(_Stage(), [_frame()] * 4, seed=0, log=lambda m: None)
    none, none_labels = confirm_examples(_Stage(), [_frame()] * 4, seed=0, lookalikes=0.0, reflectance=BALL_REFLECTANCE["orange"], log=lambda m: None)
    np.testing.assert_array_equal(none, plain)  # a share of 0 draws nothing: files made before are made again alike
    with pytest.raises(ValueError, match="look-alikes need the ball's reflectance"):
        confirm_examples(_Stage(), [_frame()], seed=0, lookalikes=0.5, log=lambda m: None)


def test_skin_is_skin_toned_shaded_away_from_the_balls_and_never_round():
    """Bare skin: drawn where no ball is, in a copy; its pixels warm (red over green over blue), shaded (not one flat
    colour), longer than wide (a ball is round); nowhere to put it leaves the image as it was."""
    import cv2

    img = np.full((120, 160, 3), 120, np.uint8)
    c = np.array([[80.0, 60.0]])
    yy, xx = np.mgrid[0:120, 0:160]
    disc = np.hypot(xx - 80, yy - 60) <= 6
    drawn = 0
    for seed in range(20):
        out = draw_skin(img, np.random.default_rng(seed), c, [10.0])
        assert out.shape == img.shape and out.dtype == np.uint8 and (img == 120).all()  # a copy
        np.testing.assert_array_equal(out[disc], img[disc])
        core = (np.abs(out.astype(int) - img).sum(-1) > 60).astype(np.uint8)
        if core.sum() >= 30:
            drawn += 1
            r, g, b = np.median(out[core > 0], axis=0)
            assert r > g > b, (seed, r, g, b)
            assert out[core > 0].astype(int).sum(-1).std() > 3  # shaded
            n, lab, stats, _ = cv2.connectedComponentsWithStats(core)
            big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            pts = np.column_stack(np.nonzero(lab == big)).astype(np.float32)
            if len(pts) >= 30 and stats[big, cv2.CC_STAT_LEFT] > 0 and stats[big, cv2.CC_STAT_TOP] > 0 \
                    and stats[big, cv2.CC_STAT_LEFT] + stats[big, cv2.CC_STAT_WIDTH] < 160 and stats[big, cv2.CC_STAT_TOP] + stats[big, cv2.CC_STAT_HEIGHT] < 120:
                ev = np.linalg.eigvalsh(np.cov(pts.T))
                assert ev[1] / ev[0] > 1.3 ** 2 * 0.8, (seed, ev)  # elongated: axes at least 1.3 : 1 (soft edges aside)
    assert drawn >= 10
    assert draw_skin(img, np.random.default_rng(0), c, np.array([1000.0])) is img


def test_skin_drawn_whole_inside_the_frame_is_never_round():
    """Every piece of skin drawn whole inside a VGA frame (at least 8 of 40) is longer than wide: its pixels' second
    moments at least 1.25 : 1 (axes 1.3 : 1 or more, its soft edge aside); a disc's are 1 : 1."""
    import cv2

    h, w = 480, 640
    img = np.full((h, w, 3), 120, np.uint8)
    checked = 0
    for seed in range(40):
        out = draw_skin(img, np.random.default_rng(seed), np.array([[w / 2, h / 2]]), [10.0])
        shape = (np.abs(out.astype(int) - img).sum(-1) > 8).astype(np.uint8)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(shape)
        assert n >= 2, seed  # a VGA frame always has room for it
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        x, y, bw, bh = stats[big, :4]
        if x > 0 and y > 0 and x + bw < w and y + bh < h:
            checked += 1
            ev = np.linalg.eigvalsh(np.cov(np.column_stack(np.nonzero(lab == big)).astype(np.float64).T))
            assert ev[1] / ev[0] > 1.25, (seed, ev)
    assert checked >= 8


def test_glints_are_small_saturated_lights_away_from_the_balls():
    img = np.full((120, 160, 3), 40, np.uint8)
    c = np.array([[80.0, 60.0]])
    yy, xx = np.mgrid[0:120, 0:160]
    disc = np.hypot(xx - 80, yy - 60) <= 6
    for seed in range(20):
        out = draw_glint(img, np.random.default_rng(seed), c, [10.0])
        assert (img == 40).all()
        np.testing.assert_array_equal(out[disc], img[disc])
        changed = np.abs(out.astype(int) - img).sum(-1) > 30
        assert 0 < changed.sum() < 0.1 * changed.size  # small
        brightest = out.reshape(-1, 3)[np.argmax(out.astype(int).sum(-1))].astype(int)
        assert brightest.max() - brightest.min() >= 40, (seed, brightest)  # of one hue, not white
    assert draw_glint(img, np.random.default_rng(0), c, np.array([1000.0])) is img


def test_frames_searched_again_with_skin_add_their_candidates_and_a_share_of_0_draws_nothing():
    stage = _Stage()
    crops, labels = confirm_examples(stage, [_frame()] * 4, seed=0, skin=1.0, log=lambda m: None)
    assert len(stage.calls) == 8 and labels.sum() == 4 * (1 + JITTER) + 4
    plain, _ = confirm_examples(_Stage(), [_frame()] * 4, seed=0, log=lambda m: None)
    none, _ = confirm_examples(_Stage(), [_frame()] * 4, seed=0, skin=0.0, log=lambda m: None)
    np.testing.assert_array_equal(none, plain)
    img, li = _frame()
    assert with_skin(img, li.centers_px, [10.0], np.random.default_rng(0)).shape == img.shape


def test_the_descriptions_note_of_frames_searched_again_names_each_share():
    """The file's words: lights alone as the shipped files say them; look-alikes and skin each named with its share."""
    from harness.experiments.detector.confirm_train import _searched_again

    assert _searched_again(0.5, 0.0) == " (50 % of the frames searched again with light sources drawn in)"
    assert _searched_again(0.5, 0.5, 0.25) == (" (50 % of the frames searched again with light sources drawn in, 50 % with things of the "
                                                "ball's colour, 25 % with bare skin and coloured glints)")
    assert _searched_again(0.5, 0.0, 0.5) == " (50 % of the frames searched again with light sources drawn in, 50 % with bare skin and coloured glints)"
    assert _searched_again(0.0, 0.0, 0.5) == " (50 % of the frames searched again with bare skin and coloured glints drawn in)"
    assert _searched_again(0.0, 0.5, 0.5).endswith("things of the ball's colour drawn in, 50 % with bare skin and coloured glints)")
    assert _searched_again(0.0, 0.0, 0.0) == ""


def test_the_fit_is_repeatable_and_refuses_one_sided_examples():
    pytest.importorskip("torch", reason="training needs rt2[train]")
    rng = np.random.default_rng(0)
    crops = rng.integers(0, 256, (12, CROP_PX, CROP_PX, 3), dtype=np.uint8)
    labels = np.array([1.0, 0.0] * 6, np.float32)
    a = fit_confirm(crops, labels, steps=3, seed=5, batch=4, log=lambda m: None)
    assert a == fit_confirm(crops, labels, steps=3, seed=5, batch=4, log=lambda m: None)
    with pytest.raises(ValueError, match="needs balls and other candidates: 0 balls, 12 others"):
        fit_confirm(crops, np.zeros(12, np.float32), steps=3, seed=5, log=lambda m: None)


def test_the_confirmation_networks_moving_average_is_kept_when_asked(monkeypatch):
    """``ema``: the network exported is the exponential moving average of its weights over the steps, not the last
    step's; repeatable; 0 keeps the last step's; a decay outside [0, 1) is refused."""
    torch = pytest.importorskip("torch", reason="training needs rt2[train]")
    import harness.experiments.detector.confirm_train as CT

    rng = np.random.default_rng(0)
    crops = rng.integers(0, 256, (12, CROP_PX, CROP_PX, 3), dtype=np.uint8)
    labels = np.array([1.0, 0.0] * 6, np.float32)
    exported, seen = [], []
    real_export, real_step = CT.export_confirm, torch.optim.Adam.step

    def export(torch_, net, *a):
        exported.append({k: v.detach().clone() for k, v in net.state_dict().items()})
        return real_export(torch_, net, *a)

    def step(self, *a, **k):
        out = real_step(self, *a, **k)
        seen.append([p.detach().clone() for g in self.param_groups for p in g["params"]])
        return out

    monkeypatch.setattr(CT, "export_confirm", export)
    monkeypatch.setattr(torch.optim.Adam, "step", step)
    lines = []
    last = fit_confirm(crops, labels, steps=6, seed=5, batch=4, log=lambda m: None)
    seen.clear()
    avg = fit_confirm(crops, labels, steps=6, seed=5, batch=4, ema=0.8, log=lines.append)
    assert avg != last and "moving average kept (decay 0.8 per step)" in lines[-1]
    expected = seen[0]
    for w in seen[1:]:
        expected = [0.8 * e + 0.2 * x for e, x in zip(expected, w)]
    names = [n for n, _ in CT.confirm_net(torch).named_parameters()]
    for name, e in zip(names, expected):
        np.testing.assert_allclose(exported[-1][name].numpy(), e.numpy(), rtol=1e-5, atol=1e-6)
    assert avg == fit_confirm(crops, labels, steps=6, seed=5, batch=4, ema=0.8, log=lambda m: None)
    for bad in (-0.1, 1.0, True, float("nan")):
        with pytest.raises(ValueError, match="ema must be a decay per step from 0 \\(none\\) to below 1"):
            fit_confirm(crops, labels, steps=2, seed=5, batch=4, ema=bad, log=lambda m: None)


def test_a_second_context_stacks_each_examples_crop_at_two_scales():
    """``context2``: the same examples (the same candidates, jitter and random places: the same seed), each with its
    crop at the second scale after the first's three channels."""
    img, li = _frame()
    img = np.random.default_rng(5).integers(0, 256, img.shape, dtype=np.uint8)  # texture: crops of two sizes differ
    one, labels_one = confirm_examples(_Stage(), [(img, li)], seed=0, log=lambda m: None)
    two, labels_two = confirm_examples(_Stage(), [(img, li)], seed=0, context2=2.0, log=lambda m: None)
    assert two.shape == (len(one), CROP_PX, CROP_PX, 6) and labels_two.tolist() == labels_one.tolist()
    np.testing.assert_array_equal(two[..., :3], one)
    np.testing.assert_array_equal(two[0, ..., 3:], confirm_crop(img, 80.0, 60.0, 10.0, 2.0, CROP_PX, 48.0))
    assert not np.array_equal(two[0, ..., 3:], confirm_crop(img, 80.0, 60.0, 10.0, CONTEXT, CROP_PX, 48.0))


def test_two_crops_fit_a_network_on_each_and_average_their_probabilities():
    """Six-channel crops: each half fitted as a crop of its own would be (the same seed), the graph's probability the
    mean of the two networks'."""
    pytest.importorskip("torch", reason="training needs rt2[train]")
    from tracker.detection.confirm import ConfirmNet

    rng = np.random.default_rng(1)
    crops = rng.integers(0, 256, (12, CROP_PX, CROP_PX, 6), dtype=np.uint8)
    labels = np.array([1.0, 0.0] * 6, np.float32)
    quiet = dict(steps=3, seed=5, batch=4, log=lambda m: None)
    pair = ConfirmNet(fit_confirm(crops, labels, **quiet), context2=2.0)
    first = ConfirmNet(fit_confirm(np.ascontiguousarray(crops[..., :3]), labels, **quiet))
    second = ConfirmNet(fit_confirm(np.ascontiguousarray(crops[..., 3:]), labels, **quiet))
    probe = rng.integers(0, 256, (5, CROP_PX, CROP_PX, 6), dtype=np.uint8)
    mean = 0.5 * (first.probabilities(probe[..., :3]) + second.probabilities(probe[..., 3:]))
    np.testing.assert_allclose(pair.probabilities(probe), mean, atol=1e-5)
    assert not np.allclose(first.probabilities(probe[..., :3]), second.probabilities(probe[..., 3:]), atol=1e-4)
