"""ProMP files: a plain NumPy ``.npz`` archive (no pickles), readable from any language with a zip
and .npy reader. Fields (see docs/promp.md):

    format "rt2.promp", version 1, robot_id, joint_names (D,), n_basis, width, n_poly,
    duration_s, duration_std_s, mu_w (D*K,), Sigma_w (D*K, D*K), Sigma_y (D, D), metadata_json
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from policies._promp_basis import RBFBasis
from checks.files import load_npz_checked

__all__ = ["FORMAT", "VERSION", "load", "save"]

FORMAT = "rt2.promp"
VERSION = 1
_FIELDS = ("format", "version", "robot_id", "joint_names", "n_basis", "width", "n_poly", "duration_s",
           "duration_std_s", "mu_w", "Sigma_w", "Sigma_y", "metadata_json")


def save(promp, path) -> Path:
    """Write ``promp`` to ``path`` (must end in .npz), atomically; returns the path."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"{path}: a ProMP file must end in .npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        metadata_json = json.dumps(promp.metadata, sort_keys=True)
    except TypeError as exc:
        raise ValueError(f"{path}: metadata must be JSON-serialisable: {exc}") from exc
    fields = {
        "format": np.array(FORMAT), "version": np.array(VERSION), "robot_id": np.array(promp.robot_id),
        "joint_names": np.array(promp.joint_names), "n_basis": np.array(promp.basis.n_basis),
        "width": np.array(promp.basis.width), "n_poly": np.array(promp.basis.n_poly),
        "duration_s": np.array(promp.duration_s), "duration_std_s": np.array(promp.duration_std_s),
        "mu_w": np.asarray(promp.mu_w), "Sigma_w": np.asarray(promp.Sigma_w),
        "Sigma_y": np.asarray(promp.Sigma_y), "metadata_json": np.array(metadata_json),
    }
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **fields)
    os.replace(tmp, path)
    return path


def _scalar(data, key: str, kind, path: Path):
    arr = data[key]
    if arr.shape != ():
        raise ValueError(f"{path}: field '{key}' must be a scalar, got shape {arr.shape}")
    try:
        return kind(arr.item())
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: field '{key}' is not a {kind.__name__}: {arr.item()!r}") from exc


def load(cls, path, *, robot_id=None, joint_names=None, n_dims=None):
    """Read a ProMP; check it against the expected robot (see :meth:`ProMP.load`)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such ProMP file")
    data = load_npz_checked(path, "ProMP file")
    missing = [k for k in _FIELDS if k not in data]
    if missing:
        raise ValueError(f"{path}: not a ProMP file, missing field(s) {missing}")
    fmt = _scalar(data, "format", str, path)
    if fmt != FORMAT:
        raise ValueError(f"{path}: field 'format' is {fmt!r}, expected {FORMAT!r}")
    version = _scalar(data, "version", int, path)
    if version != VERSION:
        raise ValueError(f"{path}: field 'version' is {version}, this code reads version {VERSION}")
    file_robot = _scalar(data, "robot_id", str, path)
    names = tuple(str(n) for n in np.atleast_1d(data["joint_names"]))
    if robot_id is not None and file_robot != robot_id:
        raise ValueError(f"{path}: field 'robot_id' is {file_robot!r} but {robot_id!r} was expected "
                         "(a primitive learned for another robot)")
    if n_dims is not None and len(names) != int(n_dims):
        raise ValueError(f"{path}: field 'joint_names' lists {len(names)} joints but {int(n_dims)} were expected")
    if joint_names is not None and names != tuple(joint_names):
        raise ValueError(f"{path}: field 'joint_names' is {list(names)}, expected {list(joint_names)}")
    try:
        metadata = json.loads(_scalar(data, "metadata_json", str, path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: field 'metadata_json' is not JSON: {exc}") from exc
    try:
        basis = RBFBasis(_scalar(data, "n_basis", int, path), _scalar(data, "width", float, path),
                         _scalar(data, "n_poly", int, path))
        return cls(basis, data["mu_w"], data["Sigma_w"], data["Sigma_y"], _scalar(data, "duration_s", float, path),
                   names, file_robot, _scalar(data, "duration_std_s", float, path), metadata)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
