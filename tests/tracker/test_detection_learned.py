"""The learned detector stage: decoding the heatmap, the model file's fields, hostile files, the detector's use of it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.learned import LEARNED_FIELDS, LearnedStage, decode_heatmap, decode_placed, learned_scale

torch = pytest.importorskip("torch", reason="the tiny test network is exported from torch (rt2[train])")


@pytest.fixture(scope="module")
def tiny_onnx():
    from harness.experiments.detector.learned_train import build_net, export_onnx

    torch.manual_seed(0)
    return export_onnx(torch, build_net(torch))


def test_decode_heatmap_finds_the_peaks_best_first_with_subcell_centres():
    out = np.zeros((4, 10, 12), np.float32)
    out[0] = -5
    out[0, 2, 3], out[1, 2, 3], out[2, 2, 3], out[3, 2, 3] = 3.0, 0.25, -0.25, np.log(10.0)
    out[0, 7, 9] = 5.0
    out[0, 7, 8] = 4.0  # a neighbour of a higher peak: not a peak
    uv, heat, d = decode_heatmap(out, 0.0, 4, 4)
    np.testing.assert_allclose(heat, [5.0, 3.0])
    np.testing.assert_allclose(uv[0], [(9 + 0.5) * 4 - 0.5, (7 + 0.5) * 4 - 0.5])
    np.testing.assert_allclose(uv[1], [(3 + 0.75) * 4 - 0.5, (2 + 0.25) * 4 - 0.5])
    np.testing.assert_allclose(d[1], 10.0, rtol=1e-6)
    assert len(decode_heatmap(out, 4.5, 4, 4)[1]) == 1  # the threshold
    assert len(decode_heatmap(out, 0.0, 1, 4)[1]) == 1  # k


def test_learned_scale_bounds_the_longer_side():
    assert learned_scale(480, 640, 640) == 1.0
    assert learned_scale(1080, 1920, 640) == pytest.approx(1 / 3)


def test_a_bright_spot_is_found_at_its_place_in_full_frames_windows_and_shrunk_frames(bright_spot_onnx):
    stage = LearnedStage(bright_spot_onnx, max_side_px=640, threshold=0.5)
    img = np.zeros((240, 320, 3), np.uint8)
    img[100:104, 200:204] = 255  # one cell: centre (201.5, 101.5)
    uv, sc, d = stage.candidates(img)
    assert len(uv) == 1 and np.linalg.norm(uv[0] - [201.5, 101.5]) <= 1e-9
    np.testing.assert_allclose(d[0], np.exp(2.0), rtol=1e-5)
    uv_w, _, _ = stage.candidates(img, (180, 80, 244, 144))
    np.testing.assert_allclose(uv_w[0], uv[0], atol=1e-9)
    assert len(stage.candidates(img, (0, 0, 64, 64))[0]) == 0  # nothing in that window
    big = np.zeros((720, 1280, 3), np.uint8)
    big[400:408, 800:808] = 255
    small = LearnedStage(bright_spot_onnx, max_side_px=640, threshold=0.5)
    uv_b, _, d_b = small.candidates(big)
    assert len(uv_b) == 1 and np.linalg.norm(uv_b[0] - [803.5, 403.5]) <= 1e-9  # found in the half-size frame, mapped back
    np.testing.assert_allclose(d_b[0], 2 * np.exp(2.0), rtol=1e-3)


def test_the_detector_uses_the_stage_for_ours_and_the_filter_for_the_paper(bright_spot_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    model = dataclasses.replace(base, learned=LearnedStage(bright_spot_onnx, threshold=0.5))
    img = np.zeros((240, 320, 3), np.uint8)
    img[100:104, 200:204] = 255
    ours = BallDetector(model, DetectorOptions(refine_with_filter=False)).detect(img)
    assert len(ours) == 1 and np.linalg.norm(ours.uv_px[0] - [201.5, 101.5]) <= 1e-9
    assert ours.areas_px[0] == round(np.pi / 4 * np.exp(2.0) ** 2)
    np.testing.assert_allclose(ours.boxes_xywh[0, 2:], np.exp(2.0), rtol=1e-5)
    assert BallDetector(model).edge_loss_px == 0.0
    off = BallDetector(model, DetectorOptions(learned=False))
    assert off.learned is None and off.edge_loss_px == base.edge_loss_px
    assert BallDetector(model, DetectorOptions(method="paper")).learned is None
    high = BallDetector(model, DetectorOptions(learned_threshold=0.9999999)).detect(img)  # the spot's heat is 14: below it
    assert len(high) == 0


def test_a_model_with_the_stage_saves_and_loads_the_same_bytes(tmp_path, tiny_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    stage = LearnedStage(tiny_onnx, stride=4, max_side_px=512, threshold=0.3, diameter_range_px=(5.0, 30.0), context_px=16, description="test")
    path = dataclasses.replace(base, learned=stage).save(tmp_path / "m.npz")
    back = BallSegmentationModel.load(path).learned
    assert back.onnx == tiny_onnx and (back.max_side_px, back.threshold, back.diameter_range_px, back.context_px, back.description) == (
        512, 0.3, (5.0, 30.0), 16, "test")
    img = np.random.default_rng(0).integers(0, 256, (96, 128, 3), dtype=np.uint8)
    np.testing.assert_array_equal(back.run(img), stage.run(img))
    assert back.size_ratio is None  # optional: absent, the tracker's own size test
    sized = dataclasses.replace(base, learned=dataclasses.replace(stage, size_ratio=1.54)).save(tmp_path / "s.npz")
    assert BallSegmentationModel.load(sized).learned.size_ratio == 1.54


def _write(tmp_path, base, tiny_onnx, change):
    fields = dict(np.load(dataclasses.replace(base, learned=LearnedStage(tiny_onnx)).save(tmp_path / "ok.npz")))
    change(fields)
    path = tmp_path / "bad.npz"
    np.savez(path, **fields)
    return path


HOSTILE = [
    ("a missing field", lambda f: f.pop("learned_threshold"), "learned stage fields incomplete"),
    ("damaged network bytes", lambda f: f.update(learned_onnx=np.frombuffer(b"\x08\x07garbage" * 20, np.uint8)), "learned_onnx"),
    ("network bytes as text", lambda f: f.update(learned_onnx=np.array("abc")), "learned_onnx"),
    ("threshold out of (0, 1)", lambda f: f.update(learned_threshold=np.array(1.5)), "threshold"),
    ("a fractional stride", lambda f: f.update(learned_stride=np.array(2.5)), "learned_stride"),
    ("max side too small", lambda f: f.update(learned_max_side_px=np.array(8)), "max_side_px"),
    ("diameters out of order", lambda f: f.update(learned_diameter_range_px=np.array([30.0, 5.0])), "diameter_range_px"),
    ("a stride the network does not have", lambda f: f.update(learned_stride=np.array(8)), "expected (4, 8, 8)"),
    ("description not text", lambda f: f.update(learned_description=np.array(3.0)), "learned_description"),
    ("track threshold as text", lambda f: f.update(learned_track_threshold=np.array("low")), "learned_track_threshold"),
    ("track threshold out of (0, 1)", lambda f: f.update(learned_track_threshold=np.array(1.5)), "track_threshold"),
    ("track threshold as a vector", lambda f: f.update(learned_track_threshold=np.array([0.2, 0.3])), "learned_track_threshold"),
    ("size ratio as text", lambda f: f.update(learned_size_ratio=np.array("wide")), "learned_size_ratio"),
    ("size ratio below 1", lambda f: f.update(learned_size_ratio=np.array(0.8)), "size_ratio"),
    ("size ratio not finite", lambda f: f.update(learned_size_ratio=np.array(np.nan)), "size_ratio"),
    ("size ratio as a vector", lambda f: f.update(learned_size_ratio=np.array([1.5, 1.6])), "learned_size_ratio"),
    ("refine flag as a number", lambda f: f.update(learned_refine=np.array(1.0)), "learned_refine"),
    ("refine flag as a vector", lambda f: f.update(learned_refine=np.array([True, False])), "learned_refine"),
    ("coarse pass of five values", lambda f: f.update(learned_coarse=np.array([640.0, 0.1, 8.0, 24.0, 1.0])), "learned_coarse"),
    ("coarse context fractional", lambda f: f.update(learned_coarse=np.array([640.0, 0.1, 8.0, 24.5])), "learned_coarse"),
    ("coarse context negative", lambda f: f.update(learned_coarse=np.array([640.0, 0.1, 8.0, -8.0])), "coarse_context_px"),
    ("coarse context not finite", lambda f: f.update(learned_coarse=np.array([640.0, 0.1, 8.0, np.inf])), "learned_coarse"),
]


@pytest.mark.parametrize("what, change, message", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_hostile_model_files_name_the_file_and_field(tmp_path, tiny_onnx, what, change, message):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    path = _write(tmp_path, base, tiny_onnx, change)
    with pytest.raises(ValueError) as e:
        BallSegmentationModel.load(path)
    assert str(path) in str(e.value) and message in str(e.value)
    assert "\n" not in str(e.value)


def test_every_field_is_written(tmp_path, tiny_onnx):
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    fields = np.load(dataclasses.replace(base, learned=LearnedStage(tiny_onnx)).save(tmp_path / "m.npz"))
    assert set(LEARNED_FIELDS) <= set(fields.files)
    back = BallSegmentationModel.load(dataclasses.replace(base, learned=LearnedStage(tiny_onnx, filter_refines=False)).save(tmp_path / "r.npz"))
    assert back.learned.filter_refines is False
    old = dict(fields)
    old.pop("learned_refine")  # files written before the flag: the filter refines
    np.savez(tmp_path / "old.npz", **old)
    assert BallSegmentationModel.load(tmp_path / "old.npz").learned.filter_refines is True
    # the coarse peaks' windows' context: written as the coarse pass's fourth value where set; files without it: the windows'
    wide = LearnedStage(tiny_onnx, max_side_px=960, coarse_side_px=640, context_px=8, coarse_context_px=24)
    back = BallSegmentationModel.load(dataclasses.replace(base, learned=wide).save(tmp_path / "c.npz")).learned
    assert (back.coarse_side_px, back.context_px, back.coarse_context_px) == (640, 8, 24)
    assert np.load(tmp_path / "c.npz")["learned_coarse"].shape == (4,) and fields["learned_coarse"].shape == (3,)
    assert BallSegmentationModel.load(tmp_path / "m.npz").learned.coarse_context_px is None


def test_the_coarse_peaks_windows_see_their_own_context_before_the_second_look(bright_spot_onnx, monkeypatch):
    """Before the second look (``second_look``: single images, proposals, rt2 label --auto) a coarse peak's window at full scale
    is searched with ``coarse_context_px`` network pixels around it; a tracker's whole frame (the heat alone) and a
    window a caller gives take ``context_px``, and so does everything where ``coarse_context_px`` is not set."""
    seen = []
    real = LearnedStage.network_input
    monkeypatch.setattr(LearnedStage, "network_input", lambda self, image, window, s, context=None: seen.append((window, context)) or real(self, image, window, s, context))
    full_hd = np.zeros((1080, 1920, 3), np.uint8)
    full_hd[496:512, 896:912] = 255  # a bright spot of whole cells at both scales: one coarse peak
    for coarse_context, second_look, expected in ((24, True, 24), (24, False, None), (None, True, None)):
        stage = LearnedStage(bright_spot_onnx, max_side_px=960, threshold=0.5, coarse_side_px=480, context_px=8, coarse_context_px=coarse_context)
        seen.clear()
        uv, _, _ = stage._two_passes(full_hd, 4, 0.5, second_look=second_look)
        assert len(uv) >= 1 and np.linalg.norm(uv[0] - [903.5, 503.5]) < 8.0
        assert seen[0] == (None, None) and len(seen) >= 2 and [c for w, c in seen[1:]] == [expected] * (len(seen) - 1), (coarse_context, second_look)
        crop, _, _ = real(stage, full_hd, seen[1][0], 0.5, seen[1][1])
        window = seen[1][0]
        # the network sees the window plus the context (network pixels at scale 0.5), padded to whole cells
        assert crop.shape[1] >= round((window[2] - window[0]) * 0.5) + 2 * (8 if expected is None else expected) - 4
    seen.clear()
    stage.candidates(full_hd, (880, 480, 930, 530))  # a caller's window: the stage's context
    assert seen == [((880, 480, 930, 530), None)]


def test_a_stage_pickles_and_runs_in_the_copy(tiny_onnx):
    import pickle

    stage = LearnedStage(tiny_onnx)
    img = np.zeros((64, 64, 3), np.uint8)
    stage.run(img)  # a session made in this thread
    copy = pickle.loads(pickle.dumps(stage))
    np.testing.assert_array_equal(copy.run(img), stage.run(img))


def test_the_filter_refines_the_network_centre_where_it_sees_the_ball(bright_spot_onnx):
    """A candidate 1.5 px off an orange disc: the filter's blob centroid replaces the centre (the disc's own); off
    any blob the filter sees (a white square for an orange filter), the network's centre stays."""
    from tracker.detection.synthetic import hand_made_model, synthetic_scene

    class Off(LearnedStage):  # the network's answer, 1.5 px off each given centre
        def candidates(self, image, window=None, k=4, threshold=None, frame_shape=None, confirm=True):
            return self.at.copy(), np.full(len(self.at), 0.9), np.full(len(self.at), self.d)

    base = hand_made_model()
    image, centers, diams = synthetic_scene(np.random.default_rng(4), size_hw=(96, 128), n_balls=1, diameter_px=(12, 12))
    stage = Off(bright_spot_onnx)
    object.__setattr__(stage, "at", centers + np.array([[1.5, 0.0]]))
    object.__setattr__(stage, "d", float(diams[0]))
    model = dataclasses.replace(base, learned=stage)
    refined = BallDetector(model).detect(image).uv_px[0]
    filt = BallDetector(base).detect(image).uv_px[0]
    np.testing.assert_allclose(refined, filt, atol=1e-9)
    assert np.linalg.norm(refined - centers[0]) < 0.5
    raw = BallDetector(model, DetectorOptions(refine_with_filter=False)).detect(image).uv_px[0]
    np.testing.assert_allclose(raw, centers[0] + [1.5, 0.0])
    other = Off(bright_spot_onnx, filter_refines=False)  # a file whose filter is of another colour: never refines
    for name in ("at", "d"):
        object.__setattr__(other, name, getattr(stage, name))
    # (refine_edges=False: the edge fit of such a stage is tests/tracker/test_detection_edge_refine.py's)
    np.testing.assert_allclose(BallDetector(dataclasses.replace(base, learned=other), DetectorOptions(refine_edges=False)).detect(image).uv_px[0],
                               centers[0] + [1.5, 0.0])
    white = np.full((96, 128, 3), 60, np.uint8)
    white[40:52, 60:72] = 250
    object.__setattr__(stage, "at", np.array([[66.0, 46.0]]))
    np.testing.assert_allclose(BallDetector(model).detect(white).uv_px[0], [66.0, 46.0])


