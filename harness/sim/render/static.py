"""Per-camera static background: the lab ray-cast once through the camera's exact lens model.

For every pixel we undistort its centre (``Camera.undistort``, distortion included) into a unit
ray, intersect it with the room, the boxes of :func:`lab_geometry` and the net, and shade the hit
(ambient + ceiling lights with the table's shadow + glossy reflections of the light panels on the
table and floor, the "specular highlights" that fool a white-ball detector). The result, a
:class:`Background`, also keeps what the per-frame kernels need: the rays, the depth of the first
opaque surface, the net's see-through veil, pixels per radian and the vignetting. It is cached per
camera in the process, so building a second :class:`~harness.sim.render.Renderer` on the same rig is free, and on
disk (``harness.common.disk_cache``: keyed by the camera, the options and this code), so the next process reads
it back in milliseconds instead of ray-casting the lab again (~1 s per VGA camera).
"""

from __future__ import annotations

from dataclasses import dataclass
import pickle

import numpy as np

from harness.common.disk_cache import cached
from harness.sim.render.lab_scene import MAT, MATERIALS, floor_texture, lab_geometry, table_line_mask
from tracker import Camera

__all__ = ["AMBIENT", "RADIANCE_SCALE", "Background", "background"]

AMBIENT = 0.25  #: ambient illumination of the static lab (diffuse part from the ceiling lights)
TABLE_ILLUMINATION = 0.95  #: irradiance at the table centre, sets the lights' intensity
RADIANCE_SCALE = 1000.0  #: radiance_u16 = radiance * RADIANCE_SCALE
_GLOSS_SIGMA_M = 0.12  #: blur of the light panels' reflection (glossy, not a mirror)


@dataclass(frozen=True, eq=False)
class Background:
    """Everything the renderer precomputes for one camera (arrays read-only).

    radiance_u16 : (H, W, 3) uint16 linear radiance * RADIANCE_SCALE, vignetting applied
    depth_m : (H, W) float32 distance along each pixel's unit ray to the first opaque surface
    veil_alpha : (H, W) float32 opacity of the net's mesh on the ray (0 where no net)
    veil_depth_m : (H, W) float32 distance to the net's mesh along the ray (inf where none)
    veil_rgb : (3,) radiance of the mesh
    rays_cam : (H, W, 3) float32 unit viewing rays of the pixel centres, camera frame
    px_per_rad : (H, W) float32 local pixels per radian (for anti-aliasing coverage)
    vignette : (H, W) float32 relative illumination of the lens
    """

    radiance_u16: np.ndarray
    depth_m: np.ndarray
    veil_alpha: np.ndarray
    veil_depth_m: np.ndarray
    veil_rgb: np.ndarray
    rays_cam: np.ndarray
    px_per_rad: np.ndarray
    vignette: np.ndarray


