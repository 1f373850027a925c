"""rt2 bench detector runs and writes its JSON rows (no timing assertions: speed is the bench's job)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import main
from tracker.detection.synthetic import hand_made_model

ROWS = {("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch"), ("full", "cv2 every pixel")}


def test_bench_json_rows_rendered_frame(tmp_path, capsys):
    out = tmp_path / "bench.json"  # default: the shipped model on a rendered lab4_vga frame
    assert main(["bench", "detector", "--repeats", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["mode"], r["backend"]) for r in rows] == [("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch"), ("full", "cv2 every pixel")]
    assert all(set(r) == {"mode", "backend", "median_ms"} and 0 < r["median_ms"] < 10_000 for r in rows)
    text = capsys.readouterr().out
    assert "rendered lab4_vga cam0 frame, orange ball (seed 0, scene" in text and "medians of 3 (ROI: 30) runs" in text
    # the table prints the measured figures the JSON holds, and the ratios are computed from them
    by = {(r["mode"], r["backend"]): r["median_ms"] for r in rows}
    for (mode, backend), ms in by.items():
        assert f"{mode:<5} {backend:<40} {ms:10.3f}" in text
    for mode in ("full", "roi"):
        assert f"{mode}: torch / cv2 = {by[mode, 'torch'] / by[mode, 'cv2']:.2f}x" in text


def test_bench_times_the_detector_on_a_frame_where_it_finds_the_ball():
    # The Python API refuses a frame whose ball the model does not find in its window: the figures are
    # always of a detection that works, never of a detector returning nothing.
    from harness.experiments.studies.bench_detector import bench, filter2d_logits
    from tracker.detection.synthetic import draw_disk

    model = hand_made_model()
    image = np.full((480, 640, 3), 100, np.uint8)
    draw_disk(image, (300.0, 200.0), 12.0, (245, 120, 20))
    rows, breakdown = bench(model, image, (300.0, 200.0), repeats=2)
    assert [(r["mode"], r["backend"]) for r in rows] == [("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch"), ("full", "cv2 every pixel")]
    assert [r["backend"] for r in breakdown] == ["cv2: logits only (LUT + one compiled 5x5x3 pass)", "cv2: logits as 3 x filter2D, summed (baseline)",
                                                 "cv2: Algorithm 1 top-K on given logits", "cv2: coarse pass only (every other pixel, 3x3)"]
    # the baseline row computes the same logits (up to float32 rounding: other summation order)
    np.testing.assert_allclose(filter2d_logits(model, image), model.logits(image), atol=1e-4)
    empty = np.full((480, 640, 3), 100, np.uint8)
    with pytest.raises(ValueError, match="the benchmark frame's ball is not found in its window"):
        bench(model, empty, (300.0, 200.0), repeats=2)


@pytest.mark.parametrize("shipped", [False, True])
def test_bench_runs_algorithm_1_as_the_detector_does(shipped):
    # The breakdown's "Algorithm 1 on given logits" row reads the detector's public settings
    # (bench_detector.blob_arguments): the same candidates as the detector's own full-frame search.
    from harness.experiments.studies.bench_detector import blob_arguments
    from tracker import BallDetector, BallSegmentationModel, DetectorOptions
    from tracker.detection.blobs import find_blobs
    from tracker.detection.synthetic import draw_disk
    from tracker.pipeline import DEFAULT_MODEL

    if shipped:  # the bench's own default frame: a rendered lab scene (ball, person, robot, distractors)
        from harness.experiments.studies.bench_detector import _bench_image

        model, image = BallSegmentationModel.load(DEFAULT_MODEL), _bench_image(None, 0)[0]
    else:
        model, image = hand_made_model(), np.full((480, 640, 3), 100, np.uint8)
        for k, (u, v) in enumerate([(300.0, 200.0), (100.0, 400.0), (500.0, 90.0)]):
            draw_disk(image, (u, v), 8.0 + 3 * k, (245, 120, 20))
    for verify in (False, True):
        det = BallDetector(model, DetectorOptions(verify=verify))
        th, tl, kw = blob_arguments(det)
        blobs = find_blobs(model.logits(image), th, tl, **kw)
        seen = BallDetector(model, DetectorOptions(verify=False, max_candidates=kw["max_blobs"])).detect(image)
        assert len(seen) > 0 and np.array_equal(blobs.centers_px, seen.uv_px)
        assert np.array_equal(blobs.areas_px, seen.areas_px)
    with pytest.raises(ValueError, match="the Algorithm 1 breakdown times the method 'ours', got 'paper'"):
        blob_arguments(BallDetector(model, DetectorOptions(method="paper")))


def test_bench_frame_from_a_coco_set(tmp_path, synthetic_ball_coco, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    out = tmp_path / "bench.json"
    assert main(["bench", "detector", "--model", str(model), "--data", str(synthetic_ball_coco(30, 0)), "--repeats", "2", "--json", str(out)]) == 0
    assert {(r["mode"], r["backend"]) for r in json.loads(out.read_text())} == ROWS


@pytest.mark.parametrize("args, message", [
    (["--repeats", "0"], "--repeats must be >= 1"),
    (["--roi-half-size-px", "0"], "--roi-half-size-px must be >= 1, got 0"),
    (["--roi-half-size-px", "-4"], "--roi-half-size-px must be >= 1, got -4"),
    # the window as large as the frame (96x128 here) or larger: the ROI rows would time the full frame again
    (["--roi-half-size-px", "48"], "--roi-half-size-px 48: a 96x96 window is not smaller than the 128x96 frame"),
    (["--roi-half-size-px", "100000"], "--roi-half-size-px 100000: a 200000x200000 window is not smaller than the 128x96 frame"),
])
def test_bench_bad_input(tmp_path, synthetic_ball_coco, capsys, args, message):
    model = hand_made_model().save(tmp_path / "hand.npz")
    out = tmp_path / "bench.json"
    assert main(["bench", "detector", "--model", str(model), "--data", str(synthetic_ball_coco(30, 0)), "--repeats", "2", *args,
                 "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and not out.exists()


def test_bench_of_the_white_model_times_a_white_ball_it_finds(tmp_path, capsys):
    """The white model's bench frame shows a white ball its learned stage finds in the window (at the tracking
    threshold, as a tracker searches); the learned rows come first and the goals line is printed."""
    pytest.importorskip("onnxruntime")
    out = tmp_path / "bench.json"
    assert main(["bench", "detector", "--model", "data/models/ball_seg_white.npz", "--repeats", "2", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["mode"], r["backend"]) for r in rows][:2] == [("full", "learned"), ("roi", "learned")]
    text = capsys.readouterr().out
    assert "white ball (seed 0, scene" in text and "goals: with the learned stage, full frame <= 6 ms, ROI <= 0.3 ms" in text
