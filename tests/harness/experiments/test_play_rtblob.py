"""RTBlob set up for the playing sessions (harness/experiments/play/rtblob_setup.py) and the play scene presets (harness/experiments/play/play_scene.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from harness.sim import lab
from harness.experiments.play.rtblob_setup import calibrate_rtblob, choose_pairs, tune_colour
from harness.experiments.play.play_scene import DISTRACTORS, SCENES, PlayScene, PlaySceneOptions


@dataclass
class _Truth:  # the fields of harness.sim.render.BallTruth that the calibration reads
    center_px: np.ndarray
    diameter_px: float
    visibility: float = 1.0


def _floor_image(rng, ball_uv, size=(160, 120)):
    """The lab's hard case for an RGB distance: a reddish-brown wooden floor with a lit patch (lower right), and a
    small shaded dark-orange ball (radius 2.5 px, centre (125, 53, 8), darker to its rim)."""
    w, h = size
    img = np.clip(rng.normal([91, 59, 55], 6, size=(h, w, 3)), 0, 255)
    yy, xx = np.mgrid[0:h, 0:w]
    lit = (xx > 100) & (yy > 80)
    img[lit] = np.clip(rng.normal([112, 62, 42], 6, size=img[lit].shape), 0, 255)
    d = np.hypot(xx - ball_uv[0], yy - ball_uv[1])
    shade = np.clip(1.0 - 0.6 * (d / 2.5) ** 2, 0.4, 1.0)[..., None]
    ball = d <= 2.5
    img[ball] = (np.array([125.0, 53.0, 8.0]) * shade)[ball]
    return img.astype(np.uint8)


# -- smoke / shapes ----------------------------------------------------------------------------------
def test_pairs_follow_the_cameras_not_their_order():
    rig = lab.lab4_vga_rig()
    pairs = choose_pairs(rig, lab.LAB4_WORKSPACE_M)
    assert sorted(map(sorted, pairs)) == [[0, 1], [2, 3]]  # the lab is numbered by RTBlob pair
    shuffled = rig.subset(["cam0", "cam2", "cam1", "cam3"])
    assert sorted(map(sorted, choose_pairs(shuffled, lab.LAB4_WORKSPACE_M))) == [[0, 2], [1, 3]]


def test_scene_presets():
    assert set(SCENES) == {"default", "second_ball", "harsh", "clean"}
    assert SCENES["default"].p_orange_held_ball == 0.0 and SCENES["second_ball"].p_orange_held_ball == 1.0
    orange = {k for k, (_, colour, _) in DISTRACTORS.items() if colour != "white"}
    assert not orange & set(SCENES["default"].distractors) and "orange" not in SCENES["default"].shirts
    assert orange <= set(SCENES["harsh"].distractors) and "orange" in SCENES["harsh"].shirts
    assert not SCENES["clean"].person and SCENES["clean"].distractors == ()


# -- bad input -----------------------------------------------------------------------------------------
def test_bad_input():
    with pytest.raises(ValueError, match="RTBlob needs at least 2 cameras"):
        choose_pairs(lab.lab4_vga_rig().subset(["cam0"]), lab.LAB4_WORKSPACE_M)
    from tracker.rig_files import resolve_rig

    with pytest.raises(ValueError, match="at most 8 cameras, the rig has 15"):
        choose_pairs(resolve_rig("sim_c15"), lab.LAB4_WORKSPACE_M)
    with pytest.raises(ValueError, match="tune_colour needs calibration samples and a grid, got 0 samples"):
        tune_colour([], (125.0, 53.0, 8.0), np.array([3.0]))
    with pytest.raises(ValueError, match=r"unknown PlaySceneOptions.distractors \['pink_cup'\]"):
        PlaySceneOptions(distractors=("pink_cup",))
    with pytest.raises(ValueError, match="p_orange_held_ball must be a probability"):
        PlaySceneOptions(p_orange_held_ball=1.5)
    with pytest.raises(ValueError, match="unknown PlaySceneOptions.shirts 'plaid'"):
        PlaySceneOptions(shirts=("plaid",))


# -- accuracy on a synthetic scene ----------------------------------------------------------------------
def test_tune_colour_picks_a_tolerance_under_which_the_ball_stands_out():
    rng = np.random.default_rng(0)
    samples = []
    for k in range(6):
        uv = rng.uniform([20, 20], [90, 70])
        samples.append((0, _floor_image(rng, uv), _Truth(uv, 5.0)))
    chosen, table = tune_colour(samples, (125.0, 53.0, 8.0), np.array([3.0]))
    by_key = {(s, sig): win for s, sig, win, *_ in table}
    assert by_key[("rgb", 0.25)] == 0.0  # the default tolerance: the lit floor beats the ball in every image
    assert by_key[(chosen["colour_space"], chosen["colour_sigma"])] == 1.0
    assert 0.0 < chosen["min_score"] < 1.0


def test_calibrated_rtblob_finds_a_still_ball_on_the_preview_rig():
    from harness.sim.render import Renderer
    from robot_models import WamKinematics
    from tracker import FrameSet, RTBlobTracker

    rig = lab.preview_rig()
    kin = WamKinematics.default()
    renderer = Renderer(rig, seed=0)
    opts = SCENES["clean"]
    options = calibrate_rtblob(rig, renderer, kin, opts, n_frames=4)
    assert options.pairs == ((0, 1),) and len(options.template_radius_px) == 2
    assert 3.0 < min(options.template_radius_px) and max(options.template_radius_px) < 7.0  # ~8-10 px balls
    r, g, b = options.reference_rgb
    assert r > g > b  # an orange
    tracker = RTBlobTracker(rig, options)
    X = np.array([-1.2, 0.05, 1.15])
    images = renderer.render(PlayScene(kin, opts, seed=99).scene_at(0, 0.0, kin.q_home, X, np.zeros(3)))
    obs = tracker.process(FrameSet(0.0, tuple(images)))
    assert obs.position_m is not None and np.linalg.norm(obs.position_m - X) < 0.01


# -- statistical checks with a seeded RNG ----------------------------------------------------------------
def test_orange_held_ball_share_follows_the_option():
    from robot_models import WamKinematics

    kin = WamKinematics.default()
    n = 300
    opts = PlaySceneOptions(p_orange_held_ball=0.2)
    held = [PlayScene(kin, opts, seed=np.random.SeedSequence([5, i])).held_ball for i in range(n)]
    share = np.mean([h == "orange" for h in held])
    assert abs(share - 0.2) < 4 * np.sqrt(0.2 * 0.8 / n)
    a = PlayScene(kin, SCENES["harsh"], seed=3)
    b = PlayScene(kin, SCENES["harsh"], seed=3)
    assert a.shirt == b.shirt and a.held_ball == b.held_ball  # same seed, same scene
    assert all(np.array_equal(x.centre_m, y.centre_m) for x, y in zip(a.distractors, b.distractors))
