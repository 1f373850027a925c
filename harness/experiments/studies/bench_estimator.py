"""``rt2 bench estimator``: run time of one robust estimate vs the number of cameras (paper Table 2).

For c in {4, 8, 15, 30, 50} (rigs ``data/rigs/sim_c{c}.yaml``): synthetic frames with one observation
per camera and 10 % outliers; the median wall time of one ``RobustTriangulator.estimate`` call
(validation, compiled kernel, result objects; everything a caller pays) for ``method="paper"`` and
``"ours"``, and of :func:`naive_estimate`, Algorithm 2 written the obvious way (a Python loop over
pairs calling ``cv2.triangulatePoints`` and ``cv2.projectPoints``). All in one process, one after
the other per camera count, so the ratios compare like with like even on a loaded machine.
"""

from __future__ import annotations

import gc
import os
import time
from pathlib import Path

import numpy as np

from harness.experiments.studies.paper_tables import BENCH_GOAL_MS, NAIVE_SPEEDUP_GOAL, PAPER_TABLE2_MS

__all__ = ["add_arguments", "bench", "naive_estimate", "run"]

CAMERAS = (4, 8, 15, 30, 50)
OUTLIER_RATE = 0.10


def naive_estimate(uv: np.ndarray, rig, eps_px: float):
    """Algorithm 2 the obvious way, with OpenCV: the baseline of the benchmark.

    uv : (n_cams, 2) distorted pixels, NaN where none
    returns (X_world (3,) or None, inlier camera indices)
    """
    import cv2

    cams = list(rig)
    seen = [i for i in range(len(cams)) if not np.isnan(uv[i]).any()]
    P = [c.K @ c.P_normalised for c in cams]
    rvec = [cv2.Rodrigues(c.R_world_to_cam)[0] for c in cams]
    und = {i: cv2.undistortPoints(uv[i].reshape(1, 1, 2), cams[i].K, cams[i].distortion, P=cams[i].K).reshape(2, 1) for i in seen}
    best: list[int] = []
    for a in range(len(seen) - 1):  # Algorithm 2 lines 2-3
        for b in range(a + 1, len(seen)):
            i, j = seen[a], seen[b]
            Xh = cv2.triangulatePoints(P[i], P[j], und[i], und[j])  # line 4
            X = (Xh[:3] / Xh[3]).reshape(1, 3)
            S = []
            for k in seen:  # lines 6-10
                proj, _ = cv2.projectPoints(X, rvec[k], cams[k].t_world_to_cam_m, cams[k].K, cams[k].distortion)
                if np.linalg.norm(proj.ravel() - uv[k]) < eps_px:
                    S.append(k)
            if len(S) > len(best):  # lines 12-14
                best = S
    if len(best) < 2:
        return None, best
    A = []  # the final position: DLT on the set, homogeneous, by SVD
    for k in best:
        x, y = und[k].ravel()
        A += [x * P[k][2] - P[k][0], y * P[k][2] - P[k][1]]
    Xh = np.linalg.svd(np.array(A))[2][-1]
    return Xh[:3] / Xh[3], best


def _time_calls(fn, frames, repeats: int, budget_s: float | None = None, warmup: int = 5) -> tuple[float, int]:
    """Median ms of fn(frame) cycling over frames; stops early past budget_s (at least 5 calls)."""
    for k in range(warmup):
        fn(frames[k % len(frames)])
    times = []
    start = time.perf_counter()
    gc.disable()
    try:
        for k in range(repeats):
            t0 = time.perf_counter_ns()
            fn(frames[k % len(frames)])
            times.append(time.perf_counter_ns() - t0)
            if budget_s is not None and k >= 4 and time.perf_counter() - start > budget_s:
                break
    finally:
        gc.enable()
    return float(np.median(times) / 1e6), len(times)