def test_the_compiled_heatmap_decoder_agrees_with_the_numpy_reference():
    """Random maps (with ties: integer heats), thresholds, k and sizes down to one cell: the same peaks, order and values."""
    rng = np.random.default_rng(3)
    for trial in range(400):
        h, w = (int(v) for v in rng.integers(1, 30, 2))
        out = (2 * rng.standard_normal((4, h, w))).astype(np.float32)
        if trial % 3 == 0:
            out[0] = np.round(out[0])
        th, k, stride = float(rng.uniform(-2, 3)), int(rng.integers(1, 12)), int(rng.choice([2, 4, 8]))
        a, b = decode_heatmap(out, th, k, stride, backend="numpy"), decode_heatmap(out, th, k, stride)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), trial
        np.testing.assert_allclose(a[2], b[2], rtol=1e-12)
    with pytest.raises(ValueError, match="backend"):
        decode_heatmap(out, 0.0, 1, 4, backend="torch")


def test_the_compiled_placement_of_candidates_agrees_with_the_numpy_reference():
    """Random maps placed at random scales and corners, kept in random boxes (some empty, some cutting peaks off),
    k below and above the peaks found: the same candidates, order and values as the numpy steps."""
    rng = np.random.default_rng(4)
    for trial in range(400):
        h, w = (int(v) for v in rng.integers(1, 30, 2))
        out = (2 * rng.standard_normal((4, h, w))).astype(np.float32)
        stride = int(rng.choice([2, 4, 8]))
        sx, sy = (1.0, 1.0) if trial % 2 else tuple(float(v) for v in rng.uniform(0.5, 3.0, 2))
        bx0, by0 = (int(v) for v in rng.integers(0, 50, 2)) if trial % 3 else (0, 0)
        x0, y0 = int(rng.integers(0, 60)), int(rng.integers(0, 60))
        box = (x0, y0, x0 + int(rng.integers(0, 120)), y0 + int(rng.integers(0, 120)))
        th, k = float(rng.uniform(-2, 3)), int(rng.integers(1, 6))
        kk = int(rng.integers(k, 4 * k + 1))
        a = decode_placed(out, th, kk, stride, (sx, sy, bx0, by0), box, k, backend="numpy")
        b = decode_placed(out, th, kk, stride, (sx, sy, bx0, by0), box, k)
        assert len(a[1]) <= k and np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2]), trial
        np.testing.assert_allclose(a[1], b[1], rtol=1e-15)  # probabilities: numpy's exp and the compiled one
    with pytest.raises(ValueError, match="backend"):
        decode_placed(out, 0.0, 1, 4, (1, 1, 0, 0), (0, 0, 9, 9), 1, backend="torch")


