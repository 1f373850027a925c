"""The static lab as renderable geometry: a room, axis-aligned boxes, the net's mesh and the lights.

Built from the constants of :mod:`harness.sim.lab`. Everything here is fixed: it is ray-cast once per
camera by :mod:`harness.sim.render.static` and cached. Materials are linear RGB reflectances; the
ceiling light panels are emissive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.sim import lab

__all__ = ["LabGeometry", "MATERIALS", "floor_texture", "lab_geometry", "table_line_mask"]

#: material id -> (name, reflectance rgb, specular gloss) ; ids index arrays in static.py
MATERIALS = (
    ("floor", (0.42, 0.16, 0.12), 0.08),
    ("wall", (0.55, 0.57, 0.6), 0.0),
    ("ceiling", (0.78, 0.78, 0.76), 0.0),
    ("light", (1.0, 1.0, 1.0), 0.0),  # emissive, see LabGeometry.light_radiance
    ("table", (0.05, 0.13, 0.36), 0.14),  # blue top; white lines come from table_line_mask
    ("table_side", (0.05, 0.12, 0.3), 0.0),
    ("metal_dark", (0.09, 0.09, 0.1), 0.0),
    ("net_post", (0.04, 0.04, 0.05), 0.0),
    ("net_band", (0.9, 0.9, 0.88), 0.0),
    ("barrier", (0.05, 0.09, 0.28), 0.0),
    ("cabinet", (0.38, 0.38, 0.4), 0.0),
    ("whiteboard", (0.88, 0.88, 0.86), 0.05),
    ("door", (0.5, 0.36, 0.22), 0.0),
    ("wall_band", (0.2, 0.22, 0.26), 0.0),
)
MAT = {name: i for i, (name, _, _) in enumerate(MATERIALS)}


@dataclass(frozen=True)
class LabGeometry:
    """room_m : (2, 3) room box (inside); boxes_m : (M, 2, 3) opaque boxes [min, max];
    box_material : (M,) material ids; lights_m : (L, 4) ceiling panels [x0, x1, y0, y1];
    light_z_m : height of the panels; net_m : (2, 3) net mesh rectangle [min, max] in the plane
    x = 0; net_alpha : opacity of the mesh seen face-on; net_rgb : (3,) mesh reflectance."""

    room_m: np.ndarray
    boxes_m: np.ndarray
    box_material: np.ndarray
    lights_m: np.ndarray
    light_z_m: float
    light_radiance: float
    net_m: np.ndarray
    net_alpha: float
    net_rgb: np.ndarray


def _box(x0, x1, y0, y1, z0, z1):
    return [[x0, y0, z0], [x1, y1, z1]]


def lab_geometry() -> LabGeometry:
    """The lab of :mod:`harness.sim.lab`: table with legs, net with posts, court barriers, a few
    fixtures on the walls, and ceiling light panels."""
    L, W, top = lab.TABLE_HALF_LENGTH_M, lab.TABLE_HALF_WIDTH_M, lab.TABLE_TOP_Z_M
    under = top - lab.TABLE_THICKNESS_M
    net_top = top + lab.NET_HEIGHT_M
    span = lab.NET_HALF_SPAN_M
    boxes, mats = [], []

    def add(box, mat):
        boxes.append(box)
        mats.append(MAT[mat])

    add(_box(-L, L, -W, W, under, top), "table")
    for sx in (-1, 1):  # two leg frames per half, and an apron under the top
        for sy in (-1, 1):
            x, y = sx * (L - 0.25), sy * (W - 0.12)
            add(_box(x - 0.025, x + 0.025, y - 0.025, y + 0.025, 0.0, under), "metal_dark")
        add(_box(sx * (L - 0.27), sx * (L - 0.23), -W + 0.12, W - 0.12, 0.12, 0.16), "metal_dark")
        xa, xb = sorted((sx * 0.2, sx * 0.24))
        add(_box(xa, xb, -W + 0.1, W - 0.1, under - 0.08, under), "metal_dark")
    add(_box(-0.02, 0.02, -span - 0.025, -span, top, net_top), "net_post")
    add(_box(-0.02, 0.02, span, span + 0.025, top, net_top), "net_post")
    add(_box(-0.03, 0.03, -span - 0.025, -W + 0.02, top - 0.05, top + 0.01), "net_post")  # clamps
    add(_box(-0.03, 0.03, W - 0.02, span + 0.025, top - 0.05, top + 0.01), "net_post")
    add(_box(-0.002, 0.002, -span, span, net_top - lab.NET_TOP_BAND_M, net_top), "net_band")
    # court barriers (0.7 m high, 2 cm thick) with a gap at each long side for walking in
    (bx0, by0), (bx1, by1) = lab.BARRIER_BOX_M
    hb = lab.BARRIER_HEIGHT_M
    for x in (bx0, bx1):
        add(_box(x - 0.01, x + 0.01, by0, by1, 0.0, hb), "barrier")
    for y in (by0, by1):
        add(_box(bx0, -1.0, y - 0.01, y + 0.01, 0.0, hb), "barrier")
        add(_box(1.0, bx1, y - 0.01, y + 0.01, 0.0, hb), "barrier")
    (rx0, ry0, _), (rx1, ry1, rz1) = lab.ROOM_M
    add(_box(rx0, rx0 + 0.6, 1.5, 3.5, 0.0, 2.0), "cabinet")
    add(_box(rx1 - 0.5, rx1, -3.8, -2.2, 0.0, 1.1), "cabinet")
    add(_box(-2.5, 0.5, ry1 - 0.02, ry1, 0.9, 2.1), "whiteboard")
    add(_box(2.0, 3.0, ry0, ry0 + 0.03, 0.0, 2.1), "door")
    add(_box(rx0, rx1, ry0, ry0 + 0.01, 0.0, 0.25), "wall_band")
    add(_box(rx0, rx1, ry1 - 0.01, ry1, 0.0, 0.25), "wall_band")
    return LabGeometry(
        room_m=np.array(lab.ROOM_M, float),
        boxes_m=np.array(boxes, float),
        box_material=np.array(mats, np.int64),
        lights_m=np.array(lab.LIGHTS_M, float),
        light_z_m=lab.CEILING_Z_M - 0.01,
        light_radiance=4.0,
        net_m=np.array([[0.0, -span, top], [0.0, span, net_top - lab.NET_TOP_BAND_M]]),
        net_alpha=0.4,
        net_rgb=np.array([0.03, 0.04, 0.1]),
    )


def table_line_mask(P_world: np.ndarray, footprint_m=None) -> np.ndarray:
    """(N,) float in [0, 1]: how much of a pixel at ``P_world`` (N, 3) on the table top is white
    line (20 mm lines along the edges, 3 mm centre line along x), box-filtered over the pixel's
    ``footprint_m`` (N,) on the table (a point sample when None)."""
    L, W = lab.TABLE_HALF_LENGTH_M, lab.TABLE_HALF_WIDTH_M
    x, y = np.abs(P_world[:, 0]), P_world[:, 1]
    f = np.full(len(x), 1e-9) if footprint_m is None else np.maximum(footprint_m, 1e-9)

    def overlap(c, lo, hi):  # fraction of [c - f/2, c + f/2] inside [lo, hi]
        return np.clip(np.minimum(c + f / 2, hi) - np.maximum(c - f / 2, lo), 0, None) / f

    edge = np.maximum(overlap(x, L - lab.TABLE_EDGE_LINE_M, L + 1), overlap(np.abs(y), W - lab.TABLE_EDGE_LINE_M, W + 1))
    centre = overlap(y, -lab.TABLE_CENTRE_LINE_M / 2, lab.TABLE_CENTRE_LINE_M / 2)
    return np.clip(np.maximum(edge, centre), 0.0, 1.0)


def floor_texture(P_world: np.ndarray) -> np.ndarray:
    """(N,) brightness factor of the sports floor: 15 cm planks along x, each a little different."""
    plank = np.floor(P_world[:, 1] / 0.15)
    seg = np.floor((P_world[:, 0] + 7.3 * plank) / 1.8)
    h = np.sin(plank * 12.9898 + seg * 78.233) * 43758.5453
    h = h - np.floor(h)  # deterministic hash in [0, 1)
    grain = 0.02 * np.sin(P_world[:, 0] * 23.0 + plank * 1.7)
    return 0.93 + 0.12 * h + grain
