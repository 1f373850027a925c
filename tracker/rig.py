"""A rig: named, calibrated cameras sharing one world frame, with an optional workspace box.

File format (``data/rigs/*.yaml``, written by :meth:`Rig.save`, documented in ``docs/rig_format.md``)::

    format: rt2.rig
    version: 1
    description: free text
    workspace_m: {min: [x, y, z], max: [x, y, z]}   # optional axis-aligned box, world frame
    cameras:
      - name: cam0
        image_size: [width, height]                  # pixels
        K: [[fx, s, cx], [0, fy, cy], [0, 0, 1]]     # pixels
        distortion: {model: plumb_bob, coefficients: [k1, k2, p1, p2, k3]}
        R_world_to_cam: [[...], [...], [...]]
        t_world_to_cam_m: [tx, ty, tz]               # metres

Lengths are metres, angles radians. OpenCV FileStorage calibration files (one per camera) are
imported with :meth:`Rig.from_opencv_files`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
import yaml

from checks.arrays import check_array, describe
from tracker.camera import DISTORTION_MODELS, Camera
from checks.files import MAX_CONFIG_BYTES, NoAliasSafeLoader, load_yaml_checked, parse_yaml_checked, read_text_capped

__all__ = ["Rig"]

FORMAT = "rt2.rig"
VERSION = 1


class Rig:
    """Ordered, named cameras plus an optional workspace box (world frame, metres).

    Camera order is the order of observation rows everywhere (``uv[i]`` is ``rig[i]``).
    """

    def __init__(self, cameras: Iterable[Camera], *, workspace_m=None, description: str = ""):
        cams = list(cameras)
        if not cams:
            raise ValueError("a rig needs at least one camera, got none")
        for c in cams:
            if not isinstance(c, Camera):
                raise ValueError(f"rig cameras must be tracker.Camera, got {describe(c)}")
        names = [c.name for c in cams]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"camera names must be unique; repeated: {dup}")
        self._cameras = tuple(cams)
        self._index = {n: i for i, n in enumerate(names)}
        self.description = str(description)
        self.workspace_m = None
        if workspace_m is not None:
            box = check_array(workspace_m, "workspace_m", (2, 3))
            if not np.isfinite(box).all() or (box[1] <= box[0]).any():
                raise ValueError(f"workspace_m must be [[min x, y, z], [max x, y, z]] with min < max, got {box.tolist()}")
            box.setflags(write=False)
            self.workspace_m = box
        self._stacked = None

    # -- container protocol ---------------------------------------------------------------------
    @property
    def cameras(self) -> tuple[Camera, ...]:
        return self._cameras

    @property
    def names(self) -> list[str]:
        return [c.name for c in self._cameras]

    def __len__(self) -> int:
        return len(self._cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self._cameras)

    def __getitem__(self, key) -> Camera:
        if isinstance(key, (int, np.integer)):
            return self._cameras[key]
        return self._cameras[self.index(key)]

    def index(self, name: str) -> int:
        """Row of camera ``name``; unknown names raise and list the valid ones."""
        try:
            return self._index[name]
        except (KeyError, TypeError):
            raise ValueError(f"unknown camera {name!r}; this rig has {self.names}") from None

    def subset(self, names: Iterable[str]) -> "Rig":
        """A new rig with the named cameras, in the given order."""
        return Rig([self[n] for n in names], workspace_m=self.workspace_m, description=self.description)

    def __repr__(self) -> str:
        return f"Rig({len(self)} cameras: {self.names})"

    # -- batched parameters for the hot paths ------------------------------------------------------
    def stacked(self) -> dict[str, np.ndarray]:
        """Per-camera parameters as stacked read-only float64 arrays (computed once).

        ``K`` (n, 3, 3), ``dist8`` (n, 8), ``R`` (n, 3, 3) world->cam, ``t`` (n, 3) metres,
        ``P`` (n, 3, 4) = [R | t] normalised projection, ``image_size`` (n, 2) (width, height),
        ``center`` (n, 3) optical centres in the world frame.
        """
        if self._stacked is None:
            cams = self._cameras
            s = {
                "K": np.stack([c.K for c in cams]),
                "dist8": np.stack([c.dist8 for c in cams]),
                "R": np.stack([c.R_world_to_cam for c in cams]),
                "t": np.stack([c.t_world_to_cam_m for c in cams]),
                "image_size": np.array([c.image_size for c in cams], float),
                "center": np.stack([c.center_world for c in cams]),
            }
            s["P"] = np.concatenate([s["R"], s["t"][:, :, None]], axis=2)
            for v in s.values():
                v.setflags(write=False)
            self._stacked = s
        return self._stacked

    def project(self, X_world) -> np.ndarray:
        """(3,) or (N, 3) world points -> (n_cams, N, 2) distorted pixels (squeezed to (n_cams, 2) for one point)."""
        single = np.ndim(X_world) == 1
        uv = np.stack([c.project(np.atleast_2d(X_world)) for c in self._cameras])
        return uv[:, 0] if single else uv

    # -- our YAML format ------------------------------------------------------------------------
    def to_dict(self) -> dict:
        cams = []
        for c in self._cameras:
            cams.append(
                {
                    "name": c.name,
                    "image_size": list(c.image_size),
                    "K": c.K.tolist(),
                    "distortion": {"model": c.distortion_model, "coefficients": c.distortion.tolist()},
                    "R_world_to_cam": c.R_world_to_cam.tolist(),
                    "t_world_to_cam_m": c.t_world_to_cam_m.tolist(),
                }
            )
        out = {"format": FORMAT, "version": VERSION, "description": self.description}
        if self.workspace_m is not None:
            out["workspace_m"] = {"min": self.workspace_m[0].tolist(), "max": self.workspace_m[1].tolist()}
        out["cameras"] = cams
        return out

    def save(self, path) -> None:
        """Write the rig to ``path`` in the rt2 YAML format."""
        path = Path(path)
        text = "# rt2 camera rig; lengths in metres, see docs/rig_format.md\n"
        text += yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=120)
        path.write_text(text)

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "rig") -> "Rig":
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a mapping at the top level, got {describe(data)}")
        if data.get("format") != FORMAT:
            raise ValueError(f"{source}: field 'format' must be {FORMAT!r}, got {describe(data.get('format'))}")
        if data.get("version") != VERSION:
            raise ValueError(f"{source}: field 'version' must be {VERSION}, got {describe(data.get('version'))}")
        cams_data = data.get("cameras")
        if not isinstance(cams_data, list) or not cams_data:
            raise ValueError(f"{source}: field 'cameras' must be a non-empty list, got {describe(cams_data)}")
        cams = []
        for i, cd in enumerate(cams_data):
            where = f"{source}: cameras[{i}]"
            if not isinstance(cd, dict):
                raise ValueError(f"{where} must be a mapping, got {describe(cd)}")
            for key in ("name", "image_size", "K", "distortion", "R_world_to_cam", "t_world_to_cam_m"):
                if key not in cd:
                    raise ValueError(f"{where}: missing field {key!r}")
            dist = cd["distortion"]
            if not isinstance(dist, dict) or "coefficients" not in dist:
                raise ValueError(f"{where}: field 'distortion' must be {{model: ..., coefficients: [...]}}")
            model = dist.get("model", "plumb_bob")
            if model not in DISTORTION_MODELS:
                raise ValueError(f"{where}: unknown distortion model {describe(model)}; valid: {sorted(DISTORTION_MODELS)}")
            cams.append(_camera(cd, where, dist["coefficients"]))
        ws = data.get("workspace_m")
        box = None
        if ws is not None:
            if not isinstance(ws, dict) or set(ws) != {"min", "max"}:
                raise ValueError(f"{source}: field 'workspace_m' must be {{min: [x, y, z], max: [x, y, z]}}, got {describe(ws)}")
            box = [ws["min"], ws["max"]]
        try:
            return cls(cams, workspace_m=box, description=data.get("description", ""))
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path) -> "Rig":
        """Read a rig written by :meth:`save` (or by hand in that format)."""
        path = Path(path)
        data = load_yaml_checked(path, "rig file")
        return cls.from_dict(data, source=str(path))

    # -- OpenCV FileStorage import --------------------------------------------------------------
    @classmethod
    def from_opencv_files(cls, paths, length_unit_m: float = 0.001, *, names=None, workspace_m=None) -> "Rig":
        """Import one OpenCV FileStorage YAML file per camera.

        Each file holds ``camera_matrix`` (3x3), ``distortion_coefficients`` (1x5 or 1x8),
        ``extrinsics`` (3x4 world-to-camera [R|t], lengths in units of ``length_unit_m`` metres),
        and optionally ``image_width``, ``image_height`` and ``camera_name`` (else the file stem).
        The ``%YAML:1.0`` header and ``!!opencv-matrix`` tags are understood.
        """
        paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        if not paths:
            raise ValueError("from_opencv_files needs at least one file, got none")
        if not (np.isfinite(length_unit_m) and length_unit_m > 0):
            raise ValueError(f"length_unit_m must be a positive number, got {length_unit_m!r}")
        if names is not None and len(names) != len(paths):
            raise ValueError(f"names has {len(names)} entries for {len(paths)} files")
        cams = []
        for i, p in enumerate(paths):
            data = _read_opencv_yaml(p)
            where = str(p)
            for key in ("camera_matrix", "distortion_coefficients", "extrinsics"):
                if key not in data:
                    raise ValueError(f"{where}: missing field {key!r}")
            K = _opencv_matrix(data["camera_matrix"], "camera_matrix", where, (3, 3))
            dist = _opencv_matrix(data["distortion_coefficients"], "distortion_coefficients", where, None).ravel()
            ext = _opencv_matrix(data["extrinsics"], "extrinsics", where, (3, 4))
            size = (data.get("image_width"), data.get("image_height"))
            if None in size:
                raise ValueError(f"{where}: missing field 'image_width' or 'image_height'")
            name = names[i] if names is not None else str(data.get("camera_name") or p.stem)
            cd = {
                "name": name,
                "image_size": size,
                "K": K,
                "R_world_to_cam": ext[:, :3],
                "t_world_to_cam_m": ext[:, 3] * length_unit_m,
            }
            cams.append(_camera(cd, where, dist))
        try:
            return cls(cams, workspace_m=workspace_m, description="imported from " + ", ".join(p.name for p in paths))
        except ValueError as exc:
            raise ValueError(f"{', '.join(map(str, paths))}: {exc}") from None


def _camera(cd: dict, where: str, dist) -> Camera:
    fields = {
        "K": cd["K"],
        "distortion": dist,
        "R_world_to_cam": cd["R_world_to_cam"],
        "t_world_to_cam_m": cd["t_world_to_cam_m"],
        "image_size": cd["image_size"],
    }
    try:
        return Camera(name=str(cd["name"]), **fields)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


class _OpenCVLoader(NoAliasSafeLoader):
    """Alias-refusing SafeLoader that understands OpenCV's ``!!opencv-matrix`` tag."""


