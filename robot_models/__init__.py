"""rt2 robot models: the 7-DOF Barrett WAM's URDF, its configuration, kinematics and IK over Pinocchio, and the
robot interface contract (``robot_interface.py``: ``WamInterface`` and the joint types) that policies act through.

Imports nothing else of rt2 but its lowest layer, ``checks`` (see docs/architecture.md). Poses are in the lab world frame, metres.

The names below are loaded on first use (PEP 562), so that ``robot_models.robot_interface``,
``robot_models.config`` and ``robot_models.limits`` import without Pinocchio: the robot link's ROS
bridge runs them under a system Python that has numpy and PyYAML only (docs/robot_link.md).
"""

from importlib import import_module

_WHERE = {
    "DEFAULT_CONFIG_PATH": "config", "DEFAULT_URDF_PATH": "config", "RobotConfig": "config",
    "load_robot_config": "config", "mount_transform": "config",
    "IkInfo": "ik", "IkOptions": "ik", "solve_ik": "ik",
    "LINK_CHAIN": "kinematics", "REQUIRED_FRAMES": "kinematics", "WamKinematics": "kinematics",
    "JointLimits": "limits",
    "JointSamples": "robot_interface", "JointState": "robot_interface", "JointTrajectory": "robot_interface",
    "WamInterface": "robot_interface", "check_joint_trajectory": "robot_interface",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'robot_models' has no attribute {name!r}")
    value = getattr(import_module(f"robot_models.{module}"), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
