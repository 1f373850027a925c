"""Calibration exchange formats: OpenCV FileStorage (one file per camera) and aniposelib's calibration.toml.

aniposelib's ``calibration.toml`` (read by anipose, Pose2Sim, caliscope) holds one table per camera::

    [cam_0]
    name = "cam0"
    size = [1280, 720]                       # width, height
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]
    rotation = [rx, ry, rz]                  # Rodrigues vector, world -> camera
    translation = [tx, ty, tz]               # world -> camera, in the file's length unit

    [metadata]
    adjusted = false
    error = 0.0

Lengths: aniposelib uses the board's unit (often mm); ``length_unit_m`` says which (default 1.0:
metres, as Pose2Sim writes). OpenCV files use millimetres by default, as the ewand framework does,
so ``Rig.from_opencv_files(paths, length_unit_m=0.001)`` reads them back.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from tracker import Camera, Rig
from tracker.rig_files import read_anipose_toml  # the reader lives with the rig resolver (--rig accepts .toml)

__all__ = ["add_export_arguments", "read_anipose_toml", "save_calibration", "write_anipose_toml", "write_exports", "write_opencv_files"]


def write_opencv_files(rig: Rig, folder, *, length_unit_m: float = 0.001) -> list[Path]:
    """One OpenCV FileStorage YAML per camera, ``<folder>/<name>.yaml``; lengths in ``length_unit_m``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for cam in rig:
        path = folder / f"{cam.name}.yaml"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        try:
            fs.write("camera_name", cam.name)
            fs.write("image_width", int(cam.image_size[0]))
            fs.write("image_height", int(cam.image_size[1]))
            fs.write("camera_matrix", np.asarray(cam.K, float))
            fs.write("distortion_model", cam.distortion_model)
            fs.write("distortion_coefficients", np.asarray(cam.distortion, float).reshape(1, -1))
            ext = np.hstack([cam.R_world_to_cam, cam.t_world_to_cam_m[:, None] / length_unit_m])
            fs.write("extrinsics", ext)
        finally:
            fs.release()
        out.append(path)
    return out


def _toml_value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    x = float(v)
    if not math.isfinite(x):
        raise ValueError(f"cannot write {x} to TOML")
    return repr(x)


def write_anipose_toml(rig: Rig, path, *, length_unit_m: float = 1.0, error: float = 0.0) -> Path:
    """aniposelib ``calibration.toml`` for ``rig`` (translations in ``length_unit_m``)."""
    path = Path(path)
    lines = []
    for i, cam in enumerate(rig):
        rvec = cv2.Rodrigues(cam.R_world_to_cam)[0].ravel()
        lines += [f"[cam_{i}]", f"name = {_toml_value(cam.name)}", f"size = {_toml_value(list(cam.image_size))}",
                  f"matrix = {_toml_value(cam.K.tolist())}", f"distortions = {_toml_value(cam.distortion.tolist())}",
                  f"rotation = {_toml_value(rvec.tolist())}",
                  f"translation = {_toml_value((cam.t_world_to_cam_m / length_unit_m).tolist())}", ""]
    lines += ["[metadata]", "adjusted = false", f"error = {_toml_value(float(error))}", ""]
    path.write_text("\n".join(lines))
    return path


def add_export_arguments(parser) -> None:
    parser.add_argument("--opencv-dir", default=None, help="also write one OpenCV FileStorage YAML per camera here (lengths in mm)")
    parser.add_argument("--anipose-toml", default=None, help="also write aniposelib's calibration.toml here (metres)")


def write_exports(rig: Rig, args, *, error: float = 0.0) -> list[str]:
    """Write the exports asked for by :func:`add_export_arguments`; returns the paths written."""
    out = []
    if getattr(args, "opencv_dir", None):
        out += [str(p) for p in write_opencv_files(rig, args.opencv_dir)]
    if getattr(args, "anipose_toml", None):
        out.append(str(write_anipose_toml(rig, args.anipose_toml, error=error)))
    return out


def save_calibration(rig: Rig, report: dict, args, *, error: float = 0.0) -> list[str]:
    """Write ``rig`` to ``args.out``, ``report`` next to it (``.report.json``) and the exports asked for;
    returns the paths written. Called only once everything was computed: bad input writes nothing."""
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rig.save(out)
    rep = out.with_suffix(".report.json")
    rep.write_text(json.dumps(report, indent=1))
    return [str(out), str(rep), *write_exports(rig, args, error=error)]
