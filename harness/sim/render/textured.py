"""Textured planes (a printed ChArUco board) drawn into rendered images through the exact camera model.

Every output pixel is sampled with ``supersample x supersample`` rays: each ray is the pixel
position undistorted by the camera's model (``Camera.undistort``), intersected with the plane, and
looked up in the texture (nearest texel of a high-resolution texture; the sub-samples average to an
area-weighted, anti-aliased value). Only the plane's bounding box in the image is visited. The
plane is drawn over whatever the image holds (no occlusion test: the board is held in free space).

Plane frame: origin at the texture's top-left corner, x along texture columns, y along texture
rows (down the texture), z = x cross y (the board's back side). This is OpenCV's ChArUco board
frame, so ``BoardSpec.corners_board_m`` are points of this frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tracker import Camera

__all__ = ["TexturedPlane", "board_plane", "draw_textured_plane"]


@dataclass(frozen=True)
class TexturedPlane:
    """texture : (H, W) uint8 gray or (H, W, 3) uint8 RGB; size_m : (width, height) it covers, metres
    R_plane_to_world : (3, 3); t_plane_to_world_m : (3,) the texture's top-left corner in the world"""

    texture: np.ndarray
    size_m: tuple[float, float]
    R_plane_to_world: np.ndarray
    t_plane_to_world_m: np.ndarray

    def __post_init__(self):
        tex = np.asarray(self.texture)
        if tex.dtype != np.uint8 or tex.ndim not in (2, 3) or (tex.ndim == 3 and tex.shape[2] != 3):
            raise ValueError(f"texture must be uint8 (H, W) or (H, W, 3), got shape {tex.shape} and dtype {tex.dtype}")
        w, h = (float(v) for v in self.size_m)
        if not (w > 0 and h > 0):
            raise ValueError(f"size_m must be two positive lengths, got {self.size_m!r}")
        R = np.asarray(self.R_plane_to_world, float)
        if R.shape != (3, 3) or abs(np.linalg.det(R) - 1) > 1e-6:
            raise ValueError(f"R_plane_to_world must be a (3, 3) rotation, got {R.tolist()}")
        t = np.asarray(self.t_plane_to_world_m, float).reshape(3)
        for name, v in (("texture", tex), ("R_plane_to_world", R), ("t_plane_to_world_m", t)):
            v = np.array(v)
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "size_m", (w, h))

    def corners_world(self) -> np.ndarray:
        """(4, 3) texture corners (top-left, top-right, bottom-right, bottom-left) in the world."""
        w, h = self.size_m
        q = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], float)
        return q @ self.R_plane_to_world.T + self.t_plane_to_world_m


def board_plane(spec, R_board_to_world, t_board_to_world_m, *, px_per_square: int = 120, margin_squares: float = 0.5) -> TexturedPlane:
    """The ChArUco board of ``spec`` (``tracker.calibration.BoardSpec``) as a textured plane with a white margin.

    The board frame (``corners_board_m``) is placed by ``R_board_to_world``, ``t_board_to_world_m``;
    the texture extends ``margin_squares`` squares beyond the chessboard on every side.
    """
    m = int(round(margin_squares * px_per_square))
    size_px = (spec.columns * px_per_square, spec.rows * px_per_square)
    img = spec.cv_board().generateImage(size_px, marginSize=0, borderBits=1)
    img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    if spec.inverted:
        img = 255 - img
    margin_m = margin_squares * spec.square_m
    R = np.asarray(R_board_to_world, float)
    t = np.asarray(t_board_to_world_m, float) - R @ np.array([margin_m, margin_m, 0.0])
    w, h = spec.size_m
    return TexturedPlane(img, (w + 2 * margin_m, h + 2 * margin_m), R, t)