def _pixel_rays(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 3) unit rays in the camera frame."""
    xn = camera.undistort(uv)
    d = np.hstack([xn, np.ones((len(xn), 1))])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _trace(O: np.ndarray, D: np.ndarray, geo):
    """First opaque hit of rays ``O + t D``. Returns t (N,), material (N,), normal (N, 3)."""
    n = len(D)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / D
        # the room, seen from inside: the nearest exit plane
        bound = np.where(D > 0, geo.room_m[1], geo.room_m[0])
        t_axes = (bound - O) * inv
        t_axes[~np.isfinite(t_axes) | (t_axes <= 0)] = np.inf
        axis = np.argmin(t_axes, axis=1)
        t = t_axes[np.arange(n), axis]
        normal = np.zeros((n, 3))
        normal[np.arange(n), axis] = -np.sign(D[np.arange(n), axis])
        mat = np.where(axis == 2, np.where(D[:, 2] < 0, MAT["floor"], MAT["ceiling"]), MAT["wall"])
        for (lo, hi), m in zip(geo.boxes_m, geo.box_material):
            # cull: only rays within the cone of the box's bounding sphere can hit it
            c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
            dist = np.linalg.norm(c - O)
            if dist > r:
                cand = np.nonzero(D @ ((c - O) / dist) > np.sqrt(1 - (r / dist) ** 2))[0]
            else:
                cand = np.arange(n)
            if len(cand) == 0:
                continue
            Dc, ic = D[cand], inv[cand]
            t_near = np.full(len(cand), -np.inf)
            t_far = np.full(len(cand), np.inf)
            near_axis = np.zeros(len(cand), np.int64)
            for k in range(3):
                t1, t2 = (lo[k] - O[k]) * ic[:, k], (hi[k] - O[k]) * ic[:, k]
                tk_min, tk_max = np.fmin(t1, t2), np.fmax(t1, t2)
                parallel = Dc[:, k] == 0
                inside = (O[k] >= lo[k]) & (O[k] <= hi[k])
                tk_min = np.where(parallel, -np.inf if inside else np.inf, tk_min)
                tk_max = np.where(parallel, np.inf if inside else -np.inf, tk_max)
                better = tk_min > t_near
                near_axis[better] = k
                t_near = np.maximum(t_near, tk_min)
                t_far = np.minimum(t_far, tk_max)
            hit = (t_near <= t_far) & (t_near > 1e-6) & (t_near < t[cand])
            if not hit.any():
                continue
            idx = cand[hit]
            ax = near_axis[hit]
            t[idx] = t_near[hit]
            mat[idx] = m
            normal[idx] = 0.0
            normal[idx, ax] = -np.sign(D[idx, ax])
    return t, mat, normal


def _light_setup(geo):
    centres = np.stack([(geo.lights_m[:, 0] + geo.lights_m[:, 1]) / 2, (geo.lights_m[:, 2] + geo.lights_m[:, 3]) / 2, np.full(len(geo.lights_m), geo.light_z_m)], axis=1)
    table_centre = np.array([[0.0, 0.0, geo.boxes_m[0, 1, 2]]])
    unit = _direct(table_centre, np.array([[0.0, 0.0, 1.0]]), centres, 1.0, None)
    return centres, (TABLE_ILLUMINATION - AMBIENT) / unit[0]


def _direct(P, normal, centres, intensity, table_box) -> np.ndarray:
    """(N,) irradiance from point lights at ``centres`` facing down, with the table's shadow."""
    E = np.zeros(len(P))
    for c in centres:
        L = c - P
        d2 = np.einsum("ij,ij->i", L, L)
        L = L / np.sqrt(d2)[:, None]
        e = intensity * np.clip(np.einsum("ij,ij->i", normal, L), 0, None) * np.clip(L[:, 2], 0, None) / d2
        if table_box is not None:
            lo, hi = table_box
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - P) / L, (hi - P) / L
                tn = np.nanmax(np.minimum(t1, t2), axis=1)
                tf = np.nanmin(np.maximum(t1, t2), axis=1)
            shadow = (tn <= tf) & (tn > 1e-4) & (P[:, 2] < lo[2])
            e = np.where(shadow, 0.0, e)
        E += e
    return E


