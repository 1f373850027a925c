"""The scripted teacher: its racket passes the requested hitting point at the requested time with the
requested velocity and normal, within the WAM's limits, reproducibly for a seed; and the shipped
hitting primitive learned from it.

Sections: smoke, shapes, accuracy on requested hits, limits, determinism / variability (seeded),
bad input, the shipped primitive (data/promp/wam_hitting.npz).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from policies.promp_demos import HitDistribution, collect_demonstrations
from policies.promp import ProMP
from policies.teacher import Demonstration, ScriptedTeacher, TeacherOptions, racket_kinematics

SHIPPED = Path(__file__).resolve().parents[2] / "data" / "promp" / "wam_hitting.npz"
X_HIT = np.array([-1.35, 0.25, 1.05])
NORMAL = np.array([1.0, -0.1, 0.2]) / np.linalg.norm([1.0, -0.1, 0.2])
V_HIT = np.array([1.6, 0.1, 0.3])


@pytest.fixture(scope="module")
def kin():
    from robot_models import WamKinematics

    return WamKinematics.default()


@pytest.fixture(scope="module")
def teacher(kin):
    return ScriptedTeacher(kin)


@pytest.fixture(scope="module")
def demo(teacher):
    return teacher.demonstrate(X_HIT, 1.1, NORMAL, V_HIT, np.random.default_rng(0))


def _hit_index(d: Demonstration) -> int:
    i = int(np.argmin(np.abs(d.t_s - d.t_hit_s)))
    assert d.t_s[i] == d.t_hit_s  # the hitting time is a sample time
    return i


# ----------------------------------------------------------------------------- smoke / shapes
def test_smoke_and_shapes(demo, teacher):
    n = len(demo.t_s)
    assert demo.q.shape == demo.qd.shape == (n, 7)
    assert np.all(np.diff(demo.t_s) > 0) and demo.t_s[0] == 0.0
    assert demo.knots_s.shape == (5,) and demo.knots_s[2] == pytest.approx(1.1)
    assert 0.2 < demo.hit_phase < 0.6
    assert teacher.robot_id == "wam7" and len(teacher.joint_names) == 7
    assert np.median(np.diff(demo.t_s)) == pytest.approx(1 / 200)


# ----------------------------------------------------------------------------- accuracy
def test_racket_passes_hitting_point_at_hitting_time(demo, kin):
    fk, jac = racket_kinematics(kin)
    i = _hit_index(demo)
    np.testing.assert_allclose(fk(demo.q_hit), X_HIT, atol=2e-4)  # IK tolerance 0.1 mm
    # the recorded trajectory (encoder noise 0.5 mrad) passes within a few mm
    assert np.linalg.norm(fk(demo.q[i]) - X_HIT) < 5e-3
    np.testing.assert_allclose(demo.q[i], demo.q_hit, atol=5 * TeacherOptions().encoder_noise_rad)
    np.testing.assert_allclose(jac(demo.q_hit) @ demo.qd[i], V_HIT, atol=1e-6)
    fk6, _ = racket_kinematics(kin, with_normal=True)
    assert fk6(demo.q_hit)[3:] @ NORMAL > np.cos(np.radians(0.2))


def test_movement_starts_and_ends_at_rest_near_home(demo, kin):
    std = TeacherOptions().rest_std_rad
    np.testing.assert_allclose(demo.qd[[0, -1]], 0.0, atol=1e-9)
    assert np.abs(demo.q[0] - kin.q_home).max() < 5 * std
    assert np.abs(demo.q[-1] - kin.q_home).max() < 5 * std


def test_within_joint_velocity_and_acceleration_limits(demo, kin):
    assert kin.within_limits(demo.q, tol_rad=1e-3).all()
    margin = TeacherOptions().limit_margin
    assert (np.abs(demo.qd) <= margin * kin.qdot_max + 1e-9).all()
    acc = np.gradient(demo.qd, demo.t_s, axis=0)
    assert (np.abs(acc) <= 1.02 * margin * kin.qddot_max).all()


def test_racket_kinematics_jacobians_match_finite_differences(kin):
    q = np.array(kin.q_home) + 0.1
    for with_normal in (False, True):
        fk, jac = racket_kinematics(kin, with_normal=with_normal)
        J = jac(q)
        h = 1e-6
        fd = np.array([(fk(q + h * e) - fk(q - h * e)) / (2 * h) for e in np.eye(7)]).T
        np.testing.assert_allclose(J, fd, atol=1e-6)


def test_many_requests_meet_their_hits(teacher, kin):
    fk, jac = racket_kinematics(kin)
    demos, rejected, reasons = collect_demonstrations(teacher, 6, np.random.default_rng(3), progress=False)
    assert len(demos) == 6 and rejected == sum(reasons.values())
    for d in demos:
        i = _hit_index(d)
        assert np.linalg.norm(fk(d.q_hit) - d.x_hit_m) < 2e-4
        np.testing.assert_allclose(jac(d.q_hit) @ d.qd[i], d.v_hit_m_s, atol=1e-6)
        assert kin.within_limits(d.q, tol_rad=1e-3).all()
        lo, hi = np.array([HitDistribution().x_m, HitDistribution().y_m, HitDistribution().z_m]).T
        assert (d.x_hit_m >= lo).all() and (d.x_hit_m <= hi).all()


# ----------------------------------------------------------------------------- determinism / variability
def test_same_seed_same_demonstration(teacher, demo):
    again = teacher.demonstrate(X_HIT, 1.1, NORMAL, V_HIT, np.random.default_rng(0))
    np.testing.assert_array_equal(again.q, demo.q)
    np.testing.assert_array_equal(again.t_s, demo.t_s)
    a = collect_demonstrations(teacher, 2, np.random.default_rng(9), progress=False)[0]
    b = collect_demonstrations(teacher, 2, np.random.default_rng(9), progress=False)[0]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.q, y.q)


def test_human_variability_between_seeds(teacher, demo):
    others = [teacher.demonstrate(X_HIT, 1.1, NORMAL, V_HIT, np.random.default_rng(s)) for s in (1, 2)]
    for d in others:
        assert d.duration_s != demo.duration_s  # timing habits vary
        assert 1e-4 < np.abs(d.q_hit - demo.q_hit).max() < 0.5  # same style, slightly different posture


# ----------------------------------------------------------------------------- bad input
def test_bad_requests_raise(teacher):
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="x_hit_m must not contain NaN or inf"):
        teacher.demonstrate([np.nan, 0, 1], 1.0, NORMAL, V_HIT, rng)
    with pytest.raises(ValueError, match=r"x_hit_m must have shape \(3,\)"):
        teacher.demonstrate([-1.3, 0.0], 1.0, NORMAL, V_HIT, rng)
    with pytest.raises(ValueError, match="normal must be non-zero"):
        teacher.demonstrate(X_HIT, 1.0, np.zeros(3), V_HIT, rng)
    with pytest.raises(ValueError, match="t_hit_s must be finite and > 0"):
        teacher.demonstrate(X_HIT, -1.0, NORMAL, V_HIT, rng)
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        teacher.demonstrate(X_HIT, 1.0, NORMAL, V_HIT, 0)
    with pytest.raises(ValueError, match="unreachable"):
        teacher.demonstrate([0.5, 0.0, 1.0], 1.0, NORMAL, V_HIT, rng)
    with pytest.raises(ValueError, match="too short"):
        teacher.demonstrate(X_HIT, 0.15, NORMAL, V_HIT, rng)
    with pytest.raises(ValueError, match="above its limit"):
        teacher.demonstrate(X_HIT, 1.0, NORMAL, [25.0, 0.0, 0.0], rng)


def test_bad_options_raise():
    with pytest.raises(ValueError, match="TeacherOptions.rate_hz must be finite and > 0"):
        TeacherOptions(rate_hz=0)
    with pytest.raises(ValueError, match="backswing_frac < 1"):
        TeacherOptions(backswing_frac=1.5)
    with pytest.raises(ValueError, match=r"HitDistribution.y_m must be \(low, high\)"):
        HitDistribution(y_m=(0.7, -0.7))
    with pytest.raises(ValueError, match="n must be a non-negative integer"):
        collect_demonstrations(None, -1, np.random.default_rng(0))


def test_infeasible_distribution_reports_instead_of_looping(teacher):
    far = HitDistribution(x_m=(1.0, 1.2))  # the opponent's side: unreachable
    with pytest.raises(ValueError, match=r"only 0 of 2 demonstrations after 5 requests.*unreachable"):
        collect_demonstrations(teacher, 2, np.random.default_rng(0), far, max_attempts=5, progress=False)


# ----------------------------------------------------------------------------- the shipped primitive
def test_shipped_primitive_matches_the_robot_and_hits(kin):
    if not SHIPPED.is_file():
        pytest.skip(f"{SHIPPED} not generated (rt2 learn promp)")
    promp = ProMP.load(SHIPPED, robot_id="wam7", joint_names=kin.joint_names)
    meta = promp.metadata
    assert meta["made_by"] == "rt2 learn promp" and meta["n_demos"] >= 20
    fk, jac = racket_kinematics(kin)
    t_hit = 1.1
    duration = t_hit / meta["hit_phase_mean"]
    cond = promp.condition_on_task(t_hit, X_HIT, None, fk, jac, duration_s=duration)
    q_hit = cond.mean_trajectory([t_hit], duration_s=duration)[0][0]
    assert np.linalg.norm(fk(q_hit) - X_HIT) < 1e-3
    q0, _ = promp.mean_trajectory([0.0])
    assert np.abs(q0[0] - kin.q_home).max() < 0.05  # starts at the ready posture


def test_shipped_primitive_rejected_for_another_robot(tmp_path):
    if not SHIPPED.is_file():
        pytest.skip(f"{SHIPPED} not generated (rt2 learn promp)")
    with pytest.raises(ValueError, match=r"wam_hitting\.npz: field 'robot_id' is 'wam7' but 'kuka_iiwa' was expected"):
        ProMP.load(SHIPPED, robot_id="kuka_iiwa")
    with pytest.raises(ValueError, match=r"wam_hitting\.npz: field 'joint_names' lists 7 joints but 6 were expected"):
        ProMP.load(SHIPPED, n_dims=6)