def test_full_frames_take_the_coarse_pass_only_where_it_removes_most_pixels(bright_spot_onnx, monkeypatch):
    from tracker.detection import learned

    stage = LearnedStage(bright_spot_onnx, max_side_px=960, threshold=0.5, coarse_side_px=480)
    calls = []
    real = LearnedStage._two_passes
    monkeypatch.setattr(LearnedStage, "_two_passes", lambda self, *a, **kw: calls.append(a[0].shape) or real(self, *a, **kw))
    vga, full_hd = np.zeros((480, 640, 3), np.uint8), np.zeros((1080, 1920, 3), np.uint8)
    vga[200:204, 300:304] = 255  # one whole cell
    uv, sc, _ = stage.candidates(vga)
    assert calls == [] and len(sc) == 1  # 640 < 1.5 x 480: one pass
    np.testing.assert_allclose(uv[0], [301.5, 201.5])
    stage.candidates(full_hd)  # 960 (shrunk) >= 1.5 x 480: coarse first
    assert calls == [full_hd.shape]
    assert learned.COARSE_MIN_RATIO == 1.5


def test_a_tracker_runs_the_stage_at_its_tracking_threshold_unless_told_otherwise(tmp_path, tiny_onnx):
    """The file's track threshold round-trips; rt2 trackers use it, an explicit learned_threshold wins, rt2-paper has no stage."""
    from tracker import Rig
    from tracker.pipeline import Tracker

    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    model = BallSegmentationModel.load(dataclasses.replace(base, learned=LearnedStage(tiny_onnx, threshold=0.4, track_threshold=0.2)).save(tmp_path / "m.npz"))
    assert model.learned.track_threshold == 0.2
    rig = Rig.load("data/rigs/lab4_vga.yaml")
    assert Tracker(rig, "rt2", model=model).engine.detector.options.learned_threshold == 0.2
    told = Tracker(rig, "rt2", model=model, detector_options=DetectorOptions(learned_threshold=0.6))
    assert told.engine.detector.options.learned_threshold == 0.6
    plain = BallSegmentationModel.load(dataclasses.replace(base, learned=LearnedStage(tiny_onnx, threshold=0.4)).save(tmp_path / "p.npz"))
    assert plain.learned.track_threshold is None
    assert Tracker(rig, "rt2", model=plain).engine.detector.options.learned_threshold is None  # the stage's own threshold
    assert Tracker(rig, "rt2-paper", model=model).engine.detector.learned is None


