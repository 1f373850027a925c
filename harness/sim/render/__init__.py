"""Synthetic cameras: render a rig's images of the simulated lab and a dynamic scene state.

``Renderer(rig, RenderOptions(), seed=...)`` with ``render(scene)`` / ``render_camera(i, scene)`` /
``render_labelled(scene)``; the scene model is in :mod:`.scene`, random scenes for data sets in
:mod:`.scenes`. See docs/renderer.md.
"""

from harness.sim.render.renderer import DRAW_METHODS, RenderOptions, Renderer
from harness.sim.render.scene_state import COLOURS, Ball, Box, Capsule, Disk, Exposure, Scene, Sphere
from harness.sim.render.truth import VISIBLE_FRACTION, BallTruth

__all__ = [
    "COLOURS",
    "DRAW_METHODS",
    "VISIBLE_FRACTION",
    "Ball",
    "BallTruth",
    "Box",
    "Capsule",
    "Disk",
    "Exposure",
    "RenderOptions",
    "Renderer",
    "Scene",
    "Sphere",
]
