"""Semi-real caliscope sequences with real white balls (harness.sim.real_balls, harness.sim.semireal with
real_balls, rt2 eval framesets --ball white, rt2 sim dataset --scene caliscope): the real rally balls pasted at
the projection of their known 3D position (within 0.5 px) at the size of their depth, smeared along the
projected flight; flights over the session's real frames in time order; seeded bytes; hostile inputs.
Skipped where ../shared/data/real is absent."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from harness.sim.real_balls import RealBalls, lens_valid
from harness.sim.render.scene_state import Ball
from harness.sim.semireal import SemiRealOptions, SemiRealSession, session_rig

CROPS = "40:52"  # a few rally balls: cutting all 83 takes a while


@pytest.fixture(scope="module")
def folder(real_data):
    return real_data / "caliscope_4cam"


@pytest.fixture(scope="module")
def rally(real_data):
    return real_data / "phone_rally"


@pytest.fixture(scope="module")
def real_balls(rally):
    return RealBalls(rally, CROPS)


@pytest.fixture(scope="module")
def session(folder, rally):
    return SemiRealSession(folder, SemiRealOptions(ball_colour="white", real_balls=rally, crop_frames=CROPS, backgrounds=2), seed=0)


def centroid(a):
    v, u = np.mgrid[0:a.shape[0], 0:a.shape[1]]
    return np.array([(a * u).sum(), (a * v).sum()]) / a.sum()


def test_pasted_where_the_camera_sees_the_ball(session, real_balls):
    rng = np.random.default_rng(0)
    lo, hi = session.rig.workspace_m
    checked = 0
    for trial in range(12):
        p = rng.uniform(lo, hi)
        v = rng.normal(0, 4.0, 3)
        look = real_balls.choose(float("nan"), rng)
        for i, cam in enumerate(session.rig):
            ball = Ball(position_m=p, velocity_mps=v, colour="white")
            T = 0.02  # a long shutter: a smear worth checking
            img, truth, alpha = real_balls.paste(session._frames[session.frame_indices[0]][i], cam, ball, T, look, rng)
            if not truth.visible or truth.visibility < 0.999:
                continue
            assert np.allclose(truth.center_px, cam.project(p))
            assert np.abs(centroid(alpha) - cam.project(p)).max() < 0.5  # the pasted ball's centre is the projection
            assert truth.diameter_px == pytest.approx(2 * cam.K[0, 0] * 0.02 / cam.depth(p[None])[0], rel=0.15)
            smear, d = RealBalls.smear_px(cam, ball, T)
            if np.hypot(*smear) > 0.8 * d:  # the matte's long axis lies along the projected flight
                a = alpha
                vv, uu = np.mgrid[0:a.shape[0], 0:a.shape[1]]
                c = centroid(a)
                du, dv = uu - c[0], vv - c[1]
                cov = np.array([[(a * du * du).sum(), (a * du * dv).sum()], [(a * du * dv).sum(), (a * dv * dv).sum()]])
                axis = np.linalg.eigh(cov)[1][:, 1]
                assert abs(axis @ smear) / np.hypot(*smear) > math.cos(math.radians(10))
            changed = np.abs(img.astype(int) - session._frames[session.frame_indices[0]][i].astype(int)).sum(axis=2) > 0
            assert np.array_equal(changed, changed & (alpha > 0))  # nothing but the ball changed
            checked += 1
    assert checked >= 12


def test_a_camera_that_cannot_see_the_ball_gets_none(session, real_balls):
    cam = session.rig[0]
    behind = cam.center_world - 0.5 * cam.R_world_to_cam[2]  # half a metre behind the camera
    assert not lens_valid(cam, behind[None], 0.02)
    img, truth, alpha = real_balls.paste(session._frames[session.frame_indices[0]][0], cam, Ball(position_m=behind, colour="white"),
                                         0.002, real_balls.choose(0.1, np.random.default_rng(0)), np.random.default_rng(0))
    assert truth.visibility == 0 and not alpha.any() and np.array_equal(img, session._frames[session.frame_indices[0]][0])


def test_flights_run_over_the_real_frames_in_time_order_seeded(folder, rally, session):
    flight = session.flight(3, 6, 100.0)
    k0, P, _ = flight
    sets = [session.flight_frameset(3, j, flight, crop=True) for j in range(6)]
    assert [s[3] for s in sets] == list(range(k0, k0 + 6))  # the backgrounds move in time order
    assert all(s[4] is not None and s[4] in {c.source for c in session.real.crops} for s in sets)
    for j, (images, truths, balls, k, _) in enumerate(sets):
        assert np.array_equal(balls[0], P[j])
        for cam, (t,) in zip(session.rig, truths):
            if t.visible:
                assert np.allclose(t.center_px, cam.project(P[j]))
    again = SemiRealSession(folder, SemiRealOptions(ball_colour="white", real_balls=rally, crop_frames=CROPS, backgrounds=2), seed=0)
    assert all(np.array_equal(a, b) for a, b in zip(sets[2][0], again.flight_frameset(3, 2, again.flight(3, 6, 100.0))[0]))
    other = SemiRealSession(folder, SemiRealOptions(ball_colour="white", real_balls=rally, crop_frames=CROPS, backgrounds=2), seed=1)
    assert not np.array_equal(other.flight(3, 6, 100.0)[1], P)
    with pytest.raises(ValueError, match="needs as many of the session's frame sets"):
        session.flight(0, 49, 100.0)


def test_options_refuse_what_does_not_fit(rally):
    with pytest.raises(ValueError, match="ball_colour must be 'white'"):
        SemiRealOptions(real_balls=rally)
    with pytest.raises(ValueError, match="crop_frames chooses among real_balls"):
        SemiRealOptions(crop_frames="0:5")
    assert SemiRealOptions(ball_colour="white", real_balls=rally).moving and not SemiRealOptions().moving


def test_dataset_of_sequences_same_seed_same_bytes(folder, rally, tmp_path, capsys):
    from harness.cli import main

    args = ["sim", "dataset", "--scene", "caliscope", "--ball", "white", "--frames", "4", "--flight-frames", "2", "--seed", "5",
            "--session", str(folder), "--crop-frames", CROPS]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "b").iterdir()) and len(files) == 17
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    data = json.loads((tmp_path / "a" / "annotations.json").read_text())
    rig = session_rig(folder)
    assert [im["camera"] for im in data["images"]] == rig.names * 4
    assert [im["frame"] for im in data["images"]] == [0] * 4 + [1] * 4 + [2] * 4 + [3] * 4  # time order
    assert data["info"]["ball"] == "white" and data["info"]["crops"]["frames"] == CROPS
    session = SemiRealSession(folder, SemiRealOptions(ball_colour="white", real_balls=rally, crop_frames=CROPS, backgrounds=2), seed=5)
    images = {im["id"]: im for im in data["images"]}
    assert data["annotations"]
    for a in data["annotations"]:
        im = images[a["image_id"]]
        P = session.flight(im["flight"], 2, 100.0)[1]
        cam = rig[rig.names.index(im["camera"])]
        assert np.abs(np.array(a["center_px"]) - cam.project(P[im["flight_frame"]])).max() < 1e-6
        assert "crop" in a and a["crop"].startswith("images/") and a["ball_colour"] == "white"
    bad = (
        (["--ball", "red"], "invalid choice: 'red'"),
        (["--session", str(tmp_path / "none")], "no camera_array.toml"),
        (["--flight-frames", "60"], "has 48"),
        (["--ball-crops", str(tmp_path)], "no COCO annotations.json"),
    )
    capsys.readouterr()
    for extra, message in bad:
        code = None
        try:
            code = main([*args, *extra, "--out", str(tmp_path / "c")])
        except SystemExit as exc:  # argparse's own refusal
            code = exc.code
        assert code == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
    assert not (tmp_path / "c" / "annotations.json").exists()
    for extra, message in ((["--crop-frames", "0:5"], "--crop-frames applies to --scene caliscope only"),
                           (["--ball-crops", str(tmp_path)], "--ball-crops applies to --scene caliscope only")):
        assert main(["sim", "dataset", "--frames", "1", "--out", str(tmp_path / "d"), *extra]) == 2
        assert message in capsys.readouterr().err


def test_eval_framesets_white_same_seed_same_figures(folder, tmp_path, capsys):
    from harness.cli import main

    args = ["eval", "framesets", "--scene", "caliscope", "--ball", "white", "--frames", "4", "--flight-frames", "2", "--seed", "0",
            "--backgrounds", "2", "--session", str(folder), "--crop-frames", CROPS, "--trackers", "rt2", "rt2-paper"]
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main([*args, "--json", str(a)]) == 0
    assert "real white balls cut from" in capsys.readouterr().out
    assert main([*args, "--json", str(b)]) == 0
    rows = json.loads(a.read_text())
    assert rows == json.loads(b.read_text()) and [r["framesets"] for r in rows] == [4, 4]
    bad = (
        (["--ball-colour", "orange"], "--ball white and --ball-colour orange disagree"),
        (["--crop-frames", "x"], "--crop-frames must be START:STOP"),
        (["--flight-frames", "60"], "has 48"),
    )
    capsys.readouterr()
    for extra, message in bad:
        assert main([*args, *extra]) == 2
        assert message in capsys.readouterr().err
    assert main(["eval", "framesets", "--scene", "lab", "--ball", "white", "--frames", "1"]) == 2
    assert "--ball applies to --scene caliscope only" in capsys.readouterr().err
    assert main(["eval", "framesets", "--scene", "caliscope", "--ball", "orange", "--crop-frames", "0:5", "--frames", "1"]) == 2
    assert "--crop-frames applies to --ball white only" in capsys.readouterr().err


def test_the_shipped_white_model_tracks_held_out_balls_in_held_out_cameras(folder, tmp_path):
    """Figures, not plumbing (README Results, "Real white balls with the learned stage"): the shipped white model in
    the rt2 tracker on 48 semi-real frame sets (two flights of 24 at 100 Hz, seed 5) of the caliscope session, with
    the rally's held-out balls (58:); cameras 2-3 and these balls were never trained on. Measured 2026-11-28 with the
    centres refined on the ball's edge: a position in 93.8 % of the frame sets, none of the OK ones wrong, median
    0.12 cm (the network's own centres: 89.6 %, 0.58 cm). Bounds with slack for CPUs' float differences."""
    from harness.cli import main

    out = tmp_path / "fs.json"
    assert main(["eval", "framesets", "--scene", "caliscope", "--ball", "white", "--crop-frames", "58:", "--model",
                 "data/models/ball_seg_white.npz", "--ball-colour", "white", "--frames", "48", "--flight-frames", "24",
                 "--seed", "5", "--session", str(folder), "--trackers", "rt2", "rt2-motion", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["tracker"] for r in rows] == ["rt2", "rt2-motion"] and all(r["framesets"] == 48 for r in rows)
    for row in rows:  # rt2-motion (the motion cue; each flight preceded by the session's frame set before it): 95.8 %
        assert row["recall"] >= 0.85 and row["wrong_ok"] == 0 and row["median_error_cm"] <= 0.3
