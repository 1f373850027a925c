"""The robot side of the harness: the WAM interface, its simulated implementation, and robot CLI commands.

See harness/robot/wam.py for the interface contract and docs/robot.md for the simulator's error model.
"""

from harness.robot.sim_wam import SimSamples, SimulatedWam, SimWamOptions
from harness.robot.wam import JointSamples, JointState, JointTrajectory, WamInterface, check_joint_trajectory

__all__ = ["JointSamples", "JointState", "JointTrajectory", "SimSamples", "SimWamOptions", "SimulatedWam",
           "WamInterface", "check_joint_trajectory"]
