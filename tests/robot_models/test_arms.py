"""Any arm from its URDF: the shipped arms' kinematics against Pinocchio's example-robot-data loader and the
UR10's published Denavit-Hartenberg table, a prismatic chain, and a table of hostile robot configs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from robot_models import ArmKinematics, WamKinematics, load_robot_config, robot_names
from robot_models.limits import JointLimits

SHIPPED = ("panda", "ur10", "xarm7")


def _needs_robot_data():
    return pytest.importorskip("example_robot_data", reason="example-robot-data is not installed (pip install 'rt2[robots]')")


# -- smoke -------------------------------------------------------------------------------------------
def test_shipped_names_and_the_wam_default():
    assert set(robot_names()) >= {"wam", *SHIPPED}
    assert WamKinematics is ArmKinematics
    kin = ArmKinematics.from_config("wam")
    assert kin.name == "wam" and kin.n_joints == 7 and kin.link_chain[1] == "link_1"
    np.testing.assert_array_equal(kin.fk(kin.q_home, "racket"), ArmKinematics.default().fk(kin.q_home, "racket"))


@pytest.mark.parametrize("name, n", [("panda", 7), ("ur10", 6), ("xarm7", 7)])
def test_shipped_arm_loads_with_its_own_joints(name, n):
    _needs_robot_data()
    kin = ArmKinematics.from_config(name)
    assert kin.n_joints == n and len(kin.link_chain) == n + 2 and kin.link_radii_m.shape == (n + 1,)
    limits = JointLimits.from_config(name)  # the bridges' limits, without Pinocchio, agree
    assert limits.joint_names == kin.joint_names
    np.testing.assert_array_equal(limits.q_min, kin.q_min)
    np.testing.assert_array_equal(limits.q_max, kin.q_max)
    np.testing.assert_array_equal(limits.qddot_max, kin.qddot_max)
    np.testing.assert_allclose(kin.fk(kin.q_home, "base"), load_robot_config(name).T_base_to_world, atol=1e-12)


# -- accuracy against the references ---------------------------------------------------------------------
@pytest.mark.parametrize("name", SHIPPED)
def test_fk_equals_example_robot_data_loader(name):
    """Flange, ball mount and every capsule point, in the base link's frame, on 1000 random configurations."""
    erd = _needs_robot_data()
    import pinocchio as pin

    cfg = load_robot_config(name)
    kin = ArmKinematics.from_config(cfg)
    ref = erd.load(name)
    model, data = ref.model, ref.model.createData()
    rng = np.random.default_rng(0)
    Q = rng.uniform(kin.q_min, kin.q_max, (1000, kin.n_joints))
    T_world_to_base = np.linalg.inv(kin.T_base_to_world)
    ours = {f: T_world_to_base @ kin.fk_batch(Q, f) for f in ("flange", "ball_mount")}
    chain = T_world_to_base[:3, :3] @ kin.link_points(Q).transpose(0, 2, 1) + T_world_to_base[:3, 3:]
    idx = [model.getJointId(j) for j in kin.joint_names]
    base_id, flange_id = model.getFrameId(cfg.base_link), model.getFrameId(cfg.flange_link)
    bodies = [model.getFrameId(f) for f in kin.link_chain[1:-1]]
    offset = np.eye(4)
    offset[:3, 3] = cfg.ball_mount_xyz_m
    worst = 0.0
    for i, q in enumerate(Q):
        q_full = pin.neutral(model)
        for j, jid in enumerate(idx):
            q_full[model.idx_qs[jid]] = q[j]
        pin.framesForwardKinematics(model, data, q_full)
        inv_base = data.oMf[base_id].inverse()
        flange = (inv_base * data.oMf[flange_id]).homogeneous
        points = np.stack([(inv_base * data.oMf[f]).translation for f in [base_id, *bodies, flange_id]])
        worst = max(worst, np.abs(ours["flange"][i] - flange).max(), np.abs(ours["ball_mount"][i] - flange @ offset).max(),
                    np.abs(chain[i].T - points).max())
    assert worst < 1e-9, f"{name}: largest difference {worst:.3g} m"


#: UR10 (CB3) Denavit-Hartenberg parameters as Universal Robots publishes them (standard DH, metres, radians)
UR10_DH = {
    "d_m": (0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922),
    "a_m": (0.0, -0.612, -0.5723, 0.0, 0.0, 0.0),
    "alpha_rad": (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0),
}


