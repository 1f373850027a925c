"""RTBlob baseline (Lampert & Peters 2012): per-camera detector, fixed-pair stereo, its published
failure modes, and bad input. Synthetic scenes are drawn with OpenCV on a textured grey background
in a 4-camera VGA rig made here (two stereo pairs, one on each long side of the table)."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import scipy.ndimage

from tracker import BallObservation, Camera, FrameSet, Rig, RTBlobDetector, RTBlobOptions, RTBlobTracker, Status
from tracker.rtblob import CORRELATION_METHODS, likelihood_reference
from tracker._rtblob_pairs import pair_covariances, triangulate_fixed_pairs

W, H = 640, 480
BALL_RGB = (235, 120, 25)  # a lit orange ball, not exactly the reference colour
DISTRACTOR_RGB = (255, 120, 0)  # exactly the reference orange: wins the arg-max where it is seen
BALL_M = np.array([0.5, 0.1, 1.0])  # over the opponent's half of the table, lab world frame
PAIRS = np.array([[0, 1], [2, 3]])


# -- the synthetic scene ----------------------------------------------------------------------------
def look_at(center, target, up=(0.0, 0.0, 1.0)):
    """R_world_to_cam, t for a camera at ``center`` looking at ``target`` (OpenCV axes)."""
    center, target, up = (np.asarray(v, float) for v in (center, target, up))
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ center


def make_rig() -> Rig:
    """Four VGA cameras 2.6 m up, two on each side of the table, all looking over the net."""
    centres = [(-0.4, 1.9, 2.6), (0.9, 1.9, 2.6), (-0.4, -1.9, 2.6), (0.9, -1.9, 2.6)]
    K = [[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]]
    cams = []
    for i, c in enumerate(centres):
        R, t = look_at(c, (0.3, 0.0, 0.95))
        cams.append(Camera(f"cam{i}", K, [-0.12, 0.06, 0.0005, -0.0004, 0.0], R, t, (W, H)))
    return Rig(cams)


@pytest.fixture(scope="module")
def rig() -> Rig:
    return make_rig()


@pytest.fixture(scope="module")
def backgrounds() -> list[np.ndarray]:
    """Textured grey background per camera (seeded), drawn once per module."""
    rng = np.random.default_rng(20121)
    return [np.clip(rng.normal(110, 25, (H, W, 1)) + rng.normal(0, 6, (H, W, 3)), 0, 255).astype(np.uint8) for _ in range(4)]


def draw_disk(img: np.ndarray, uv, radius_px: float, rgb) -> None:
    s = 16  # 4 fractional bits: sub-pixel centre and radius
    centre = (int(round(uv[0] * s)), int(round(uv[1] * s)))
    cv2.circle(img, centre, int(round(radius_px * s)), tuple(int(c) for c in rgb), -1, cv2.LINE_AA, 4)


def render(rig, backgrounds, objects) -> tuple:
    """objects: (X_world (3,), radius_m, rgb, cameras that see it or None for all) -> images (H, W, 3)."""
    images = []
    for i, cam in enumerate(rig):
        img = backgrounds[i].copy()
        for X, radius_m, rgb, cams in objects:
            if cams is None or i in cams:
                depth = cam.depth(X)[0]
                draw_disk(img, cam.project(X), cam.K[0, 0] * radius_m / depth, rgb)
        images.append(img)
    return tuple(images)


def ball(X=BALL_M, cams=None):
    return (np.asarray(X, float), 0.02, BALL_RGB, cams)


# -- smoke ------------------------------------------------------------------------------------------
def test_tracker_reports_the_ball_with_the_rt2_output_type(rig, backgrounds):
    obs = RTBlobTracker(rig).process(FrameSet(1.25, render(rig, backgrounds, [ball()]), index=7))
    assert isinstance(obs, BallObservation)
    assert obs.tracker == "rtblob" and obs.status is Status.OK and obs.has_position
    assert obs.t_s == 1.25 and obs.support == 4 and obs.inliers.tolist() == [True] * 4
    assert obs.latency_s > 0 and obs.notes == ()
    assert np.linalg.norm(obs.position_m - BALL_M) < 0.02


def test_detector_smoke_and_repr():
    det = RTBlobDetector((W, H), 4.0)
    assert "640x480" in repr(det) and det.correlation in CORRELATION_METHODS
    img = np.full((H, W, 3), 110, np.uint8)
    draw_disk(img, (100.0, 200.0), 4.0, BALL_RGB)
    uv, score = det.detect(img)
    assert np.abs(uv - [100, 200]).max() <= 1.0 and 0.5 < score <= 1.0


# -- shapes and agreement of the implementations ------------------------------------------------------
def test_detector_output_shapes_and_ranges(backgrounds):
    det = RTBlobDetector((W, H), 5.0)
    L, S = det.likelihood(backgrounds[0]), det.response(backgrounds[0])
    assert L.shape == S.shape == (H, W) and L.dtype == S.dtype == np.float32
    assert L.min() >= 0 and L.max() <= 1 and S.max() <= 1 + 1e-6
    uv, score = det.detect(backgrounds[0])  # nothing orange: not seen
    assert uv.shape == (2,) and np.isnan(uv).all() and score < det.options.min_score


@pytest.mark.parametrize("space, sigma", [("rgb", 0.25), ("chromaticity", 0.08)])
def test_lookup_table_likelihood_matches_the_plain_formula(space, sigma):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    img[0, :3] = 0  # black pixels: chromaticity undefined, treated as grey
    opts = RTBlobOptions(colour_space=space, colour_sigma=sigma)
    fast = RTBlobDetector((80, 60), 3.0, opts).likelihood(img)
    assert np.abs(fast - likelihood_reference(img, opts)).max() < 1e-6


@pytest.mark.parametrize("radius_px", [2.0, 4.5, 7.0])
def test_all_correlation_methods_give_the_same_response(radius_px):
    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, (90, 120, 3), dtype=np.uint8)
    dets = {m: RTBlobDetector((120, 90), radius_px, RTBlobOptions(correlation=m)) for m in CORRELATION_METHODS}
    L = dets["numpy"].likelihood(img).astype(float)
    # plain reference of Eq. (2): direct correlation with zeros outside the image
    ref = scipy.ndimage.correlate(L, dets["numpy"].template.astype(float), mode="constant", cval=0.0)
    for method, det in dets.items():
        assert np.abs(det.response(img) - ref).max() < 1e-5, method
    assert dets["auto"].correlation == ("filter2d" if radius_px < 6 else "scipy")


def test_explicit_fft_size_is_used_and_gives_the_same_response():
    img = np.random.default_rng(5).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    a = RTBlobDetector((64, 48), 3.0, RTBlobOptions(correlation="scipy"))
    b = RTBlobDetector((64, 48), 3.0, RTBlobOptions(correlation="scipy", fft_size=(64, 80)))
    assert b.fft_size == (64, 80) and a.fft_size != b.fft_size
    assert np.abs(a.response(img) - b.response(img)).max() < 1e-5


def test_info_holds_both_pair_positions_and_the_mean_is_reported(rig, backgrounds):
    obs, info = RTBlobTracker(rig).process_with_info(FrameSet(0.0, render(rig, backgrounds, [ball()])))
    assert info.pair_cameras.tolist() == [[0, 1], [2, 3]]
    assert info.pair_positions_m.shape == (2, 3) and info.pair_covariances_m2.shape == (2, 3, 3)
    assert np.allclose(obs.position_m, info.pair_positions_m.mean(axis=0))
    assert np.allclose(obs.covariance_m2, info.pair_covariances_m2.sum(axis=0) / 4)
    assert obs.uv_px.shape == (4, 2) and info.scores.shape == (4,) and info.radius_px.tolist() == [4.0] * 4


def test_pairs_by_name_and_cameras_outside_pairs_are_ignored(rig, backgrounds):
    images = list(render(rig, backgrounds, [ball()]))
    images[3] = None  # cam3 is in no pair: its missing frame is not even noticed
    tracker = RTBlobTracker(rig, RTBlobOptions(pairs=(("cam0", "cam2"),)))
    obs = tracker.process(FrameSet(0.0, tuple(images)))
    assert obs.support == 2 and obs.inliers.tolist() == [True, False, True, False] and obs.notes == ()
    assert np.isnan(obs.uv_px[[1, 3]]).all() and np.linalg.norm(obs.position_m - BALL_M) < 0.02


def test_one_pair_only_reports_that_pair(rig, backgrounds):
    images = list(render(rig, backgrounds, [ball()]))
    images[2] = None
    obs, info = RTBlobTracker(rig).process_with_info(FrameSet(0.0, tuple(images)))
    assert obs.status is Status.OK and obs.support == 2 and obs.inliers.tolist() == [True, True, False, False]
    assert np.isnan(info.pair_positions_m[1]).all() and np.allclose(obs.position_m, info.pair_positions_m[0])
    assert np.allclose(obs.covariance_m2, info.pair_covariances_m2[0])
    assert "camera cam2: no frame" in obs.notes


def test_no_covariance_when_pixel_sigma_is_none(rig, backgrounds):
    obs, info = RTBlobTracker(rig, RTBlobOptions(pixel_sigma_px=None)).process_with_info(
        FrameSet(0.0, render(rig, backgrounds, [ball()]))
    )
    assert obs.covariance_m2 is None and info.pair_covariances_m2 is None and obs.has_position


# -- bad input ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "image, match",
    [
        (np.zeros((H, W, 3), np.float32), "dtype uint8"),
        (np.zeros((H, W), np.uint8), r"\(H, W, 3\).*shape \(480, 640\)"),
        (np.zeros((H, W, 4), np.uint8), r"shape \(480, 640, 4\)"),
        (np.zeros((0, 0, 3), np.uint8), "image is empty"),
        ([[1, 2, 3]], "image must be an"),
        (None, "image must be an"),
        (np.zeros((240, 320, 3), np.uint8), "image is 320x240 px but the camera is calibrated for 640x480"),
    ],
)
def test_detector_rejects_bad_images(image, match):
    det = RTBlobDetector((W, H), 4.0)
    for call in (det.detect, det.likelihood, det.response):
        with pytest.raises(ValueError, match=match):
            call(image)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"correlation": "fftw"}, r"unknown correlation 'fftw'; valid: \['auto', 'scipy'"),
        ({"colour_space": "hsv"}, r"unknown colour_space 'hsv'; valid: \['rgb', 'chromaticity'\]"),
        ({"subpixel": "gauss"}, "unknown subpixel 'gauss'"),
        ({"colour_sigma": 0.0}, "colour_sigma must be a positive number, got 0.0"),
        ({"reference_rgb": (300, 0, 0)}, r"reference_rgb must be three numbers in \[0, 255\]"),
        ({"reference_rgb": "orange"}, "reference_rgb must be three numbers"),
        ({"template_radius_px": 0.5}, "template_radius_px must be at least 1 px"),
        ({"min_score": 1.5}, r"min_score must be a number in \[0, 1\], got 1.5"),
        ({"pairs": ((0, 0),)}, "a pair needs two different cameras"),
        ({"pairs": ((0, 1, 2),)}, "each entry of pairs must be two cameras"),
        ({"pairs": ()}, "pairs must be a non-empty sequence"),
        ({"pairs": ((0, -1),)}, "pairs must hold camera indices >= 0 or names"),
        ({"fft_size": (480,)}, r"fft_size must be \(height, width\)"),
        ({"fft_size": (600, 800), "correlation": "filter2d"}, "fft_size applies to the FFT correlations only"),
        ({"pixel_sigma_px": -1.0}, "pixel_sigma_px must be a positive number"),
    ],
)
def test_options_reject_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RTBlobOptions(**kwargs)


def test_options_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        RTBlobOptions().min_score = 0.0


def test_detector_rejects_bad_construction():
    with pytest.raises(ValueError, match=r"fft_size \(300, 300\) is too small for 640x480"):
        RTBlobDetector((W, H), 4.0, RTBlobOptions(correlation="scipy", fft_size=(300, 300)))
    with pytest.raises(ValueError, match="radius_px must be a number >= 1, got 0.5"):
        RTBlobDetector((W, H), 0.5)
    with pytest.raises(ValueError, match=r"image_size must be \(width, height\)"):
        RTBlobDetector((W, H, 3), 4.0)
    with pytest.raises(ValueError, match="options must be RTBlobOptions"):
        RTBlobDetector((W, H), 4.0, {"min_score": 0.1})


def test_tracker_rejects_bad_construction(rig):
    two = rig.subset(["cam0", "cam1"])
    with pytest.raises(ValueError, match=r"refer to camera 2 but the rig has 2 cameras \['cam0', 'cam1'\]"):
        RTBlobTracker(two)
    with pytest.raises(ValueError, match=r"unknown camera 'cam9'; this rig has"):
        RTBlobTracker(rig, RTBlobOptions(pairs=(("cam0", "cam9"),)))
    with pytest.raises(ValueError, match="template_radius_px has 2 radii for a rig of 4 cameras"):
        RTBlobTracker(rig, RTBlobOptions(template_radius_px=(4.0, 5.0)))
    with pytest.raises(ValueError, match=r"ball would be 0.40 px in camera 'cam0' at expected_distance_m=30"):
        RTBlobTracker(rig, RTBlobOptions(expected_distance_m=30.0))
    with pytest.raises(ValueError, match="rig must be a tracker.Rig"):
        RTBlobTracker("lab4_vga.yaml")


def test_tracker_rejects_bad_frame_sets(rig, backgrounds):
    tracker = RTBlobTracker(rig)
    images = list(render(rig, backgrounds, [ball()]))
    with pytest.raises(ValueError, match="frameset must be a tracker.FrameSet"):
        tracker.process(tuple(images))
    with pytest.raises(ValueError, match="frameset.t_s must be a finite number of seconds, got nan"):
        tracker.process(FrameSet(float("nan"), tuple(images)))
    with pytest.raises(ValueError, match=r"one image \(or None\) per camera, 4 for .*got 3 images"):
        tracker.process(FrameSet(0.0, tuple(images[:3])))
    images[1] = images[1].astype(np.float32)
    with pytest.raises(ValueError, match=r"frameset.images\[1\] \(camera 'cam1'\) must have dtype uint8"):
        tracker.process(FrameSet(0.0, tuple(images)))


def test_missing_and_wrong_size_frames_are_skipped_and_flagged(rig, backgrounds):
    images = list(render(rig, backgrounds, [ball()]))
    images[0] = None
    images[3] = cv2.resize(images[3], (320, 240))
    obs = RTBlobTracker(rig).process(FrameSet(0.0, tuple(images)))
    assert obs.status is Status.TOO_FEW_OBSERVATIONS and obs.position_m is None and obs.support == 0
    assert obs.covariance_m2 is None and not obs.inliers.any()
    assert obs.notes[0] == "camera cam0: no frame"
    assert obs.notes[1].startswith("camera cam3: frameset.images[3] (camera 'cam3') is 320x240 px")
    assert obs.notes[1].endswith("skipped")
    assert np.isfinite(obs.uv_px[[1, 2]]).all() and np.isnan(obs.uv_px[[0, 3]]).all()


# -- accuracy on the synthetic scene --------------------------------------------------------------------
@pytest.mark.parametrize("subpixel, tol_px", [("none", 0.75), ("parabola", 0.2)])
def test_detector_finds_the_disk_centre(backgrounds, subpixel, tol_px):
    rng = np.random.default_rng(6)
    det = RTBlobDetector((W, H), 4.0, RTBlobOptions(subpixel=subpixel))
    for _ in range(12):
        uv_true = rng.uniform([10, 10], [W - 10, H - 10])
        img = backgrounds[0].copy()
        draw_disk(img, uv_true, rng.uniform(3.5, 4.5), BALL_RGB)
        uv, score = det.detect(img)
        assert np.linalg.norm(uv - uv_true) < tol_px and score > 0.5


def test_tracker_position_within_two_centimetres(rig, backgrounds):
    rng = np.random.default_rng(7)
    tracker = RTBlobTracker(rig)
    for _ in range(6):
        X = rng.uniform([-0.5, -0.5, 0.85], [1.2, 0.5, 1.4])
        obs = tracker.process(FrameSet(0.0, render(rig, backgrounds, [ball(X)])))
        assert obs.support == 4 and np.linalg.norm(obs.position_m - X) < 0.02


def test_nothing_orange_reports_nothing(rig, backgrounds):
    obs = RTBlobTracker(rig).process(FrameSet(0.0, tuple(b.copy() for b in backgrounds)))
    assert obs.status is Status.TOO_FEW_OBSERVATIONS and obs.position_m is None
    assert len(obs.notes) == 4 and all("no ball (peak" in n and "< min_score 0.2" in n for n in obs.notes)


# -- the published failure modes ---------------------------------------------------------------------------
def test_a_wrong_object_in_one_camera_moves_one_pair_unchecked(rig, backgrounds):
    """One camera picks another orange object: its pair moves, the other does not, nothing is flagged."""
    clean_obs = RTBlobTracker(rig).process(FrameSet(0.0, render(rig, backgrounds, [ball()])))
    distractor = (BALL_M + [0.0, 0.0, 0.5], 0.03, DISTRACTOR_RGB, (0,))  # e.g. something 50 cm above
    obs, info = RTBlobTracker(rig).process_with_info(FrameSet(0.0, render(rig, backgrounds, [ball(), distractor])))
    err_a, err_b = np.linalg.norm(info.pair_positions_m - BALL_M, axis=1)
    err = np.linalg.norm(obs.position_m - BALL_M)
    clean = np.linalg.norm(clean_obs.position_m - BALL_M)
    assert err_b < 0.02 and err_a > 0.4
    assert err > 10 * clean and err > 0.2  # the mean inherits half of pair A's error
    assert obs.status is Status.OK and obs.support == 4 and obs.notes == ()  # reported with full support
    # ...although the wrong pair is plainly inconsistent: its point reprojects far from the pixels used
    reproj = np.stack([rig[i].project(info.pair_positions_m[0]) for i in (0, 1)])
    assert np.linalg.norm(reproj - obs.uv_px[:2], axis=1).min() > 20.0


def test_a_pair_that_sees_another_object_gives_the_published_25_to_30_cm_mode(rig, backgrounds):
    """Both cameras of one pair pick a second ball 0.55 m away: the mean is off by half of that."""
    other = BALL_M + np.array([0.0, -0.45, 0.3162])  # 0.55 m from the ball
    distractor = (other, 0.03, DISTRACTOR_RGB, (0, 1))
    obs, info = RTBlobTracker(rig).process_with_info(FrameSet(0.0, render(rig, backgrounds, [ball(), distractor])))
    assert np.linalg.norm(info.pair_positions_m[0] - other) < 0.02
    assert np.linalg.norm(info.pair_positions_m[1] - BALL_M) < 0.02
    assert 0.25 <= np.linalg.norm(obs.position_m - BALL_M) <= 0.30
    assert obs.status is Status.OK and obs.support == 4


def test_wrong_pixels_in_one_camera_give_rare_errors_of_metres():
    """Statistical: a uniformly random wrong pixel in cam0 (seeded). Pair B stays exact; the mean's
    error is never small, typically tens of cm and sometimes metres (RT2 paper, Sec. 3.2, reports
    errors of tens of metres at ~0.1 %; how far depends on the solver and the geometry)."""
    rig = make_rig()
    rng = np.random.default_rng(8)
    err_mean, err_b = [], []
    for _ in range(300):
        X = rng.uniform([-0.5, -0.5, 0.85], [1.2, 0.5, 1.4])
        uv = rig.project(X)
        uv[0] = rng.uniform([0, 0], [W - 1, H - 1])
        X_pairs = triangulate_fixed_pairs(rig, uv, PAIRS)
        err_mean.append(np.linalg.norm(X_pairs.mean(axis=0) - X))
        err_b.append(np.linalg.norm(X_pairs[1] - X))
    err_mean = np.array(err_mean)
    assert max(err_b) < 1e-9
    assert np.mean(err_mean < 0.02) < 0.02 and np.median(err_mean) > 0.3
    assert 0.05 < np.mean(err_mean > 1.0) < 0.5
    assert err_mean.max() > 3.0


# -- statistical check of the covariance ------------------------------------------------------------------------
def test_pair_covariance_matches_the_scatter_of_noisy_triangulations():
    """Eq. (5): with 1 px Gaussian pixel noise, the squared Mahalanobis error is chi^2 with 3 dof."""
    rig = make_rig()
    rng = np.random.default_rng(9)
    d2 = []
    for _ in range(300):
        X = rng.uniform([-0.5, -0.5, 0.85], [1.2, 0.5, 1.4])
        X_pairs = triangulate_fixed_pairs(rig, rig.project(X) + rng.normal(0.0, 1.0, (4, 2)), PAIRS)
        C = pair_covariances(rig, X_pairs, PAIRS, 1.0)
        d2 += [(X_pairs[k] - X) @ np.linalg.solve(C[k], X_pairs[k] - X) for k in range(2)]
    assert 2.7 < np.mean(d2) < 3.3  # E[chi^2_3] = 3; sd of the mean over 600 draws ~ 0.1
    assert 0.9 < np.mean(np.array(d2) < 7.815) < 0.98  # the chi^2_3 95% quantile


def test_triangulation_is_exact_without_noise_and_nan_where_a_pixel_is_missing():
    rig = make_rig()
    X = np.array([0.2, -0.3, 1.1])
    uv = rig.project(X)
    uv[3] = np.nan
    X_pairs = triangulate_fixed_pairs(rig, uv, PAIRS)
    assert np.abs(X_pairs[0] - X).max() < 1e-9 and np.isnan(X_pairs[1]).all()
    C = pair_covariances(rig, np.array([X, [0.3, 0.0, 5.0]]), PAIRS, 1.0)  # 2nd point: above (behind) the cameras
    assert np.isfinite(C[0]).all() and np.allclose(C[0], C[0].T) and np.isnan(C[1]).all()


# -- real data: the ewand recordings (cogsys-tuebingen/ewand, Apache-2.0) ------------------------------------
def test_fixed_pairs_reproduce_the_ewand_wand_spacings(ewand_dir, ewand_rig):
    """Four real calibrated cameras watching a 3-ball wand (balls 130 mm and 260 mm apart): each fixed
    pair, triangulated alone from the lab's own detections, reproduces the spacings to ~2 mm, and the
    two pairs' positions of the same ball differ by a couple of cm, which RTBlob never checks."""
    tables = [np.loadtxt(ewand_dir / f"frame_{i}.csv", delimiter=";") for i in range(4)]
    t_common = sorted(set.intersection(*(set(t[:, 0]) for t in tables)))[::3]
    rows = [t[np.searchsorted(t[:, 0], t_common)] for t in tables]
    uv = np.stack([r[:, 1:].reshape(-1, 3, 2) for r in rows], axis=1)  # (frames, cams, balls, 2)
    uv[uv < 0] = np.nan  # -1: not detected
    X = np.stack([[triangulate_fixed_pairs(ewand_rig, uv[f, :, b], PAIRS) for b in range(3)] for f in range(len(uv))])
    d12 = np.nanmedian(np.linalg.norm(X[:, 0] - X[:, 1], axis=-1), axis=0)  # per pair
    d23 = np.nanmedian(np.linalg.norm(X[:, 1] - X[:, 2], axis=-1), axis=0)
    assert np.abs(d12 - 0.130).max() < 0.002 and np.abs(d23 - 0.260).max() < 0.003
    gap = np.linalg.norm(X[:, :, 0] - X[:, :, 1], axis=-1)
    assert np.isfinite(gap).sum() > 300 and 0.005 < np.nanmedian(gap) < 0.03


# -- the benchmark command (runs; its timings are not asserted) -------------------------------------------------
def test_bench_command_prints_a_table_and_writes_json(tmp_path, capsys):
    from harness.cli import main

    out = tmp_path / "rtblob.json"
    assert main(["bench", "rtblob", "--repeats", "1", "--radius-px", "4", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["stage"] for r in rows] == ["likelihood"] * 2 + ["detect"] * len(CORRELATION_METHODS) + ["process"]
    assert all(r["median_ms"] > 0 for r in rows)
    assert "frame sets per second" in capsys.readouterr().out
    assert main(["bench", "rtblob", "--repeats", "0"]) == 2
