"""The auto labels of a smeared ball: its centre from its grey silhouette (``harness.experiments.autolabel.silhouette``),
and each kept position smoothed along its flight (``consensus.smoothed``); hostile inputs to both."""

from __future__ import annotations

import numpy as np
import pytest

from harness.experiments.autolabel.consensus import AutoOptions, FrameSetLabels, moved, smoothed
from harness.experiments.autolabel.silhouette import silhouette_centre
from tracker.detection.synthetic import draw_disk


def _background(h=160, w=200, seed=0):
    """A textured grey background: noise and a slow ramp (a real wall is not flat)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    return np.clip(90 + 0.15 * xx + 0.1 * yy + rng.normal(0, 4, (h, w)), 0, 255)[..., None].repeat(3, axis=2)


def _smeared(bg, centre, d, smear_px, angle_deg, colour=(235, 235, 228), n=24, shading=0.0):
    """``bg`` with a ball of diameter ``d`` swept over ``smear_px`` along ``angle_deg`` about ``centre`` (its mid-exposure
    position: by symmetry the matte's centroid), each instant's disk ``2 shading`` darker on its -u side than its +u side."""
    e = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    alpha = np.zeros(bg.shape[:2])
    ball = np.zeros(bg.shape)
    xx = np.mgrid[0:bg.shape[0], 0:bg.shape[1]][1]
    for s in np.linspace(-0.5, 0.5, n) * smear_px:
        p = np.asarray(centre, float) + s * e
        cover = np.zeros(bg.shape, np.uint8)
        draw_disk(cover, p, d, (255, 255, 255))
        a = cover[..., 0] / 255.0 / n
        shade = 1.0 - shading + shading * np.clip((xx - p[0]) / (d / 2), -1, 1)
        alpha += a
        ball += (a * shade)[..., None] * np.asarray(colour, float)
    return np.clip(bg * (1 - alpha[..., None]) + ball + 0.5, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("d, smear, angle, shading", [(24.0, 24.0, 20.0, 0.0), (36.0, 40.0, -60.0, 0.0), (18.0, 0.0, 0.0, 0.0),
                                                      (50.0, 55.0, 135.0, 0.0), (18.0, 0.0, 0.0, 0.08)])
def test_a_smeared_ball_is_centred_at_the_middle_of_its_smear(d, smear, angle, shading):
    """On a textured wall with a slope of light, the silhouette's centroid lands on the middle of the smear from a start
    a quarter diameter off along it; the circle of the edge fit slides towards one end of a smear longer than the
    ball (the reason for the silhouette). (A ball shaded along its smear pulls the silhouette towards its lit end:
    the module docstring's figures.)"""
    from tracker.detection.edge_refine import refine_edges

    c = np.array([101.3, 79.6])
    img = _smeared(_background(), c, d, smear, angle, shading=shading)
    e = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    start = c + 0.25 * d * e
    got = silhouette_centre(img, start, d)
    assert got is not None and np.linalg.norm(got - c) < 0.5, got
    if smear > d:
        edge, _, ok = refine_edges(img, start[None], np.array([d]))
        assert not ok[0] or np.linalg.norm(edge[0] - c) > 2 * np.linalg.norm(got - c)


def test_the_white_models_centring_uses_the_silhouette_then_the_edge():
    from harness.experiments.autolabel.consensus import centring
    from tracker.pipeline import load_model

    c, d = np.array([101.3, 79.6]), 30.0
    img = _smeared(_background(), c, d, 30.0, 10.0)
    centre = centring(load_model("data/models/ball_seg_white.npz"))
    assert np.linalg.norm(centre(img, c + [5.0, 1.0], d) - c) < 0.5
    # where the silhouette merges with a bright bar, the edge fit answers (a circle near the ball, not None)
    barred = img.copy()
    barred[75:85, 100:200] = 240
    assert silhouette_centre(barred, c, d) is None
    got = centre(barred, c, d)
    assert got is None or np.linalg.norm(got - c) < d / 2


def _no_ball_cases():
    bg = _background().astype(np.uint8)
    c, d = np.array([101.3, 79.6]), 30.0
    ball = _smeared(_background(), c, d, 0.0, 0.0)
    corner = _smeared(_background(), np.array([4.0, 5.0]), d, 0.0, 0.0)
    faint = _smeared(_background(), c, d, 0.0, 0.0, colour=(118, 118, 118))  # the wall there: ~113 + a slope
    huge = _smeared(_background(), c, 3 * d, 0.0, 0.0)
    return [
        ("no ball: background only", bg, c, d),
        ("no contrast: the ball as grey as the wall", faint, c, d),
        ("cut by the image's border", corner, np.array([4.0, 5.0]), d),
        ("a blob three times too wide", huge, c, d),
        ("NaN centre", ball, np.array([np.nan, 79.6]), d),
        ("infinite diameter", ball, c, np.inf),
        ("a diameter under 2 px", ball, c, 1.0),
        ("centre far outside the image", ball, np.array([-500.0, 1e6]), d),
        ("a 3x3 image", ball[:3, :3], np.array([1.0, 1.0]), d),
    ]


@pytest.mark.parametrize("name, image, uv, d", _no_ball_cases(), ids=[c[0] for c in _no_ball_cases()])
def test_no_clear_silhouette_is_none_never_a_wrong_centre(name, image, uv, d):
    assert silhouette_centre(image, uv, d) is None


# -- the flight's smoothing ------------------------------------------------------------------------------------
def _labels(P, t, index):
    """FrameSetLabels at positions ``P`` (n, 3) and times ``t`` (no camera: only the positions matter here)."""
    return [FrameSetLabels(int(i), int(i), float(ti), np.asarray(p, float), 3, 0.5, np.ones(0, bool), np.zeros(0),
                           np.zeros((0, 2)), np.zeros(0), 0.9, ()) for p, ti, i in zip(P, t, index)]


def _flight(n=20, rate=100.0, bounce_at=None, t0=0.0, seed=0, noise_m=0.001):
    t = t0 + np.arange(n) / rate
    v, g = np.array([3.0, 0.5, -1.5]), np.array([0.0, 0.0, -9.81])
    tt = t - t0
    P = np.array([0.0, 1.0, 0.5]) + v * tt[:, None] + 0.5 * g * tt[:, None] ** 2
    if bounce_at is not None:  # on the table at frame bounce_at: the vertical velocity (-3 m/s) turns, 0.9 x as fast
        tb = tt[bounce_at]
        vz = v[2] + g[2] * tb
        after = tt > tb
        P[after, 2] = P[bounce_at, 2] - 0.9 * vz * (tt[after] - tb) + 0.5 * g[2] * (tt[after] - tb) ** 2
    noisy = P + np.random.default_rng(seed).normal(0, noise_m, P.shape)
    return t, P, noisy


class _NoRig(list):
    """A rig without cameras (``moved`` projects into none)."""


def test_smoothing_brings_noisy_positions_closer_to_their_flight():
    t, P, noisy = _flight(40)
    out = smoothed(_labels(noisy, t, range(40)), _NoRig(), AutoOptions())
    raw = np.linalg.norm(noisy - P, axis=1)
    smooth = np.linalg.norm(np.array([f.position_m for f in out]) - P, axis=1)
    assert np.median(smooth) < 0.6 * np.median(raw) and smooth.max() < raw.max()
    assert [f.index for f in out] == list(range(40))
    off = smoothed(_labels(noisy, t, range(40)), _NoRig(), AutoOptions(smooth_window=0))
    assert all(np.array_equal(a.position_m, p) for a, p in zip(off, noisy))  # 0: off


def test_smoothing_never_crosses_a_bounce_a_pause_or_a_wrong_position():
    """A bounce on the table in the window (no parabola fits: the positions there stay), two flights 1 s apart (never
    one window), a position 1.5 cm off its flight (left out of its neighbours' fits; itself moved onto the flight)."""
    t, P, noisy = _flight(30, bounce_at=15)
    out = np.array([f.position_m for f in smoothed(_labels(noisy, t, range(30)), _NoRig(), AutoOptions())])
    assert np.linalg.norm(out - P, axis=1).max() <= np.linalg.norm(noisy - P, axis=1).max() + 1e-9

    t1, P1, n1 = _flight(12, seed=1)
    t2, P2, n2 = _flight(12, t0=t1[-1] + 1.0, seed=2)
    P2 += [0.0, 0.0, 0.3]  # the second flight is elsewhere: a window spanning both would not fit
    n2 += [0.0, 0.0, 0.3]
    out = smoothed(_labels(np.vstack([n1, n2]), np.r_[t1, t2], range(24)), _NoRig(), AutoOptions())
    err = np.linalg.norm(np.array([f.position_m for f in out]) - np.vstack([P1, P2]), axis=1)
    raw = np.linalg.norm(np.vstack([n1, n2]) - np.vstack([P1, P2]), axis=1)
    assert err.max() <= raw.max() and np.median(err) < 0.7 * np.median(raw)

    t, P, noisy = _flight(30, noise_m=0.0002)
    noisy[12] += [0.0, 0.015, 0.0]
    out = np.array([f.position_m for f in smoothed(_labels(noisy, t, range(30)), _NoRig(), AutoOptions())])
    err = np.linalg.norm(out - P, axis=1)
    assert err.max() < 0.001, err.round(4)  # the others not pulled towards it, itself moved onto the flight


def test_moved_labels_are_projected_again():
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    X = np.array([0.1, 0.4, 1.1])
    f = FrameSetLabels(0, 0, 0.0, X, 3, 0.5, np.ones(4, bool), np.zeros(4), np.zeros((4, 2)), np.zeros(4), 0.9, ((),) * 4)
    Y = X + [0.01, 0.0, 0.0]
    g = moved(f, Y, rig, AutoOptions())
    for j, cam in enumerate(rig):
        assert np.allclose(g.center_px[j], cam.project(Y[None])[0])
        assert g.diameter_px[j] == pytest.approx(0.04 * cam.K[0, 0] / cam.depth(Y[None])[0])
    assert g.support == 3 and g.confidence == 0.9 and np.array_equal(g.position_m, Y)


@pytest.mark.parametrize("value, message", [(-1, r"smooth_window must be an integer in \[0, 50\], got -1"),
                                            (51, r"got 51"), (2.5, r"got 2.5"), (True, r"got True"), ("8", r"got '8'")])
def test_hostile_smoothing_windows_are_refused(value, message):
    with pytest.raises(ValueError, match=message):
        AutoOptions(smooth_window=value)
    with pytest.raises(ValueError, match="smooth_max_rms_m"):
        AutoOptions(smooth_max_rms_m=float("nan"))
