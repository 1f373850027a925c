"""``rt2 calib loop``: the accuracy experiment with a self-made calibration vs with the true rig.

Both runs render with the true rig (``--rig``) and share seed, robot motion and scene; only the rig the
trackers triangulate with differs: the true one, or ``--calibrated`` (e.g. ``rt2 calib check``'s
rig.yaml, calibrated from rendered board views and a wand). The figures (mean, median, p90 error after
the robot registration) with the self-made calibration should be within 20 % of those with the true rig.
"""

from __future__ import annotations

import json
from pathlib import Path

from harness.experiments.accuracy.config import AccuracyConfig
from harness.experiments.accuracy.rig_error import CalibrationErrorOptions
from harness.experiments.accuracy.stats import TRACKER_KINDS

__all__ = ["add_arguments", "run"]

FIGURES = ("mean_cm", "median_cm", "p90_cm")
GOAL_RATIO = 1.2


def add_arguments(parser) -> None:
    parser.add_argument("--calibrated", required=True, help="the self-made rig file the trackers get")
    parser.add_argument("--rig", default="lab4_vga", help="the true rig the images are rendered with (default lab4_vga)")
    parser.add_argument("--frames", type=int, default=500, help="frame sets per run (default 500)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trackers", nargs="+", default=["rt2"], choices=TRACKER_KINDS)
    parser.add_argument("--out", required=True, help="folder: one accuracy run per rig (true/, calibrated/) and loop.json")


def run(args) -> int:
    from harness.experiments.accuracy.experiment import run_accuracy
    from tracker.rig_files import resolve_rig

    if args.frames < 100:
        raise ValueError(f"--frames must be >= 100 (the robot registration needs them), got {args.frames}")
    truth, calibrated = resolve_rig(args.rig), resolve_rig(args.calibrated)
    if truth.names != calibrated.names:
        raise ValueError(f"--calibrated {args.calibrated}: cameras {calibrated.names} differ from --rig {args.rig}'s {truth.names}")
    out = Path(args.out)
    base = dict(seed=args.seed, n_frames=args.frames, rig=args.rig, trackers=tuple(args.trackers))
    runs = {"true": CalibrationErrorOptions(enabled=False), "calibrated": CalibrationErrorOptions(rig_file=str(args.calibrated))}
    rows, cal = {}, {}
    for name, opts in runs.items():
        res = run_accuracy(AccuracyConfig(**base, calibration_error=opts), out / name, workers=1, log=False, progress=False)
        rows[name] = {r["tracker"]: r for r in res.rows}
        cal[name] = res.calibration_error
    table, ok = [], True
    for tr in args.trackers:
        for fig in FIGURES:
            a, b = rows["true"][tr][fig], rows["calibrated"][tr][fig]
            ratio = b / a if a else float("inf")
            ok &= ratio <= GOAL_RATIO
            table.append({"tracker": tr, "figure": fig, "true_rig": a, "calibrated": b, "ratio": ratio})
    rep = {"rig": args.rig, "calibrated": str(args.calibrated), "frames": args.frames, "seed": args.seed, "figures": table,
           "goal_ratio": GOAL_RATIO, "met": bool(ok),
           "calibrated_rig_error": {k: cal["calibrated"].get(k) for k in ("reprojection_px", "triangulation_mm", "triangulation_after_rigid_mm") if k in cal["calibrated"]}}
    out.mkdir(parents=True, exist_ok=True)
    (out / "loop.json").write_text(json.dumps(rep, indent=1, default=float))
    print(f"accuracy, {args.frames} frame sets, seed {args.seed}: trackers with the true rig vs with {args.calibrated}")
    print(f"{'tracker':>10s} {'figure':>10s} {'true rig':>9s} {'calibrated':>10s} {'ratio':>6s}")
    for r in table:
        print(f"{r['tracker']:>10s} {r['figure']:>10s} {r['true_rig']:9.3f} {r['calibrated']:10.3f} {r['ratio']:6.2f}")
    print(f"goal: ratio <= {GOAL_RATIO} -> {'MET' if ok else 'NOT MET'}; wrote {out / 'loop.json'}")
    return 0
