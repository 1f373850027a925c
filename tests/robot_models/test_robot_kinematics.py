"""WAM URDF and kinematics: against an independent DH chain, finite differences, limits, bad input, IK reach."""

from __future__ import annotations

import dataclasses

import itertools
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from robot_models import LINK_CHAIN, REQUIRED_FRAMES, IkInfo, IkOptions, WamKinematics, mount_transform
from robot_models import _urdf_gen

URDF = Path(__file__).resolve().parents[2] / "robot_models" / "wam7.urdf"

# Barrett WAM user manual, standard DH (issue 5), typed here independently of robot_models/_urdf_gen.py
A_M = [0, 0, 0.045, -0.045, 0, 0, 0]
ALPHA = [-np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, 0]
D_M = [0, 0, 0.55, 0, 0.30, 0, 0.06]
SHOULDER_M = 0.346
Q_MIN = [-2.6, -2.0, -2.8, -0.9, -4.76, -1.6, -3.0]
Q_MAX = [2.6, 2.0, 2.8, 3.1, 1.24, 1.6, 3.0]
QDOT_MAX = [3.2, 6.3, 10, 10, 24, 19, 27]


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def dh_frames(q):
    """Independent standard-DH chain: dict frame name -> (4, 4) in the base frame."""
    T = _trans(0, 0, SHOULDER_M)  # DH frame 0
    out = {"base": np.eye(4)}
    for i in range(7):
        out[f"link_{i + 1}"] = T @ _rz(q[i])  # URDF link i = DH frame i-1 turned by theta_i
        T = T @ _rz(q[i]) @ _trans(0, 0, D_M[i]) @ _trans(A_M[i], 0, 0) @ _rx(ALPHA[i])
    out["flange"] = T
    out["ball_mount"] = T @ _trans(0, 0, 0.045)
    out["racket"] = T @ _trans(0, 0, 0.16) @ _ry(np.pi / 2)
    return out


@pytest.fixture(scope="module")
def kin_base():
    return WamKinematics.from_urdf(URDF)  # mount = identity: world = URDF base


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


def _random_q(kin, n, seed=0):
    return np.random.default_rng(seed).uniform(kin.q_min, kin.q_max, size=(n, 7))


# -- smoke -------------------------------------------------------------------------------------------
def test_default_model_loads_with_frames(kin):
    assert kin.n_joints == 7
    assert kin.joint_names == tuple(f"joint_{i}" for i in range(1, 8))
    for f in REQUIRED_FRAMES + LINK_CHAIN:
        assert f in kin.frame_names
    assert kin.fk(kin.q_home, "racket").shape == (4, 4)


def test_committed_urdf_is_generated_file():
    assert URDF.read_text() == _urdf_gen.urdf_text(), "run `python -m robot_models._urdf_gen` to regenerate"


# -- accuracy against the manual -----------------------------------------------------------------
def test_urdf_matches_independent_dh_chain(kin_base):
    for q in _random_q(kin_base, 40, seed=1):
        ref = dh_frames(q)
        for name, T_ref in ref.items():
            np.testing.assert_allclose(kin_base.fk(q, name), T_ref, atol=1e-9, err_msg=name)


def test_mount_is_applied_in_world(kin):
    T_mount = mount_transform((-1.75, 0.0, 0.70), (0.0, 0.0, 0.0))
    np.testing.assert_allclose(kin.T_base_to_world, T_mount)
    for q in _random_q(kin, 5, seed=2):
        np.testing.assert_allclose(kin.fk(q, "racket"), T_mount @ dh_frames(q)["racket"], atol=1e-9)


def test_mount_transform_matches_pinocchio_rpy():
    rpy = (0.3, -0.7, 2.1)
    np.testing.assert_allclose(mount_transform((1, 2, 3), rpy)[:3, :3], pin.rpy.rpyToMatrix(*rpy), atol=1e-12)


def test_limits_equal_the_manual(kin_base):
    np.testing.assert_array_equal(kin_base.q_min, Q_MIN)
    np.testing.assert_array_equal(kin_base.q_max, Q_MAX)
    np.testing.assert_array_equal(kin_base.model.velocityLimit, QDOT_MAX)  # URDF carries the defaults
    np.testing.assert_array_equal(kin_base.qdot_max, QDOT_MAX)


