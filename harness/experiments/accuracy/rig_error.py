"""The calibration the trackers get: a seeded error model of a calibrated camera rig.

On the real robot the cameras were calibrated with a mean re-projection error of 1.3 px (paper
Sec. 3.1: "the average re-projection error reported by the camera calibration procedure"); the
trackers triangulate with that calibration while the light follows the true geometry. The accuracy
experiment does the same: the renderer draws every frame with the TRUE rig (the one in the rig file),
the trackers get an ESTIMATED rig from :func:`estimated_rig`, per camera independently:

* extrinsics: a rotation error about each camera axis, N(0, ``rotation_deg``), and an error of the
  optical centre along each world axis, N(0, ``position_m``);
* intrinsics: both focal lengths scaled by 1 + N(0, ``focal_frac``) (the aspect ratio is well fixed),
  the principal point moved by N(0, ``principal_px``) per axis;
* lens distortion: k1 and k2 moved by N(0, ``radial``), p1 and p2 by N(0, ``tangential``) (k3 and the
  rational terms unchanged; a rig without distortion keeps none).

Size of the error: the **re-projection error** a calibration reports, measured here on noise-free
observations of points spread over the rig's workspace: the true pixels of each point (true rig, every
camera that sees it, points seen by at least two cameras) are triangulated with the estimated rig
(linear, then Gauss-Newton on the pixel error) and re-projected with it; the mean pixel distance over
points and cameras is the figure (:func:`calibration_residuals`). With ``target_reprojection_px`` set
(default 1.3 px, the paper's figure) every drawn component is multiplied by one factor so that this
mean equals the target; the sigmas are sized so that the factor is about 1 (docs/accuracy.md has the
measurement). Also reported: the pixel shift between where the estimated rig and the true rig project
a point (larger: it includes what triangulation absorbs) and the 3D error of the triangulated points,
raw and after the best rigid alignment (the part the robot-to-camera registration cannot absorb).

Not modelled: correlations a real calibration has between its parameters (e.g. principal point vs
rotation), rolling shutter, and calibration drift during a session.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from harness.experiments.accuracy.registration import fit_rigid
from tracker import Rig, triangulate_linear
from tracker.triangulation import project_points

__all__ = ["CalibrationErrorOptions", "calibration_residuals", "estimated_rig", "perturb_rig", "reprojection_residuals"]

#: the seed stream of the calibration error (SeedSequence([seed, CALIBRATION_STREAM]))
CALIBRATION_STREAM = 4
#: parameter blocks drawn per camera: rotation (3), centre (3), focal (1), principal point (2), distortion (4)
_N_DRAWS = 13


@dataclass(frozen=True)
class CalibrationErrorOptions:
    """Options of :func:`estimated_rig` (see the module docstring).

    enabled : False = the trackers get the true rig (``rt2 accuracy --ideal`` / ``--no-calibration-error``)
    rotation_deg, position_m, focal_frac, principal_px, radial, tangential : standard deviations of
        the per-camera errors before scaling
    target_reprojection_px : scale the drawn errors so the mean re-projection error is this (None: as drawn)
    n_points : workspace points on which the re-projection error is measured
    rig_file : a calibrated rig (e.g. written by ``rt2 calib``) the trackers get instead of a drawn error;
        its error is measured the same way (``rt2 calib loop``)
    """

    enabled: bool = True
    rotation_deg: float = 0.05
    position_m: float = 0.003
    focal_frac: float = 0.002
    principal_px: float = 0.8
    radial: float = 0.004
    tangential: float = 0.0002
    target_reprojection_px: float | None = 1.3
    n_points: int = 600
    rig_file: str | None = None

    def __post_init__(self):
        if not isinstance(self.enabled, bool):
            raise ValueError(f"CalibrationErrorOptions.enabled must be True or False, got {self.enabled!r}")
        for name in ("rotation_deg", "position_m", "focal_frac", "principal_px", "radial", "tangential"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 <= v < 1 or name == "principal_px" and 0 <= v < 100):
                raise ValueError(f"CalibrationErrorOptions.{name} must be a standard deviation >= 0 (and small), got {v!r}")
        t = self.target_reprojection_px
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 < t <= 50):
            raise ValueError(f"CalibrationErrorOptions.target_reprojection_px must be in (0, 50] px or None, got {t!r}")
        if isinstance(self.n_points, bool) or not isinstance(self.n_points, int) or self.n_points < 20:
            raise ValueError(f"CalibrationErrorOptions.n_points must be an integer >= 20, got {self.n_points!r}")
        if self.rig_file is not None and not (isinstance(self.rig_file, str) and self.rig_file.strip()):
            raise ValueError(f"CalibrationErrorOptions.rig_file must be a rig file path or None, got {self.rig_file!r}")

    def sigmas(self) -> np.ndarray:
        """(13,) standard deviation of each unit draw (the order of :func:`perturb_rig`'s ``draws``)."""
        return np.array([np.deg2rad(self.rotation_deg)] * 3 + [self.position_m] * 3 + [self.focal_frac]
                        + [self.principal_px] * 2 + [self.radial] * 2 + [self.tangential] * 2)


def perturb_rig(rig: Rig, errors, description: str = "") -> Rig:
    """A copy of ``rig`` with per-camera errors applied.

    errors : (n_cams, 13) rotation vector about the camera axes (rad, 3), optical-centre offset (m,
        world, 3), relative focal error (1), principal-point offset (px, 2), dk1, dk2, dp1, dp2
    """
    E = np.asarray(errors, float)
    if E.shape != (len(rig), _N_DRAWS) or not np.isfinite(E).all():
        raise ValueError(f"errors must be a finite ({len(rig)}, {_N_DRAWS}) array for this rig, got shape {E.shape}")
    data = rig.to_dict()
    for cd, cam, e in zip(data["cameras"], rig, E):
        R = Rotation.from_rotvec(e[0:3]).as_matrix() @ cam.R_world_to_cam  # camera axes rotate by e[0:3]
        centre = cam.center_world + e[3:6]
        K = cam.K.copy()
        K[0, 0] *= 1.0 + e[6]
        K[1, 1] *= 1.0 + e[6]
        K[0, 2] += e[7]
        K[1, 2] += e[8]
        d = cam.distortion.copy()
        n = min(len(d), 4)
        d[:n] += e[9 : 9 + n]
        cd.update(K=K.tolist(), R_world_to_cam=R.tolist(), t_world_to_cam_m=(-R @ centre).tolist())
        cd["distortion"]["coefficients"] = d.tolist()
    data["description"] = description or f"{rig.description} (perturbed)"
    return Rig.from_dict(data, source="perturbed rig")


def _workspace_points(rig: Rig, box_m, n: int, rng: np.random.Generator):
    """(m, 3) points of the box seen by >= 2 cameras, their true pixels (m, n_cams, 2) and seen mask (m, n_cams)."""
    box = np.asarray(box_m, float)
    X = rng.uniform(box[0], box[1], size=(n, 3))
    uv = project_points(X, rig)
    seen = np.stack([rig[i].in_image(uv[:, i]) for i in range(len(rig))], axis=1) & np.isfinite(uv[..., 0])
    keep = seen.sum(axis=1) >= 2
    return X[keep], uv[keep], seen[keep]


def _triangulate(rig: Rig, uv, seen, iterations: int = 8) -> np.ndarray:
    """(m, 3) points from pixels uv (m, n_cams, 2) in the cameras ``seen`` (m, n_cams): linear
    triangulation, then Gauss-Newton on the pixel error (central-difference Jacobian), batched."""
    xn = np.stack([rig[i].undistort(np.where(seen[:, i, None], uv[:, i], np.nan)) for i in range(len(rig))], axis=1)
    X = triangulate_linear(xn, rig.stacked()["P"])
    h = 1e-6
    mask = seen[..., None]
    for _ in range(iterations):
        r = np.where(mask, project_points(X, rig) - uv, 0.0)  # (m, n, 2)
        J = np.stack([(project_points(X + h * e, rig) - project_points(X - h * e, rig)) / (2 * h) for e in np.eye(3)], axis=-1)
        J = np.where(mask[..., None], J, 0.0)  # (m, n, 2, 3)
        H = np.einsum("mnri,mnrj->mij", J, J)
        g = np.einsum("mnri,mnr->mi", J, r)
        X = X - np.linalg.solve(H, g[..., None])[..., 0]
    return X


def reprojection_residuals(rig: Rig, uv_px, seen=None) -> tuple[np.ndarray, np.ndarray]:
    """The re-projection error a calibration reports: each point triangulated from its pixels in the
    cameras that see it (linear, then Gauss-Newton on the pixel error) and projected back.

    uv_px : (m, n_cams, 2) distorted pixels, NaN where a camera has none; seen : optional (m, n_cams)
    bool (default: the finite pixels); every point needs >= 2 cameras
    returns X_world (m, 3) and residual_px (m, n_cams), NaN where not seen
    """
    uv = np.asarray(uv_px, float)
    if uv.ndim != 3 or uv.shape[1:] != (len(rig), 2):
        raise ValueError(f"uv_px must have shape (m, {len(rig)}, 2) for this rig, got shape {uv.shape}")
    finite = np.isfinite(uv).all(axis=-1)
    seen = finite if seen is None else np.asarray(seen, bool) & finite
    if (seen.sum(axis=1) < 2).any():
        raise ValueError(f"every point needs pixels in >= 2 cameras; {int((seen.sum(axis=1) < 2).sum())} of {len(uv)} have fewer")
    X = _triangulate(rig, np.where(seen[..., None], uv, 0.0), seen)
    res = np.linalg.norm(project_points(X, rig) - uv, axis=-1)
    return X, np.where(seen, res, np.nan)


def _q(v, scale=1.0, nd=4) -> dict:
    v = np.asarray(v, float) * scale
    return {"mean": round(float(v.mean()), nd), "median": round(float(np.median(v)), nd),
            "p95": round(float(np.percentile(v, 95)), nd), "max": round(float(v.max()), nd)}


def calibration_residuals(true_rig: Rig, est_rig: Rig, X_world, uv_true=None, seen=None) -> dict:
    """How wrong ``est_rig`` is on the points ``X_world`` (m, 3) (see the module docstring).

    uv_true, seen : the points' true pixels (m, n_cams, 2) and which cameras see them (default:
    projected with ``true_rig``, inside the image). Returns JSON-able figures: ``reprojection_px``
    (what a calibration reports, :func:`reprojection_residuals` on the true pixels), ``projection_shift_px``,
    ``triangulation_mm`` and ``triangulation_after_rigid_mm`` (mean, median, p95, max each), ``n_points``.
    """
    X = np.asarray(X_world, float)
    if uv_true is None:
        uv_true = project_points(X, true_rig)
        seen = np.stack([true_rig[i].in_image(uv_true[:, i]) for i in range(len(true_rig))], axis=1)
    seen = np.asarray(seen, bool) & np.isfinite(uv_true[..., 0])
    X_hat, res = reprojection_residuals(est_rig, uv_true, seen)
    reproj = res[seen]
    shift = np.linalg.norm(project_points(X, est_rig) - uv_true, axis=-1)[seen]
    err3 = np.linalg.norm(X_hat - X, axis=1)
    T = fit_rigid(X, X_hat)
    err3_rigid = np.linalg.norm(X @ T[:3, :3].T + T[:3, 3] - X_hat, axis=1)
    return {"reprojection_px": _q(reproj), "projection_shift_px": _q(shift), "triangulation_mm": _q(err3, 1e3, 3),
            "triangulation_after_rigid_mm": _q(err3_rigid, 1e3, 3), "n_points": int(len(X))}


def estimated_rig(rig: Rig, options: CalibrationErrorOptions = CalibrationErrorOptions(), *, seed: int,
                  workspace_m=None) -> tuple[Rig, dict]:
    """The rig the trackers get, and what its error is (JSON-able ``info``).

    rig : the true rig; workspace_m : (2, 3) box of the measurement points (default: the rig's
    ``workspace_m``); seed : the session seed (stream ``[seed, 4]``: same seed, same calibration).
    Disabled options return ``rig`` itself and ``{"enabled": False}``.
    """
    if not isinstance(options, CalibrationErrorOptions):
        raise ValueError(f"options must be CalibrationErrorOptions, got {type(options).__name__}")
    if not options.enabled:
        return rig, {"enabled": False}
    box = rig.workspace_m if workspace_m is None else np.asarray(workspace_m, float)
    if box is None or np.shape(box) != (2, 3):
        raise ValueError(f"the calibration error is measured in a workspace box: rig {rig.description!r} has none; pass workspace_m")
    draw_rng, point_rng = (np.random.default_rng(s) for s in np.random.SeedSequence([int(seed), CALIBRATION_STREAM]).spawn(2))
    if options.rig_file is not None:  # a real calibration (rt2 calib): measure its error, draw nothing
        from tracker.rig_files import resolve_rig

        est = resolve_rig(options.rig_file)
        if est.names != rig.names:
            raise ValueError(f"rig_file {options.rig_file}: cameras {est.names} do not match the true rig's {rig.names}")
        X, uv, seen = _workspace_points(rig, box, options.n_points, point_rng)
        return est, {"enabled": True, "rig_file": options.rig_file, "workspace_m": np.asarray(box).tolist(),
                     **calibration_residuals(rig, est, X, uv, seen)}
    unit = draw_rng.standard_normal((len(rig), _N_DRAWS)) * options.sigmas()
    X, uv, seen = _workspace_points(rig, box, options.n_points, point_rng)
    if len(X) < 20:
        raise ValueError(f"only {len(X)} of {options.n_points} points of the workspace {np.asarray(box).tolist()} are seen by two cameras")
    desc = f"estimated calibration of {rig.description!r} (simulated error, seed {int(seed)})"

    def make(scale):
        est = perturb_rig(rig, unit * scale, desc)
        return est, calibration_residuals(rig, est, X, uv, seen)

    scale = 1.0
    est, fig = make(scale)
    target = options.target_reprojection_px
    if target is not None:  # the figure is nearly linear in the scale: a few secant steps
        for _ in range(4):
            got = fig["reprojection_px"]["mean"]
            if abs(got - target) <= 0.002 * target:
                break
            scale *= target / got
            est, fig = make(scale)
    E = unit * scale
    per_camera = [{"name": cam.name, "rotation_deg": round(float(np.rad2deg(np.linalg.norm(e[0:3]))), 5),
                   "position_mm": round(float(np.linalg.norm(e[3:6]) * 1e3), 4), "focal_pct": round(float(e[6] * 100), 5),
                   "principal_px": np.round(e[7:9], 4).tolist(), "distortion_delta": np.round(e[9:13], 7).tolist()}
                  for cam, e in zip(rig, E)]
    info = {"enabled": True, "scale": round(float(scale), 6), "target_reprojection_px": target,
            "workspace_m": np.asarray(box).tolist(), **fig, "per_camera": per_camera}
    return est, info
