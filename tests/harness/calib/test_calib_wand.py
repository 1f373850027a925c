"""Wand bundle adjustment (tracker.calibration.extrinsics, `rt2 calib wand`): synthetic truth, the real
ewand recording (github.com/cogsys-tuebingen/ewand, Apache-2.0), bad input."""

from __future__ import annotations

import numpy as np
import pytest

from harness.calib.compare import compare_to_truth
from harness.cli import main
from tracker.rig_files import resolve_rig
from tracker import Camera, Rig
from tracker.calibration.extrinsics import WandOptions, calibrate_wand, order_wand_points

OFFSETS = np.array([0.0, 0.13, 0.39])


def wand_views(rig, n_frames, rng, *, noise_px=0.2, planar=False):
    """Random wand poses in the rig's workspace -> (n_cams, F, 3, 2) pixels (NaN outside the image)."""
    lo, hi = rig.workspace_m if rig.workspace_m is not None else (np.array([-1, -1, 0.8]), np.array([1, 1, 1.8]))
    lo, hi = lo + 0.3, hi - 0.3
    X0 = rng.uniform(lo, hi, (n_frames, 3))
    u = rng.normal(size=(n_frames, 3))
    if planar:
        X0[:, 2] = 1.2
        u[:, 2] = 0.0
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    X = X0[:, None] + OFFSETS[None, :, None] * u[:, None]
    uv = rig.project(X.reshape(-1, 3)).reshape(len(rig), n_frames, 3, 2)
    uv = uv + rng.normal(0, noise_px, uv.shape)
    for c, cam in enumerate(rig):
        out = ~cam.in_image(uv[c].reshape(-1, 2)).reshape(n_frames, 3)
        uv[c][out] = np.nan
    return uv


def intrinsics_only(rig):
    return [Camera(c.name, c.K, c.distortion, np.eye(3), np.zeros(3), c.image_size) for c in rig]


# -- accuracy on a synthetic scene ------------------------------------------------------------------
def test_recovers_lab4_vga_poses_from_a_synthetic_wand():
    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 300, np.random.default_rng(0))
    res = calibrate_wand(intrinsics_only(truth), uv, OFFSETS)
    rig = Rig([Camera(c.name, c.K, c.distortion, res.R[i], res.t[i], c.image_size) for i, c in enumerate(truth)])
    cmp = compare_to_truth(rig, truth, align=True)
    assert cmp["worst"]["centre_mm"] < 3.0
    assert cmp["worst"]["rotation_deg"] < 0.05
    # the wand lengths scatter no more than the same detections triangulated with the true rig
    from harness.calib.compare import wand_lengths

    ref = wand_lengths(truth, uv[:, res.holdout_frames], OFFSETS)["ball1-ball3"]
    err = (res.total_m - 0.39) * 1000
    assert np.nanstd(err) < 1.1 * ref["error_std"] and abs(np.nanmean(err)) < 0.3
    for r in res.reproj_px.values():
        assert r["median_px"] < 0.4


def test_order_wand_points_labels_by_spacing():
    uv = np.array([[10.0, 10.0], [10.0, 140.0], [10.0, 400.0]])  # 130 : 260
    assert np.allclose(order_wand_points(uv[::-1], OFFSETS), uv)
    assert np.allclose(order_wand_points(uv[[1, 2, 0]], OFFSETS), uv)
    assert np.isnan(order_wand_points(uv[:2], OFFSETS)).all()


# -- bad input ----------------------------------------------------------------------------------------
def test_planar_wand_motion_is_refused():
    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 150, np.random.default_rng(1), planar=True)
    with pytest.raises(ValueError, match="degenerate"):
        calibrate_wand(intrinsics_only(truth), uv, OFFSETS)


def test_camera_sharing_no_view_is_named():
    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 150, np.random.default_rng(2))
    uv[3, :, :, :] = np.nan
    uv[3, :60] = uv[0, :60]  # cam3 "sees" only frames nobody else... made disjoint below
    uv[[0, 1, 2], :60] = np.nan
    with pytest.raises(ValueError, match=r"\['cam3'\] share no usable view"):
        calibrate_wand(intrinsics_only(truth), uv, OFFSETS, WandOptions(min_camera_obs=30))