_OpenCVLoader.add_constructor(
    "tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node, deep=True)
)


def _read_opencv_yaml(path: Path) -> dict:
    text = read_text_capped(path, MAX_CONFIG_BYTES, "calibration file")
    # OpenCV writes "%YAML:1.0", which is not a valid YAML directive; drop it.
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML"):
        lines = lines[1:]
        if lines and lines[0].strip() == "---":
            lines = lines[1:]
    data = parse_yaml_checked("\n".join(lines), f"{path} (OpenCV calibration)", _OpenCVLoader)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level, got {describe(data)}")
    return data


def _opencv_matrix(node, field: str, where: str, shape) -> np.ndarray:
    if not isinstance(node, dict) or not {"rows", "cols", "data"} <= set(node):
        raise ValueError(f"{where}: field {field!r} must be a matrix with rows, cols and data, got {describe(node)}")
    rows, cols = (_dimension(node[k], k, field, where) for k in ("rows", "cols"))
    data = node["data"]
    try:
        arr = np.asarray(data, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: field {field!r} has non-numeric data {describe(data)}") from None
    if arr.ndim != 1 or arr.size != rows * cols:
        raise ValueError(f"{where}: field {field!r} declares {rows}x{cols} but holds {arr.size} values")
    arr = arr.reshape(rows, cols)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{where}: field {field!r} must be {shape[0]}x{shape[1]}, got {rows}x{cols}")
    return arr


def _dimension(value, key: str, field: str, where: str) -> int:
    """``rows`` / ``cols`` of an OpenCV matrix: a positive int (OpenCV writes ints; ``3.0`` is refused too)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{where}: field {field!r}: {key} must be a positive integer, got {describe(value)}")
    return value
