"""``rt2 bench renderer``: images per second of the synthetic cameras on one core.

Per scene type, ``Renderer.render(scene)`` is timed over a seeded list of scenes on every camera
of the rig (OpenCV limited to one thread; the numba kernel is single-threaded), and the median
time per *image* (frame-set time / cameras) is reported with its rate. Scene types: ``empty``
(static lab + noise only: the floor of the cost), ``ball`` (one ball at 8 m/s), ``dataset`` (the
random data-set scenes of ``rt2 sim dataset``), ``crowded`` (person, robot, racket, two balls and
up to ten distractors), and ``dataset`` again with the plain-numpy reference kernel for the
same-process speed ratio. Goal: >= 200 VGA images/s on ``dataset`` scenes.
"""

from __future__ import annotations

import gc
import time

import numpy as np

__all__ = ["GOAL_FRAMES_PER_S", "add_arguments", "bench", "format_table", "run"]

GOAL_FRAMES_PER_S = 200.0


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="lab4_vga", help="rig name in data/rigs or a rig file (default: lab4_vga)")
    parser.add_argument("--frames", type=int, default=200, help="frame sets timed per scene type (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scenes (default 0)")
    parser.add_argument("--json", metavar="PATH", help="also write the rows as JSON to PATH")


def _scenes(kind: str, n: int, seed: int, workspace_m) -> list:
    from harness.sim.render import Ball, Scene
    from harness.sim.render.scenes import SceneOptions, random_scene

    if kind == "empty":
        return [Scene(frame_index=i) for i in range(n)]
    rng = np.random.default_rng([seed, 7])
    if kind == "ball":
        lo, hi = np.asarray(workspace_m)
        return [Scene(balls=(Ball(rng.uniform(lo, hi), (-8.0, 0.5, 1.0)),), frame_index=i) for i in range(n)]
    opts = SceneOptions() if kind == "dataset" else SceneOptions(
        p_no_ball=0.0, p_person=1.0, p_robot=1.0, p_racket=1.0, p_second_ball=1.0, max_distractors=10
    )  # fmt: skip
    return [random_scene(np.random.default_rng([seed, i]), workspace_m, opts, frame_index=i) for i in range(n)]


def _time(renderer, scenes, budget_s: float | None) -> tuple[float, int]:
    """Median ms per frame set over ``scenes`` (after a warm-up), stopping early past ``budget_s``."""
    for s in scenes[:3]:
        renderer.render(s)
    times = []
    start = time.perf_counter()
    gc.disable()
    try:
        for k, s in enumerate(scenes):
            t0 = time.perf_counter_ns()
            renderer.render(s)
            times.append(time.perf_counter_ns() - t0)
            if budget_s is not None and k >= 9 and time.perf_counter() - start > budget_s:
                break
    finally:
        gc.enable()
    return float(np.median(times) / 1e6), len(times)


def bench(rig="lab4_vga", *, frames: int = 200, seed: int = 0, progress: bool = True) -> list[dict]:
    """Rows {scene, method, frames_per_s, median_ms, frame_sets}; ``median_ms`` is per image."""
    import cv2
    from harness.common.progress import progress_bar

    from harness.sim.render import Renderer, RenderOptions
    from tracker.rig_files import resolve_rig

    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 10:
        raise ValueError(f"--frames must be an integer >= 10, got {frames!r}")
    rig = resolve_rig(rig)
    cv2.setNumThreads(1)  # one core: the claim is per core
    workspace = rig.workspace_m if rig.workspace_m is not None else None
    if workspace is None:
        from harness.sim.lab import LAB4_WORKSPACE_M

        workspace = LAB4_WORKSPACE_M
    renderers = {m: Renderer(rig, RenderOptions(method=m), seed=seed) for m in ("numba", "numpy")}
    plan = [("empty", "numba"), ("ball", "numba"), ("dataset", "numba"), ("crowded", "numba"), ("dataset", "numpy")]
    rows = []
    for kind, method in progress_bar(plan, desc="bench renderer", unit="scene type", disable=not progress):
        scenes = _scenes(kind, frames, seed, workspace)
        ms_set, n = _time(renderers[method], scenes, 20.0 if method == "numpy" else None)
        ms = ms_set / len(rig)
        rows.append({"scene": kind, "method": method, "frames_per_s": 1000.0 / ms, "median_ms": ms, "frame_sets": n, "cameras": len(rig)})
    return rows


def format_table(rows: list[dict]) -> str:
    base = {r["scene"]: r["median_ms"] for r in rows if r["method"] == "numpy"}
    lines = [
        "| scene | kernel | images/s (one core) | median ms / image | frame sets timed | numpy / numba | goal >= 200/s |",
        "|---|---|---:|---:|---:|---:|:---|",
    ]
    for r in rows:
        ratio = f"{base[r['scene']] / r['median_ms']:.1f}x" if (r["method"] == "numba" and r["scene"] in base) else ""
        goal = ("met" if r["frames_per_s"] >= GOAL_FRAMES_PER_S else "MISSED") if r["method"] == "numba" else ""
        lines.append(f"| {r['scene']} | {r['method']} | {r['frames_per_s']:.0f} | {r['median_ms']:.2f} | {r['frame_sets']} | {ratio} | {goal} |")
    return "\n".join(lines)


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the benchmark, not after
    rows = bench(args.rig, frames=args.frames, seed=args.seed)
    print(format_table(rows))
    if args.json:
        atomic_write_json(args.json, rows, "--json")
        print(f"wrote {args.json}")
    return 0
