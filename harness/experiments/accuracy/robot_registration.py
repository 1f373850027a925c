"""The robot base -> camera world transform from an accuracy session log (``rt2 calib robot``), with its
bootstrap uncertainty; the fit is the accuracy experiment's robust registration (see harness/cli/calib_robot.py)."""

from __future__ import annotations

import numpy as np

from harness.experiments.accuracy.motion import world_to_base
from harness.experiments.accuracy.registration import RegistrationOptions, fit_rigid, register_rigid, registration_std, transform_difference
from tracker import Status
from tracker.calibration.poses import rotation_angle_deg

__all__ = ["register_from_log"]


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
        "T_base_to_world": T.tolist(), "robot": cfg.get("robot", "wam"), "tracker": name, "pairs": info.n_pairs, "inliers": info.n_inliers,
        "rms_mm": 1000 * info.rms_m, "max_mm": 1000 * info.max_m,
        "std_rotation_deg": float(np.sqrt(np.mean(np.square(rots)))) if rots else None,
        "std_translation_mm": (1000 * np.std(trans, axis=0)).tolist() if trans else None,
        "ball_position_std_mm": {"median": float(1000 * np.median(pos_std)), "max": float(1000 * pos_std.max())},
        "vs_nominal_mount": {"rotation_deg": nominal_deg, "translation_mm": 1000 * nominal_m},
        "spread_m": info.spread_m.tolist(),
    }
