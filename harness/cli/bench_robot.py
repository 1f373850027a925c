"""``rt2 bench robot``: run time of the robot model and the simulated WAM (medians of repeats).

Rows: batched FK (numba kernel, numpy reference) against a per-configuration Pinocchio loop, measured in
the same process; link points for the renderer; one Jacobian; one IK solve; simulated ticks with the numba
kernel against its numpy reference.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from harness.sim.robot.sim_wam import SimulatedWam, SimWamOptions
from robot_models import WamKinematics

__all__ = ["add_arguments", "run"]


def _median_s(fn, repeats: int) -> float:
    fn()  # warm-up (numba compile, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", type=int, default=5000, help="configurations per FK batch")
    parser.add_argument("--ticks", type=int, default=5000, help="simulated ticks per run")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    if args.n < 1 or args.ticks < 1 or args.repeats < 1:
        raise ValueError(f"--n, --ticks and --repeats must be >= 1, got {args.n}, {args.ticks}, {args.repeats}")
    kin = WamKinematics.default()
    rng = np.random.default_rng(args.seed)
    Q = rng.uniform(kin.q_min, kin.q_max, size=(args.n, kin.n_joints))
    rows = []

    def add(name, seconds, per, unit_count, baseline=None):
        rows.append({"what": name, "median_s": seconds, "per_item_us": seconds / unit_count * 1e6, "per": per,
                     "speedup_vs": baseline[0] if baseline else None,
                     "speedup": baseline[1] / seconds if baseline else None})

    t_pin = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="pinocchio"), args.repeats)
    add("fk_batch pinocchio loop", t_pin, "config", args.n)
    t_np = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="numpy"), args.repeats)
    add("fk_batch numpy", t_np, "config", args.n, ("fk_batch pinocchio loop", t_pin))
    t_nb = _median_s(lambda: kin.fk_batch(Q, "ball_mount", method="numba"), args.repeats)
    add("fk_batch numba", t_nb, "config", args.n, ("fk_batch pinocchio loop", t_pin))
    add("link_points (9 frames)", _median_s(lambda: kin.link_points(Q), args.repeats), "config", args.n)
    add("jacobian (one q)", _median_s(lambda: kin.jacobian(Q[0], "racket"), args.repeats * 50), "call", 1)
    target = kin.position(kin.q_home, "racket") + np.array([0.1, 0.2, -0.1])
    add("ik racket position+normal", _median_s(lambda: kin.ik(target, "racket", normal_world=[1, 0, 0]), args.repeats),
        "solve", 1)
    times = {}
    for backend in ("numpy", "numba"):
        def session(backend=backend):
            sim = SimulatedWam(kin, SimWamOptions(backend=backend), seed=args.seed)
            t = np.array([0.0, args.ticks / sim.control_rate_hz])
            q = np.stack([kin.q_home, np.clip(kin.q_home + 0.3, kin.q_min, kin.q_max)])
            sim.command_trajectory(t, q)
            sim.step(args.ticks)
        times[backend] = _median_s(session, max(1, args.repeats // 2) if backend == "numpy" else args.repeats)
    add("simulated ticks numpy", times["numpy"], "tick", args.ticks)
    add("simulated ticks numba", times["numba"], "tick", args.ticks, ("simulated ticks numpy", times["numpy"]))
    if args.json:
        print(json.dumps({"n": args.n, "ticks": args.ticks, "repeats": args.repeats, "rows": rows}, indent=1))
        return 0
    print(f"robot benchmarks: N={args.n} configurations, {args.ticks} ticks, median of {args.repeats} repeats")
    print(f"  {'what':32} {'median (ms)':>12} {'per item (us)':>14}  speed-up")
    for r in rows:
        sp = f"x{r['speedup']:.1f} vs {r['speedup_vs']}" if r["speedup"] else ""
        print(f"  {r['what']:32} {r['median_s'] * 1e3:12.3f} {r['per_item_us']:14.3f}  {sp}")
    return 0
