"""``rt2 calib check``: calibrate a rig from rendered data (ChArUco views, a waved wand) and compare with its truth."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from harness.calib.check import CheckConfig, run_check

__all__ = ["add_arguments", "run"]

GOALS = {"focal_pct": 0.3, "principal_px": 1.0, "centre_mm": 3.0, "rotation_deg": 0.05}


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="lab4_vga", help="the true rig: a name in data/rigs or a rig file (default lab4_vga)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--board-views", type=int, default=60, help="rendered ChArUco views per camera (default 60)")
    parser.add_argument("--wand-frames", type=int, default=300, help="rendered wand frame sets (default 300)")
    parser.add_argument("--out", required=True, help="folder for the calibrated rig (rig.yaml) and the figures (check.json)")


def run(args) -> int:
    for name in ("board_views", "wand_frames"):
        if getattr(args, name) < 10:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 10, got {getattr(args, name)}")
    cfg = CheckConfig(rig=args.rig, seed=args.seed, n_board_views=args.board_views, n_wand_frames=args.wand_frames)
    res = run_check(cfg)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rig = res.pop("rig_obj")
    rig.save(out / "rig.yaml")
    res["config"] = asdict(cfg)
    res["goals"] = GOALS
    (out / "check.json").write_text(json.dumps(res, indent=1))
    print(format_check(res))
    print(f"wrote {out / 'rig.yaml'}, {out / 'check.json'}")
    return 0


def format_check(res: dict) -> str:
    intr, ext = res["intrinsics"]["vs_truth"]["cameras"], res["extrinsics_vs_truth"]["cameras"]
    lines = [f"rig {res['rig']} ({res['cameras']} cameras), seed {res['seed']}: calibrated from rendered data vs the truth",
             f"{'camera':>8s} {'focal %':>8s} {'pp px':>6s} {'centre mm':>9s} {'rot deg':>8s} {'wand rms px':>11s}"]
    for n, r in intr.items():
        e = ext[n]
        lines.append(f"{n:>8s} {r['focal_pct']:8.3f} {r['principal_px']:6.2f} {e['centre_mm']:9.2f} {e['rotation_deg']:8.4f} "
                     f"{res['wand']['reprojection_px'][n]['rms_px']:11.2f}")
    w = res["extrinsics_vs_truth"]["worst"]
    wi = res["intrinsics"]["vs_truth"]["worst"]
    lines.append(f"{'worst':>8s} {wi['focal_pct']:8.3f} {wi['principal_px']:6.2f} {w['centre_mm']:9.2f} {w['rotation_deg']:8.4f}")
    lines.append(f"{'goal':>8s} {GOALS['focal_pct']:8.3f} {GOALS['principal_px']:6.2f} {GOALS['centre_mm']:9.2f} {GOALS['rotation_deg']:8.4f}")
    h = res["wand"]["holdout_total_error_mm"]
    lines.append(f"wand 390 mm on {h['n']} held-out frame sets: error {h['mean']:+.2f} mm mean, {h['std']:.2f} mm std (goal std <= 0.5), "
                 f"{h.get('robust_std', float('nan')):.2f} mm robust std (1.4826 MAD), max |error| {h.get('max_abs', float('nan')):.2f} mm; "
                 f"balls labelled in {100 * res['wand']['detected_fraction']:.0f} % of camera views; table fit residual "
                 f"{max(res['table_fit_residual_mm']):.1f} mm")
    return "\n".join(lines)
