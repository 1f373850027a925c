"""The accuracy experiment (paper Sec. 3.2): a ball on the WAM's end effector, the robot's kinematics as ground truth.

``rt2 accuracy`` runs it (:mod:`.cli`), ``rt2 reevaluate`` re-runs trackers on its session log
(:mod:`.reevaluate`). Modules: :mod:`.config` (AccuracyConfig), :mod:`.motion` (the simulated WAM at the
camera clock), :mod:`.scene` (what the cameras see), :mod:`.faults`, :mod:`.trackers`, :mod:`.frames`
(render + track per frame set), :mod:`.rig_error` (the trackers' calibration error), :mod:`.distractors`
(distractors that come and go), :mod:`.registration` (Kabsch/Umeyama, trimmed), :mod:`.evaluate`,
:mod:`.stats`, :mod:`.figure`, :mod:`.session_log`, :mod:`.experiment`. See docs/accuracy.md.
"""

from harness.experiments.accuracy.config import AccuracyConfig
from harness.experiments.accuracy.evaluate import TrackRecord, evaluate
from harness.experiments.accuracy.experiment import AccuracyResult, run_accuracy
from harness.experiments.accuracy.faults import FaultPlan
from harness.experiments.accuracy.motion import MotionOptions, RobotMotion, simulate_motion
from harness.experiments.accuracy.registration import RegistrationInfo, RegistrationOptions, fit_rigid, register_rigid
from harness.experiments.accuracy.rig_error import CalibrationErrorOptions, estimated_rig
from harness.experiments.accuracy.session_scene import SceneOptions, SessionScene
from harness.experiments.accuracy.stats import JSON_KEYS, error_stats

__all__ = [
    "AccuracyConfig",
    "AccuracyResult",
    "CalibrationErrorOptions",
    "FaultPlan",
    "JSON_KEYS",
    "MotionOptions",
    "RegistrationInfo",
    "RegistrationOptions",
    "RobotMotion",
    "SceneOptions",
    "SessionScene",
    "TrackRecord",
    "error_stats",
    "estimated_rig",
    "evaluate",
    "fit_rigid",
    "register_rigid",
    "run_accuracy",
    "simulate_motion",
]