def _dh_chain(q, d, a, alpha):
    T = np.eye(4)
    for qi, di, ai, al in zip(q, d, a, alpha):
        c, s, ca, sa = np.cos(qi), np.sin(qi), np.cos(al), np.sin(al)
        T = T @ np.array([[c, -s * ca, s * sa, ai * c], [s, c * ca, -c * sa, ai * s], [0, sa, ca, di], [0, 0, 0, 1]])
    return T


def test_ur10_equals_its_published_dh_table():
    _needs_robot_data()
    kin = ArmKinematics.from_config("ur10")
    rng = np.random.default_rng(1)
    Q = rng.uniform(kin.q_min, kin.q_max, (1000, 6))
    ours = np.linalg.inv(kin.T_base_to_world) @ kin.fk_batch(Q, "flange")
    dh = np.stack([_dh_chain(q, UR10_DH["d_m"], UR10_DH["a_m"], UR10_DH["alpha_rad"]) for q in Q])
    assert np.abs(ours[:, :3, 3] - dh[:, :3, 3]).max() < 1e-9
    assert np.abs(ours[:, :3, :3] - dh[:, :3, :3]).max() < 1e-9


# -- a prismatic joint -------------------------------------------------------------------------------
_PRISMATIC_URDF = """<robot name="slide_arm">
  <link name="root"/><link name="carriage"/><link name="arm"/><link name="tip"/><link name="finger"/>
  <joint name="slide" type="prismatic"><parent link="root"/><child link="carriage"/>
    <origin xyz="0 0 0.5" rpy="0 0 0"/><axis xyz="1 0 0"/><limit lower="-0.3" upper="0.4" velocity="1" effort="1"/></joint>
  <joint name="turn" type="revolute"><parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="2" effort="1"/></joint>
  <joint name="tip_fixed" type="fixed"><parent link="arm"/><child link="tip"/><origin xyz="0.3 0 0" rpy="0 1.5707963267948966 0"/></joint>
  <joint name="grip" type="prismatic"><parent link="tip"/><child link="finger"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.04" velocity="0.1" effort="1"/></joint>
</robot>
"""


def slide_config(tmp_path, **changes):
    urdf = tmp_path / "slide.urdf"
    urdf.write_text(_PRISMATIC_URDF)
    doc = {"format": "rt2.robot", "version": 1, "urdf": str(urdf), "base_link": "root", "flange_link": "tip",
           "mount": {"xyz_m": [-2.0, 0.0, 0.7]},
           "limits": {"qdot_max_rad_s": [1.0, 2.0], "qddot_max_rad_s2": [5.0, 5.0]},
           "q_home_rad": [0.1, 0.2], "render": {"link_radii_m": [0.05, 0.05, 0.05]}}
    for key, value in changes.items():
        if value is None:
            doc.pop(key)
        else:
            doc[key] = value
    path = tmp_path / "slide.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_prismatic_chain_fk_all_methods_agree(tmp_path):
    kin = ArmKinematics.from_config(slide_config(tmp_path))
    assert kin.joint_names == ("slide", "turn") and kin.link_chain == ("base", "carriage", "arm", "flange")
    Q = np.random.default_rng(2).uniform(kin.q_min, kin.q_max, (50, 2))
    ref = kin.fk_batch(Q, "racket", method="pinocchio")
    for method in ("numba", "numpy"):
        np.testing.assert_allclose(kin.fk_batch(Q, "racket", method=method), ref, atol=1e-12)
    q = np.array([0.25, 0.0])  # slide 0.25 m along x, no turn: flange 0.3 m further along x
    np.testing.assert_allclose(kin.position(q, "flange"), [-2.0 + 0.55, 0.0, 0.7 + 0.6], atol=1e-12)


