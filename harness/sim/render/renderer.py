"""The synthetic multi-camera renderer: a rig and a scene state in, one uint8 RGB image per camera out.

Per camera and frame: the cached static background is scaled to the frame's brightness (one
OpenCV pass), the dynamic primitives are drawn in small windows by the numba kernel (depth-tested
against the background's depth map and each other), and sensor noise is added from precomputed
tiles. Nothing else touches the full frame, which is what makes >= 200 VGA frames/s possible
(``rt2 bench renderer``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from checks.per_thread import PerThread
from harness.sim.render._kernels import draw_numba
from harness.sim.render.primitives import AMBIENT, DIFFUSE, DN_PER_RADIANCE, LIGHT_DIR_WORLD, SPECULAR_GAIN, pack_scene
from harness.sim.render.reference import draw_numpy
from harness.sim.render.scene_state import Scene
from harness.sim.render.sensor import NoiseBank, background_dn
from harness.sim.render.static import Background, background
from harness.sim.render.truth import BallTruth, ball_truths
from tracker import Rig

__all__ = ["DRAW_METHODS", "RenderOptions", "Renderer"]

#: draw kernels by name: the numba hot path and its plain-numpy reference
DRAW_METHODS = {"numba": draw_numba, "numpy": draw_numpy}
#: shading models: (ambient, diffuse, specular gain)
SHADINGS = {"phong": (AMBIENT, DIFFUSE, SPECULAR_GAIN), "flat": (1.0, 0.0, 0.0)}


@dataclass(frozen=True)
class RenderOptions:
    """Renderer settings (the scene's :class:`~harness.sim.render.scene_state.Exposure` varies per frame).

    reference_exposure_s : exposure at which the lab renders at nominal brightness
    noise_dn : read-noise sigma at gain 1, pixel values (scales with gain); 0 = no noise
    supersample : rays per pixel side for the static background (2 -> anti-aliased table lines)
    vignette : illumination loss at the image corners (0..0.9)
    shading : ``"phong"`` (ambient + diffuse + highlights) or ``"flat"`` (objects show their
        reflectance uniformly: for geometric checks of the rendered silhouettes)
    method : draw kernel, a key of :data:`DRAW_METHODS`
    """

    reference_exposure_s: float = 0.002
    noise_dn: float = 2.0
    supersample: int = 2
    vignette: float = 0.2
    shading: str = "phong"
    method: str = "numba"

    def __post_init__(self):
        if not (isinstance(self.reference_exposure_s, (int, float)) and 0 < self.reference_exposure_s <= 0.1):
            raise ValueError(f"RenderOptions.reference_exposure_s must be in (0, 0.1] s, got {self.reference_exposure_s!r}")
        if not (isinstance(self.noise_dn, (int, float)) and 0 <= self.noise_dn <= 50):
            raise ValueError(f"RenderOptions.noise_dn must be in [0, 50], got {self.noise_dn!r}")
        if isinstance(self.supersample, bool) or not isinstance(self.supersample, int) or not 1 <= self.supersample <= 4:
            raise ValueError(f"RenderOptions.supersample must be an integer in [1, 4], got {self.supersample!r}")
        if not (isinstance(self.vignette, (int, float)) and 0 <= self.vignette <= 0.9):
            raise ValueError(f"RenderOptions.vignette must be in [0, 0.9], got {self.vignette!r}")
        if self.shading not in SHADINGS:
            raise ValueError(f"unknown RenderOptions.shading {self.shading!r}; valid: {sorted(SHADINGS)}")
        if self.method not in DRAW_METHODS:
            raise ValueError(f"unknown RenderOptions.method {self.method!r}; valid: {sorted(DRAW_METHODS)}")


class Renderer:
    """Renders :class:`~harness.sim.render.scene_state.Scene` states through every camera of ``rig``.

    rig : the cameras (any size and lens model of :class:`tracker.Camera`)
    options : :class:`RenderOptions`
    seed : selects the sensor noise; with ``scene.frame_index`` it fixes every frame's noise, so
        the same (seed, scene) gives the same bytes in any process and order

    Construction ray-casts the static lab once per camera (a few seconds per VGA camera; cached
    per process, so further renderers on the same rig are immediate).
    """

    def __init__(self, rig: Rig, options: RenderOptions | None = None, *, seed: int = 0):
        if not isinstance(rig, Rig):
            raise ValueError(f"Renderer needs a tracker.Rig, got {type(rig).__name__}")
        options = RenderOptions() if options is None else options
        if not isinstance(options, RenderOptions):
            raise ValueError(f"options must be a RenderOptions, got {type(options).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.rig, self.options, self.seed = rig, options, int(seed)
        self._draw = DRAW_METHODS[options.method]
        self._zbufs = PerThread(dict)  # each thread's reusable depth buffers by shape (_zbuf; not pickled)
        self._backgrounds: list[Background] = [
            background(cam, supersample=options.supersample, vignette_strength=options.vignette) for cam in rig
        ]
        self._noise = {}
        self._params = []
        for cam in rig:
            R = np.ascontiguousarray(cam.R_world_to_cam, dtype=float)
            light = np.concatenate([R @ LIGHT_DIR_WORLD, SHADINGS[options.shading]])
            self._params.append((cam.K.copy(), cam.dist8.copy(), R, cam.t_world_to_cam_m.copy(), light))
            size = cam.image_size
            if size not in self._noise:
                self._noise[size] = NoiseBank(*size, seed=self.seed)

    def __len__(self) -> int:
        return len(self.rig)

    def background(self, i: int) -> Background:
        """The precomputed static background of camera ``i``."""
        return self._backgrounds[self._index(i)]

    def render(self, scene: Scene, out: list[np.ndarray] | None = None) -> list[np.ndarray]:
        """One (H, W, 3) uint8 RGB image per rig camera, in rig order.

        out : optional one C-contiguous (H, W, 3) uint8 array per camera to render into (e.g. shared
            memory): the same bytes as new images, without allocating and copying them
        """
        prims, n_balls = self._pack(scene)
        if out is not None:
            out = list(out)
            if len(out) != len(self.rig):
                raise ValueError(f"out must hold one image per camera ({len(self.rig)}), got {len(out)}")
            for i, (a, cam) in enumerate(zip(out, self.rig)):
                w, h = cam.image_size
                if not (isinstance(a, np.ndarray) and a.shape == (h, w, 3) and a.dtype == np.uint8 and a.flags.c_contiguous
                        and a.flags.writeable):
                    raise ValueError(f"out[{i}] must be a writable C-contiguous ({h}, {w}, 3) uint8 array, got "
                                     f"{getattr(a, 'shape', type(a).__name__)} {getattr(a, 'dtype', '')}")
        return [self._render(i, scene, prims, n_balls, None if out is None else out[i])[0] for i in range(len(self.rig))]

    def render_camera(self, i: int, scene: Scene) -> np.ndarray:
        """Camera ``i``'s (H, W, 3) uint8 RGB image of ``scene``."""
        prims, n_balls = self._pack(scene)
        return self._render(self._index(i), scene, prims, n_balls)[0]

    def render_labelled(self, scene: Scene) -> tuple[list[np.ndarray], list[tuple[BallTruth, ...]]]:
        """Images plus, per camera, one :class:`~harness.sim.render.truth.BallTruth` per scene ball."""
        prims, n_balls = self._pack(scene)
        images, truths = [], []
        for i, cam in enumerate(self.rig):
            img, coverage = self._render(i, scene, prims, n_balls)
            images.append(img)
            truths.append(ball_truths(cam, scene.balls, scene.exposure.exposure_s, coverage))
        return images, truths

    # -- internals ----------------------------------------------------------------------------------
    def _zbuf(self, i: int) -> np.ndarray:
        """This thread's reusable depth buffer of camera ``i``'s size (no allocation per frame)."""
        bufs = self._zbufs.get()
        depth = self._backgrounds[i].depth_m
        buf = bufs.get(depth.shape)
        if buf is None:
            buf = bufs[depth.shape] = np.empty_like(depth)
        return buf

    def _index(self, i) -> int:
        if isinstance(i, str):
            return self.rig.index(i)
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < len(self.rig):
            raise ValueError(f"camera index must be in [0, {len(self.rig)}) or a camera name {self.rig.names}, got {i!r}")
        return int(i)

    @staticmethod
    def _pack(scene: Scene):
        if not isinstance(scene, Scene):
            raise ValueError(f"render needs a harness.sim.render.Scene, got {type(scene).__name__}")
        return pack_scene(scene)

    def _render(self, i: int, scene: Scene, prims: np.ndarray, n_balls: int, out: np.ndarray | None = None):
        bg = self._backgrounds[i]
        K, d8, R, t, L_cam = self._params[i]
        exp = scene.exposure
        brightness = exp.light_level * exp.gain * exp.exposure_s / self.options.reference_exposure_s
        img = background_dn(bg.radiance_u16, brightness, out)
        coverage = np.zeros(n_balls)
        if len(prims):
            zbuf = self._zbuf(i)
            np.copyto(zbuf, bg.depth_m)  # the draw kernel's depth test writes into it
            self._draw(
                img, zbuf, bg.rays_cam, bg.px_per_rad, bg.veil_alpha, bg.veil_depth_m, bg.veil_rgb, bg.vignette,
                K, d8, R, t, prims, L_cam, brightness * DN_PER_RADIANCE, coverage,
            )  # fmt: skip
        sigma = self.options.noise_dn * exp.gain
        if sigma > 0:
            rng = np.random.default_rng([self.seed, scene.frame_index, i])
            self._noise[self.rig[i].image_size].add(img, sigma, rng)
        return img, coverage