def _shade(O, D, t, mat, normal, geo, centres, intensity, footprint_m) -> np.ndarray:
    """(N, 3) linear radiance of the hits; ``footprint_m`` (N,) is the size of the pixel on the
    surface (anti-aliases the table's lines, which can be thinner than a pixel)."""
    P = O + t[:, None] * D
    albedo = np.array([m[1] for m in MATERIALS])[mat]
    gloss = np.array([m[2] for m in MATERIALS])[mat]
    top = (mat == MAT["table"]) & (normal[:, 2] > 0.5)
    if top.any():
        w = table_line_mask(P[top], footprint_m[top])[:, None]
        albedo[top] = (1 - w) * albedo[top] + w * np.array([0.9, 0.9, 0.88])
    floor = mat == MAT["floor"]
    if floor.any():
        albedo[floor] *= floor_texture(P[floor])[:, None]
    E = AMBIENT + _direct(P, normal, centres, intensity, geo.boxes_m[0])
    rad = albedo * E[:, None]
    # glossy reflection of the ceiling panels (Sec. "specular highlights" of the renderer docs)
    glossy = gloss > 0
    if glossy.any():
        g = np.nonzero(glossy)[0]
        R = D[g] - 2 * np.einsum("ij,ij->i", D[g], normal[g])[:, None] * normal[g]
        up = R[:, 2] > 1e-3
        s = np.where(up, (geo.light_z_m - P[g, 2]) / np.where(up, R[:, 2], 1.0), 0.0)
        Q = P[g] + s[:, None] * R
        spec = np.zeros(len(g))
        for x0, x1, y0, y1 in geo.lights_m:
            dx = np.maximum(np.maximum(x0 - Q[:, 0], Q[:, 0] - x1), 0)
            dy = np.maximum(np.maximum(y0 - Q[:, 1], Q[:, 1] - y1), 0)
            spec += np.exp(-(dx * dx + dy * dy) / (2 * _GLOSS_SIGMA_M**2))
        rad[g] += (gloss[g] * geo.light_radiance * np.where(up, spec, 0.0))[:, None]
    ceiling = mat == MAT["ceiling"]
    if ceiling.any():
        x, y = P[ceiling, 0], P[ceiling, 1]
        lit = np.zeros(len(x), bool)
        for x0, x1, y0, y1 in geo.lights_m:
            lit |= (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        idx = np.nonzero(ceiling)[0][lit]
        rad[idx] = geo.light_radiance
    return rad


def _veil(O, D, t_opaque, geo):
    """Net mesh along the rays: (alpha, t) with alpha 0 and t inf where the ray misses it."""
    (_, y0, z0), (_, y1, z1) = geo.net_m
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -O[0] / D[:, 0]
    P = O + np.nan_to_num(t, posinf=0.0, neginf=0.0)[:, None] * D
    hit = np.isfinite(t) & (t > 0) & (t < t_opaque) & (P[:, 1] >= y0) & (P[:, 1] <= y1) & (P[:, 2] >= z0) & (P[:, 2] <= z1)
    # a mesh seen at a grazing angle covers more: 1 - (1 - a)^(1 / |cos|)
    cos = np.abs(D[:, 0]).clip(1e-3, 1)
    alpha = np.where(hit, np.minimum(1 - (1 - geo.net_alpha) ** (1 / cos), 0.95), 0.0)
    return alpha, np.where(hit, t, np.inf)


def _render(camera: Camera, supersample: int, vignette_strength: float) -> dict:
    """The :class:`Background`'s arrays by name, computed."""
    geo = lab_geometry()
    centres, intensity = _light_setup(geo)
    w, h = camera.image_size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    R_cam_to_world = camera.R_world_to_cam.T
    O = camera.center_world
    rays_cam = _pixel_rays(camera, uv)
    D = rays_cam @ R_cam_to_world.T
    # pixels per radian: angle between neighbouring pixel rays
    rc = rays_cam.reshape(h, w, 3)
    ang_x = np.arccos(np.clip(np.einsum("ijk,ijk->ij", rc[:, 1:], rc[:, :-1]), -1, 1))
    ang_y = np.arccos(np.clip(np.einsum("ijk,ijk->ij", rc[1:], rc[:-1]), -1, 1))
    ax = np.concatenate([ang_x, ang_x[:, -1:]], axis=1)
    ay = np.concatenate([ang_y, ang_y[-1:]], axis=0)
    ppr = (2.0 / (ax + ay)).ravel()
    t0, mat0, n0 = _trace(O, D, geo)
    veil_a, veil_t = _veil(O, D, t0, geo)
    veil_rgb = geo.net_rgb * TABLE_ILLUMINATION

    def footprint(t, D, normal, scale):  # pixel size on the surface, metres
        cos = np.abs(np.einsum("ij,ij->i", D, normal)).clip(0.2, 1)
        return t / ppr_sel / np.sqrt(cos) * scale

    ppr_sel = ppr
    rad = _shade(O, D, t0, mat0, n0, geo, centres, intensity, footprint(t0, D, n0, 1.0))
    rad = (1 - veil_a)[:, None] * rad + veil_a[:, None] * veil_rgb
    if supersample > 1:
        # anti-alias silhouettes: re-render only pixels whose 3x3 neighbourhood mixes surfaces
        # (material, or the net's veil) with a supersample x supersample grid of rays
        m = mat0.reshape(h, w)
        a = veil_a.reshape(h, w) > 0
        edge = np.zeros((h, w), bool)
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            sl_a = (slice(0, h - dy), slice(max(-dx, 0), w - max(dx, 0)))
            sl_b = (slice(dy, h), slice(max(dx, 0), w - max(-dx, 0)))
            diff = (m[sl_a] != m[sl_b]) | (a[sl_a] != a[sl_b])
            edge[sl_a] |= diff
            edge[sl_b] |= diff
        idx = np.nonzero(edge.ravel())[0]
        if len(idx):
            offs = (np.arange(supersample) + 0.5) / supersample - 0.5
            acc = np.zeros((len(idx), 3))
            ppr_sel = ppr[idx]
            for oy in offs:
                for ox in offs:
                    Ds = _pixel_rays(camera, uv[idx] + [ox, oy]) @ R_cam_to_world.T
                    ts, ms, ns = _trace(O, Ds, geo)
                    rs = _shade(O, Ds, ts, ms, ns, geo, centres, intensity, footprint(ts, Ds, ns, 1.0 / supersample))
                    al, _ = _veil(O, Ds, ts, geo)
                    acc += (1 - al)[:, None] * rs + al[:, None] * veil_rgb
            rad[idx] = acc / supersample**2
    # vignetting: relative illumination falls off toward the corners
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    r2 = ((uv[:, 0] - cx) ** 2 + (uv[:, 1] - cy) ** 2) / (cx**2 + cy**2)
    vig = 1 - vignette_strength * r2
    rad *= vig[:, None]
    return dict(
        radiance_u16=np.clip(np.round(rad * RADIANCE_SCALE), 0, 65535).astype(np.uint16).reshape(h, w, 3),
        depth_m=t0.astype(np.float32).reshape(h, w),
        veil_alpha=veil_a.astype(np.float32).reshape(h, w),
        veil_depth_m=veil_t.astype(np.float32).reshape(h, w),
        veil_rgb=veil_rgb.astype(float),
        rays_cam=np.ascontiguousarray(rc, dtype=np.float32),
        px_per_rad=ppr.astype(np.float32).reshape(h, w),
        vignette=vig.astype(np.float32).reshape(h, w),
    )


def _render_key(camera: Camera, supersample: int, vignette_strength: float) -> bytes:
    return pickle.dumps((_camera_key(camera), supersample, vignette_strength), protocol=4)


#: :func:`_render` kept on disk (harness/common/disk_cache.py): once per machine for a camera, not per process
_render_on_disk = cached("sim-static-background", _render, key_of=_render_key,
                         code_of=(__name__, "harness.sim.render.lab_scene", "harness.sim.lab", "tracker.camera",
                                  "tracker.distortion"))


def _camera_key(camera: Camera) -> tuple:
    return (
        camera.image_size,
        camera.K.tobytes(),
        camera.dist8.tobytes(),
        camera.R_world_to_cam.tobytes(),
        camera.t_world_to_cam_m.tobytes(),
    )


def background(camera: Camera, *, supersample: int = 2, vignette_strength: float = 0.2) -> Background:
    """The static lab seen by ``camera`` (cached on the camera's parameters and the options).

    supersample : rays per pixel side for the radiance (2 -> 4 rays per pixel, anti-aliased lines)
    vignette_strength : illumination loss at the image corners (0 = none)
    """
    full = (_camera_key(camera), int(supersample), float(vignette_strength))
    bg = _CACHE.get(full)
    if bg is None:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))  # drop the oldest
        arrays = _render_on_disk(camera, int(supersample), float(vignette_strength))
        for arr in arrays.values():
            arr.setflags(write=False)
        bg = Background(**arrays)
        _CACHE[full] = bg
    return bg


_CACHE: dict = {}
_CACHE_SIZE = 16
