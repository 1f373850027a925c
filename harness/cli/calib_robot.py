"""``rt2 calib robot``: the robot base -> camera world transform from a session log, with its uncertainty.

The ball sits on the end effector. Its position in the base frame comes from the reported joints: the
log's ``/ground_truth/ball`` is forward kinematics of the reported joints mapped through the nominal
mount (``session`` metadata ``T_base_to_world_nominal``), so it maps back to the base frame exactly.
The camera-frame positions are a tracker's OK observations (``/tracker/<name>/ball``). The fit is the
accuracy experiment's robust registration (``harness.experiments.accuracy.registration.register_rigid``: Umeyama /
Kabsch with trimmed re-fits). Uncertainty: a seeded bootstrap over the kept pairs (rotation, translation)
and the first-order spread of the transformed ball positions (``registration_std``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from harness.experiments.accuracy.robot_registration import register_from_log

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--log", required=True, help="a session log (.mcap) with /ground_truth/ball (FK of the reported joints) and a tracker's ball")
    parser.add_argument("--tracker", default=None, help="whose observations to use (default: the log's registration tracker, else the first)")
    parser.add_argument("--out", default=None, help="write T_base_to_world and its uncertainty here (YAML)")
    parser.add_argument("--frames", choices=["register", "all"], default="register",
                        help="'register': the frames the accuracy run registered on (its register mask without fault-injected frames; all frames for other logs); 'all'")
    parser.add_argument("--bootstrap", type=int, default=200, help="bootstrap resamples for the uncertainty (default 200)")
    parser.add_argument("--seed", type=int, default=0)


def run(args) -> int:
    if args.bootstrap < 0:
        raise ValueError(f"--bootstrap must be >= 0, got {args.bootstrap}")
    path = Path(args.log)
    if not path.is_file():
        raise ValueError(f"--log {str(path)!r}: no such file")
    res = register_from_log(path, args.tracker, frames=args.frames, bootstrap=args.bootstrap, seed=args.seed)
    T = np.asarray(res["T_base_to_world"])
    print(f"robot base -> camera world from {res['inliers']} of {res['pairs']} frames ({res['tracker']}): rms {res['rms_mm']:.2f} mm, max {res['max_mm']:.2f} mm")
    print("T_base_to_world =\n" + "\n".join("  " + " ".join(f"{v:+.5f}" for v in row) for row in T))
    if res["std_rotation_deg"] is not None:
        print(f"uncertainty (bootstrap {args.bootstrap}): rotation {res['std_rotation_deg']:.4f} deg, translation "
              + ", ".join(f"{v:.2f}" for v in res["std_translation_mm"]) + " mm (x, y, z)")
    print(f"difference to the log's nominal mount: {res['vs_nominal_mount']['rotation_deg']:.4f} deg, {res['vs_nominal_mount']['translation_mm']:.2f} mm")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("# robot base -> camera world (X_world = R X_base + t), metres; rt2 calib robot\n"
                       + yaml.safe_dump({"format": "rt2.robot_registration", "version": 1, "log": str(path), **res}, sort_keys=False))
        print(f"wrote {out}")
    return 0
