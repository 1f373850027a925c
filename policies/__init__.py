"""rt2 policies: what the robot decides from ball observations.

May import ``robot_models`` and the types of ``tracker``, never ``harness`` (docs/architecture.md).
The ball model lives here so that the hitting policy predicts the ball with the same physics the
simulated world uses.
"""

from policies.ball_estimation import (
    BallEKF,
    BallEstimate,
    EKFOptions,
    EstimatorOptions,
    FitInfo,
    fit_initial_state,
    fit_initial_state_mixture,
)
from policies.ball_model import (
    BallParams,
    TableGeometry,
    acceleration,
    make_state,
    predict,
    predict_batch,
    simulate,
    surface_contact,
)
from policies.filters import FILTERS, BallFilter, BallTrajectoryPrediction, make_filter
from policies.promp import EMInfo, NIWPrior, ProMP, RBFBasis
from policies.hitting import HitPlan, HittingOptions, HittingPolicy, PolicyStatus, PolicyStep
from policies.teacher import Demonstration, ScriptedTeacher, TeacherOptions, racket_kinematics

__all__ = [
    "FILTERS",
    "BallFilter",
    "BallTrajectoryPrediction",
    "make_filter",
    "BallEKF",
    "BallEstimate",
    "BallParams",
    "EKFOptions",
    "EstimatorOptions",
    "TableGeometry",
    "acceleration",
    "FitInfo",
    "fit_initial_state",
    "fit_initial_state_mixture",
    "make_state",
    "predict",
    "predict_batch",
    "simulate",
    "surface_contact",
    "Demonstration",
    "EMInfo",
    "NIWPrior",
    "ProMP",
    "RBFBasis",
    "ScriptedTeacher",
    "TeacherOptions",
    "racket_kinematics",
    "HitPlan",
    "HittingOptions",
    "HittingPolicy",
    "PolicyStatus",
    "PolicyStep",
]
