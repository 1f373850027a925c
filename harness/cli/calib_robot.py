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

from harness.experiments.accuracy.motion import world_to_base
from harness.experiments.accuracy.registration import RegistrationOptions, fit_rigid, register_rigid, registration_std, transform_difference
from tracker import Status
from tracker.calibration.poses import rotation_angle_deg

__all__ = ["add_arguments", "register_from_log", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--log", required=True, help="a session log (.mcap) with /ground_truth/ball (FK of the reported joints) and a tracker's ball")
    parser.add_argument("--tracker", default=None, help="whose observations to use (default: the log's registration tracker, else the first)")
    parser.add_argument("--out", default=None, help="write T_base_to_world and its uncertainty here (YAML)")
    parser.add_argument("--frames", choices=["register", "all"], default="register",
                        help="'register': the frames the accuracy run registered on (its register mask without fault-injected frames; all frames for other logs); 'all'")
    parser.add_argument("--bootstrap", type=int, default=200, help="bootstrap resamples for the uncertainty (default 200)")
    parser.add_argument("--seed", type=int, default=0)


def register_from_log(path, tracker=None, *, frames: str = "register", bootstrap: int = 200, seed: int = 0) -> dict:
    from harness.logs.reader import SessionLogReader
    from harness.logs.topics import GROUND_TRUTH_BALL, tracker_topic

    with SessionLogReader(path) as log:
        session = log.metadata("session")
        if "T_base_to_world_nominal" not in session:
            raise ValueError(f"{path}: the session metadata has no T_base_to_world_nominal (not a robot session log)")
        T_nom = np.asarray(session["T_base_to_world_nominal"], float)
        trackers = [t for t in session.get("trackers", []) if tracker_topic(t) in log.topics()]
        cfg = session.get("config", {})
        name = tracker or (cfg.get("registration_tracker") if cfg.get("registration_tracker") in trackers else (trackers or [None])[0])
        if name is None or tracker_topic(name) not in log.topics():
            raise ValueError(f"{path}: no observations of tracker {name!r}; trackers in this log: {trackers}")
        if GROUND_TRUTH_BALL not in log.topics():
            raise ValueError(f"{path}: no {GROUND_TRUTH_BALL} (ball FK from the joints) in this log")
        fk, cam = {}, {}
        for msg in log.messages([GROUND_TRUTH_BALL, tracker_topic(name)]):
            d = msg.data
            if msg.topic == GROUND_TRUTH_BALL:
                fk[int(d.frame_index)] = d.position_m
            elif Status(d.status) == Status.OK and d.position_m is not None:
                cam[msg.sequence] = np.asarray(d.position_m, float)
    use = set(fk) & set(cam)
    if frames == "register" and session.get("kind") == "accuracy":
        from harness.experiments.accuracy.config import AccuracyConfig
        from harness.experiments.accuracy.evaluate import fault_plan_of
        from harness.experiments.accuracy.faults import affected_frames

        config = AccuracyConfig.from_dict(cfg, where=f"{path}: session config")
        n_cams = len(session.get("camera_names", []))
        # the run's registration frames, without the ones its injected faults touched (as the run did)
        mask = config.register_mask & ~affected_frames(fault_plan_of(config, n_cams), config.n_frames)
        use = {f for f in use if f < len(mask) and mask[f]}
    frames = sorted(use)
    if len(frames) < 10:
        raise ValueError(f"{path}: only {len(frames)} frames have both the ball's FK and an OK position of {name}; need >= 10")
    X_world_fk = np.array([fk[f] for f in frames])
    X_base = world_to_base(X_world_fk, T_nom)
    X_cam = np.array([cam[f] for f in frames])
    ok = np.isfinite(X_base).all(axis=1) & np.isfinite(X_cam).all(axis=1)
    X_base, X_cam = X_base[ok], X_cam[ok]
    T, info = register_rigid(X_base, X_cam, RegistrationOptions())
    rng = np.random.default_rng(seed)
    A, B = X_base[info.inliers], X_cam[info.inliers]
    rots, trans = [], []
    for _ in range(bootstrap):
        idx = rng.integers(0, len(A), len(A))
        Tb = fit_rigid(A[idx], B[idx])
        rots.append(float(rotation_angle_deg(Tb[:3, :3], T[:3, :3])))
        trans.append(Tb[:3, 3] - T[:3, 3])
    pos_std = registration_std(A, info.rms_m, A)
    nominal_deg, nominal_m = transform_difference(T, T_nom)
    return {
        "T_base_to_world": T.tolist(), "tracker": name, "pairs": info.n_pairs, "inliers": info.n_inliers,
        "rms_mm": 1000 * info.rms_m, "max_mm": 1000 * info.max_m,
        "std_rotation_deg": float(np.sqrt(np.mean(np.square(rots)))) if rots else None,
        "std_translation_mm": (1000 * np.std(trans, axis=0)).tolist() if trans else None,
        "ball_position_std_mm": {"median": float(1000 * np.median(pos_std)), "max": float(1000 * pos_std.max())},
        "vs_nominal_mount": {"rotation_deg": nominal_deg, "translation_mm": 1000 * nominal_m},
        "spread_m": info.spread_m.tolist(),
    }


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
