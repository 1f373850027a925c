"""Dynamic primitives as one float table, and the shading constants both draw kernels share.

:func:`pack_scene` turns a :class:`~harness.sim.render.scene_state.Scene` into a ``(n, N_COLS)`` float64
table in the world frame (capsules, spheres, disks and boxes first, balls last, so a ball's
visibility is measured against everything else). The numba kernel (:mod:`._kernels`) and the
numpy reference (:mod:`.reference`) both read this table, so they draw exactly the same thing.
"""

from __future__ import annotations

import numpy as np

from harness.sim.render.scene_state import Scene

__all__ = [
    "AMBIENT",
    "CAPSULE",
    "BALL",
    "BOX",
    "DISK",
    "DIFFUSE",
    "DN_PER_RADIANCE",
    "LIGHT_DIR_WORLD",
    "NEAR_M",
    "N_COLS",
    "SHININESS",
    "SPECULAR_GAIN",
    "blur_samples",
    "pack_scene",
]

# primitive types (column 0)
CAPSULE, DISK, BOX, BALL = 0, 1, 2, 3
#: columns: 0 type | 1:4 a | 4:7 b | 7 radius | 8:11 rgb | 11:14 rgb back | 14 specular |
#: 15:24 R_box_to_world (row-major) | 24 ball index
#: a/b are: capsule p0/p1 (sphere: p0 = p1), disk centre/unit normal, box centre/half size,
#: ball position at exposure start/end.
N_COLS = 25

AMBIENT = 0.4  #: ambient part of the dynamic objects' illumination
DIFFUSE = 0.6  #: diffuse part, from LIGHT_DIR_WORLD
SPECULAR_GAIN = 2.5  #: radiance of a highlight of specular strength 1 (white, saturating)
SHININESS = 32  #: Blinn-Phong exponent (a power of two: five squarings in the kernel)
LIGHT_DIR_WORLD = np.array([0.15, 0.1, 1.0]) / np.linalg.norm([0.15, 0.1, 1.0])  #: toward the ceiling lights
DN_PER_RADIANCE = 200.0  #: pixel value of radiance 1 at brightness 1 (before vignetting)
NEAR_M = 0.01  #: closer than this to the camera plane is not drawn


def pack_scene(scene: Scene) -> tuple[np.ndarray, int]:
    """(n, N_COLS) primitive table of ``scene`` (world frame) and the number of balls (last rows).

    A ball at ``position_m`` with ``velocity_mps`` spans ``position_m -+ velocity_mps *
    exposure_s / 2`` over the exposure (positions are at mid-exposure).
    """
    rows = []
    for c in scene.capsules:
        rows.append(_row(CAPSULE, c.p0_m, c.p1_m, c.radius_m, c.colour, c.colour, c.specular))
    for s in scene.spheres:
        rows.append(_row(CAPSULE, s.centre_m, s.centre_m, s.radius_m, s.colour, s.colour, s.specular))
    for d in scene.disks:
        rows.append(_row(DISK, d.centre_m, d.normal, d.radius_m, d.colour_front, d.colour_back, d.specular))
    for b in scene.boxes:
        rows.append(_row(BOX, b.centre_m, b.size_m / 2, 0.0, b.colour, b.colour, b.specular, R=b.R_box_to_world))
    half = scene.exposure.exposure_s / 2
    for i, ball in enumerate(scene.balls):
        a = ball.position_m - ball.velocity_mps * half
        b = ball.position_m + ball.velocity_mps * half
        rows.append(_row(BALL, a, b, ball.radius_m, ball.colour, ball.colour, ball.specular, index=i))
    table = np.array(rows, float).reshape(-1, N_COLS)
    return table, len(scene.balls)


def _row(kind, a, b, radius, rgb, rgb_back, specular, *, R=None, index=-1) -> np.ndarray:
    row = np.zeros(N_COLS)
    row[0] = kind
    row[1:4] = a
    row[4:7] = b
    row[7] = radius
    row[8:11] = rgb
    row[11:14] = rgb_back
    row[14] = specular
    row[15:24] = (np.eye(3) if R is None else R).ravel()
    row[24] = index
    return row


def blur_samples(blur_px: float) -> int:
    """Number of time samples for a ball smeared over ``blur_px`` pixels (2 per pixel, 1..64)."""
    return min(max(int(blur_px * 2.0) + 1, 1), 64)
