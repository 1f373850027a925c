"""``rt2 sim wam``: run a seeded ball-mount trajectory on the simulated WAM and measure its errors.

Reports (1) tracking: the true joints against the commanded reference, and the ball-mount position they
give; (2) "ground truth" error: the ball position from the *reported* joints (what an experiment
logs) against the true one, caused by the zero-offset bias, encoder quantisation and noise.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from harness.sim.robot.sim_wam import SimulatedWam, SimWamOptions
from harness.sim.trajectories import BALL_BOX_WORLD_M, TrajectoryOptions, random_via_trajectory
from robot_models import DEFAULT_CONFIG_PATH, WamKinematics, load_robot_config

__all__ = ["add_arguments", "run", "simulate"]


def simulate(config=None, *, seed: int = 0, n_via: int = 8, backend: str | None = None) -> dict:
    """Run one session; returns the figures printed by ``rt2 sim wam`` (floats, mm and mrad)."""
    cfg = load_robot_config(config)
    kin = WamKinematics.from_config(cfg)
    sim_map = dict(cfg.simulator)
    if backend is not None:
        sim_map["backend"] = backend
    sim = SimulatedWam(kin, SimWamOptions.from_mapping(sim_map, where=f"{config or DEFAULT_CONFIG_PATH}: simulator"), seed=seed)
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="robot YAML (default data/robot/wam.yaml)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the trajectory, the bias and the noise")
    parser.add_argument("--n-via", type=int, default=8, help="via points of the trajectory")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    r = simulate(args.config, seed=args.seed, n_via=args.n_via)
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    print(f"simulated WAM, seed {r['seed']}: {r['ticks']} ticks ({r['duration_s']:.2f} s), "
          f"trajectory {r['trajectory_method']}")
    print(f"  zero-offset bias (deg):        {r['bias_deg']}")
    print(f"  joint tracking max (mrad):     {r['joint_tracking_max_mrad']}")
    print(f"  joint tracking rms (mrad):     {r['joint_tracking_rms_mrad']}")
    print(f"  saturated ticks per joint:     {r['saturated_ticks']}")
    print(f"  ticks against a hard stop:     {r['limit_ticks']}")
    print(f"  {'ball position error (mm)':34} {'median':>8} {'p95':>8} {'max':>8}")
    for name, key in (("true vs commanded (tracking)", "ball_tracking_mm"),
                      ("reported vs true (bias+encoder)", "ball_reported_vs_true_mm")):
        v = r[key]
        print(f"  {name:34} {v['median']:8.2f} {v['p95']:8.2f} {v['max']:8.2f}")
    return 0
