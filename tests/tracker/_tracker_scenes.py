"""Scenes for tracker's own tests, built from tracker alone (tracker's tests never import harness/).

``shipped_rig(name)``: a rig of ``data/rigs`` (``sim_c4``, ``sim_c8``, ``lab4_vga``, ...), read with
``tracker.Rig.load``; observations of random balls with outliers come from
:func:`tracker.synthetic.simulate_observations`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tracker import Rig

RIG_DIR = Path(__file__).resolve().parents[2] / "data" / "rigs"

#: the pipeline tests' ball flight (drawn in test_pipeline.py, rendered in test_pipeline_rendered.py):
#: frame interval, first position and constant velocity, lab frame
FLIGHT_DT_S = 0.005
FLIGHT_X0_M = np.array([-1.0, 0.1, 1.3])
FLIGHT_V_MPS = np.array([-4.0, 0.3, 0.5])


def shipped_rig(name: str) -> Rig:
    """The rig ``data/rigs/<name>.yaml``."""
    return Rig.load(RIG_DIR / f"{name}.yaml")