@pytest.mark.parametrize("hw", [(720, 1280), (480, 640), (1080, 1440)])
def test_an_aligned_window_gives_the_network_the_full_frames_input_and_output_inside(hw):
    """``LearnedStage.aligned_window`` (the motion cue's region search): the box the network sees starts and ends on
    the full frame's grid of 8 network pixels (or the frame's edge), so the resized input equals the full frame's
    there and the network's output too, away from the box's edges; the window still holds the one asked for."""
    import math

    import cv2

    stage = BallSegmentationModel.load("data/models/ball_seg_white.npz").learned
    h, w = hw
    img = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8), (9, 9), 3)
    s = stage.scale_of(h, w)
    full = img if s == 1.0 else cv2.resize(img, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
    out_full = stage.run(full)
    for window in [(300, 200, 700, 460), (17, 33, 211, 101), (0, 0, 100, 100), (w - 300, h - 200, w, h)]:
        a = stage.aligned_window(window, h, w)
        assert a[0] <= window[0] and a[1] <= window[1] and a[2] >= min(window[2], w) and a[3] >= min(window[3], h)
        m = stage.context_px / s
        box = (max(0, math.floor(a[0] - m)), max(0, math.floor(a[1] - m)), min(w, math.ceil(a[2] + m)), min(h, math.ceil(a[3] + m)))
        net = [v * s for v in box]
        assert all(abs(v - round(v)) < 1e-9 for v in net)
        assert all(box[k] == (w, h)[k % 2] or round(net[k]) % 8 == 0 for k in range(4))  # the grid, or the frame's edge
        x0, y0, x1, y1 = (round(v) for v in net)
        crop = img[box[1]:box[3], box[0]:box[2]]
        if s != 1.0:
            crop = cv2.resize(crop, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        assert np.array_equal(crop, full[y0:y1, x0:x1])
        out = stage.run(crop)
        inner = out_full[:, y0 // 4: y0 // 4 + out.shape[1], x0 // 4: x0 // 4 + out.shape[2]]
        edge = 16  # cells: the network's reach (~64 of its pixels) from the box's edge
        if out.shape[1] > 2 * edge and out.shape[2] > 2 * edge:
            assert np.array_equal(out[:, edge:-edge, edge:-edge], inner[:, edge:-edge, edge:-edge])


def test_the_size_test_takes_the_threshold_a_learned_stage_records(tmp_path, bright_spot_onnx):
    """A stage whose diameters are 1.45x the ball's (the bright-spot network: always e^2 px) gives a position when
    it records a size ratio of 1.54 (``TrackerOptions.model_size_ratio``, the default), none at the tracker's own 1.3
    (``model_size_ratio=False``, or a stage without a record); the re-run estimator of logged candidates too."""
    from tracker import CandidateEstimator, FrameSet, Rig, Tracker, TrackerOptions
    from tracker.size_test import size_threshold

    rig = Rig.load("data/rigs/lab4_vga.yaml")
    X = np.mean(np.asarray(rig.workspace_m, float), axis=0)
    uv = np.asarray(rig.project(X), float).reshape(len(rig), 2)
    d_net = math.exp(2.0)
    z_over_f = [float(c.depth(X[None])[0]) / (0.5 * (c.K[0, 0] + c.K[1, 1])) for c in rig]
    radius = d_net * float(np.median(z_over_f)) / (2 * 1.45)  # the ball whose width the network overstates 1.45x
    images = []
    for cam, (u, v) in zip(rig, uv):
        img = np.zeros((cam.image_size[1], cam.image_size[0], 3), np.uint8)
        cx, cy = int(u) // 4 * 4, int(v) // 4 * 4  # the 4x4 cell holding the projection, white
        img[cy:cy + 4, cx:cx + 4] = 255
        images.append(img)
    base = BallSegmentationModel.load("data/models/ball_seg_default.npz")
    stage = LearnedStage(bright_spot_onnx, threshold=0.5, context_px=8)
    paths = {}
    for name, ratio in (("recorded", 1.54), ("none", None)):
        paths[name] = dataclasses.replace(base, learned=dataclasses.replace(stage, size_ratio=ratio)).save(tmp_path / f"{name}.npz")
    opts = dict(ball_radius_m=radius, size_from_rig=False, hypotheses=None, handover_max_age_s=None)

    def position(model, **more):
        with Tracker(rig, "rt2", model=model, options=TrackerOptions(**opts, **more)) as tracker:
            return tracker.process(FrameSet(0.0, tuple(images), 0))

    ok = position(paths["recorded"])
    assert ok.status.has_position and np.linalg.norm(ok.position_m - X) < 0.02, ok
    assert not position(paths["recorded"], model_size_ratio=False).status.has_position
    assert not position(paths["none"]).status.has_position
    assert size_threshold(1.3, 1.54) == 1.54 and size_threshold(1.3, 1.54, False) == 1.3
    assert size_threshold(1.6, 1.54) == 1.6 and size_threshold(None, 1.54) is None and size_threshold(1.3, None) == 1.3
    # the re-run estimator of logged candidates (rt2 track --rerun, rt2 accuracy's re-evaluation) takes the record too
    assert CandidateEstimator(rig, "rt2", size_ratio=1.54).size_test.max_ratio == 1.54
    assert CandidateEstimator(rig, "rt2").size_test.max_ratio == 1.3
