"""Topic names, schema names and the error type of rt2 session logs (documented in docs/logging.md).

One session = one MCAP file. Topics follow one scheme so a reader (or Foxglove) can find things
without configuration::

    /camera/<camera>/image         foxglove.CompressedImage (png, jpeg) or foxglove.RawImage (raw)
    /camera/<camera>/detections    rt2.Detections          candidates (pixels) and scores
    /camera/<camera>/annotations   foxglove.ImageAnnotations  the same candidates, drawn on the image
    /camera/<camera>/calibration   foxglove.CameraCalibration  once, from the rig
    /tracker/<tracker>/ball        rt2.BallObservation     one per frame set and tracker
    /ground_truth/ball             rt2.GroundTruthBall     ball centre from the simulator's kinematics
    /robot/joint_states            foxglove.JointStates    measured q, qdot
    /robot/command                 foxglove.JointStates    commanded q
    /tf                            foxglove.FrameTransforms  the arm's link frames, per tick
    /tf_static                     foxglove.FrameTransforms  camera frames, once
    /scene/static                  foxglove.SceneUpdate    table, net, camera frustums, once
    /scene/arm                     foxglove.SceneUpdate    the arm as lines between link frames
    /scene/balls                   foxglove.SceneUpdate    the true ball and each tracker's ball
    /figures/<name>                rt2.Figures             an experiment's final figures
"""

from __future__ import annotations

import re

__all__ = [
    "LogError",
    "check_name",
    "image_topic",
    "detections_topic",
    "annotations_topic",
    "calibration_topic",
    "tracker_topic",
    "figures_topic",
    "GROUND_TRUTH_BALL",
    "JOINT_STATES",
    "COMMAND",
    "TF",
    "TF_STATIC",
    "SCENE_STATIC",
    "SCENE_ARM",
    "SCENE_BALLS",
    "WORLD_FRAME",
]


class LogError(ValueError):
    """A session log cannot be written or read as asked (bad file, bad field, bad value).

    A subclass of ``ValueError`` so the ``rt2`` CLI turns it into a one-line message.
    """


GROUND_TRUTH_BALL = "/ground_truth/ball"
JOINT_STATES = "/robot/joint_states"
COMMAND = "/robot/command"
TF = "/tf"
TF_STATIC = "/tf_static"
SCENE_STATIC = "/scene/static"
SCENE_ARM = "/scene/arm"
SCENE_BALLS = "/scene/balls"
#: name of the lab world frame in transforms and scene entities
WORLD_FRAME = "world"

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")


def check_name(name, what: str) -> str:
    """Return ``name`` if it can be one path element of a topic (letters, digits, ``_.-``)."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise LogError(f"{what} must be a non-empty name of letters, digits, '_', '.' or '-', got {name!r}")
    return name


def image_topic(camera: str) -> str:
    return f"/camera/{camera}/image"


def detections_topic(camera: str) -> str:
    return f"/camera/{camera}/detections"


def annotations_topic(camera: str) -> str:
    return f"/camera/{camera}/annotations"


def calibration_topic(camera: str) -> str:
    return f"/camera/{camera}/calibration"


def tracker_topic(tracker: str) -> str:
    return f"/tracker/{tracker}/ball"


def figures_topic(name: str) -> str:
    return f"/figures/{name}"
