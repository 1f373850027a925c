"""The simulated WAM (``SimulatedWam``): 500 Hz tracking loop, limits, encoders, zero-offset bias.

The interface contract (``WamInterface``, ``JointState``, ``JointTrajectory``, ``check_joint_trajectory``)
lives in robot_models/robot_interface.py, where policies can see it, and the joint reference every robot
side follows (``PiecewiseReference``) beside it in robot_models/joint_reference.py; docs/robot.md describes
the simulator's error model and docs/robot_link.md the network protocol.
"""

from harness.sim.robot.simulated_wam import SimSamples, SimulatedWam, SimWamOptions

__all__ = ["SimSamples", "SimWamOptions", "SimulatedWam"]
