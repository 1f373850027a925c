"""Find a rig file by name or path (what every ``--rig`` option of the ``rt2`` commands accepts), and read
aniposelib / caliscope ``.toml`` calibrations as a :class:`~tracker.rig.Rig`.

``resolve_rig("lab4_vga")`` loads ``data/rigs/lab4_vga.yaml``; a path (absolute, relative, with or
without ``.yaml``) loads that file. Unknown names raise a ``ValueError`` listing the rigs available.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import cv2
import numpy as np

from checks.files import MAX_CONFIG_BYTES, read_text_capped
from tracker.camera import Camera
from tracker.rig import Rig

__all__ = ["RIGS_DIR", "available_rigs", "read_anipose_toml", "resolve_rig", "rig_path"]

#: the project's rig files
RIGS_DIR = Path(__file__).resolve().parents[1] / "data" / "rigs"


def available_rigs() -> list[str]:
    """Names of the rigs in ``data/rigs`` (file stems), sorted."""
    return sorted(p.stem for p in RIGS_DIR.glob("*.yaml"))


def rig_path(name_or_path) -> Path:
    """The rig file meant by ``name_or_path``: an existing file, else ``data/rigs/<name>.yaml``."""
    text = str(name_or_path)
    if not text.strip():
        raise ValueError(f"--rig must name a rig {available_rigs()} or a rig file, got {text!r}")
    path = Path(text).expanduser()
    if path.is_file():
        return path
    if path.is_dir():
        raise ValueError(f"rig {text!r} is a folder; give a rig file (.yaml) or one of {available_rigs()}")
    if path.parent == Path(".") and path.suffix in ("", ".yaml", ".yml"):
        candidate = RIGS_DIR / (path.stem + ".yaml")
        if candidate.is_file():
            return candidate
    raise ValueError(f"unknown rig {text!r}: no such file, and not a rig in {RIGS_DIR}; available: {available_rigs()}")


def resolve_rig(name_or_path) -> Rig:
    """Load the rig named ``name_or_path`` (see the module docstring)."""
    if isinstance(name_or_path, Rig):
        return name_or_path
    return Rig.load(rig_path(name_or_path))


def read_anipose_toml(path, *, length_unit_m: float = 1.0) -> Rig:
    """Rig from an aniposelib ``calibration.toml`` (``rotation`` as a Rodrigues vector or a 3x3 matrix,
    as caliscope writes it). Tables without ``matrix`` (``metadata``) are skipped."""
    path = Path(path)
    try:
        data = tomllib.loads(read_text_capped(path, MAX_CONFIG_BYTES, "calibration file"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    tables = [(k, v) for k, v in data.items() if isinstance(v, dict) and "matrix" in v]
    tables += [(f"{k}.{kk}", vv) for k, v in data.items() if isinstance(v, dict) and "matrix" not in v
               for kk, vv in v.items() if isinstance(vv, dict) and "matrix" in vv]
    if not tables:
        raise ValueError(f"{path}: no camera tables (with 'matrix') found")
    cams = []
    for key, t in tables:
        where = f"{path}: [{key}]"
        for field in ("size", "matrix", "distortions", "rotation", "translation"):
            if field not in t:
                raise ValueError(f"{where}: missing field {field!r}")
        rot = np.asarray(t["rotation"], float)
        R = cv2.Rodrigues(rot.reshape(3, 1))[0] if rot.size == 3 else rot.reshape(3, 3)
        dist = np.asarray(t["distortions"], float).ravel()
        try:
            cams.append(Camera(name=str(t.get("name", key)), K=t["matrix"], distortion=dist, R_world_to_cam=R,
                               t_world_to_cam_m=np.asarray(t["translation"], float) * length_unit_m,
                               image_size=tuple(int(s) for s in t["size"])))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    return Rig(cams, description=f"imported from {path.name}")
