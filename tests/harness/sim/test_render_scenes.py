"""Random data-set scenes (harness.sim.render.scenes), the lab rig (harness.sim.lab) and the rig resolver."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim import lab
from harness.sim.render import Ball, Scene
from harness.sim.render.primitives import pack_scene
from harness.sim.render.scenes import SceneOptions, person, random_scene, robot_arm
from tracker.rig_files import RIGS_DIR, available_rigs, resolve_rig
from tracker import Rig


def _scenes(n, seed=0, options=None):
    return [random_scene(np.random.default_rng([seed, i]), lab.LAB4_WORKSPACE_M, options, frame_index=i) for i in range(n)]


# -- smoke / shapes --------------------------------------------------------------------------------
def test_random_scene_is_a_scene_with_a_ball_and_clutter():
    scenes = _scenes(20)
    assert all(isinstance(s, Scene) for s in scenes)
    assert [s.frame_index for s in scenes] == list(range(20))
    assert sum(len(s.capsules) > 0 for s in scenes) >= 15  # people and robots
    table, n_balls = pack_scene(scenes[0])
    assert table.shape[1] == 25 and n_balls == len(scenes[0].balls)


def test_person_and_robot_builders():
    rng = np.random.default_rng(0)
    caps, spheres, tip = person(rng, (-2.0, 1.2), hand_target=(-1.6, 0.8, 1.3))
    assert len(caps) == 9 and len(spheres) == 2
    assert np.linalg.norm(tip - [-1.6, 0.8, 1.3]) < 0.15  # the hand reaches its target
    caps, disks = robot_arm(rng, racket=True)
    assert len(disks) == 1 and np.allclose(caps[0].p0_m, lab.ROBOT_BASE_M)


# -- bad input -------------------------------------------------------------------------------------
def test_scene_options_validate():
    with pytest.raises(ValueError, match=r"SceneOptions.p_no_ball must be a probability in \[0, 1\], got 1.5"):
        SceneOptions(p_no_ball=1.5)
    with pytest.raises(ValueError, match="SceneOptions.brightness must be"):
        SceneOptions(brightness=(2.0, 1.0))
    with pytest.raises(ValueError, match="max_distractors must be a non-negative integer"):
        SceneOptions(max_distractors=-1)


def test_resolve_rig_by_name_path_and_unknown(tmp_path):
    assert "lab4_vga" in available_rigs()
    rig = resolve_rig("lab4_vga")
    assert rig.names == ["cam0", "cam1", "cam2", "cam3"]
    assert resolve_rig(str(RIGS_DIR / "lab4_vga.yaml")).names == rig.names
    assert resolve_rig("lab4_vga.yaml").names == rig.names
    path = tmp_path / "mine.yaml"
    lab.preview_rig().save(path)
    assert resolve_rig(path).names == ["cam0", "cam1"]
    with pytest.raises(ValueError, match=r"unknown rig 'lab5'.*available: \[.*'lab4_vga'"):
        resolve_rig("lab5")
    with pytest.raises(ValueError, match="is a folder"):
        resolve_rig(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: nope\n")
    with pytest.raises(ValueError, match="field 'format' must be 'rt2.rig'"):
        resolve_rig(bad)


# -- accuracy: the lab rig ---------------------------------------------------------------------------
def test_lab4_vga_file_is_the_documented_function():
    saved, built = Rig.load(RIGS_DIR / "lab4_vga.yaml"), lab.lab4_vga_rig()
    assert saved.names == built.names
    np.testing.assert_allclose(saved.workspace_m, lab.LAB4_WORKSPACE_M)
    for a, b in zip(saved, built):
        assert a.image_size == b.image_size == (640, 480)
        for name in ("K", "distortion", "R_world_to_cam", "t_world_to_cam_m"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-12)
        assert -0.2 <= a.distortion[0] <= -0.1 and a.distortion_model == "plumb_bob"
        assert 2.8 <= a.center_world[2] <= 3.2  # on the ceiling


def test_lab4_vga_sees_the_whole_flight_and_the_hitting_region_with_three_or_four_cameras():
    from harness.sim.trajectories import BALL_BOX_WORLD_M

    rig = lab.lab4_vga_rig()
    cov = lab.coverage(rig, lab.workspace_grid(step_m=0.1))
    assert cov.fraction_at_least(2) == 1.0  # the whole flight, launcher to behind the robot, by >= 2 cameras, ball >= 6 px
    assert cov.fraction_at_least(3) > 0.9
    assert lab.LAB4_WORKSPACE_M[0, 0] <= -2.3 and lab.LAB4_WORKSPACE_M[1, 0] >= 2.0  # launcher at x 1.6-2.0
    hit = lab.coverage(rig, lab.workspace_grid(lab.LAB4_HITTING_BOX_M, 0.05))
    assert hit.fraction_at_least(3) == 1.0 and hit.fraction_at_least(4) > 0.9
    assert lab.coverage(rig, lab.workspace_grid(BALL_BOX_WORLD_M, 0.05)).fraction_at_least(4) == 1.0
    assert lab.coverage(rig, lab.workspace_grid(lab.LAB4_LAUNCHER_BOX_M, 0.1)).fraction_at_least(2) == 1.0
    assert (cov.diameter_px[cov.seen] >= 6.0).all()
    r = lab.coverage_report(rig, lab.LAB4_HITTING_BOX_M)
    assert r["triangulation_std_mm"][1] < 3.0 and r["pair_any"] == 1.0  # RTBlob's pairs 0+1, 2+3


def test_triangulation_std_matches_a_monte_carlo_triangulation():
    """The first-order std of :func:`lab.triangulation_std_m` against triangulating noisy pixels (seeded)."""
    from tracker.triangulation import triangulate_pairs

    rig = lab.lab4_vga_rig().subset(["cam1", "cam3"])
    X = np.array([[-1.3, 0.1, 1.2]])
    cov = lab.coverage(rig, X)
    want = lab.triangulation_std_m(rig, X, cov.seen, pixel_sigma_px=0.5)[0]
    rng = np.random.default_rng(0)
    n = 2000
    xn = [c.undistort(c.project(X)[0] + 0.5 * rng.standard_normal((n, 2))) for c in rig]  # (n, 2) per camera
    P = rig.stacked()["P"]
    est = triangulate_pairs(xn[0], xn[1], P[0], P[1])
    worst = np.sqrt(np.linalg.eigvalsh(np.cov((est - X).T))[-1])
    assert worst == pytest.approx(want, rel=0.15)
    assert lab.triangulation_std_m(rig, np.array([[9.0, 0.0, 1.0]]), np.zeros((2, 1), bool))[0] == np.inf


# -- statistical checks with a seeded RNG ----------------------------------------------------------
def test_same_generator_state_same_scene():
    a, b = _scenes(5, seed=3), _scenes(5, seed=3)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(pack_scene(x)[0], pack_scene(y)[0])
        assert x.exposure == y.exposure
    c = _scenes(5, seed=4)
    assert not all(np.array_equal(pack_scene(x)[0], pack_scene(y)[0]) for x, y in zip(a, c))


def test_scene_statistics_follow_the_options():
    n = 400
    scenes = _scenes(n, seed=1)
    opts = SceneOptions()
    no_ball = np.mean([len(s.balls) == 0 for s in scenes])
    assert abs(no_ball - opts.p_no_ball) < 3 * np.sqrt(opts.p_no_ball * (1 - opts.p_no_ball) / n)
    firsts = [s.balls[0] for s in scenes if s.balls]
    white = np.mean([np.allclose(b.colour, Ball([0, 0, 1], colour="white").colour) for b in firsts])
    assert abs(white - opts.p_white) < 0.08
    speeds = np.array([np.linalg.norm(b.velocity_mps) for b in firsts])
    assert speeds.max() <= opts.max_speed_mps + 1e-9 and (speeds > 3).mean() > 0.2 and (speeds < 1).mean() > 0.2
    brightness = np.array([s.exposure.light_level * s.exposure.gain * s.exposure.exposure_s / 0.002 for s in scenes])
    assert brightness.min() >= 0.5 * opts.brightness[0] and np.median(brightness) == pytest.approx(np.mean(opts.brightness), rel=0.2)
    never = _scenes(50, seed=2, options=SceneOptions(p_no_ball=1.0))
    assert all(len(s.balls) == 0 for s in never)


def test_the_two_distractor_placements_are_the_documented_ones():
    from harness.sim.render.placed_distractors import ACCURACY, DISTRACTORS, PLAY, place_distractor
    from harness.sim.render.scene_state import Box, Sphere

    for placement, ring, radius in ((ACCURACY, (0.6, 1.4), (0.05, 0.07)), (PLAY, (0.7, 1.4), (0.03, 0.045))):
        rng = np.random.default_rng(0)
        for _ in range(200):
            for name, (shape, colour, where) in DISTRACTORS.items():
                obj = place_distractor(rng, name, placement)
                assert isinstance(obj, Sphere if shape == "sphere" else Box)
                if where == "floor":
                    d = np.linalg.norm(obj.centre_m[:2] - lab.ROBOT_BASE_M[:2])
                    assert ring[0] <= d <= ring[1] and obj.centre_m[2] < 0.5
                else:
                    assert -1.25 <= obj.centre_m[0] <= -0.2 and obj.centre_m[2] > lab.TABLE_TOP_Z_M
                if shape == "sphere":
                    assert radius[0] <= obj.radius_m <= radius[1]
                if name == "white_box" and placement is PLAY:
                    assert obj.size_m[2] == 0.15
        again = place_distractor(np.random.default_rng(5), "white_box", placement)
        assert np.array_equal(again.centre_m, place_distractor(np.random.default_rng(5), "white_box", placement).centre_m)
    # the same seed puts a floor object elsewhere under the two placements (distance and angle drawn in turn)
    a = place_distractor(np.random.default_rng(1), "orange_box", ACCURACY).centre_m
    b = place_distractor(np.random.default_rng(1), "orange_box", PLAY).centre_m
    assert not np.allclose(a, b)