def test_jacobian_matches_finite_differences(kin):
    h = 1e-6
    for q in _random_q(kin, 5, seed=3) * 0.9:
        for frame in ("racket", "ball_mount"):
            T0 = kin.fk(q, frame)
            num = np.zeros((6, 7))
            num_local = np.zeros((6, 7))
            for j in range(7):
                dq = np.zeros(7)
                dq[j] = h
                Tp, Tm = kin.fk(q + dq, frame), kin.fk(q - dq, frame)
                num[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
                dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T0[:3, :3].T  # skew(omega) in world axes
                num[3:, j] = [dR[2, 1], dR[0, 2], dR[1, 0]]
                num_local[:3, j] = T0[:3, :3].T @ num[:3, j]
                num_local[3:, j] = T0[:3, :3].T @ num[3:, j]
            np.testing.assert_allclose(kin.jacobian(q, frame), num, atol=1e-7)
            np.testing.assert_allclose(kin.jacobian(q, frame, reference="local"), num_local, atol=1e-7)
            # spatial ("world") velocity: v_origin = v_point - omega x p
            Jw = kin.jacobian(q, frame, reference="world")
            np.testing.assert_allclose(Jw[3:], num[3:], atol=1e-7)
            np.testing.assert_allclose(Jw[:3], num[:3] - np.cross(num[3:].T, T0[:3, 3]).T, atol=1e-7)


# -- shapes and batching ------------------------------------------------------------------------------
def test_batched_fk_equals_single_and_pinocchio(kin):
    Q = _random_q(kin, 25, seed=4)
    for frame in ("ball_mount", "racket", "link_4"):
        single = np.stack([kin.fk(q, frame) for q in Q])
        np.testing.assert_allclose(kin.fk_batch(Q, frame), single, atol=1e-12)
        for method in ("numba", "numpy", "pinocchio"):
            np.testing.assert_allclose(kin.fk_batch(Q, frame, method=method), single, atol=1e-12)
        np.testing.assert_allclose(kin.positions(Q, frame), single[:, :3, 3], atol=1e-12)
    assert kin.fk_batch(Q[:0]).shape == (0, 4, 4)


def test_link_points_shapes_and_values(kin):
    Q = _random_q(kin, 6, seed=5)
    pts = kin.link_points(Q)
    assert pts.shape == (6, len(LINK_CHAIN), 3)
    assert kin.link_points(Q[0]).shape == (len(LINK_CHAIN), 3)
    assert kin.link_radii_m.shape == (len(LINK_CHAIN) - 1,)
    for k, name in enumerate(LINK_CHAIN):
        np.testing.assert_allclose(pts[:, k], kin.positions(Q, name), atol=1e-12)
    # segment lengths are the DH lengths whatever q: shoulder height, upper arm, forearm, flange
    seg = np.linalg.norm(np.diff(pts, axis=1), axis=2)
    np.testing.assert_allclose(seg[:, 0], SHOULDER_M)
    np.testing.assert_allclose(seg[:, 3], np.hypot(0.55, 0.045))
    np.testing.assert_allclose(seg[:, 5], 0.30)
    np.testing.assert_allclose(seg[:, 7], 0.06)


def test_within_limits_and_clip(kin):
    Q = np.stack([kin.q_home, kin.q_max + 0.1])
    np.testing.assert_array_equal(kin.within_limits(Q), [True, False])
    assert kin.within_limits(kin.q_home) is True
    np.testing.assert_allclose(kin.clip(Q)[1], kin.q_max)


# -- bad input -----------------------------------------------------------------------------------------
def test_urdf_without_named_frames_lists_frames_present(tmp_path):
    text = _urdf_gen.urdf_text()
    start = text.index('  <joint name="racket_joint"')
    stripped = text[:start] + "</robot>\n"
    path = tmp_path / "no_racket.urdf"
    path.write_text(stripped)
    with pytest.raises(ValueError, match=r"frame\(s\) \['racket'\] not found; frames present: .*'ball_mount'"):
        WamKinematics.from_urdf(path)
    assert "racket" not in WamKinematics.from_urdf(path, frames=("ball_mount",)).frame_names


def test_bad_urdf_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        WamKinematics.from_urdf(tmp_path / "nope.urdf")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(ValueError, match="bad.urdf: not a valid URDF"):
        WamKinematics.from_urdf(bad)


def test_wrong_q_length_and_values(kin):
    with pytest.raises(ValueError, match=r"q must have length 7 .*got shape \(6,\)"):
        kin.fk(np.zeros(6))
    with pytest.raises(ValueError, match=r"Q must have length 7 .*got shape \(3, 8\)"):
        kin.fk_batch(np.zeros((3, 8)))
    with pytest.raises(ValueError, match="must be finite"):
        kin.fk(np.full(7, np.nan))
    with pytest.raises(ValueError, match="one configuration"):
        kin.jacobian(np.zeros((2, 7)))


def test_out_of_limits_names_joint_and_limit(kin):
    q = kin.q_home.copy()
    q[3] = 3.5
    with pytest.raises(ValueError, match=r"joint_4 = 3.5 rad is outside its limits \[-0.9, 3.1\]"):
        kin.fk(q)
    Q = np.stack([kin.q_home, q])
    with pytest.raises(ValueError, match=r"Q \(row 1\): joint_4"):
        kin.fk_batch(Q)
    assert kin.fk(q, check_limits=False).shape == (4, 4)  # reported angles may carry a bias


def test_unknown_frame_method_reference(kin):
    with pytest.raises(ValueError, match=r"unknown frame 'paddle'; frames present: .*'racket'"):
        kin.fk(kin.q_home, "paddle")
    with pytest.raises(ValueError, match=r"unknown fk method 'cuda'; valid: \['numba', 'numpy', 'pinocchio'\]"):
        kin.fk_batch(kin.q_home[None], method="cuda")
    with pytest.raises(ValueError, match="unknown Jacobian reference 'body'"):
        kin.jacobian(kin.q_home, reference="body")


def test_bad_mount_and_ik_input(kin):
    with pytest.raises(ValueError, match="mount must be a"):
        WamKinematics.from_urdf(URDF, mount=np.ones((4, 4)))
    with pytest.raises(ValueError, match="position_world_m must be 3 finite numbers"):
        kin.ik([1.0, 2.0])
    with pytest.raises(ValueError, match="normal_world must be a non-zero 3-vector"):
        kin.ik([-1.3, 0, 1.1], normal_world=[0, 0, 0])
    with pytest.raises(ValueError, match="IkOptions.tol_m must be > 0"):
        IkOptions(tol_m=0)


# -- IK and reachability ----------------------------------------------------------------------------------
def test_ik_recovers_reachable_poses(kin):
    rng = np.random.default_rng(6)
    for q_true in _random_q(kin, 8, seed=7) * 0.8:
        T = kin.fk(q_true, "racket")
        q, info = kin.ik(T[:3, 3], "racket", normal_world=T[:3, 2], rng=rng)
        assert info.success, info
        T_sol = kin.fk(q, "racket")
        assert np.linalg.norm(T_sol[:3, 3] - T[:3, 3]) < 1e-4
        assert np.arccos(np.clip(T_sol[:3, 2] @ T[:3, 2], -1, 1)) < 1e-3
        assert kin.within_limits(q)


def test_hitting_region_reachable_with_racket_facing_opponent(kin):
    """Issue 5: the racket reaches x -1.6..-1.1, y -0.7..0.7, z 0.8..1.4 m facing the opponent's court."""
    target = np.array([0.685, 0.0, 0.91])
    pts = np.array(list(itertools.product([-1.6, -1.35, -1.1], [-0.7, -0.35, 0.0, 0.35, 0.7], [0.8, 1.1, 1.4])))
    rng = np.random.default_rng(8)
    failed = []
    for p in pts:
        q, info = kin.ik(p, "racket", normal_world=target - p, rng=rng)
        if not info.success:
            failed.append(p.tolist())
    assert not failed, f"unreachable hitting points: {failed}"


def test_ik_reports_failure_out_of_reach(kin):
    q, info = kin.ik([1.0, 0.0, 1.0], "racket", options=IkOptions(restarts=1, max_iters=50))  # 2.75 m away
    assert not info.success and info.pos_err_m > 1.0
    assert kin.within_limits(q)
    assert isinstance(info, IkInfo) and info.starts == 2 and 0 < info.iterations <= 100
    with pytest.raises(dataclasses.FrozenInstanceError):
        info.success = True


# -- real data -------------------------------------------------------------------------------------------
def test_real_launcher_balls_at_robot_end_are_reachable(kin, real_data):
    """Real MPI launcher flights (ball_prediction @ 6532302, BSD-3-Clause): where they cross the robot's
    end of the table the racket reaches them. Their frame is undocumented: the launch point is near x = 0
    and the flights bounce at x ~ 2.0-2.15 and end at x ~ 2.74, so we assume the launcher stands at the
    opponent's table end and map x_lab = 1.37 - x, y_lab = -y, z_lab = z (a half turn about z)."""
    data = np.genfromtxt(real_data / "mpi_launcher_trajectories" / "no_spin_robot_simple.csv", delimiter=",",
                         names=True)
    rng = np.random.default_rng(9)
    reached, total = 0, 0
    for k in np.unique(data["traj"])[::4]:  # 12 of 48 flights
        f = data[data["traj"] == k]
        x_lab = 1.37 - f["x_m"]
        i = int(np.argmin(np.abs(x_lab - (-1.3))))  # the sample nearest the hitting plane x = -1.3 m
        p = np.array([x_lab[i], -f["y_m"][i], f["z_m"][i]])
        assert -1.45 < p[0] < -1.15 and 0.8 < p[2] < 1.4, p  # the mapping puts the ball in the hitting region
        _, info = kin.ik(p, "racket", normal_world=np.array([0.685, 0.0, 0.91]) - p, rng=rng)
        reached += info.success
        total += 1
    assert reached == total
