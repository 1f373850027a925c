"""The simulated lab: static geometry constants and the 4-camera ceiling rig ``lab4_vga``.

Lab world frame (shared by every simulated part): metres, origin on the floor under the centre
of the table, x along the table's long axis from the robot's end (x < 0) toward the opponent's
end, y to the left seen from the robot, z up.

The 4-camera rig imitates the paper's real setup ("four cameras attached to the ceiling",
Sec. 4.2): VGA cameras ~3 m up, looking down at the robot's half of the table and the space
behind it where the robot hits the ball. :func:`lab4_vga_rig` builds it; :func:`coverage` measures
how many cameras see each point of a volume and how large a ball appears; ``data/rigs/lab4_vga.yaml``
is ``lab4_vga_rig()`` saved (regenerate with ``python -m harness.lab --write``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracker import Camera, Rig

__all__ = [
    "BALL_RADIUS_M",
    "CEILING_Z_M",
    "LAB4_WORKSPACE_M",
    "LIGHTS_M",
    "NET_HALF_SPAN_M",
    "NET_HEIGHT_M",
    "ROBOT_BASE_M",
    "ROOM_M",
    "TABLE_HALF_LENGTH_M",
    "TABLE_HALF_WIDTH_M",
    "TABLE_THICKNESS_M",
    "TABLE_TOP_Z_M",
    "Coverage",
    "coverage",
    "lab4_vga_rig",
    "look_at",
    "preview_rig",
    "workspace_grid",
]

# -- static geometry (ITTF table and net) ----------------------------------------------------------
TABLE_TOP_Z_M = 0.76
TABLE_HALF_LENGTH_M = 1.37  #: table x in [-1.37, 1.37]
TABLE_HALF_WIDTH_M = 0.7625  #: table y in [-0.7625, 0.7625]
TABLE_THICKNESS_M = 0.025
TABLE_EDGE_LINE_M = 0.02  #: white lines along all four edges
TABLE_CENTRE_LINE_M = 0.003  #: white centre line along x (for doubles)
NET_HEIGHT_M = 0.1525  #: net top above the table surface
NET_HALF_SPAN_M = 0.915  #: net spans y in [-0.915, 0.915] at x = 0
NET_TOP_BAND_M = 0.015  #: white band along the top of the net
BALL_RADIUS_M = 0.02  #: 40 mm ball

# -- the room ------------------------------------------------------------------------------------
ROOM_M = np.array([[-6.0, -4.5, 0.0], [6.0, 4.5, 3.4]])  #: floor-to-ceiling box [min, max]
CEILING_Z_M = 3.4
BARRIER_HEIGHT_M = 0.7  #: dark court barriers around the play area
BARRIER_BOX_M = np.array([[-4.5, -3.2], [4.5, 3.2]])  #: barriers stand on this rectangle's edges (x, y)
#: ceiling light panels, each [x_min, x_max, y_min, y_max] at z = CEILING_Z_M - 0.01
LIGHTS_M = np.array(
    [[x - 0.3, x + 0.3, y - 0.6, y + 0.6] for x in (-3.0, -1.0, 1.0, 3.0) for y in (-1.8, 1.8)]
)

#: floor point under the robot's pedestal; the arm's mount (data/robot/wam.yaml) stands on it,
#: and tests/test_lab_robot.py checks the two agree
ROBOT_BASE_M = np.array([-1.75, 0.0, 0.0])

#: the volume where the robot hits: what lab4_vga must see (min, max corners, world frame)
LAB4_WORKSPACE_M = np.array([[-2.3, -1.2, 0.7], [0.3, 1.2, 2.0]])


# -- camera placement ----------------------------------------------------------------------------
def look_at(eye_m, target_m) -> tuple[np.ndarray, np.ndarray]:
    """Extrinsics of a camera at ``eye_m`` looking at ``target_m`` with the image's up direction
    toward the far side (the horizontal part of the viewing direction), so it also works for
    cameras looking nearly straight down.

    eye_m, target_m : (3,) world points, metres
    returns ``R_world_to_cam`` (3, 3) and ``t_world_to_cam_m`` (3,), OpenCV camera axes
    """
    eye = np.asarray(eye_m, float)
    z = np.asarray(target_m, float) - eye
    if np.linalg.norm(z) == 0:
        raise ValueError(f"look_at: eye and target coincide at {eye.tolist()}")
    z /= np.linalg.norm(z)
    up = np.array([z[0], z[1], 0.0]) if np.hypot(z[0], z[1]) > 1e-6 else np.array([1.0, 0.0, 0.0])
    up = up / np.linalg.norm(up) + np.array([0.0, 0.0, 1.0])  # tilt the up hint off the view axis
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ eye


@dataclass(frozen=True)
class _Mount:
    name: str
    eye_m: tuple
    target_m: tuple


#: The four ceiling cameras: two behind the robot, two over the opponent's half near the side
#: lines, each aimed diagonally into the workspace (placement found by maximising :func:`coverage`).
_LAB4_MOUNTS = (
    _Mount("cam0", (-4.88, 1.09, 2.92), (-1.44, 0.02, 1.4)),
    _Mount("cam1", (-4.76, -1.07, 3.13), (-1.32, -0.01, 1.29)),
    _Mount("cam2", (2.28, 1.49, 3.04), (-1.55, -0.2, 0.76)),
    _Mount("cam3", (2.07, -2.01, 2.85), (-1.81, 0.2, 1.09)),
)
_LAB4_SIZE = (640, 480)
_LAB4_F_PX = (945.0, 940.0, 900.0, 905.0)  #: 7 mm lenses on 7.5 um pixels
#: plumb_bob k1, k2, p1, p2, k3 per camera: barrel distortion like a 4-6 mm C-mount lens
_LAB4_DISTORTION = (
    (-0.18, 0.06, 0.0004, -0.0003, 0.0),
    (-0.16, 0.05, -0.0002, 0.0005, 0.0),
    (-0.17, 0.05, 0.0003, 0.0002, 0.0),
    (-0.15, 0.04, -0.0005, -0.0001, 0.0),
)
_LAB4_PRINCIPAL_OFFSET_PX = ((3.1, -2.4), (-4.0, 1.7), (2.2, 3.5), (-1.3, -2.9))


def lab4_vga_rig() -> Rig:
    """The 4-camera VGA ceiling rig of the simulated lab (saved as ``data/rigs/lab4_vga.yaml``).

    Four 640x480 cameras with 7 mm lenses (f = 900-945 px, 38 x 29 deg field of view), plumb_bob
    distortion with k1 in [-0.18, -0.15], mounted 2.85-3.13 m high: cam0/cam1 behind the robot
    (x ~ -4.8 m, y ~ +-1.1 m), cam2/cam3 over the opponent's half beside the side lines
    (x ~ 2.2 m, y ~ +-1.5..2 m); each looks diagonally into the workspace
    :data:`LAB4_WORKSPACE_M` (x in [-2.3, 0.3], y in [-1.2, 1.2], z in [0.7, 2.0]). The mounts were
    found by a seeded random search maximising :func:`coverage` on a 0.1 m grid: every grid point
    is seen by >= 2 cameras, 96 % by >= 3, 79 % by >= 4, with the ball 6.2-17 px across (median 8.6 px)
    (``python -m harness.lab`` prints these figures).
    """
    cams = []
    for mount, f, dist, (dcx, dcy) in zip(_LAB4_MOUNTS, _LAB4_F_PX, _LAB4_DISTORTION, _LAB4_PRINCIPAL_OFFSET_PX):
        R, t = look_at(mount.eye_m, mount.target_m)
        w, h = _LAB4_SIZE
        K = np.array([[f, 0.0, (w - 1) / 2 + dcx], [0.0, f, (h - 1) / 2 + dcy], [0.0, 0.0, 1.0]])
        cams.append(Camera(mount.name, K, np.array(dist), R, t, _LAB4_SIZE))
    return Rig(
        cams,
        workspace_m=LAB4_WORKSPACE_M,
        description="lab4_vga: simulated lab, four 640x480 ceiling cameras over the robot's half (harness.lab.lab4_vga_rig)",
    )


def preview_rig(width: int = 200, height: int = 150) -> Rig:
    """A small, fast 2-camera rig for tests and quick previews (not a lab rig).

    Two cameras with the mounts of lab4's cam0 and cam2 but aimed at (-1.2, 0, 1.2) with a long
    lens (f = 5 * width, ~11 deg field of view, k1 = -0.15), so a ball near that point is
    about 8-10 px across in a ``width`` x ``height`` image.
    """
    cams = []
    for name, mount, k1 in (("cam0", _LAB4_MOUNTS[0], -0.15), ("cam1", _LAB4_MOUNTS[2], -0.12)):
        R, t = look_at(mount.eye_m, (-1.2, 0.0, 1.2))
        f = 5.0 * width
        K = np.array([[f, 0.0, (width - 1) / 2 + 1.3], [0.0, f, (height - 1) / 2 - 0.8], [0.0, 0.0, 1.0]])
        cams.append(Camera(name, K, np.array([k1, 0.05, 0.0003, -0.0002, 0.0]), R, t, (width, height)))
    return Rig(cams, workspace_m=[[-1.5, -0.3, 0.9], [-0.9, 0.3, 1.5]], description="preview rig (harness.lab.preview_rig)")


# -- coverage ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Coverage:
    """How a rig sees a set of points.

    n_seeing : (N,) number of cameras that see each point with the whole ball in the image and
        at least ``min_diameter_px`` across
    diameter_px : (n_cams, N) apparent ball diameter per camera (NaN behind the camera)
    """

    n_seeing: np.ndarray
    diameter_px: np.ndarray

    def fraction_at_least(self, k: int) -> float:
        return float(np.mean(self.n_seeing >= k))


def coverage(rig: Rig, X_world, *, radius_m: float = BALL_RADIUS_M, min_diameter_px: float = 6.0) -> Coverage:
    """Count the cameras that see a ball of ``radius_m`` at each of ``X_world``.

    X_world : (N, 3) world points, metres
    A camera sees a point when the ball's centre projects at least one ball radius inside the image
    and the ball is at least ``min_diameter_px`` across. Occlusion is not modelled.
    """
    X = np.asarray(X_world, float).reshape(-1, 3)
    n = np.zeros(len(X), int)
    diam = np.full((len(rig), len(X)), np.nan)
    for i, cam in enumerate(rig):
        uv = cam.project(X)
        # offset along the camera's x axis: the projected radius, distortion included
        uv_side = cam.project(X + radius_m * cam.R_world_to_cam[0])
        d = 2 * np.linalg.norm(uv_side - uv, axis=1)
        diam[i] = d
        w, h = cam.image_size
        r = d / 2
        with np.errstate(invalid="ignore"):
            inside = (uv[:, 0] - r >= -0.5) & (uv[:, 0] + r <= w - 0.5) & (uv[:, 1] - r >= -0.5) & (uv[:, 1] + r <= h - 0.5)
            n += inside & (cam.depth(X) > 0) & (d >= min_diameter_px)
    return Coverage(n_seeing=n, diameter_px=diam)


def _seen_mask(rig: Rig, cov: Coverage) -> np.ndarray:
    """(n_cams, N) which camera-point pairs count in ``cov.n_seeing`` (recomputed per camera)."""
    return np.stack([coverage(rig.subset([c.name]), workspace_grid()).n_seeing > 0 for c in rig])


def workspace_grid(box_m=LAB4_WORKSPACE_M, step_m: float = 0.1) -> np.ndarray:
    """(N, 3) grid points filling ``box_m`` (min, max corners) every ``step_m``."""
    box = np.asarray(box_m, float)
    axes = [np.arange(lo, hi + step_m / 2, step_m) for lo, hi in box.T]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build the lab4_vga rig, print its coverage, optionally save it.")
    parser.add_argument("--write", action="store_true", help="write data/rigs/lab4_vga.yaml")
    args = parser.parse_args(argv)
    rig = lab4_vga_rig()
    cov = coverage(rig, workspace_grid())
    seen = cov.diameter_px[_seen_mask(rig, cov)]
    print(f"workspace {LAB4_WORKSPACE_M.tolist()} on a 0.1 m grid:")
    for k in range(5):
        print(f"  seen by >= {k} cameras: {100 * cov.fraction_at_least(k):5.1f} %")
    print(f"  40 mm ball across, where seen: min {seen.min():.1f} px, median {np.median(seen):.1f} px, max {seen.max():.1f} px")
    if args.write:
        path = Path(__file__).resolve().parents[1] / "data" / "rigs" / "lab4_vga.yaml"
        rig.save(path)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