def test_too_few_detections_name_the_camera():
    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 150, np.random.default_rng(3))
    uv[2, 5:] = np.nan
    with pytest.raises(ValueError, match="camera cam2: only"):
        calibrate_wand(intrinsics_only(truth), uv, OFFSETS)


def test_cli_bad_wand_writes_nothing(tmp_path, ewand_dir, capsys):
    out = tmp_path / "rig.yaml"
    yamls = [str(p) for p in sorted(ewand_dir.glob("frame_*.yaml"))]
    code = main(["calib", "wand", "--recording", str(ewand_dir), "--intrinsics", *yamls, "--wand", "0.13", "--out", str(out)])
    assert code == 2 and not out.exists()
    assert "hold 3 balls per row but --wand describes 2" in capsys.readouterr().err
    code = main(["calib", "wand", "--recording", str(ewand_dir), "--intrinsics", *yamls, "--wand=-1,2", "--out", str(out)])
    assert code == 2 and not out.exists()
    assert "--wand spacings must be positive" in capsys.readouterr().err


# -- real data: ewand -------------------------------------------------------------------------------
def test_ewand_real_wand_reproduces_lengths_and_shipped_geometry(tmp_path, ewand_dir, ewand_rig, capsys):
    """Every 2nd frame set (fast): the held-out wand lengths within 1 mm of 130 / 390 mm, the relative
    rotations within 0.4 deg and baselines within 1 % of the shipped calibration."""
    yamls = [str(p) for p in sorted(ewand_dir.glob("frame_*.yaml"))]
    out = tmp_path / "ewand.yaml"
    code = main(["calib", "wand", "--recording", str(ewand_dir), "--intrinsics", *yamls, "--wand", "0.13,0.26",
                 "--every", "2", "--out", str(out), "--reference", *yamls, "--opencv-dir", str(tmp_path / "ocv"),
                 "--anipose-toml", str(tmp_path / "calibration.toml")])
    assert code == 0, capsys.readouterr().err
    import json

    rep = json.loads(out.with_suffix(".report.json").read_text())
    w = rep["holdout_wand_mm"]
    assert abs(w["ball1-ball2"]["median"] - 130) < 1.0 and abs(w["ball1-ball3"]["median"] - 390) < 1.0
    for d in rep["reference"]["pairs"].values():
        assert d["rotation_deg"] < 0.4
        assert abs(d["baseline_m"] / d["baseline_ref_m"] - 1) < 0.01
    rig = Rig.load(out)
    from harness.calib.exports import read_anipose_toml

    back = read_anipose_toml(tmp_path / "calibration.toml")
    assert np.allclose(back.stacked()["center"], rig.stacked()["center"], atol=1e-9)
    ocv = Rig.from_opencv_files(sorted((tmp_path / "ocv").glob("*.yaml")), length_unit_m=0.001)
    assert np.allclose(ocv.stacked()["P"], rig.stacked()["P"], atol=1e-9)


def test_same_seed_same_result(ewand_dir):
    from harness.calib.inputs import load_intrinsics, read_detection_csvs
    import cv2

    cams = load_intrinsics(sorted(ewand_dir.glob("frame_*.yaml")))
    _, uv = read_detection_csvs(sorted(ewand_dir.glob("frame_*.csv")))
    uv = uv[:, ::4]
    runs = []
    for _ in range(2):
        cv2.setRNGSeed(5)
        runs.append(calibrate_wand(cams, uv, OFFSETS))
    assert np.array_equal(runs[0].R, runs[1].R) and np.array_equal(runs[0].t, runs[1].t)


