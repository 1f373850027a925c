"""From per-frame tracker positions and ground truth to the experiment's figures (live run and re-evaluation).

Both ``rt2 accuracy`` and ``rt2 reevaluate`` call :func:`evaluate` on the same kind of arrays, so with the
same inputs they produce the same figures, bit for bit:

1. registration (the frames of ``config.register_mask``): the registration tracker's ``OK`` positions against the
   ground truth in the robot base frame, :func:`register_rigid` (Kabsch/Umeyama, trimmed re-fit);
2. scoring (the other frames): per tracker the distance to the registered ground truth
   (:func:`harness.experiments.accuracy.stats.error_stats`), the paper's error bands, and the injected faults.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.experiments.accuracy.config import AccuracyConfig
from harness.experiments.accuracy.faults import FaultPlan, affected_frames
from harness.experiments.accuracy.motion import world_to_base
from harness.experiments.accuracy.registration import register_rigid, registration_std, transform_difference
from harness.experiments.accuracy.stats import error_stats, mode_shares

__all__ = ["MAX_REGISTRATION_STD_M", "TrackRecord", "evaluate", "fault_plan_of"]

#: registration is called well-conditioned when the transform it found is uncertain by less than this
#: (first-order std, 90th percentile over the scored ground-truth points, metres)
MAX_REGISTRATION_STD_M = 0.003


@dataclass
class TrackRecord:
    """Per-frame outcome of one tracker over a run (n = config.n_frames rows, frame order).

    position_m : (n, 3) world positions, NaN rows where no position (or the frame is absent)
    ok : (n,) bool, status OK
    flagged : (n,) bool, the observation carries notes
    present : (n,) bool, the frame was processed (False for frames lost from a truncated log)
    """

    position_m: np.ndarray
    ok: np.ndarray
    flagged: np.ndarray
    present: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "TrackRecord":
        return cls(np.full((n, 3), np.nan), np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool))

    def put(self, k: int, obs) -> None:
        """Store observation ``obs`` (a tracker.BallObservation) of frame ``k``."""
        if obs.position_m is not None:
            self.position_m[k] = obs.position_m
        self.ok[k] = obs.status.value == "ok"
        self.flagged[k] = bool(obs.notes)
        self.present[k] = True


def fault_plan_of(config: AccuracyConfig, n_cams: int) -> FaultPlan:
    return FaultPlan.default(config.n_frames, n_cams) if config.inject_faults else FaultPlan.none()


def evaluate(config: AccuracyConfig, records: dict, gt_world_m, gt_present, T_base_to_world_nominal,
             camera_names) -> tuple[dict, dict]:
    """The figures of a run (JSON-able; no timing in it, so the same inputs give the same figures) and
    the errors behind them, {tracker: (n_scored,) metres, NaN = no position} (for the histogram).

    records : {tracker: :class:`TrackRecord`}; gt_world_m : (n, 3) FK of the reported joints through
    the nominal mount (what the log holds); gt_present : (n,) bool; T_base_to_world_nominal : (4, 4)
    """
    n = config.n_frames
    gt_world = np.asarray(gt_world_m, float)
    if gt_world.shape != (n, 3):
        raise ValueError(f"gt_world_m must have shape ({n}, 3) for {n} frames, got {gt_world.shape}")
    gt_base = world_to_base(gt_world, T_base_to_world_nominal)
    ref = config.registration_tracker
    if ref not in records:
        raise ValueError(f"registration needs tracker {ref!r}, got records of {sorted(records)}")
    present = np.asarray(gt_present, bool) & np.all([r.present for r in records.values()], axis=0)
    in_reg = config.register_mask
    reg = present & in_reg & records[ref].ok & ~affected_frames(fault_plan_of(config, len(camera_names)), n)  # faulted frames never register
    if reg.sum() < config.registration.min_pairs:
        raise ValueError(f"only {int(reg.sum())} of the {config.n_register} registration frames have an OK {ref} position "
                         f"and ground truth; registration needs {config.registration.min_pairs}")
    T, info = register_rigid(gt_base[reg], records[ref].position_m[reg], config.registration)
    gt_reg = gt_base @ T[:3, :3].T + T[:3, 3]
    scored = present & ~in_reg
    if not scored.any():
        raise ValueError(f"no frame outside the {config.n_register} registration frames to score")
    rot_deg, trans_m = transform_difference(T, T_base_to_world_nominal)
    reg_std = float(np.percentile(registration_std(gt_base[reg][info.inliers], info.rms_m, gt_base[scored]), 90))
    rows, modes, errors = [], {}, {}
    for kind in records:
        e = np.linalg.norm(records[kind].position_m - gt_reg, axis=1)  # NaN where no position
        errors[kind] = e[scored]
        rows.append(error_stats(kind, e[scored]))
        modes[kind] = mode_shares(e[scored])
    figures = {
        "rows": rows,
        "modes": modes,
        "n_frames": n,
        "n_present": int(present.sum()),
        "n_register": config.n_register,
        "register_layout": config.register_layout,
        "n_scored": int(scored.sum()),
        "registration": {
            "tracker": ref, "pairs": info.n_pairs, "inliers": info.n_inliers, "iterations": info.iterations,
            "rms_cm": round(100 * info.rms_m, 4), "max_cm": round(100 * info.max_m, 4),
            "spread_cm": [round(100 * float(s), 3) for s in info.spread_m],
            "std_at_scored_p90_cm": round(100 * reg_std, 4),
            "well_conditioned": bool(reg_std <= MAX_REGISTRATION_STD_M),
            "T_base_to_world": np.round(T, 9).tolist(),
            "vs_true_mount": {"rotation_deg": round(rot_deg, 5), "translation_cm": round(100 * trans_m, 4)},
        },
        "faults": _fault_figures(config, records, errors, scored, camera_names),
    }
    return figures, errors


def _fault_figures(config, records, errors, scored, camera_names) -> dict:
    plan = fault_plan_of(config, len(camera_names))
    if not plan.active:
        return {"injected": False}
    out = {"injected": True, "plan": plan.summary(camera_names), "by_kind": {}}
    k = np.arange(config.n_frames)
    spans = {"no_frame": (plan.no_frame[1] <= k) & (k < plan.no_frame[2]),
             "wrong_size": (plan.wrong_size[1] <= k) & (k < plan.wrong_size[2]),
             "non_monotonic": k == plan.non_monotonic_frame}
    for fault, hit in spans.items():
        hit = hit & np.all([r.present for r in records.values()], axis=0)
        entry = {"frames": int(hit.sum())}
        for kind, r in records.items():
            with_pos = int(np.isfinite(r.position_m[hit, 0]).sum())
            err = errors[kind][hit[scored]]
            err = err[np.isfinite(err)]
            entry[kind] = {"flagged": int(r.flagged[hit].sum()), "with_position": with_pos,
                           "median_error_cm": round(float(np.median(err)) * 100, 4) if err.size else None}
        out["by_kind"][fault] = entry
    return out
