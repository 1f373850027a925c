"""Seeded ball-mount trajectories for the accuracy experiment: limits, box, determinism, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim.robot import SimulatedWam, SimWamOptions
from harness.sim.trajectories import BALL_BOX_WORLD_M, TrajectoryOptions, random_via_trajectory
from robot_models import WamKinematics


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


@pytest.fixture(scope="module")
def spline_and_quintic(kin):
    return {m: random_via_trajectory(kin, seed=3, options=TrajectoryOptions(n_via=5, method=m))
            for m in ("spline", "quintic")}


# -- smoke, shapes --------------------------------------------------------------------------------------
def test_shapes_and_sampling(kin, spline_and_quintic):
    for traj, info in spline_and_quintic.values():
        n = traj.t_s.shape[0]
        assert traj.q.shape == traj.qdot.shape == traj.qddot.shape == (n, 7)
        np.testing.assert_allclose(np.diff(traj.t_s)[:-1], 1 / 500)
        assert traj.t_s[0] == 0.0 and traj.duration_s == pytest.approx(info["knot_t_s"][-1])
        assert info["via_world_m"].shape == (5, 3) and info["via_q"].shape == (6, 7)
    assert spline_and_quintic["quintic"][1]["method"] == "quintic"
    assert spline_and_quintic["spline"][1]["method"] == "spline"  # seed 3 keeps the spline within limits and box


# -- accuracy: limits, box, consistency -----------------------------------------------------------------
def test_within_limits_and_starts_and_ends_at_rest(kin, spline_and_quintic):
    opts = TrajectoryOptions()
    for traj, info in spline_and_quintic.values():
        assert kin.within_limits(traj.q).all()
        assert (np.abs(traj.qdot) <= opts.speed_fraction * kin.qdot_max * (1 + 1e-6)).all()
        assert (np.abs(traj.qddot) <= opts.accel_fraction * kin.qddot_max * (1 + 1e-6)).all()
        np.testing.assert_allclose(traj.q[0], kin.q_home, atol=1e-12)
        np.testing.assert_allclose(traj.qdot[[0, -1]], 0, atol=1e-9)


def test_via_points_reached_and_path_in_box(kin, spline_and_quintic):
    box = np.asarray(BALL_BOX_WORLD_M)
    for traj, info in spline_and_quintic.values():
        P = kin.positions(traj.q)
        assert (P >= box[0] - 0.1 - 1e-9).all() and (P <= box[1] + 0.1 + 1e-9).all()
        assert info["max_box_excursion_m"] <= 0.1 + 1e-9
        # the trajectory passes through every via point at its knot time
        for k, p in enumerate(info["via_world_m"], start=1):
            i = int(np.argmin(np.abs(traj.t_s - info["knot_t_s"][k])))
            assert np.linalg.norm(P[i] - p) < 2e-3
            assert (p >= box[0]).all() and (p <= box[1]).all()
        # the ball sits on top of the flange: tool axis within the cone around +z at the via points
        zs = kin.fk_batch(info["via_q"][1:])[:, :3, 2]
        assert (zs[:, 2] >= np.cos(np.deg2rad(30)) - 1e-3).all()


def test_velocities_are_derivatives_of_positions(spline_and_quintic):
    for traj, _ in spline_and_quintic.values():
        dt = np.diff(traj.t_s)[:, None]
        np.testing.assert_allclose(np.diff(traj.q, axis=0) / dt, 0.5 * (traj.qdot[1:] + traj.qdot[:-1]), atol=2e-4)


def test_simulated_wam_follows_trajectory(kin, spline_and_quintic):
    traj, _ = spline_and_quintic["spline"]
    sim = SimulatedWam(kin, SimWamOptions(), seed=0)
    moved = traj.shifted(0.2)
    sim.command_trajectory(moved.t_s, moved.q, moved.qdot)
    s = sim.advance_to(moved.t_s[-1] + 0.3)
    err_m = np.linalg.norm(kin.positions(s.q_true) - kin.positions(s.q_ref), axis=1)
    assert err_m.max() < 0.01 and (sim.limit_ticks == 0).all()


# -- determinism -------------------------------------------------------------------------------------------
def test_same_seed_same_trajectory(kin):
    opts = TrajectoryOptions(n_via=3)
    a, ia = random_via_trajectory(kin, seed=5, options=opts)
    b, ib = random_via_trajectory(kin, seed=5, options=opts)
    c, _ = random_via_trajectory(kin, seed=6, options=opts)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(ia["via_world_m"], ib["via_world_m"])
    assert a.q.shape != c.q.shape or not np.array_equal(a.q, c.q)


# -- bad input ------------------------------------------------------------------------------------------------
def test_bad_input(kin):
    with pytest.raises(ValueError, match=r"box_world_m must be \[\[min x, y, z\], \[max x, y, z\]\] with min < max"):
        random_via_trajectory(kin, [[0, 0, 1], [0, 1, 2]])
    with pytest.raises(ValueError, match=r"unknown trajectory method 'bezier'; valid: \['spline', 'quintic'\]"):
        TrajectoryOptions(method="bezier")
    with pytest.raises(ValueError, match="speed_fraction must be in"):
        TrajectoryOptions(speed_fraction=1.5)
    with pytest.raises(ValueError, match="unknown frame 'paddle'"):
        random_via_trajectory(kin, options=TrajectoryOptions(frame="paddle"))
    with pytest.raises(ValueError, match=r"only 0 of 2 via points reachable in box"):
        random_via_trajectory(kin, [[1.0, -0.2, 1.0], [1.2, 0.2, 1.2]], seed=0,  # beyond the net: out of reach
                              options=TrajectoryOptions(n_via=2, tries_per_via=2))


def test_spline_leaving_limits_or_box_falls_back_to_quintic(kin):
    traj, info = random_via_trajectory(kin, seed=2, options=TrajectoryOptions(n_via=5))  # spline asked for
    assert info["method"] == "quintic"
    assert kin.within_limits(traj.q).all() and info["max_box_excursion_m"] <= 0.1 + 1e-9
