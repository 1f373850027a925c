"""A simulated arm (the WAM by default) on a seeded ball-mount trajectory (``rt2 sim wam [--robot NAME]``):
tracking errors with its own gains and limits, and the ball position from the *reported* joints against the
true one (zero-offset bias, encoder quantisation, noise)."""

from __future__ import annotations

import numpy as np

from harness.sim.robot.arms import load_arm
from harness.sim.robot.simulated_wam import SimulatedWam, SimWamOptions
from harness.sim.trajectories import BALL_BOX_WORLD_M, TrajectoryOptions, random_via_trajectory

__all__ = ["simulate"]


def simulate(config=None, *, seed: int = 0, n_via: int = 8, backend: str | None = None) -> dict:
    """Run one session of the arm ``config`` (a name, a robot YAML path; None = the WAM); returns the figures
    printed by ``rt2 sim wam`` (floats, mm and mrad)."""
    arm = load_arm(config, check_reach=False)
    kin, cfg = arm.kin, arm.config
    sim_map = dict(cfg.simulator)
    if backend is not None:
        sim_map["backend"] = backend
    sim = SimulatedWam(kin, SimWamOptions.from_mapping(sim_map, where=f"{cfg.where}: simulator", n_joints=kin.n_joints),
                       seed=seed)
    traj, info = random_via_trajectory(kin, BALL_BOX_WORLD_M, q_start=kin.q_home,
                                       options=TrajectoryOptions(n_via=n_via), seed=seed)
    start = 0.1
    sim.command_trajectory(traj.t_s + start, traj.q, traj.qdot)
    s = sim.advance_to(start + traj.t_s[-1] + 0.5)
    p_true = kin.positions(s.q_true)
    p_ref = kin.positions(s.q_ref)
    p_rep = kin.positions(s.q, check_limits=False)
    track_mm = np.linalg.norm(p_true - p_ref, axis=1) * 1e3
    truth_mm = np.linalg.norm(p_rep - p_true, axis=1) * 1e3
    jerr = np.abs(s.q_true - s.q_ref)
    return {
        "seed": seed, "ticks": len(s), "duration_s": float(s.t_s[-1]), "trajectory_method": info["method"],
        "bias_deg": np.rad2deg(sim.bias_rad).round(4).tolist(),
        "joint_tracking_max_mrad": (jerr.max(0) * 1e3).round(4).tolist(),
        "joint_tracking_rms_mrad": (np.sqrt((jerr**2).mean(0)) * 1e3).round(4).tolist(),
        "ball_tracking_mm": {"median": float(np.median(track_mm)), "p95": float(np.percentile(track_mm, 95)),
                             "max": float(track_mm.max())},
        "ball_reported_vs_true_mm": {"median": float(np.median(truth_mm)), "p95": float(np.percentile(truth_mm, 95)),
                                     "max": float(truth_mm.max())},
        "saturated_ticks": sim.saturated_ticks.tolist(), "limit_ticks": sim.limit_ticks.tolist(),
    }
