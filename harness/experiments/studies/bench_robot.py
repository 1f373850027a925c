"""Run time of an arm's model and its simulated arm (``rt2 bench robot [--robot NAME]``; medians of repeats; the WAM by default).

Rows: batched FK (numba kernel, numpy reference) against a per-configuration Pinocchio loop, measured in
the same process; link points for the renderer; one Jacobian; one IK solve; simulated ticks with the numba
kernel against its numpy reference.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from harness.sim.robot.arms import load_arm
from harness.sim.robot.simulated_wam import SimulatedWam

__all__ = ["bench_robot"]


def _median_s(fn, repeats: int) -> float:
    fn()  # warm-up (numba compile, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_robot(n: int = 5000, ticks: int = 5000, repeats: int = 7, seed: int = 0, robot: str | None = None) -> list[dict]:
    """One row per measurement: ``what``, ``median_s``, ``per_item_us``, ``per``, ``speedup_vs``, ``speedup``.

    robot : the arm (a shipped arm's name or a robot config's path; None = the WAM)."""
    if n < 1 or ticks < 1 or repeats < 1:
        raise ValueError(f"--n, --ticks and --repeats must be >= 1, got {n}, {ticks}, {repeats}")
    arm = load_arm(robot, check_reach=False)
    kin = arm.kin
    rng = np.random.default_rng(seed)
    Q = rng.uniform(kin.q_min, kin.q_max, size=(n, kin.n_joints))
    rows = []

    def add(name, seconds, per, unit_count, baseline=None):
        rows.append({"what": name, "median_s": seconds, "per_item_us": seconds / unit_count * 1e6, "per": per,
                     "speedup_vs": baseline[0] if baseline else None,
                     "speedup": baseline[1] / seconds if baseline else None})

    t_pin = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="pinocchio"), repeats)
    add("fk_batch pinocchio loop", t_pin, "config", n)
    t_np = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="numpy"), repeats)
    add("fk_batch numpy", t_np, "config", n, ("fk_batch pinocchio loop", t_pin))
    t_nb = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="numba"), repeats)
    add("fk_batch numba", t_nb, "config", n, ("fk_batch pinocchio loop", t_pin))
    add(f"link_points ({len(kin.link_chain)} frames)", _median_s(lambda: kin.link_points(Q), repeats), "config", n)
    add("jacobian (one q)", _median_s(lambda: kin.jacobian(Q[0], "racket"), repeats * 50), "call", 1)
    target = kin.position(kin.q_home, "racket") + np.array([0.1, 0.2, -0.1])  # (the WAM's: a reachable step)
    add("ik racket position+normal", _median_s(lambda: kin.ik(target, "racket", normal_world=[1, 0, 0]), repeats),
        "solve", 1)
    times = {}
    for backend in ("numpy", "numba"):
        def session(backend=backend):
            sim = SimulatedWam(kin, dataclasses.replace(arm.sim_options, backend=backend), seed=seed)
            t = np.array([0.0, ticks / sim.control_rate_hz])
            q = np.stack([kin.q_home, np.clip(kin.q_home + 0.3, kin.q_min, kin.q_max)])
            sim.command_trajectory(t, q)
            sim.step(ticks)
        times[backend] = _median_s(session, max(1, repeats // 2) if backend == "numpy" else repeats)
    add("simulated ticks numpy", times["numpy"], "tick", ticks)
    add("simulated ticks numba", times["numba"], "tick", ticks, ("simulated ticks numpy", times["numpy"]))
    return rows