def bench(cameras=CAMERAS, *, repeats: int = 2000, naive_budget_s: float = 3.0, seed: int = 0, progress: bool = True) -> list[dict]:
    """Rows {cameras, method, median_ms, calls} for paper, ours and naive at every camera count."""
    from harness.common.progress import progress_bar

    from harness.sim.study_rigs import load_sim_rig
    from tracker.synthetic import simulate_observations
    from tracker import RobustTriangulator

    if repeats < 5:
        raise ValueError(f"--repeats must be >= 5, got {repeats}")
    rows = []
    for c in progress_bar(cameras, desc="bench estimator", unit="rig", disable=not progress):
        rig = load_sim_rig(c)
        _, uv, _ = simulate_observations(rig, 200, OUTLIER_RATE, np.random.default_rng([seed, c]))
        frames = list(uv)
        for method in ("paper", "ours"):
            est = RobustTriangulator(rig, method=method)
            ms, n = _time_calls(est.estimate, frames, repeats)
            rows.append({"cameras": c, "method": method, "median_ms": ms, "calls": n})
        eps = RobustTriangulator(rig).options.eps_px
        ms, n = _time_calls(lambda f: naive_estimate(f, rig, eps), frames, repeats, naive_budget_s, warmup=1)
        rows.append({"cameras": c, "method": "naive", "median_ms": ms, "calls": n})
    return rows


def format_table(rows: list[dict]) -> str:
    t = {(r["cameras"], r["method"]): r for r in rows}
    cams = sorted({r["cameras"] for r in rows})
    lines = [
        "| cameras | paper's C++ (Table 2) ms | Alg.2 (ours impl.) ms | ours ms | naive cv2 ms (calls) | naive / ours | goal ours ms | met |",
        "|---:|---:|---:|---:|---:|---:|---:|:---|",
    ]
    for c in cams:
        o, p, nv = t[(c, "ours")], t[(c, "paper")], t[(c, "naive")]
        goal = BENCH_GOAL_MS.get(c)
        ratio = nv["median_ms"] / o["median_ms"]
        met = []
        if goal is not None:
            met.append("time yes" if o["median_ms"] <= goal else "time NO")
        if c >= 15:
            met.append(f">={NAIVE_SPEEDUP_GOAL:g}x yes" if ratio >= NAIVE_SPEEDUP_GOAL else f">={NAIVE_SPEEDUP_GOAL:g}x NO")
        lines.append(
            f"| {c} | {PAPER_TABLE2_MS.get(c, float('nan')):g} | {p['median_ms']:.4f} | {o['median_ms']:.4f} "
            f"| {nv['median_ms']:.3f} ({nv['calls']}) | {ratio:.0f}x | {goal if goal is not None else '—'} | {', '.join(met) or '—'} |"
        )
    return "\n".join(lines)


def add_arguments(parser) -> None:
    parser.add_argument("--cameras", type=int, nargs="+", default=list(CAMERAS), help="camera counts (default 4 8 15 30 50)")
    parser.add_argument("--repeats", type=int, default=2000, help="timed calls per method (default 2000)")
    parser.add_argument("--naive-budget-s", type=float, default=3.0, help="time budget of the naive loop per camera count, s")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic frames (default 0)")
    parser.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write [{cameras, method, median_ms}] as JSON")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the benchmark, not after
    for c in args.cameras:
        if c < 2:
            raise ValueError(f"--cameras: every count must be >= 2, got {c}")
    rows = bench(args.cameras, repeats=args.repeats, naive_budget_s=args.naive_budget_s, seed=args.seed, progress=not args.no_progress)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"Median ms per estimate call, one observation per camera, {OUTLIER_RATE:.0%} outliers; "
          f"{os.cpu_count()} cores, load average {load}.\n")  # fmt: skip
    print(format_table(rows))
    if args.json:
        atomic_write_json(args.json, [{k: r[k] for k in ("cameras", "method", "median_ms")} for r in rows], "--json")
        print(f"\nwrote {args.json}")
    return 0