def test_calibrate_recording_from_python_matches_the_cli_and_repeats_with_its_seed(tmp_path, ewand_dir):
    """harness.calib.wand.calibrate_recording is rt2 calib wand's work: same rig and report as the command
    wrote, the same again for the same seed, and nothing written by the function itself."""
    import json

    from harness.calib.wand import calibrate_recording

    yamls = [str(p) for p in sorted(ewand_dir.glob("frame_*.yaml"))]
    out = tmp_path / "cli.yaml"
    assert main(["calib", "wand", "--recording", str(ewand_dir), "--intrinsics", *yamls, "--wand", "0.13,0.26",
                 "--every", "4", "--seed", "3", "--out", str(out)]) == 0
    before = set(tmp_path.iterdir())
    cals = [calibrate_recording(ewand_dir, yamls, wand="0.13,0.26", every=4, seed=3) for _ in range(2)]
    assert set(tmp_path.iterdir()) == before
    for a, b in ((cals[0].rig, cals[1].rig), (cals[0].rig, Rig.load(out))):
        assert np.allclose(a.stacked()["P"], b.stacked()["P"], rtol=0, atol=1e-9)
    assert cals[0].report["holdout_wand_mm"] == cals[1].report["holdout_wand_mm"]
    written = json.loads(out.with_suffix(".report.json").read_text())
    assert written["fit_frames"] == cals[0].report["fit_frames"] and written["cameras"] == cals[0].rig.names
    assert cals[0].world_residual_m is None
    assert cals[0].error_px == pytest.approx(np.mean([v["rms_px"] for v in cals[0].report["reprojection_px"].values()]))


def test_calibrate_recording_bad_options_name_the_option(ewand_dir):
    from harness.calib.wand import calibrate_recording

    yamls = sorted(ewand_dir.glob("frame_*.yaml"))
    with pytest.raises(ValueError, match="either --wand"):
        calibrate_recording(ewand_dir, yamls)
    with pytest.raises(ValueError, match="--ball needs --world-points"):
        calibrate_recording(ewand_dir, yamls, ball=True)
    with pytest.raises(ValueError, match="--every must be >= 1, got 0"):
        calibrate_recording(ewand_dir, yamls, wand="0.13,0.26", every=0)


def test_wand_from_a_session_log_with_unlabelled_detections(tmp_path):
    """Detections as a tracker logs them (unordered, per camera) -> labelled along the wand -> calibrated."""
    from harness.logs.writer import SessionLogWriter

    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 200, np.random.default_rng(4), noise_px=0.1)
    rng = np.random.default_rng(5)
    log = tmp_path / "wand.mcap"
    w = SessionLogWriter(log, metadata={"kind": "calibration", "seed": 4}, log_images="none")
    for f in range(uv.shape[1]):
        for c, name in enumerate(truth.names):
            pts = uv[c, f][~np.isnan(uv[c, f]).any(axis=1)]
            pts = pts[rng.permutation(len(pts))]
            w.write_detections(f * 0.01, name, pts, np.ones(len(pts)), f)
    w.close()
    intr = tmp_path / "intrinsics.yaml"
    Rig(intrinsics_only(truth)).save(intr)
    out = tmp_path / "rig.yaml"
    assert main(["calib", "wand", "--recording", str(log), "--intrinsics", str(intr), "--wand", "0.13,0.26", "--out", str(out)]) == 0
    rig = Rig.load(out)
    assert compare_to_truth(rig, truth, align=True)["worst"]["centre_mm"] < 3.0


def test_single_ball_with_world_points(tmp_path):
    """--ball: one ball, no length in it; the table corners (clicked = projected + 0.2 px) give scale and frame."""
    import yaml

    from harness.calib.check import TABLE_CORNERS_M

    truth = resolve_rig("lab4_vga")
    uv = wand_views(truth, 300, np.random.default_rng(6), noise_px=0.15)[:, :, :1]
    csvs = tmp_path / "det"
    csvs.mkdir()
    for c, name in enumerate(truth.names):
        rows = [f"{f * 1000};{u:.4f};{v:.4f}" if np.isfinite(u) else f"{f * 1000};-1;-1" for f, (u, v) in enumerate(uv[c, :, 0])]
        (csvs / f"{c}_{name}.csv").write_text("\n".join(rows) + "\n")
    click = truth.project(TABLE_CORNERS_M) + np.random.default_rng(7).normal(0, 0.2, (4, 4, 2))
    points = [{"world_m": X.tolist(), "pixels": {n: click[c, k].tolist() for c, n in enumerate(truth.names)
                                                 if truth[c].in_image(click[c, k][None])[0]}} for k, X in enumerate(TABLE_CORNERS_M)]
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(points))
    intr = tmp_path / "intrinsics.yaml"
    Rig(intrinsics_only(truth)).save(intr)
    out = tmp_path / "rig.yaml"
    base = ["calib", "wand", "--recording", str(csvs), "--intrinsics", str(intr), "--out", str(out)]
    assert main(base + ["--ball"]) == 2 and not out.exists()  # no scale without world points
    assert main(base + ["--ball", "--world-points", str(tmp_path / "table.yaml")]) == 0
    cmp = compare_to_truth(Rig.load(out), truth)
    assert cmp["worst"]["centre_mm"] < 10 and cmp["worst"]["rotation_deg"] < 0.1


