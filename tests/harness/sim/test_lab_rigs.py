"""The simulated lab's larger rigs (harness.sim.lab_rigs): lab8_vga (eight VGA cameras) and lab9_ace (nine
1440x1080 cameras): the files equal the functions, the coverage the docs give, found by every ``--rig``,
rendered with the lab's distractors and tracked."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim import lab
from harness.sim.lab_rigs import LARGE_RIGS, lab8_vga_rig, lab9_ace_rig
from harness.sim.render import Ball, Renderer, RenderOptions, Scene
from harness.sim.render.placed_distractors import ACCURACY, DISTRACTORS, place_distractor
from harness.sim.render.scene_state import Box, Sphere
from tracker import Rig, Tracker
from tracker.observation import FrameSet, Status
from tracker.rig_files import RIGS_DIR, available_rigs, resolve_rig


# -- the files are the functions -------------------------------------------------------------------
@pytest.mark.parametrize("stem", sorted(LARGE_RIGS))
def test_rig_file_is_the_documented_function(stem):
    saved, built = Rig.load(RIGS_DIR / f"{stem}.yaml"), LARGE_RIGS[stem]()
    assert stem in available_rigs() and resolve_rig(stem).names == saved.names == built.names
    np.testing.assert_allclose(saved.workspace_m, lab.LAB4_WORKSPACE_M)
    for a, b in zip(saved, built):
        assert a.image_size == b.image_size
        for name in ("K", "distortion", "R_world_to_cam", "t_world_to_cam_m"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-12)
        assert 2.8 <= a.center_world[2] <= lab.CEILING_Z_M  # on the walls or the ceiling
        lo, hi = lab.ROOM_M
        assert (lo[:2] < a.center_world[:2]).all() and (a.center_world[:2] < hi[:2]).all()  # inside the room


def test_lab8_vga_keeps_lab4_vga_and_adds_four_vga_cameras():
    rig, four = lab8_vga_rig(), lab.lab4_vga_rig()
    assert len(rig) == 8 and rig.names[:4] == four.names
    for a, b in zip(rig, four):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.R_world_to_cam, b.R_world_to_cam)
    assert all(c.image_size == (640, 480) for c in rig)


def test_lab9_ace_has_nine_1440x1080_cameras():
    rig = lab9_ace_rig()
    assert len(rig) == 9 and all(c.image_size == (1440, 1080) for c in rig)


# -- coverage: what the docs say --------------------------------------------------------------------
def test_lab8_vga_sees_more_of_the_flight_than_lab4_vga():
    grid = lab.workspace_grid(step_m=0.1)
    eight, four = lab.coverage(lab8_vga_rig(), grid), lab.coverage(lab.lab4_vga_rig(), grid)
    assert eight.fraction_at_least(2) == 1.0
    assert eight.fraction_at_least(3) > four.fraction_at_least(3) and eight.fraction_at_least(3) > 0.96
    hit = lab.coverage(lab8_vga_rig(), lab.workspace_grid(lab.LAB4_HITTING_BOX_M, 0.05))
    assert hit.fraction_at_least(6) == 1.0 and hit.fraction_at_least(8) > 0.85
    assert (eight.diameter_px[eight.seen] >= 6.0).all()


def test_lab9_ace_sees_the_flight_with_three_or_more_cameras():
    cov = lab.coverage(lab9_ace_rig(), lab.workspace_grid(step_m=0.1))
    assert cov.fraction_at_least(3) == 1.0 and cov.fraction_at_least(5) > 0.9
    d = cov.diameter_px[cov.seen]
    assert d.min() >= 10.0 and 14.0 <= np.median(d) <= 20.0


# -- rendered with the lab's distractors, then tracked ----------------------------------------------
def _scene_with_distractors(X_ball, seed: int) -> Scene:
    rng = np.random.default_rng(seed)
    objects = [place_distractor(rng, name, ACCURACY) for name in DISTRACTORS]
    return Scene(balls=(Ball(X_ball, colour="orange"),), spheres=tuple(o for o in objects if isinstance(o, Sphere)),
                 boxes=tuple(o for o in objects if isinstance(o, Box)))


@pytest.fixture(scope="module")
def lab8_renderer():
    return Renderer(resolve_rig("lab8_vga"), RenderOptions(supersample=1), seed=0)  # the static lab ray-cast once per pixel: quicker


@pytest.mark.parametrize("stem, cameras", [("lab8_vga", None), ("lab9_ace", ["ace0", "ace4", "ace8"])])
def test_rendered_with_distractors_and_tracked(stem, cameras, lab8_renderer):
    rig = resolve_rig(stem)
    rig = rig if cameras is None else rig.subset(cameras)  # three of Ace's nine: each costs ~5 VGA images
    X = np.array([-1.3, 0.15, 1.15])  # in the hitting region
    renderer = lab8_renderer if stem == "lab8_vga" else Renderer(rig, RenderOptions(supersample=1), seed=0)
    images = renderer.render(_scene_with_distractors(X, seed=1))
    assert [im.shape for im in images] == [(c.image_size[1], c.image_size[0], 3) for c in rig]
    tracker = Tracker(rig, kind="rt2")
    obs = tracker.process(FrameSet(t_s=0.0, images=images))
    assert obs.status is Status.OK, obs.notes
    assert np.linalg.norm(obs.position_m - X) < 0.01
    assert obs.support >= len(rig) - 1


# -- the full-frame fallback on eight cameras: only the cameras that need it ---------------------------
def _track(renderer, positions, **options):
    tracker = Tracker(renderer.rig, kind="rt2", workers=2, **options)
    out = []
    for k, X in enumerate(positions):
        images = renderer.render(Scene(balls=(Ball(X, colour="orange"),), frame_index=k))
        searches = tracker.stats.full_frame_searches
        obs = tracker.process(FrameSet(t_s=k / 200, images=images))
        out.append((obs, tracker.stats.full_frame_searches - searches))
    tracker.close()
    return out


def test_fallback_searches_four_full_frames_and_windows_for_the_rest(lab8_renderer):
    """One track (no ball hypotheses): a ball 1 m from where the last one's motion says (a new serve). The
    windows miss it; the fallback searches the full frames of two batches of two cameras, confirms it with
    >= 3 of them and finds it in the other cameras' windows at its pixels; every camera in full at once
    finds the same."""
    v = np.array([-4.0, 0.3, 0.0])
    X0 = np.array([-0.9, 0.1, 1.2])
    positions = [X0 + v * k / 200 for k in range(8)] + [np.array([-1.6, -0.4, 1.0])]
    staged = _track(lab8_renderer, positions, hypotheses=None)
    at_once = _track(lab8_renderer, positions, hypotheses=None, retry_confirm_support=None)
    assert all(o.status is Status.OK for o, _ in staged[:-1])
    (obs, full), (obs_all, full_all) = staged[-1], at_once[-1]
    assert obs.status is obs_all.status is Status.OK, obs.notes
    assert full == 4 and full_all == 8
    assert any("windows at the ball found in" in n for n in obs.notes), obs.notes
    assert obs.support >= 7 and obs.support == obs_all.support
    np.testing.assert_allclose(obs.position_m, obs_all.position_m, atol=1e-3)
    assert np.linalg.norm(obs.position_m - positions[-1]) < 0.01


def test_fallback_searches_every_camera_for_a_new_ball_with_hypotheses(lab8_renderer):
    """The same new ball with the ball hypotheses (rt2's default): every camera's full frame, as they ask
    for it to see every ball in view; the next frame set's windows are where the new ball is (its motion
    starts anew, no velocity across the jump: no second fallback)."""
    v = np.array([-4.0, 0.3, 0.0])
    X0 = np.array([-0.9, 0.1, 1.2])
    X1 = np.array([-1.6, -0.4, 1.0])
    positions = [X0 + v * k / 200 for k in range(8)] + [X1, X1 + v / 200]
    (obs, full), (obs_next, full_next) = _track(lab8_renderer, positions)[-2:]
    assert obs.status is Status.OK and full == 8
    assert np.linalg.norm(obs.position_m - positions[-2]) < 0.01
    assert obs_next.status is Status.OK and full_next == 0, obs_next.notes
    assert np.linalg.norm(obs_next.position_m - positions[-1]) < 0.01
