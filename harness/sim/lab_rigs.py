"""The simulated lab's larger rigs: eight VGA cameras (``lab8_vga``) and nine 1440x1080 cameras (``lab9_ace``).

Real labs use 6-10 cameras for coverage; Sony AI's table-tennis robot Ace runs nine 1440x1080 cameras at
200 Hz. Both rigs see the same lab (:mod:`harness.sim.lab`: table, net, barriers, lights, robot base) and
the same flight volume as ``lab4_vga`` (:data:`~harness.sim.lab.LAB4_WORKSPACE_M`: the launcher, the
whole table and the space behind the robot's end), so a scene rendered for one is a scene for all three.

* :func:`lab8_vga_rig` (``data/rigs/lab8_vga.yaml``): ``lab4_vga``'s four cameras unchanged plus four
  more VGA cameras on the side walls and over the robot's end, as a lab that adds cameras to a working
  4-camera set-up would mount them: cam4/cam5 on the left and right walls level with the robot's half,
  cam6 on the left wall level with the opponent's half, cam7 on the ceiling behind the robot looking
  down the table. The flight volume is seen by >= 2 cameras everywhere and by >= 3 at 96.6 % of it (lab4_vga:
  91.5 %), the hitting region by >= 6 everywhere and by all eight at 87 %; ball 6.0-15.7 px across.
* :func:`lab9_ace_rig` (``data/rigs/lab9_ace.yaml``): nine 1440x1080 cameras (3.45 um pixels, 6-8 mm
  lenses) ringing the table 2.9-3.3 m up: three on each side wall, one on each end wall and one on the
  ceiling over the net. The flight volume is seen by >= 3 cameras everywhere and by >= 5 at 92.5 % of it;
  ball 11-55 px across (median 16.6 px), triangulation std 0.7 mm (0.5 px noise).

``python -m harness.sim.lab_rigs`` prints their coverage (:func:`harness.sim.lab.coverage_report`);
``--write`` saves both files. ``tests/harness/sim/test_lab_rigs.py`` checks the files equal the functions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.sim.lab import LAB4_HITTING_BOX_M, LAB4_LAUNCHER_BOX_M, LAB4_WORKSPACE_M, coverage_report, lab4_vga_rig, look_at
from tracker import Camera, Rig

__all__ = ["LARGE_RIGS", "lab8_vga_rig", "lab9_ace_rig"]

#: the four cameras lab8_vga adds to lab4_vga's: name, eye (x, y, z) m, aim point (x, y, z) m, f px,
#: plumb_bob k1, k2, p1, p2, k3, principal point offset (px)
_LAB8_MORE = (
    ("cam4", (-1.30, 4.30, 3.05), (-1.05, 0.10, 1.20), 1150.0, (-0.13, 0.05, 0.0002, 0.0004, 0.0), (1.8, -2.2)),
    ("cam5", (-1.80, -4.30, 3.00), (-0.95, -0.10, 1.20), 1150.0, (-0.14, 0.05, -0.0003, 0.0001, 0.0), (-2.6, 1.4)),
    ("cam6", (1.90, 4.30, 3.10), (0.10, 0.20, 1.15), 1000.0, (-0.12, 0.04, 0.0001, -0.0004, 0.0), (0.9, 2.7)),
    ("cam7", (-4.20, 1.00, 3.30), (-0.60, 0.00, 0.95), 900.0, (-0.15, 0.06, -0.0001, 0.0002, 0.0), (-1.7, -0.6)),
)
_VGA = (640, 480)

#: lab9_ace's nine cameras: name, eye, aim point, f px (1440x1080, 3.45 um pixels: 6 mm = 1739 px, 8 mm = 2319 px)
_ACE_MOUNTS = (
    ("ace0", (-2.60, -4.30, 3.00), (-1.20, -0.20, 1.20), 2319.0),
    ("ace1", (0.00, -4.30, 3.10), (0.00, 0.00, 1.10), 1739.0),
    ("ace2", (2.60, -4.30, 3.00), (1.20, 0.00, 1.10), 2319.0),
    ("ace3", (-2.60, 4.30, 3.00), (-1.20, 0.20, 1.20), 2319.0),
    ("ace4", (0.00, 4.30, 3.10), (0.00, 0.00, 1.10), 1739.0),
    ("ace5", (2.60, 4.30, 3.00), (1.20, 0.00, 1.10), 2319.0),
    ("ace6", (-5.70, 0.60, 2.90), (-1.40, 0.00, 1.20), 2319.0),
    ("ace7", (5.70, -0.60, 2.90), (0.40, 0.00, 1.10), 2319.0),
    ("ace8", (-0.40, 0.30, 3.30), (-0.60, 0.00, 0.76), 1739.0),
)
_ACE_SIZE = (1440, 1080)
_ACE_DISTORTION = (-0.08, 0.03, 0.0, 0.0, 0.0)  #: a mild barrel, like a machine-vision 6-8 mm lens


def _camera(name, eye_m, target_m, f_px, size, distortion, offset_px=(0.0, 0.0)) -> Camera:
    R, t = look_at(eye_m, target_m)
    w, h = size
    K = np.array([[f_px, 0.0, (w - 1) / 2 + offset_px[0]], [0.0, f_px, (h - 1) / 2 + offset_px[1]], [0.0, 0.0, 1.0]])
    return Camera(name, K, np.array(distortion, float), R, t, size)


def lab8_vga_rig() -> Rig:
    """Eight 640x480 cameras: ``lab4_vga``'s four (cam0-cam3, unchanged) and four more (cam4-cam7, module
    docstring), the workspace :data:`~harness.sim.lab.LAB4_WORKSPACE_M` (saved as ``data/rigs/lab8_vga.yaml``)."""
    cams = list(lab4_vga_rig())
    cams += [_camera(name, eye, aim, f, _VGA, dist, off) for name, eye, aim, f, dist, off in _LAB8_MORE]
    return Rig(cams, workspace_m=LAB4_WORKSPACE_M,
               description="lab8_vga: simulated lab, lab4_vga's four ceiling cameras and four more on the walls, 640x480 "
                           "(harness.sim.lab_rigs.lab8_vga_rig)")


def lab9_ace_rig() -> Rig:
    """Nine 1440x1080 cameras ringing the table (module docstring), the workspace
    :data:`~harness.sim.lab.LAB4_WORKSPACE_M` (saved as ``data/rigs/lab9_ace.yaml``)."""
    cams = [_camera(name, eye, aim, f, _ACE_SIZE, _ACE_DISTORTION) for name, eye, aim, f in _ACE_MOUNTS]
    return Rig(cams, workspace_m=LAB4_WORKSPACE_M,
               description="lab9_ace: simulated lab, nine 1440x1080 cameras around and above the table like Sony AI's Ace "
                           "(harness.sim.lab_rigs.lab9_ace_rig)")


#: the rigs this module writes: file stem -> function
LARGE_RIGS = {"lab8_vga": lab8_vga_rig, "lab9_ace": lab9_ace_rig}


def _main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build lab8_vga and lab9_ace, print their coverage, optionally save them.")
    parser.add_argument("--write", action="store_true", help="write data/rigs/lab8_vga.yaml and data/rigs/lab9_ace.yaml")
    args = parser.parse_args(argv)
    boxes = (("flight volume (workspace)", LAB4_WORKSPACE_M), ("hitting region", LAB4_HITTING_BOX_M),
             ("launcher box", LAB4_LAUNCHER_BOX_M))
    for stem, build in LARGE_RIGS.items():
        rig = build()
        print(f"{stem} coverage on a 0.1 m grid (a camera counts when the whole 40 mm ball is in its image, >= 6 px):")
        for name, box in boxes:
            r = coverage_report(rig, box, pairs=((0, 1),))
            shares = ", ".join(f">= {k}: {100 * f:5.1f} %" for k, f in enumerate(r["at_least"]) if k >= 1)
            print(f"  {name}: cameras seeing {shares}")
            print("    ball across where seen: min {:.1f} px, median {:.1f} px, max {:.1f} px".format(*r["diameter_px"]))
            print("    triangulation std (0.5 px noise): median {:.2f} mm, p90 {:.2f} mm".format(*r["triangulation_std_mm"]))
        if args.write:
            path = Path(__file__).resolve().parents[2] / "data" / "rigs" / f"{stem}.yaml"
            rig.save(path)
            print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