def draw_textured_plane(image: np.ndarray, camera: Camera, plane: TexturedPlane, *, supersample: int = 3) -> np.ndarray:
    """Return a copy of ``image`` (H, W, 3) or (H, W) uint8 with ``plane`` drawn by ``camera``; unchanged if not in view."""
    out = image.copy()
    R = camera.R_world_to_cam @ plane.R_plane_to_world  # plane -> camera
    p0 = camera.R_world_to_cam @ plane.t_plane_to_world_m + camera.t_world_to_cam_m
    n = R[:, 2]
    cw = plane.corners_world()
    if (camera.depth(cw) <= 1e-6).any():
        return out  # (part of) the plane behind the camera: not drawn
    # bounding box from the distorted projection of the plane's outline (dense along the edges)
    s = np.linspace(0, 1, 17)[:, None]
    edge = np.concatenate([cw[k] + s * (cw[(k + 1) % 4] - cw[k]) for k in range(4)])
    uv = camera.project(edge)
    H, W = out.shape[:2]
    x0, y0 = np.floor(np.nanmin(uv, axis=0)).astype(int) - 2
    x1, y1 = np.ceil(np.nanmax(uv, axis=0)).astype(int) + 2
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W - 1), min(y1, H - 1)
    if x1 < x0 or y1 < y0:
        return out
    ss = int(supersample)
    off = (np.arange(ss) + 0.5) / ss - 0.5
    xs = (np.arange(x0, x1 + 1)[:, None] + off[None, :]).ravel()
    ys = (np.arange(y0, y1 + 1)[:, None] + off[None, :]).ravel()
    xn = _undistort_grid(camera, xs, ys)
    # ray (x, y, 1) meets the plane n . X = n . p0 at depth s; plane coordinates q = R^T (s d - p0)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = (n @ p0) / (xn[:, 0] * n[0] + xn[:, 1] * n[1] + n[2])
    qx = depth * (xn[:, 0] * R[0, 0] + xn[:, 1] * R[1, 0] + R[2, 0]) - p0 @ R[:, 0]
    qy = depth * (xn[:, 0] * R[0, 1] + xn[:, 1] * R[1, 1] + R[2, 1]) - p0 @ R[:, 1]
    th, tw = plane.texture.shape[:2]
    u = qx * (tw / plane.size_m[0])
    v = qy * (th / plane.size_m[1])
    inside = (depth > 0) & (u >= 0) & (u < tw) & (v >= 0) & (v < th)
    ui = np.clip(u, 0, tw - 1).astype(int)
    vi = np.clip(v, 0, th - 1).astype(int)
    tex = plane.texture.reshape(th, tw, -1).astype(np.float32)
    val = np.where(inside[:, None], tex[vi, ui], 0.0)
    nh, nw = y1 - y0 + 1, x1 - x0 + 1
    val = val.reshape(nh, ss, nw, ss, -1).mean(axis=(1, 3))
    cov = inside.reshape(nh, ss, nw, ss).mean(axis=(1, 3))[..., None]
    region = out[y0:y1 + 1, x0:x1 + 1].astype(np.float32)
    if region.ndim == 2:
        region = region[..., None]
    if val.shape[-1] == 1 and region.shape[-1] == 3:
        val = np.repeat(val, 3, axis=-1)
    blended = val + (1 - cov) * region  # val already weighted by coverage
    out[y0:y1 + 1, x0:x1 + 1] = np.clip(np.rint(blended), 0, 255).astype(np.uint8).reshape(out[y0:y1 + 1, x0:x1 + 1].shape)
    return out


def _undistort_grid(camera: Camera, xs: np.ndarray, ys: np.ndarray, step_px: float = 2.0) -> np.ndarray:
    """Undistorted normalised coordinates of the pixel grid ``xs x ys`` (row-major, (len(ys) * len(xs), 2)).

    The smooth inverse distortion is solved exactly on a coarse grid (``step_px``) and interpolated
    bilinearly (error << 0.01 px for lens distortion)."""
    cx = np.arange(xs[0] - step_px, xs[-1] + 2 * step_px, step_px)
    cy = np.arange(ys[0] - step_px, ys[-1] + 2 * step_px, step_px)
    gx, gy = np.meshgrid(cx, cy)
    coarse = camera.undistort(np.column_stack([gx.ravel(), gy.ravel()])).reshape(len(cy), len(cx), 2).astype(np.float32)
    fx = (xs - cx[0]) / step_px
    fy = (ys - cy[0]) / step_px
    ix = np.minimum(fx.astype(int), len(cx) - 2)
    iy = np.minimum(fy.astype(int), len(cy) - 2)
    ax = (fx - ix).astype(np.float32)[None, :, None]
    ay = (fy - iy).astype(np.float32)[:, None, None]
    c00 = coarse[iy][:, ix]
    c01 = coarse[iy][:, ix + 1]
    c10 = coarse[iy + 1][:, ix]
    c11 = coarse[iy + 1][:, ix + 1]
    out = (1 - ay) * ((1 - ax) * c00 + ax * c01) + ay * ((1 - ax) * c10 + ax * c11)
    return out.reshape(-1, 2)
