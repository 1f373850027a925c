"""rt2 robot models: the 7-DOF Barrett WAM's URDF, its configuration, kinematics and IK over Pinocchio, and the
robot interface contract (``robot_interface.py``: ``WamInterface`` and the joint types) that policies act through.

Imports nothing else of rt2 but its lowest layer, ``checks`` (see docs/architecture.md). Poses are in the lab world frame, metres.
"""

from robot_models.config import DEFAULT_CONFIG_PATH, DEFAULT_URDF_PATH, RobotConfig, load_robot_config, mount_transform
from robot_models.ik import IkInfo, IkOptions, solve_ik
from robot_models.kinematics import LINK_CHAIN, REQUIRED_FRAMES, WamKinematics
from robot_models.robot_interface import JointSamples, JointState, JointTrajectory, WamInterface, check_joint_trajectory

__all__ = ["DEFAULT_CONFIG_PATH", "DEFAULT_URDF_PATH", "IkInfo", "IkOptions", "JointSamples", "JointState", "JointTrajectory",
           "LINK_CHAIN", "REQUIRED_FRAMES", "RobotConfig", "WamInterface", "WamKinematics", "check_joint_trajectory",
           "load_robot_config", "mount_transform", "solve_ik"]