def test_detection_csvs_bad_input_is_named(tmp_path):
    from harness.calib.inputs import read_detection_csvs

    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("timestamp_ns;u1;v1\n1;10;20\n2;11;21\n")
    b.write_text("1;10;20;30;40\n")
    with pytest.raises(ValueError, match="disagree on the number of balls"):
        read_detection_csvs([a, b])
    b.write_text("1;10;20\n2;x;21\n")
    with pytest.raises(ValueError, match=r"b.csv: line 2 is not numbers"):
        read_detection_csvs([a, b])
    b.write_text("7;10;20\n")
    with pytest.raises(ValueError, match="share no timestamp"):
        read_detection_csvs([a, b])
    b.write_text("2;-1;-1\n1;5;6\n")
    ts, uv = read_detection_csvs([a, b])
    assert ts.tolist() == [1, 2] and np.isnan(uv[1, 1]).all() and uv[1, 0, 0].tolist() == [5, 6]


@pytest.mark.parametrize("row, needle", [
    ("nan;10;20", "line 3: timestamp 'nan' is not a whole number of ns"),
    ("NaN;10;20", "line 3: timestamp 'NaN' is not a whole number of ns"),
    (";10;20", "line 3: timestamp '' is not a whole number of ns"),
    ("1e30;10;20", "line 3: timestamp '1e30' does not fit a 64-bit time in ns"),
    ("inf;10;20", "line 3: timestamp 'inf' is not a whole number of ns"),
    ("-inf;10;20", "line 3: timestamp '-inf' is not a whole number of ns"),
    ("2.5;10;20", "line 3: timestamp '2.5' is not a whole number of ns"),
    ("9223372036854775808;10;20", "does not fit a 64-bit time"),
    ("3;inf;20", "line 3: pixel coordinate inf is not finite"),
    ("3;10;-inf", "line 3: pixel coordinate -inf is not finite"),
])
def test_detection_csvs_bad_timestamps_and_infinities_name_file_and_line(tmp_path, row, needle):
    """Never a silent cast to int64's minimum (and a pairing on it), never an array index: the file and line."""
    from harness.calib.inputs import read_detection_csvs

    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("1;10;20\n2;11;21\n")
    b.write_text(f"timestamp_ns;u1;v1\n1;10;20\n{row}\n")
    with pytest.raises(ValueError, match="b.csv: " + needle.replace("(", r"\(") if needle.startswith("line") else needle):
        read_detection_csvs([a, b])


def test_detection_csv_timestamps_are_exact_nanoseconds(tmp_path):
    from harness.calib.inputs import read_detection_csvs

    a = tmp_path / "a.csv"
    a.write_text("1732600000000000001;10;20\n1732600000000000002;11;21\n2e9;1;2\n")  # beyond float64's integers
    ts, uv = read_detection_csvs([a])
    assert ts.tolist() == [2_000_000_000, 1732600000000000001, 1732600000000000002]


def test_order_wand_points_ignores_extra_candidates():
    uv = np.array([[10.0, 10.0], [12.0, 140.0], [16.0, 400.0]])  # 130 : 260, a slightly slanted line
    noisy = np.vstack([uv, [[200.0, 50.0], [90.0, 300.0]]])[[3, 1, 4, 0, 2]]
    assert np.allclose(order_wand_points(noisy, OFFSETS), uv)
    assert np.isnan(order_wand_points(np.array([[0.0, 0], [50, 80], [300, 10], [120, 400]]), OFFSETS)).all()
