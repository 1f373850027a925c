"""The learned stage's confirmation network: its crops, the model file's fields, hostile files, how it re-ranks a
whole frame's candidates (and leaves windows alone)."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.confirm import CONFIRM_FIELDS, ConfirmNet, confirm_crop
from tracker.detection.learned import LearnedStage

torch = pytest.importorskip("torch", reason="the test networks are exported from torch (rt2[train])")


def _redness_onnx(p: int = 48) -> bytes:
    """A confirmation network that believes in red centres: logit = 20 (R - G) / 255 - 5 over the crop's central 4x4."""
    from harness.experiments.detector.confirm_train import export_confirm

    class Redness(torch.nn.Module):
        def forward(self, crops):
            c = crops[:, p // 2 - 2: p // 2 + 2, p // 2 - 2: p // 2 + 2, :]
            return 20.0 * (c[..., 0].mean((1, 2)) - c[..., 1].mean((1, 2))) / 255.0 - 5.0

    return export_confirm(torch, Redness(), p)


@pytest.fixture(scope="module")
def redness_onnx():
    return _redness_onnx()


@pytest.fixture(scope="module")
def trained_shape_onnx():
    """The real layout (:func:`harness.experiments.detector.confirm_train`'s network), untrained."""
    from harness.experiments.detector.confirm_train import CROP_PX, confirm_net, export_confirm

    torch.manual_seed(0)
    return export_confirm(torch, confirm_net(torch).eval(), CROP_PX)


def _two_spots():
    img = np.zeros((240, 320, 3), np.uint8)
    img[100:104, 200:204] = 255  # white: the heat's best (centre (201.5, 101.5))
    img[40:44, 60:64] = (255, 80, 80)  # pink: the heat's second (centre (61.5, 41.5)), the confirmation's first
    return img


def test_a_crop_is_the_square_around_the_candidate_resampled_with_its_border_reflected():
    img = np.zeros((100, 120, 3), np.uint8)
    img[48:52, 58:62] = 200  # a 4-px square centred at (59.5, 49.5)
    c = confirm_crop(img, 59.5, 49.5, 4.0, 6.0, 24, 24.0)  # 24 px around it, as they are
    assert c.shape == (24, 24, 3) and c.dtype == np.uint8
    assert (c[10:14, 10:14] == 200).all() and c.sum() == 200 * 16 * 3
    big = confirm_crop(img, 59.5, 49.5, 16.0, 6.0, 24, 24.0)  # 96 px shrunk 4x by area: the square's light kept, in the middle
    assert big.shape == (24, 24, 3) and big.sum() == 200 * 16 * 3 // 16 and big[11:13, 11:13].sum() == big.sum()
    small = confirm_crop(img, 59.5, 49.5, 1.0, 6.0, 48, 12.0)  # at least min_side_px (12) around it, enlarged
    assert small.shape == (48, 48, 3) and small[24, 24, 0] == 200
    edge = confirm_crop(img, 1.0, 1.0, 4.0, 6.0, 24, 24.0)  # past the frame's corner: reflected, never an error
    assert edge.shape == (24, 24, 3)
    gone = confirm_crop(img, -500.0, -500.0, 4.0, 6.0, 24, 24.0)
    assert gone.shape == (24, 24, 3) and not gone.any()


def test_the_confirmation_reranks_a_whole_frame_and_leaves_windows_to_the_heat(bright_spot_onnx, redness_onnx):
    img = _two_spots()
    heat_only = LearnedStage(bright_spot_onnx, max_side_px=640, threshold=0.3)
    uv, sc, _ = heat_only.candidates(img, k=4)
    assert len(uv) == 2 and np.allclose(uv[0], [201.5, 101.5]) and np.allclose(uv[1], [61.5, 41.5]) and sc[0] > 0.9 > 0.7 > sc[1] > 0.5
    stage = dataclasses.replace(heat_only, confirm=ConfirmNet(redness_onnx, threshold=0.3))
    uv_c, sc_c, _ = stage.candidates(img, k=4)
    assert len(uv_c) == 1 and np.allclose(uv_c[0], [61.5, 41.5])  # white: sqrt(~0.007 * 0.98) < 0.3, dropped
    np.testing.assert_allclose(sc_c[0], np.sqrt(sc[1] / (1 + np.exp(-(20 * 175 / 255 - 5)))), rtol=1e-4)  # sqrt(p * heat)
    uv_all, sc_all, _ = stage.candidates(img, k=4, threshold=0.01)  # a caller's threshold applies to the confirmed scores
    assert np.allclose(uv_all[0], [61.5, 41.5]) and np.allclose(uv_all[1], [201.5, 101.5]) and sc_all[0] > sc_all[1]
    uv_h, sc_h, _ = stage.candidates(img, k=4, confirm=False)  # the heat alone, at the stage's own threshold
    np.testing.assert_array_equal(uv_h, uv)
    uv_w, sc_w, _ = stage.candidates(img, (180, 80, 244, 144), k=4)  # a window: the heat, not looked at again
    assert np.allclose(uv_w[0], [201.5, 101.5]) and sc_w[0] > 0.9


def test_the_detector_ranks_by_the_confirmation_unless_told_not_to(bright_spot_onnx, redness_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    stage = LearnedStage(bright_spot_onnx, max_side_px=640, threshold=0.3, confirm=ConfirmNet(redness_onnx, threshold=0.3))
    model = dataclasses.replace(base, learned=stage)
    img = _two_spots()
    opts = dict(refine_edges=False, refine_with_filter=False)
    first = BallDetector(model, DetectorOptions(max_candidates=1, **opts)).detect(img).uv_px
    assert np.allclose(first[0], [61.5, 41.5])
    plain = BallDetector(model, DetectorOptions(max_candidates=1, confirm=False, **opts)).detect(img).uv_px
    assert np.allclose(plain[0], [201.5, 101.5])
    with pytest.raises(ValueError, match="confirm"):
        DetectorOptions(confirm=1)


def test_a_stage_with_its_confirmation_saves_loads_and_pickles(tmp_path, bright_spot_onnx, trained_shape_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    net = ConfirmNet(trained_shape_onnx, crop_px=48, context=5.0, min_side_px=40.0, candidates=6, gate=0.07, threshold=0.35, description="test net")
    stage = LearnedStage(bright_spot_onnx, threshold=0.4, confirm=net)
    path = dataclasses.replace(base, learned=stage).save(tmp_path / "m.npz")
    assert set(CONFIRM_FIELDS) <= set(np.load(path).files)
    back = BallSegmentationModel.load(path).learned
    assert back.threshold == 0.4 and back.confirm.onnx == trained_shape_onnx
    assert (back.confirm.crop_px, back.confirm.context, back.confirm.min_side_px, back.confirm.candidates, back.confirm.gate,
            back.confirm.threshold, back.confirm.description) == (48, 5.0, 40.0, 6, 0.07, 0.35, "test net")
    img = _two_spots()
    for a, b in zip(back.candidates(img, threshold=0.01), stage.candidates(img, threshold=0.01)):
        np.testing.assert_array_equal(a, b)
    copy = pickle.loads(pickle.dumps(stage))
    for a, b in zip(copy.candidates(img, threshold=0.01), stage.candidates(img, threshold=0.01)):
        np.testing.assert_array_equal(a, b)
    assert "onnx" not in repr(net)  # the bytes stay out of messages
    plain = BallSegmentationModel.load(dataclasses.replace(base, learned=LearnedStage(bright_spot_onnx)).save(tmp_path / "p.npz"))
    assert plain.learned.confirm is None  # optional: a file without it ranks by the heat


def _fields(tmp_path, bright_spot_onnx, trained_shape_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    stage = LearnedStage(bright_spot_onnx, confirm=ConfirmNet(trained_shape_onnx))
    return dict(np.load(dataclasses.replace(base, learned=stage).save(tmp_path / "ok.npz")))


def _geometry(**change):
    g = dict(crop_px=48.0, context=6.0, min_side_px=48.0, candidates=6.0, gate=0.05, threshold=0.5)
    g.update(change)
    return np.array(list(g.values()))


HOSTILE = [
    ("geometry missing", lambda f: f.pop("learned_confirm_geometry"), "confirmation network fields incomplete"),
    ("network missing", lambda f: f.pop("learned_confirm_onnx"), "confirmation network fields incomplete"),
    ("damaged network bytes", lambda f: f.update(learned_confirm_onnx=np.frombuffer(b"\x08\x07garbage" * 20, np.uint8)), "learned_confirm_onnx"),
    ("network bytes as text", lambda f: f.update(learned_confirm_onnx=np.array("abc")), "learned_confirm_onnx"),
    ("the heatmap network's bytes", lambda f: f.update(learned_confirm_onnx=f["learned_onnx"]), "learned_confirm_onnx"),
    ("geometry of five numbers", lambda f: f.update(learned_confirm_geometry=_geometry()[:5]), "learned_confirm_geometry"),
    ("geometry as text", lambda f: f.update(learned_confirm_geometry=np.array("wide")), "learned_confirm_geometry"),
    ("geometry not finite", lambda f: f.update(learned_confirm_geometry=_geometry(context=np.nan)), "learned_confirm_geometry"),
    ("a fractional crop size", lambda f: f.update(learned_confirm_geometry=_geometry(crop_px=47.5)), "learned_confirm_geometry"),
    ("a crop size the network does not take", lambda f: f.update(learned_confirm_geometry=_geometry(crop_px=32.0)), "learned_confirm_onnx"),
    ("no candidates", lambda f: f.update(learned_confirm_geometry=_geometry(candidates=0.0)), "candidates"),
    ("context below one diameter", lambda f: f.update(learned_confirm_geometry=_geometry(context=0.5)), "context"),
    ("gate out of (0, 1)", lambda f: f.update(learned_confirm_geometry=_geometry(gate=1.0)), "gate"),
    ("threshold out of (0, 1)", lambda f: f.update(learned_confirm_geometry=_geometry(threshold=-0.1)), "threshold"),
    ("description not text", lambda f: f.update(learned_confirm_description=np.array(3.0)), "learned_confirm_description"),
    ("geometry of eight numbers", lambda f: f.update(learned_confirm_geometry=np.append(_geometry(), [2.0, 2.0])), "learned_confirm_geometry"),
    ("a second context below one diameter", lambda f: f.update(learned_confirm_geometry=np.append(_geometry(), 0.5)), "context2"),
    ("a second context not finite", lambda f: f.update(learned_confirm_geometry=np.append(_geometry(), np.inf)), "learned_confirm_geometry"),
    ("a second crop the three-channel network does not take", lambda f: f.update(learned_confirm_geometry=np.append(_geometry(), 2.0)),
     "learned_confirm_onnx"),
    ("without a learned stage", lambda f: [f.pop(k) for k in list(f) if k.startswith("learned_") and not k.startswith("learned_confirm")],
     "without a learned stage"),
]


@pytest.mark.parametrize("what, change, message", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_hostile_confirmation_fields_name_the_file_and_field(tmp_path, bright_spot_onnx, trained_shape_onnx, what, change, message):
    fields = _fields(tmp_path, bright_spot_onnx, trained_shape_onnx)
    change(fields)
    path = tmp_path / "bad.npz"
    np.savez(path, **fields)
    with pytest.raises(ValueError) as e:
        BallSegmentationModel.load(path)
    assert str(path) in str(e.value) and message in str(e.value)
    assert "\n" not in str(e.value)


def test_a_confirmation_network_is_checked_when_made(trained_shape_onnx):
    with pytest.raises(ValueError, match="onnx"):
        ConfirmNet(b"short")
    with pytest.raises(ValueError, match="crop_px"):
        ConfirmNet(trained_shape_onnx, crop_px=True)
    with pytest.raises(ValueError, match="confirm must be a ConfirmNet"):
        LearnedStage(b"x" * 32, confirm="yes")
    assert "not a confirmation network" in ConfirmNet(trained_shape_onnx, crop_px=32).check()


def test_a_tracker_reports_the_heats_candidates_unless_its_caller_asks_for_the_second_look(rig, bright_spot_onnx, redness_onnx):
    from tracker import Tracker

    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    model = dataclasses.replace(base, learned=LearnedStage(bright_spot_onnx, threshold=0.3, track_threshold=0.2,
                                                           confirm=ConfirmNet(redness_onnx, threshold=0.3)))
    assert Tracker(rig, "rt2", model=model).engine.detector.options.confirm is False
    asked = Tracker(rig, "rt2", model=model, detector_options=DetectorOptions()).engine.detector.options
    assert asked.confirm is True and asked.learned_threshold == 0.2


@pytest.fixture(scope="module")
def two_crop_onnx():
    """The real layout for two crops (six channels: a network on each, their probabilities averaged), untrained."""
    from harness.experiments.detector.confirm_train import CROP_PX, confirm_net, confirm_pair, export_confirm

    torch.manual_seed(0)
    return export_confirm(torch, confirm_pair(torch, confirm_net(torch).eval(), confirm_net(torch).eval()), CROP_PX, 6)


def test_a_second_crop_is_stacked_after_the_first_and_kept_in_the_file(tmp_path, bright_spot_onnx, two_crop_onnx, trained_shape_onnx):
    """``context2``: each candidate's crop at a second scale, its three channels after the first crop's; the file's
    geometry gets a seventh number, a file of one crop keeps six (the files made before load as they were)."""
    net = ConfirmNet(two_crop_onnx, context=6.0, context2=2.0)
    assert net.channels == 6 and net.check() is None
    img = _two_spots()
    crops = net.crops(img, [[201.5, 101.5]], [4.0])
    assert crops.shape == (1, 48, 48, 6)
    np.testing.assert_array_equal(crops[0, ..., :3], confirm_crop(img, 201.5, 101.5, 4.0, 6.0, 48, 48.0))
    np.testing.assert_array_equal(crops[0, ..., 3:], confirm_crop(img, 201.5, 101.5, 4.0, 2.0, 48, 48.0))
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    path = dataclasses.replace(base, learned=LearnedStage(bright_spot_onnx, confirm=net)).save(tmp_path / "two.npz")
    assert np.load(path)["learned_confirm_geometry"].shape == (7,)
    back = BallSegmentationModel.load(path).learned.confirm
    assert (back.context, back.context2, back.channels) == (6.0, 2.0, 6)
    np.testing.assert_array_equal(back.probabilities(crops), net.probabilities(crops))
    one = dataclasses.replace(base, learned=LearnedStage(bright_spot_onnx, confirm=ConfirmNet(trained_shape_onnx))).save(tmp_path / "one.npz")
    assert np.load(one)["learned_confirm_geometry"].shape == (6,) and BallSegmentationModel.load(one).learned.confirm.context2 is None
    # a six-channel network without its second context (or the reverse) is refused where it is made
    assert "not a confirmation network" in ConfirmNet(two_crop_onnx).check()
    for bad in (0.5, float("nan"), True, "2"):
        with pytest.raises(ValueError, match="context2"):
            ConfirmNet(two_crop_onnx, context2=bad)


def test_the_second_crop_is_what_a_two_crop_network_reads():
    """A network that reads only the second crop (its share of red pixels): a white spot with a red one 20 px away
    scores high when the second crop reaches that far (16 diameters: 64 px) and low when it does not (2: 8 px), whatever
    the first crop."""
    from harness.experiments.detector.confirm_train import export_confirm

    class SecondRedness(torch.nn.Module):
        def forward(self, crops):
            red = (crops[..., 3].float() - crops[..., 4].float()).clamp(min=0.0).mean((1, 2))
            return 4.0 * (red - 0.5)  # a 4x4 red spot in a 64-px crop: ~1 of 255 on average

    img = np.zeros((120, 160, 3), np.uint8)
    img[58:62, 58:62] = 255
    img[58:62, 78:82] = (255, 0, 0)
    onnx = export_confirm(torch, SecondRedness(), 48, 6)
    far, near = (ConfirmNet(onnx, context=2.0, context2=c2, min_side_px=8.0) for c2 in (16.0, 2.0))
    assert far.probabilities(far.crops(img, [[59.5, 59.5]], [4.0]))[0] > 0.5 > near.probabilities(near.crops(img, [[59.5, 59.5]], [4.0]))[0]