# -- bad input: hostile robot configs, one line naming the file and the field -----------------------------
@pytest.mark.parametrize("changes, match", [
    ({"base_link": "plinth"}, r"slide\.yaml: .*base_link: link 'plinth' is not in the URDF"),
    ({"flange_link": "wrist"}, r"slide\.yaml: .*flange_link: link 'wrist' is not in the URDF"),
    ({"flange_link": "root", "base_link": "tip"}, r"slide\.yaml: .*base_link: link 'tip' is moved by joint"),
    ({"limits": {"qdot_max_rad_s": [1.0, 2.0], "qddot_max_rad_s2": [5.0, 5.0], "q_max": [0.5, 2.0]}},
     r"slide\.yaml: limits\.q_max: slide = 0\.5 m is beyond the URDF's range \[-0\.3, 0\.4\] m"),
    ({"limits": {"qdot_max_rad_s": [1.0, 2.0], "qddot_max_rad_s2": [5.0, 5.0], "q_min": [-0.3, -2.5]}},
     r"slide\.yaml: limits\.q_min: turn = -2\.5 rad is beyond the URDF's range"),
    ({"q_home_rad": [0.1, 0.2, 0.3], "limits": {"qdot_max_rad_s": [1, 1, 1], "qddot_max_rad_s2": [1, 1, 1]},
      "render": {"link_radii_m": [0.1] * 4}}, r"slide\.yaml: q_home_rad: 3 values, but the URDF has 2 joints"),
    ({"q_home_rad": [0.5, 0.0]}, r"slide\.yaml: q_home_rad: slide = 0\.5 rad is outside its limits"),
    ({"limits": {"qdot_max_rad_s": [1.0], "qddot_max_rad_s2": [5.0, 5.0]}},
     r"slide\.yaml: qdot_max_rad_s must have 2 values \(one per joint"),
    ({"render": {"link_radii_m": [0.05, 0.05]}}, r"slide\.yaml: link_radii_m must have 3 values"),
    ({"urdf": {"package": "no-such-robot-package", "path": "x.urdf"}},
     r"slide\.yaml: urdf: package 'no-such-robot-package' is not installed"),
])
def test_hostile_configs_name_file_and_field(tmp_path, changes, match):
    path = slide_config(tmp_path, **changes)
    with pytest.raises(ValueError, match=match) as err:
        ArmKinematics.from_config(path)
    assert "\n" not in str(err.value)


def test_joint_without_limits_names_the_joint(tmp_path):
    path = slide_config(tmp_path)
    urdf = tmp_path / "slide.urdf"
    urdf.write_text(_PRISMATIC_URDF.replace('type="revolute"', 'type="continuous"'))
    with pytest.raises(ValueError, match=r"slide\.yaml: .*slide\.urdf: joint 'turn' is 'continuous': it has no position limits"):
        ArmKinematics.from_config(path)
    urdf.write_text(_PRISMATIC_URDF.replace('<limit lower="-0.3" upper="0.4" velocity="1" effort="1"/>', ""))
    with pytest.raises(ValueError, match=r"joint 'slide' needs <limit lower= upper= velocity=> numbers"):
        ArmKinematics.from_config(path)
    with pytest.raises(ValueError, match=r"joint 'slide' needs <limit"):
        JointLimits.from_config(path)  # the bridges' reading says the same


def test_unknown_robot_name_lists_the_shipped_ones():
    with pytest.raises(ValueError, match=r"unknown robot 'kuka'; shipped: \[.*'panda'.*'wam'"):
        load_robot_config("kuka")
    with pytest.raises(FileNotFoundError, match="robot config not found"):
        load_robot_config("/nonexistent/arm.yaml")


def test_the_wam_config_in_code_equals_its_file():
    cfg = load_robot_config("wam")
    made = dataclasses.replace(cfg, path=None)
    a, b = ArmKinematics.from_config(made), ArmKinematics.from_config(cfg)
    q = a.q_home
    np.testing.assert_array_equal(a.fk(q, "ball_mount"), b.fk(q, "ball_mount"))


@pytest.mark.parametrize("n, refused", [(16, False), (17, True)])
def test_an_arm_of_more_joints_than_the_link_carries_is_refused_by_its_file(tmp_path, n, refused):
    """urdf_chain, which every reader of an arm uses (ArmKinematics, JointLimits), refuses a chain longer than
    MAX_JOINTS, naming the file: the robot link and the lab truth stream carry no more."""
    from robot_models.limits import MAX_JOINTS, urdf_chain

    links = "".join(f'<link name="l{i}"/>' for i in range(n + 1))
    joints = "".join(f'<joint name="j{i}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
                     f'<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>'
                     for i in range(n))
    urdf = tmp_path / "long.urdf"
    urdf.write_text(f'<robot name="long">{links}{joints}</robot>')
    assert MAX_JOINTS == 16
    if refused:
        with pytest.raises(ValueError, match=rf"long.urdf: 17 movable joints .* at most 16"):
            urdf_chain(urdf, "l0", f"l{n}")
    else:
        assert len(urdf_chain(urdf, "l0", f"l{n}")) == 16
