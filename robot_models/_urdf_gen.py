"""Generator of ``robot_models/wam7.urdf`` from the 7-DOF Barrett WAM's standard DH table.

Run ``python -m robot_models._urdf_gen`` to rewrite the committed URDF; a test checks that the
committed file equals what this module writes, and that its kinematics equal an independent DH chain.

Numbers (Barrett WAM user manual, standard DH, metres and radians)::

    joint   a        alpha    d      limits (rad)
    1       0       -pi/2     0      -2.6 .. 2.6
    2       0        pi/2     0      -2.0 .. 2.0
    3       0.045   -pi/2     0.55   -2.8 .. 2.8
    4      -0.045    pi/2     0      -0.9 .. 3.1
    5       0       -pi/2     0.30   -4.76 .. 1.24
    6       0        pi/2     0      -1.6 .. 1.6
    7       0        0        0.06   -3.0 .. 3.0
    base plate to shoulder (DH frame 0): 0.346 m along the base z axis.

Standard DH: ``T_{i-1,i} = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; joint i turns about z_{i-1}.
A URDF joint applies its fixed origin *before* its rotation, so the URDF link ``link_i`` is DH frame
i-1 turned by theta_i, and joint i+1's origin is the constant part ``Tz(d_i) Tx(a_i) Rx(alpha_i)``
of DH row i. The fixed ``flange`` frame is DH frame 7 (the tool plate).

Inertial data are rough (documented in docs/robot.md): masses are the per-link masses commonly quoted
for the 7-DOF WAM (from memory of Barrett's mass table, not re-checked against the manual), each link
a uniform solid cylinder of an estimated radius along the segment to the next joint origin. rt2 only
uses the kinematics. Velocity limits written into the URDF are the defaults of ``data/robot/wam.yaml``
(measured by a table-tennis lab; Barrett publishes none); the yaml file overrides them at run time.
Efforts are order-of-magnitude placeholders required by the URDF schema and unused by rt2.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["DH_A_M", "DH_ALPHA_RAD", "DH_D_M", "BASE_TO_SHOULDER_M", "Q_MIN_RAD", "Q_MAX_RAD",
           "QDOT_MAX_RAD_S", "BALL_IN_FLANGE_M", "RACKET_IN_FLANGE_M", "urdf_text", "write_urdf"]

PI = math.pi
DH_A_M = (0.0, 0.0, 0.045, -0.045, 0.0, 0.0, 0.0)
DH_ALPHA_RAD = (-PI / 2, PI / 2, -PI / 2, PI / 2, -PI / 2, PI / 2, 0.0)
DH_D_M = (0.0, 0.0, 0.55, 0.0, 0.30, 0.0, 0.06)
BASE_TO_SHOULDER_M = 0.346
Q_MIN_RAD = (-2.6, -2.0, -2.8, -0.9, -4.76, -1.6, -3.0)
Q_MAX_RAD = (2.6, 2.0, 2.8, 3.1, 1.24, 1.6, 3.0)
QDOT_MAX_RAD_S = (3.2, 6.3, 10.0, 10.0, 24.0, 19.0, 27.0)
EFFORT_NM = (60.0, 60.0, 45.0, 30.0, 10.0, 10.0, 3.0)  # placeholders, unused

#: Ball centre on the flange's z (tool) axis: a 40 mm ball on a 25 mm stem.
BALL_IN_FLANGE_M = (0.0, 0.0, 0.045)
#: Racket centre on the tool axis, 0.16 m beyond the flange (handle plus 75 mm disk radius).
RACKET_IN_FLANGE_M = (0.0, 0.0, 0.16)
#: Racket frame: z (the racket normal) = flange x, x = -flange z (towards the handle), y = flange y.
RACKET_RPY_IN_FLANGE = (0.0, PI / 2, 0.0)

#: Mass (kg) and cylinder radius (m) per body: base, link_1 .. link_7.
_MASS_KG = (9.97, 10.77, 3.87, 1.80, 2.40, 0.12, 0.42, 0.07)
_RADIUS_M = (0.10, 0.10, 0.09, 0.05, 0.045, 0.04, 0.04, 0.04)
_RACKET_MASS_KG = 0.18
_RACKET_RADIUS_M = 0.075


def _fmt(values) -> str:
    return " ".join(f"{0.0 if abs(v) < 1e-15 else v:.15g}" for v in values)


def _cylinder_inertia(mass: float, radius: float, seg: np.ndarray) -> np.ndarray:
    """(3, 3) inertia about the centre of a solid cylinder whose axis is ``seg`` (a sphere if short)."""
    length = float(np.linalg.norm(seg))
    if length < 1e-3:
        return np.eye(3) * 0.4 * mass * radius**2
    u = seg / length
    i_axial = 0.5 * mass * radius**2
    i_perp = mass * (3 * radius**2 + length**2) / 12.0
    return i_perp * (np.eye(3) - np.outer(u, u)) + i_axial * np.outer(u, u)


def _inertial(mass: float, radius: float, seg) -> str:
    seg = np.asarray(seg, float)
    inertia = _cylinder_inertia(mass, radius, seg)
    com = seg / 2
    return (
        "    <inertial>\n"
        f'      <origin xyz="{_fmt(com)}" rpy="0 0 0"/>\n'
        f'      <mass value="{mass:g}"/>\n'
        f'      <inertia ixx="{inertia[0, 0]:.6g}" ixy="{inertia[0, 1]:.6g}" ixz="{inertia[0, 2]:.6g}" '
        f'iyy="{inertia[1, 1]:.6g}" iyz="{inertia[1, 2]:.6g}" izz="{inertia[2, 2]:.6g}"/>\n'
        "    </inertial>\n"
    )


def _joint_origins() -> list[tuple[tuple, tuple]]:
    """(xyz, rpy) of joint_1 .. joint_7 and of the fixed flange joint, in the parent link's frame."""
    origins = [((0.0, 0.0, BASE_TO_SHOULDER_M), (0.0, 0.0, 0.0))]
    for a, alpha, d in zip(DH_A_M, DH_ALPHA_RAD, DH_D_M):
        # constant part of DH row i: Tz(d) Tx(a) Rx(alpha) == translation (a, 0, d), then roll alpha
        origins.append(((a, 0.0, d), (alpha, 0.0, 0.0)))
    return origins


