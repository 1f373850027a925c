"""The ball's size in each camera over the workspace, and the detectors' size limits that follow from it.

A detector's size limits (the accepted blob area, the search window, RTBlob's template radius) are a
property of the rig: a 40 mm ball is ~7 px across 3 m from a VGA camera and ~60 px across 1 m from
a 1280x720 one. :func:`ball_diameter_range_px` measures, per camera, the ball's pixel diameter at
the workspace's nearest and farthest points that camera sees (its lens model included);
:func:`size_limits` and :func:`rtblob_radius_floor_px` turn that into the limits
:class:`tracker.Tracker` gives its detectors (``TrackerOptions.size_from_rig``; docs/pipeline.md,
"Size limits from the rig").

The rule widens, never narrows: a limit already wide enough for the rig (the model's trained blob
area range, the default window, RTBlob's template for ``expected_distance_m``) is kept as it is, so
a rig whose balls the model was trained on sees exactly the detector it had.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from checks.arrays import check_array, describe
from tracker.rig import Rig

__all__ = ["SizeLimits", "ball_diameter_range_px", "rtblob_radius_floor_px", "size_limits"]

#: workspace grid points per axis where the ball's size is measured (plus each camera's nearest box point)
GRID = 9


def ball_diameter_range_px(rig: Rig, workspace_m=None, *, ball_radius_m: float = 0.02) -> np.ndarray:
    """(n_cams, 2) the smallest and largest diameter, pixels, of a ball of ``ball_radius_m`` anywhere
    in the workspace box that camera sees (centre in front of it and inside its image).

    workspace_m : (2, 3) ``[min, max]`` box, world frame, metres (default: ``rig.workspace_m``)
    Measured on a ``GRID``^3 grid of the box plus the box point nearest to each camera, through the
    camera's lens model: the diameter is the mean of the silhouette's two image-space spans (the
    projections of the ball's rim points across and along the image rows). NaN row: the camera
    sees no point of the box.
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig must be a tracker.Rig, got {describe(rig)}")
    box = rig.workspace_m if workspace_m is None else check_array(workspace_m, "workspace_m", (2, 3))
    if box is None:
        raise ValueError(f"rig {rig.description!r} has no workspace_m; pass workspace_m=[[min x, y, z], [max x, y, z]]")
    box = np.asarray(box, float)
    if not np.isfinite(box).all() or (box[1] <= box[0]).any():
        raise ValueError(f"workspace_m must be [[min x, y, z], [max x, y, z]] with min < max, got {box.tolist()}")
    r = float(ball_radius_m)
    if not (math.isfinite(r) and 0 < r < 1):
        raise ValueError(f"ball_radius_m must be a radius in metres in (0, 1), got {ball_radius_m!r}")
    axes = [np.linspace(box[0, k], box[1, k], GRID) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    out = np.full((len(rig), 2), np.nan)
    for i, cam in enumerate(rig):
        nearest = np.clip(cam.center_world, box[0], box[1])
        X = np.vstack([grid, nearest])
        d = _diameters_px(cam, X, r)
        if np.isfinite(d).any():
            out[i] = np.nanmin(d), np.nanmax(d)
    return out


def _diameters_px(cam, X_world: np.ndarray, r: float) -> np.ndarray:
    """(n,) the ball's image diameter at each centre ``X_world`` (n, 3); NaN where the camera does not see it."""
    Xc = cam.to_camera(X_world)
    z = Xc[:, 2]
    front = z > 2.0 * r  # the whole ball in front of the camera
    d = np.full(len(X_world), np.nan)
    if not front.any():
        return d
    Xc = Xc[front]
    ray = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
    across = np.cross(ray, [0.0, 1.0, 0.0])  # perpendicular to the ray, along the image rows
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    down = np.cross(across, ray)
    dist = np.linalg.norm(Xc, axis=1, keepdims=True)
    s = r * dist / np.sqrt(np.maximum(dist**2 - r * r, 1e-12))  # rim offset whose rays touch the ball's silhouette
    R, t = cam.R_world_to_cam, cam.t_world_to_cam_m
    rims = [Xc + sgn * s * v for v in (across, down) for sgn in (1.0, -1.0)]
    uv = [cam.project((P - t) @ R) for P in rims]  # camera -> world: R^T (P - t)
    centre = cam.project((Xc - t) @ R)
    span = 0.5 * (np.linalg.norm(uv[0] - uv[1], axis=1) + np.linalg.norm(uv[2] - uv[3], axis=1))
    seen = cam.in_image(centre) & np.isfinite(span)
    d[np.flatnonzero(front)[seen]] = span[seen]
    return d


@dataclass(frozen=True)
class SizeLimits:
    """The detectors' size limits on one rig, per camera (rig order).

    diameter_px : (n_cams, 2) the ball's smallest and largest diameter over the workspace, pixels (NaN: unseen)
    area_px : (n_cams, 2) accepted blob area [min, max], pixels (rt2's blob filter); a camera's own
        limit where the rule keeps it, else a whole number of pixels
    roi_half_size_px : (n_cams,) int, half side of the search window around a predicted pixel
    """

    diameter_px: np.ndarray
    area_px: np.ndarray
    roi_half_size_px: np.ndarray


def size_limits(diameter_px, area_px, roi_half_size_px: int, *, edge_loss_px: float = 0.0) -> SizeLimits:
    """The blob area range and window size per camera for balls of ``diameter_px`` (n_cams, 2).

    area_px : (2,) the detector's own [min, max] blob area (the model's ``area_range_px`` or the options');
    roi_half_size_px : its own window half side; edge_loss_px : how much narrower than the ball its blob is
    (the model's ``edge_loss_px``). A ball of diameter d makes a blob of about pi/4 (d - edge)^2 pixels.
    Per camera with a finite range ``[d_min, d_max]``:

    * min area = the own one, lowered to floor(pi/4 (d_min - edge)^2) (at least 1) when the farthest ball's blob is smaller;
    * max area = the own one, raised to ceil(pi/4 (d_max - edge)^2) when the nearest ball's blob is larger;
    * window half side = max(own, ceil(d_max)): the nearest ball fits with half a diameter to spare on each side.

    Cameras that see no point of the workspace (NaN) keep the detector's own limits.
    """
    d = np.asarray(diameter_px, float).reshape(-1, 2)
    own = np.asarray(area_px, float).reshape(2)
    e = float(edge_loss_px)
    n = len(d)
    area = np.tile(own, (n, 1))
    half = np.full(n, int(roi_half_size_px), np.int64)
    for i in np.flatnonzero(np.isfinite(d).all(axis=1)):
        lo = math.pi / 4 * max(d[i, 0] - e, 1.0) ** 2
        hi = math.pi / 4 * max(d[i, 1] - e, 1.0) ** 2
        if lo < own[0]:
            area[i, 0] = max(math.floor(lo), 1)
        if hi > own[1]:
            area[i, 1] = math.ceil(hi)
        half[i] = max(half[i], math.ceil(d[i, 1]))
    return SizeLimits(d, area, half)


def rtblob_radius_floor_px(diameter_px) -> np.ndarray:
    """(n_cams,) the smallest template radius RTBlob should use per camera: the farthest ball's radius
    (``diameter_px[:, 0] / 2``; NaN where the camera sees no point of the workspace). A template
    smaller than the ball peaks anywhere inside it; a larger one still peaks at the centre."""
    return 0.5 * np.asarray(diameter_px, float).reshape(-1, 2)[:, 0]
