"""Synthetic camera rigs and observations for the simulation studies (paper Sec. 3.1).

The rigs are a deterministic formula, no random numbers: ``c`` cameras on a sphere of radius
4 m around the centre of the robot's workspace, evenly spread in azimuth, at elevations between
20 and 60 degrees (ceiling mounts 2.7-4.7 m high), each looking at the workspace centre, with a
focal length chosen so the whole workspace box fills at most 90 % of its 864x648 image, and mild
barrel distortion. One pixel covers 4-6 mm at the workspace centre. The paper does not give its
geometry; the image size is the one calibrated parameter, chosen so that our run of the paper's
own Algorithm 2 reproduces the paper's error for 4 cameras and 1 % outliers (0.72 vs 0.71 cm);
every other cell is then a prediction. The geometry is documented in data/rigs/README.md; the
files ``data/rigs/sim_c{c}.yaml`` are written by ``python -m harness.sim.study_rigs`` and a test checks
they equal this formula.

The study's observations (Sec. 3.1) are :func:`tracker.synthetic.simulate_observations` on these rigs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tracker import Camera, Rig

__all__ = [
    "SIM_CAMERA_COUNTS",
    "SIM_WORKSPACE_M",
    "load_sim_rig",
    "make_sim_rig",
    "sim_rig_path",
    "write_sim_rigs",
]

RIG_DIR = Path(__file__).resolve().parents[2] / "data" / "rigs"
SIM_CAMERA_COUNTS = (4, 8, 15, 30, 50)
#: Robot workspace, lab world frame (metres): the robot's half of the table (x < 0), a little
#: behind its end, 1 m to either side of the centre line, from the table top to 1 m above it.
SIM_WORKSPACE_M = np.array([[-2.2, -1.0, 0.76], [0.0, 1.0, 1.76]])
IMAGE_SIZE = (864, 648)
RADIUS_M = 4.0
ELEVATION_DEG = (20.0, 60.0)
FILL = 0.9  # the workspace box spans at most this fraction of the half-image
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R_world_to_cam, t_world_to_cam_m for a camera at ``center`` looking at ``target``, z up."""
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def make_sim_rig(n_cams: int) -> Rig:
    """The deterministic study rig with ``n_cams`` cameras (see the module docstring)."""
    if isinstance(n_cams, bool) or not isinstance(n_cams, (int, np.integer)) or n_cams < 2:
        raise ValueError(f"n_cams must be an integer >= 2, got {n_cams!r}")
    box = SIM_WORKSPACE_M
    target = box.mean(axis=0)
    corners = np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    w, h = IMAGE_SIZE
    cams = []
    for i in range(n_cams):
        azimuth = 2.0 * np.pi * (i + 0.5) / n_cams
        frac = ((i + 0.5) * GOLDEN) % 1.0  # low-discrepancy spread of elevations
        elevation = np.radians(ELEVATION_DEG[0] + (ELEVATION_DEG[1] - ELEVATION_DEG[0]) * frac)
        center = target + RADIUS_M * np.array(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
        )
        R, t = _look_at(center, target)
        Xc = corners @ R.T + t
        xn = np.abs(Xc[:, :2] / Xc[:, 2:])
        f = FILL * min((w / 2) / xn[:, 0].max(), (h / 2) / xn[:, 1].max())
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        k1 = -0.05 - 0.05 * frac  # mild barrel distortion, as on typical machine-vision lenses
        cams.append(Camera(f"sim{i:02d}", K, [k1, 0.02, 0.0, 0.0, 0.0], R, t, IMAGE_SIZE))
    desc = (
        f"simulation-study rig: {n_cams} cameras, radius {RADIUS_M} m around the workspace centre, "
        f"elevation {ELEVATION_DEG[0]:g}-{ELEVATION_DEG[1]:g} deg, {w}x{h} px (harness/sim/study_rigs.py)"
    )
    return Rig(cams, workspace_m=box, description=desc)


def sim_rig_path(n_cams: int) -> Path:
    return RIG_DIR / f"sim_c{n_cams}.yaml"


def load_sim_rig(n_cams: int) -> Rig:
    """Load ``data/rigs/sim_c{n_cams}.yaml``."""
    path = sim_rig_path(n_cams)
    if not path.is_file():
        raise FileNotFoundError(f"no simulation rig {path}; write it with `python -m harness.sim.study_rigs`")
    return Rig.load(path)


def write_sim_rigs(counts=SIM_CAMERA_COUNTS) -> list[Path]:
    """Write ``data/rigs/sim_c{c}.yaml`` for every count; returns the paths."""
    paths = []
    for c in counts:
        path = sim_rig_path(c)
        make_sim_rig(c).save(path)
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in write_sim_rigs():
        print(p)