def urdf_text() -> str:
    """The URDF document (str) of the WAM with ``base``, ``link_1..7``, ``flange``, ``ball_mount``, ``racket``."""
    origins = _joint_origins()
    out = [
        '<?xml version="1.0"?>\n',
        "<!-- 7-DOF Barrett WAM, generated by robot_models/_urdf_gen.py from the standard DH table of\n"
        "     Barrett's WAM user manual. Written for rt2 (BSD-3-Clause); kinematics only are exact,\n"
        "     inertias are rough estimates. Do not edit by hand: run `python -m robot_models._urdf_gen`. -->\n",
        '<robot name="wam7">\n',
        '  <link name="base">\n',
        _inertial(_MASS_KG[0], _RADIUS_M[0], origins[0][0]),
        "  </link>\n",
    ]
    parent = "base"
    for i in range(7):
        xyz, rpy = origins[i]
        child = f"link_{i + 1}"
        out += [
            f'  <joint name="joint_{i + 1}" type="revolute">\n',
            f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n',
            f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>\n',
            '    <axis xyz="0 0 1"/>\n',
            f'    <limit lower="{Q_MIN_RAD[i]:g}" upper="{Q_MAX_RAD[i]:g}" '
            f'velocity="{QDOT_MAX_RAD_S[i]:g}" effort="{EFFORT_NM[i]:g}"/>\n',
            "  </joint>\n",
            f'  <link name="{child}">\n',
            _inertial(_MASS_KG[i + 1], _RADIUS_M[i + 1], origins[i + 1][0]),
            "  </link>\n",
        ]
        parent = child
    fixed = [
        ("flange", "link_7", origins[7][0], origins[7][1]),
        ("ball_mount", "flange", BALL_IN_FLANGE_M, (0.0, 0.0, 0.0)),
        ("racket", "flange", RACKET_IN_FLANGE_M, RACKET_RPY_IN_FLANGE),
    ]
    for child, par, xyz, rpy in fixed:
        out += [
            f'  <joint name="{child}_joint" type="fixed">\n',
            f'    <parent link="{par}"/>\n    <child link="{child}"/>\n',
            f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>\n',
            "  </joint>\n",
            f'  <link name="{child}"/>\n' if child != "racket" else
            f'  <link name="{child}">\n{_inertial(_RACKET_MASS_KG, _RACKET_RADIUS_M, (0.0, 0.0, 0.0))}  </link>\n',
        ]
    out.append("</robot>\n")
    return "".join(out)


def write_urdf(path: str | Path | None = None) -> Path:
    """Write :func:`urdf_text` to ``path`` (default: ``robot_models/wam7.urdf``) and return the path."""
    target = Path(path) if path is not None else Path(__file__).resolve().parent / "wam7.urdf"
    target.write_text(urdf_text())
    return target


if __name__ == "__main__":
    print(write_urdf())
