"""The robust multi-camera estimator: one trustworthy 3D ball position from unreliable pixels.

Implements Algorithm 2 of the paper (every pair of observations from different cameras proposes a
point; keep the largest set of cameras that agree within ``eps_px``) and, as ``method="ours"``,
goes beyond it: several candidates per camera, MSAC tie-break, cheirality and workspace checks,
Levenberg-Marquardt refinement in pixels, inlier re-collection, a covariance, and a status that
says how much to trust the answer. ``method="paper"`` runs the same kernel with the paper's
literal choices so every study can show both side by side. See docs/estimator.md.

    est = RobustTriangulator(rig, eps_px=6.0)
    X_world, info = est.estimate(uv)          # uv: (n_cams, 2) or (n_cams, k, 2) pixels, NaN = none
    if info.status is Status.OK: ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from tracker import _robust_kernels as kern
from tracker._robust_reference import estimate_reference
from tracker.observation import Status
from tracker.rig import Rig

__all__ = ["EstimateBatch", "EstimateInfo", "METHODS", "RobustOptions", "RobustTriangulator"]

#: Status codes written by the kernels, in code order.
STATUS_BY_CODE = (Status.OK, Status.LOW_SUPPORT, Status.NO_CONSENSUS, Status.TOO_FEW_OBSERVATIONS)
TIE_BREAKS = ("msac", "first")
BACKENDS = ("numba", "numpy")


@dataclass(frozen=True)
class RobustOptions:
    """Options of :class:`RobustTriangulator` (``method="paper"`` uses only ``eps_px``,
    ``min_support``, ``pixel_sigma_px`` and ``max_candidates_per_camera``)."""

    eps_px: float = 6.0  #: consistency threshold on the reprojection error (Algorithm 2's epsilon), pixels
    min_support: int = 3  #: cameras needed for Status.OK; 2 agreeing cameras give LOW_SUPPORT
    pixel_sigma_px: float = 1.3  #: pixel noise for the covariance (the paper's calibration error, Sec. 3.1)
    tie_break: str = "msac"  #: equally large sets: lower sum of min(err^2, eps^2) ("msac") or first found
    refine: bool = True  #: Levenberg-Marquardt on the pixel loss L(X) over the inlier set
    recollect: bool = True  #: re-collect inliers at the refined point and refine again
    recollect_rounds: int = 3  #: at most this many re-collections
    use_workspace: bool = True  #: reject candidates outside the rig's workspace box (if it has one)
    workspace_margin_m: float = 0.1  #: grow the box by this much on every side
    min_depth_m: float = 0.05  #: reject candidates closer than this to (or behind) either camera
    max_candidates_per_camera: int = 4  #: largest k accepted in uv (n_cams, k, 2)
    max_iterations: int = 10  #: Levenberg-Marquardt iterations
    tol_m: float = 1e-10  #: stop refining when the step is shorter than this

    def __post_init__(self):
        for name in ("eps_px", "pixel_sigma_px"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value > 0):
                raise ValueError(f"RobustOptions.{name} must be a positive number, got {value!r}")
        for name in ("workspace_margin_m", "min_depth_m", "tol_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value >= 0):
                raise ValueError(f"RobustOptions.{name} must be a non-negative number, got {value!r}")
        for name, low in (("min_support", 2), ("recollect_rounds", 0), ("max_candidates_per_camera", 1), ("max_iterations", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"RobustOptions.{name} must be an integer >= {low}, got {value!r}")
        for name in ("refine", "recollect", "use_workspace"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"RobustOptions.{name} must be True or False, got {getattr(self, name)!r}")
        if self.tie_break not in TIE_BREAKS:
            raise ValueError(f"RobustOptions.tie_break must be one of {list(TIE_BREAKS)}, got {self.tie_break!r}")


#: method -> kernel flags. "paper": Algorithm 2 literally (candidate 0 per camera, strictly larger
#: set replaces, first largest wins, final point = linear triangulation of the set, no refinement).
METHODS = {
    "ours": {"paper": False},
    "paper": {"paper": True},
}


@dataclass(frozen=True)
class EstimateInfo:
    """What :meth:`RobustTriangulator.estimate` knows about its answer (arrays are per rig camera).

    status : :class:`~tracker.Status` (OK / LOW_SUPPORT have a position)
    support : cameras in the consistent set (0 without a position)
    inliers : (n_cams,) bool, cameras in the set
    candidate_index : (n_cams,) int, the candidate used per camera, -1 where none
    reproj_error_px : (n_cams,) pixel error at the position: of the used candidate for inliers, of
        the nearest candidate otherwise; NaN where the camera has no observation or no position
    covariance_m2 : (3, 3) position covariance from ``pixel_sigma_px`` noise, or None
    cost : MSAC cost, sum over observing cameras of min(err^2, eps^2), px^2 (NaN without position)
    n_observations : cameras with at least one candidate
    n_candidates : pair candidates that were scored
    method : "ours" or "paper"
    """

    status: Status
    support: int
    inliers: np.ndarray
    candidate_index: np.ndarray
    reproj_error_px: np.ndarray
    covariance_m2: np.ndarray | None
    cost: float
    n_observations: int
    n_candidates: int
    method: str

    @property
    def has_position(self) -> bool:
        return self.status.has_position


@dataclass(frozen=True)
class EstimateBatch:
    """Results of :meth:`RobustTriangulator.estimate_many`, one row per frame (see EstimateInfo)."""

    status_code: np.ndarray  #: (n_frames,) int, index into STATUS_BY_CODE
    support: np.ndarray  #: (n_frames,)
    candidate_index: np.ndarray  #: (n_frames, n_cams)
    reproj_error_px: np.ndarray  #: (n_frames, n_cams)
    covariance_m2: np.ndarray  #: (n_frames, 3, 3), NaN without position
    cost: np.ndarray  #: (n_frames,)
    n_observations: np.ndarray  #: (n_frames,)
    n_candidates: np.ndarray  #: (n_frames,)
    method: str

    @property
    def inliers(self) -> np.ndarray:
        return self.candidate_index >= 0

    @property
    def has_position(self) -> np.ndarray:
        return self.status_code <= kern.ST_LOW_SUPPORT

    def status(self, i: int) -> Status:
        return STATUS_BY_CODE[self.status_code[i]]

    def __len__(self) -> int:
        return len(self.status_code)

    def __getitem__(self, i: int) -> EstimateInfo:
        cov = self.covariance_m2[i]
        return EstimateInfo(
            STATUS_BY_CODE[self.status_code[i]], int(self.support[i]), self.candidate_index[i] >= 0,
            self.candidate_index[i], self.reproj_error_px[i], None if np.isnan(cov).any() else cov,
            float(self.cost[i]), int(self.n_observations[i]), int(self.n_candidates[i]), self.method,
        )  # fmt: skip


class RobustTriangulator:
    """Robust 3D position from the distorted pixels of the rig's cameras (paper Algorithm 2+).

    rig : the calibrated cameras; observation row i belongs to ``rig[i]``
    options : :class:`RobustOptions`; keyword arguments override single fields
    method : "ours" (default) or "paper" (Algorithm 2 literally)
    backend : "numba" (compiled kernel, the default) or "numpy" (the plain reference)

    Not thread-safe across threads that release the GIL: the kernel reuses workspaces allocated here.
    """

    def __init__(self, rig: Rig, options: RobustOptions | None = None, *, method: str = "ours", backend: str = "numba", **overrides):
        if not isinstance(rig, Rig):
            raise ValueError(f"rig must be a tracker.Rig, got {type(rig).__name__}")
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; valid: {sorted(METHODS)}")
        if backend not in BACKENDS:
            raise ValueError(f"unknown backend {backend!r}; valid: {list(BACKENDS)}")
        if options is None:
            options = RobustOptions()
        elif not isinstance(options, RobustOptions):
            raise ValueError(f"options must be a RobustOptions, got {type(options).__name__}")
        if overrides:
            valid = {f.name for f in fields(RobustOptions)}
            unknown = sorted(set(overrides) - valid)
            if unknown:
                raise ValueError(f"unknown option(s) {unknown}; valid: {sorted(valid)}")
            options = RobustOptions(**{**{f.name: getattr(options, f.name) for f in fields(RobustOptions)}, **overrides})
        self.rig, self.options, self.method, self.backend = rig, options, method, backend
        self.n_cams = n = len(rig)
        self._k_max = options.max_candidates_per_camera
        self._cam = kern.pack_cameras(rig.stacked())
        self._camT = np.ascontiguousarray(self._cam.T)
        self._fopt, self._iopt = _pack_options(rig, options, METHODS[method]["paper"])
        nf, ni = kern.work_sizes(n, self._k_max)
        self._fw, self._iw = np.zeros(nf), np.zeros(ni, np.int64)
        self._nf, self._ni = kern.fout_size(n), kern.iout_size(n)

    def __repr__(self) -> str:
        return f"RobustTriangulator({len(self.rig)} cameras, method={self.method!r}, eps_px={self.options.eps_px})"

    # -- input -----------------------------------------------------------------------------------
    def _as_array(self, uv, batched: bool) -> np.ndarray:
        """Validate at the boundary; returns C-contiguous float64 (..., n_cams, k, 2)."""
        if isinstance(uv, Mapping):
            if batched:
                raise ValueError("estimate_many takes an array (n_frames, n_cams[, k], 2), not a mapping")
            uv = self._from_mapping(uv)
        a = np.asarray(uv, dtype=np.float64)
        lead = 1 if batched else 0
        n = self.n_cams
        if a.ndim == lead + 2 and a.shape[lead:] == (n, 2):
            a = a.reshape(a.shape[:lead] + (n, 1, 2))
        elif not (a.ndim == lead + 3 and a.shape[lead] == n and a.shape[-1] == 2 and a.shape[-2] >= 1):
            want = "(n_frames, " if batched else "("
            raise ValueError(f"uv must have shape {want}{n}, 2) or {want}{n}, k, 2) for this {n}-camera rig, got shape {a.shape}")
        if a.shape[-2] > self._k_max:
            raise ValueError(f"uv has {a.shape[-2]} candidates per camera; max_candidates_per_camera is {self._k_max}")
        nan = np.isnan(a)
        if np.isinf(a).any() or (nan[..., 0] != nan[..., 1]).any():
            bad = np.argwhere(np.isinf(a) | (nan != nan[..., ::-1]))[0]
            raise ValueError(f"uv must hold finite pixels or NaN pairs (no observation); found {float(a[tuple(bad)])} at index {tuple(int(i) for i in bad)}")
        return np.ascontiguousarray(a)

    def _from_mapping(self, uv: Mapping) -> np.ndarray:
        rows = {}
        for name, value in uv.items():
            rows[self.rig.index(name)] = np.atleast_2d(np.asarray(value, dtype=np.float64))
        k = max((r.shape[0] for r in rows.values()), default=1)
        out = np.full((self.n_cams, k, 2), np.nan)
        for i, r in rows.items():
            if r.ndim != 2 or r.shape[1] != 2:
                raise ValueError(f"uv[{self.rig.names[i]!r}] must have shape (2,) or (k, 2), got shape {r.shape}")
            out[i, : len(r)] = r
        return out

    # -- estimation ------------------------------------------------------------------------------
    def estimate(self, uv) -> tuple[np.ndarray | None, EstimateInfo]:
        """One robust position.

        uv : (n_cams, 2) or (n_cams, k, 2) distorted pixels, NaN where a camera saw no ball (or
            NaN-padded candidates); or a mapping camera name -> (2,) or (k, 2) pixels
        returns (X_world (3,) metres or None, :class:`EstimateInfo`)
        """
        a = self._as_array(uv, batched=False)
        fout, iout = np.empty(self._nf), np.empty(self._ni, np.int64)
        if self.backend == "numba":
            kern.estimate_one(a, self._cam, self._camT, self._fopt, self._iopt, self._fw, self._iw, fout, iout)
        else:
            estimate_reference(a, self.rig, self._fopt, self._iopt, fout, iout)
        n = self.n_cams
        status = STATUS_BY_CODE[iout[kern.O_STATUS]]
        cand = iout[kern.O_CAND :]
        cov = fout[kern.O_COV : kern.O_COV + 9].reshape(3, 3)
        info = EstimateInfo(
            status, int(iout[kern.O_SUPPORT]), cand >= 0, cand, fout[kern.O_ERR : kern.O_ERR + n],
            None if cov[0, 0] != cov[0, 0] else cov, float(fout[kern.O_COST]),
            int(iout[kern.O_NOBS]), int(iout[kern.O_NCAND]), self.method,
        )  # fmt: skip
        return (fout[:3] if iout[kern.O_STATUS] <= kern.ST_LOW_SUPPORT else None), info

    def estimate_checked(self, uv, stage) -> tuple[np.ndarray | None, EstimateInfo, float, list]:
        """The consensus with a last stage: :meth:`estimate`, then ``stage(X, info.candidate_index)`` ->
        ``(value, passed)``; while a position fails, its candidates are dropped (from a copy of ``uv``
        made at the first failure: ``uv`` itself is never changed) and the consensus is redone, until a
        position passes or none is left. The rt2 pipeline's stage is the 3D size test
        (:meth:`tracker.size_test.SizeTest.stage`).

        Returns ``(X, info, value, failed)``: the final estimate, its stage value (NaN without a
        position) and ``[(cameras, value), ...]`` of each failed position (cameras: indices with a
        candidate in it).
        """
        X, info = self.estimate(uv)
        value, failed = math.nan, []
        while X is not None:
            value, passed = stage(X, info.candidate_index)
            if passed:
                break
            if not failed:
                uv = uv.copy()  # the common case (nothing fails) allocates nothing
            cams = np.flatnonzero(info.candidate_index >= 0)
            failed.append((cams, value))
            uv[cams, info.candidate_index[cams]] = np.nan
            X, info = self.estimate(uv)
            value = math.nan
        return X, info, value, failed

    def estimate_many(self, uv) -> tuple[np.ndarray, EstimateBatch]:
        """Robust positions for many frames in one compiled call (for studies and logs).

        uv : (n_frames, n_cams, 2) or (n_frames, n_cams, k, 2) distorted pixels, NaN = none
        returns (X_world (n_frames, 3), NaN rows where no position; :class:`EstimateBatch`)
        """
        a = self._as_array(uv, batched=True)
        F = a.shape[0]
        fout, iout = np.empty((F, self._nf)), np.empty((F, self._ni), np.int64)
        if self.backend == "numba":
            kern.estimate_batch(a, self._cam, self._camT, self._fopt, self._iopt, self._fw, self._iw, fout, iout)
        else:
            for f in range(F):
                estimate_reference(a[f], self.rig, self._fopt, self._iopt, fout[f], iout[f])
        X = fout[:, :3].copy()
        status = iout[:, kern.O_STATUS]
        X[status > kern.ST_LOW_SUPPORT] = np.nan
        batch = EstimateBatch(
            status, iout[:, kern.O_SUPPORT], iout[:, kern.O_CAND :], fout[:, kern.O_ERR :],
            fout[:, kern.O_COV : kern.O_COV + 9].reshape(F, 3, 3), fout[:, kern.O_COST],
            iout[:, kern.O_NOBS], iout[:, kern.O_NCAND], self.method,
        )  # fmt: skip
        return X, batch


def _pack_options(rig: Rig, o: RobustOptions, paper: bool) -> tuple[np.ndarray, np.ndarray]:
    fopt = np.zeros(kern.N_FOPT)
    fopt[kern.F_EPS_PX] = o.eps_px
    fopt[kern.F_MIN_DEPTH_M] = o.min_depth_m
    fopt[kern.F_SIGMA_PX] = o.pixel_sigma_px
    fopt[kern.F_TOL_M] = o.tol_m
    use_box = o.use_workspace and rig.workspace_m is not None and not paper
    if use_box:
        fopt[kern.F_BOX : kern.F_BOX + 3] = rig.workspace_m[0] - o.workspace_margin_m
        fopt[kern.F_BOX + 3 : kern.F_BOX + 6] = rig.workspace_m[1] + o.workspace_margin_m
    iopt = np.zeros(kern.N_IOPT, np.int64)
    iopt[kern.I_PAPER] = paper
    iopt[kern.I_TIE_BREAK] = o.tie_break == "msac" and not paper
    iopt[kern.I_CHECK_DEPTH] = not paper
    iopt[kern.I_USE_BOX] = use_box
    iopt[kern.I_REFINE] = o.refine and not paper
    iopt[kern.I_RECOLLECT] = o.recollect and not paper
    iopt[kern.I_MAX_ITER] = o.max_iterations
    iopt[kern.I_MIN_SUPPORT] = o.min_support
    iopt[kern.I_ROUNDS] = o.recollect_rounds
    return fopt, iopt
