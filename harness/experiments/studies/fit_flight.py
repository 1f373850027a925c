"""``rt2 sim fit-flight``: fit the ball model to 88 real launcher flights and measure its prediction error.

Data: ``../shared/data/real/mpi_launcher_trajectories`` (MPI-IS ``ball_prediction`` @ 6532302,
BSD-3-Clause): four sets of flights tracked at ~180 Hz. Procedure (docs/ball_physics.md, sec. 5):

1. split the flights, stratified by set and seeded, into a fit set and a held-out set;
2. on the fit set, jointly fit the global parameters and one initial state per flight by
   minimising the error of the whole simulated flight (multi-step prediction) against every
   observed position (soft-L1, scale 3 mm) -- for (a) the spin-free baseline (gravity, drag,
   bounce: C_D, e, mu, table height) and (b) the full model (per-flight spin, Magnus lift with
   the published C_L, spin-dependent drag C_DS, bounce e, mu and spin transfer, table height);
3. choose the spin prior of the full model's state estimator on the fit set (same protocol);
4. for each held-out flight, estimate the state from its first 20 samples and predict the
   position 100, 200 and 300 ms after the 20th sample; the truth is the observed sample nearest
   to that time (within 3 ms; horizons past the end of a flight are skipped and counted).

Row ``full-launcher`` is the spin estimate of the software's goal: the same 20-sample MAP fit, with
the spin prior of the flight's **launcher setting** (wheel speeds and angles, ``launch_params.csv``:
what the lab sets, so known before the serve) learned from the fit set only -- mean and covariance of
the spins the joint fit gave the fit flights of that setting, plus ``min_std`` rad/s on the diagonal,
``min_std`` chosen by leave-one-flight-out on the fit set. Row ``full-launcher-mix``: the setting is
not known; the mixture of the settings' priors (eq. 8, Laplace evidence). Row
``full-launcher-recognised``: the setting is not told either, but recognised from the launch
velocity of the 20 samples (each setting's wheels give their own; a Gaussian per setting over the
fit flights' launch velocities), then that setting's prior.

Row ``full-known-spin`` is a diagnostic, not a predictor: the same 20-sample estimate with the spin
held at the value that fits the whole held-out flight, i.e. how good prediction gets once the spin
is known.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from harness.common.progress import progress_bar

from policies.ball_estimation import (
    BallEKF,
    EKFOptions,
    EstimatorOptions,
    fit_initial_state,
    fit_initial_state_mixture,
    spin_prior_from_spins,
)
from policies.ball_model import BallParams, TableGeometry, simulate

DEFAULT_DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "real" / "mpi_launcher_trajectories"
SETS = ("mn5008_backspin", "mn5008_topspin", "mn5008_no_spin", "no_spin_robot_simple")
HORIZONS_MS = (100, 200, 300)
N_OBSERVED = 20
MATCH_TOL_S = 0.003
#: Reference figures (median cm at +100/200/300 ms): the spin-free predictor we set out to beat
#: (gravity + drag + bounce with textbook parameters) and the goal set for the fitted model.
REFERENCE_CM = {"reference: spin-free predictor": (3.0, 4.7, 7.1), "goal": (2.0, 3.0, 4.5)}
#: Goal of the spin-estimating predictor (median cm at +100/200/300 ms from the first 20 samples) and the row held to it.
SPIN_GOAL_CM = (1.0, 2.5, 4.0)
SPIN_GOAL_MODEL = "full-launcher"
#: Floor (rad/s) added to the launcher-setting spin prior's std, chosen on the fit set by leave-one-flight-out.
LAUNCHER_PRIOR_MIN_STD_GRID_RAD_S = (2.0, 5.0, 10.0)
#: Global parameters fitted per model, with (initial value, lower, upper) bounds.
FREE = {
    "baseline": {"surface_z_m": (0.74, 0.65, 0.80), "drag_coefficient": (0.47, 0.05, 1.5),
                 "table_restitution": (0.9, 0.5, 1.0), "table_friction": (0.25, 0.0, 1.5)},
    "full": {"surface_z_m": (0.74, 0.65, 0.80), "drag_coefficient": (0.47, 0.05, 1.5),
             "drag_spin_coefficient": (0.5, 0.0, 5.0), "table_restitution": (0.9, 0.5, 1.0),
             "table_friction": (0.25, 0.0, 1.5), "table_spin_transfer": (0.5, 0.0, 1.0)},
}
SPIN_PRIOR_GRID_RAD_S = (15.0, 30.0, 60.0, 120.0)
#: Spin prior of the whole-flight fit behind the ``full-known-spin`` diagnostic row: wide, the
#: whole flight (bounce included) observes the spin well.
KNOWN_SPIN_PRIOR_STD_RAD_S = 300.0
N_SPIN_COMPONENTS = 4


@dataclass(frozen=True)
class Flight:
    """One recorded flight: ``t_s`` (n,) from its first sample, ``X`` (n, 3) metres, data frame."""

    set_name: str
    traj: int
    t_s: np.ndarray
    X: np.ndarray
    launch: dict


def load_flights(folder: Path = DEFAULT_DATA) -> list[Flight]:
    """Read ``<set>.csv`` and ``launch_params.csv``; ValueError names the file and row on bad data."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"launcher flight folder not found: {folder}")
    launch: dict[tuple[str, int], dict] = {}
    lp = folder / "launch_params.csv"
    if lp.is_file():
        with lp.open() as fh:
            for row in csv.DictReader(fh):
                launch[(row["set"], int(row["traj"]))] = {k: float(v) for k, v in row.items() if k not in ("set", "traj")}
    flights = []
    want = ["traj", "t_s", "x_m", "y_m", "z_m"]
    for name in SETS:
        path = folder / f"{name}.csv"
        if not path.is_file():
            raise FileNotFoundError(f"flight file not found: {path}")
        with path.open() as fh:
            header = fh.readline().strip().split(",")
        if header[:5] != want:
            raise ValueError(f"{path}: expected columns starting {want}, got {header}")
        data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(5), ndmin=2)
        if not np.isfinite(data).all():
            row = int(np.argwhere(~np.isfinite(data))[0][0]) + 2
            raise ValueError(f"{path}: non-finite value on line {row}")
        for k in np.unique(data[:, 0]).astype(int):
            rows = data[data[:, 0] == k]
            t = rows[:, 1] - rows[0, 1]
            if not (np.diff(t) > 0).all():
                raise ValueError(f"{path}: traj {k} has non-increasing t_s")
            flights.append(Flight(name, int(k), t, rows[:, 2:5].copy(), launch.get((name, int(k)), {})))
    return flights


def split_flights(flights: list[Flight], seed: int, holdout_fraction: float = 1 / 3,
                  max_per_set: int | None = None) -> tuple[list[Flight], list[Flight]]:
    """Seeded split stratified by set; ``max_per_set`` first subsamples each set (fast runs)."""
    rng = np.random.default_rng(seed)
    fit, held = [], []
    for name in SETS:
        group = [f for f in flights if f.set_name == name]
        order = rng.permutation(len(group))
        if max_per_set is not None:
            order = order[:max_per_set]
        n_held = max(1, int(round(holdout_fraction * len(order))))
        held += [group[i] for i in order[:n_held]]
        fit += [group[i] for i in order[n_held:]]
    return fit, held


def data_table(surface_z_m: float) -> TableGeometry:
    """The data frame's table: fitted height; extent generous (x, y of the table undocumented)."""
    return TableGeometry(surface_z_m=float(surface_z_m), x_min_m=0.0, x_max_m=5.0, y_min_m=-1.0, y_max_m=1.0)


def _model_params(model: str, values: dict) -> tuple[BallParams, TableGeometry]:
    vals = dict(values)
    table = data_table(vals.pop("surface_z_m"))
    base = BallParams(lift_coefficient=0.0, drag_spin_coefficient=0.0) if model == "baseline" else BallParams()
    return base.replace(**vals), table


def _initial_state(f: Flight) -> np.ndarray:
    m = f.t_s < 0.12
    coef = np.polynomial.polynomial.polyfit(f.t_s[m], f.X[m], 2)
    return np.concatenate([coef[0], coef[1], np.zeros(3)])


def fit_global(flights: list[Flight], model: str, *, max_nfev: int = 200, dt_s: float = 2e-3,
               progress: bool = True) -> tuple[dict, dict]:
    """Joint least squares over global parameters and per-flight initial states (step 2).

    Returns ``(values, info)``: fitted global values (``FREE[model]`` keys) and per-set median
    residuals (mm), per-flight spins (rad/s), cost and evaluations.
    """
    free = FREE[model]
    names = list(free)
    ns = 9 if model == "full" else 6
    nf = len(flights)
    x0 = np.concatenate([_initial_state(f)[:ns] for f in flights] + [[v[0] for v in free.values()]])
    lb = np.concatenate([np.full(nf * ns, -np.inf), [v[1] for v in free.values()]])
    ub = np.concatenate([np.full(nf * ns, np.inf), [v[2] for v in free.values()]])
    sizes = [3 * len(f.t_s) for f in flights]
    bar = progress_bar(desc=f"fit {model}", unit="eval", file=sys.stderr, disable=not progress, leave=False)

    def residuals(x):
        params, table = _model_params(model, dict(zip(names, x[nf * ns:])))
        out = []
        for i, f in enumerate(flights):
            st = x[i * ns:(i + 1) * ns]
            st = st if ns == 9 else np.concatenate([st, np.zeros(3)])
            sim, _ = simulate(st, f.t_s, params, table, dt_s=dt_s)
            out.append(((sim[:, 0:3] - f.X) * 1000.0).ravel())  # millimetres
        bar.update()
        return np.concatenate(out)

    sparsity = lil_matrix((sum(sizes), len(x0)), dtype=np.int8)
    r0 = 0
    for i, n in enumerate(sizes):
        sparsity[r0:r0 + n, i * ns:(i + 1) * ns] = 1
        sparsity[r0:r0 + n, nf * ns:] = 1
        r0 += n
    res = least_squares(residuals, x0, jac_sparsity=sparsity, bounds=(lb, ub), loss="soft_l1", f_scale=3.0,
                        x_scale="jac", max_nfev=max_nfev)
    bar.close()
    values = {k: float(v) for k, v in zip(names, res.x[nf * ns:])}
    err = np.linalg.norm(res.fun.reshape(-1, 3), axis=1)
    per_set, r0 = {}, 0
    for f, n in zip(flights, sizes):
        per_set.setdefault(f.set_name, []).append(np.median(err[r0:r0 + n // 3]))
        r0 += n // 3
    spins = {}
    if ns == 9:
        for i, f in enumerate(flights):
            spins.setdefault(f.set_name, []).append(res.x[i * ns + 6:i * ns + 9])
        values_spins = np.array([res.x[i * ns + 6:i * ns + 9] for i in range(nf)])
    else:
        values_spins = np.zeros((nf, 3))
    info = {"median_residual_mm": {k: float(np.median(v)) for k, v in per_set.items()},
            "mean_spin_rad_s": {k: np.mean(v, axis=0).round(1).tolist() for k, v in spins.items()},
            "nfev": int(res.nfev), "cost": float(res.cost), "spins_rad_s": values_spins}
    return values, info


def spin_mixture(spins: np.ndarray, n_components: int, seed: int, min_std_rad_s: float = 5.0) -> list[tuple]:
    """Gaussian-mixture spin prior from fitted spins (n, 3): seeded k-means, isotropic std per cluster."""
    from scipy.cluster.vq import kmeans2

    k = min(n_components, len(spins))
    centres, labels = kmeans2(spins, k, seed=seed, minit="++")
    comps = []
    for j in range(k):
        member = spins[labels == j]
        if len(member) == 0:
            continue
        std = float(np.sqrt(np.mean((member - centres[j]) ** 2))) if len(member) > 1 else min_std_rad_s
        comps.append((len(member) / len(spins), centres[j].tolist(), max(std, min_std_rad_s)))
    return comps


def launcher_setting(f: Flight) -> tuple:
    """What the lab sets for a serve: the launcher's angles and wheel speeds (``launch_params.csv``), or
    the set's name when the file gives none."""
    return tuple(sorted(f.launch.items())) if f.launch else (("set", f.set_name),)


def launcher_spin_priors(flights: list[Flight], spins_rad_s: np.ndarray, min_std_rad_s: float,
                         exclude: int | None = None) -> dict[tuple, tuple]:
    """Spin prior per launcher setting, ``{setting: (mean (3,), cov (3, 3))}``, from fitted spins (n, 3) of
    ``flights`` (the fit set), flight ``exclude`` left out (leave-one-out on the fit set)."""
    groups: dict[tuple, list] = {}
    for i, (f, w) in enumerate(zip(flights, spins_rad_s)):
        if i != exclude:
            groups.setdefault(launcher_setting(f), []).append(w)
    return {k: spin_prior_from_spins(np.array(v), min_std_rad_s=min_std_rad_s) for k, v in groups.items()}


def _launcher_options(f: Flight, priors: dict, options: EstimatorOptions) -> EstimatorOptions:
    if launcher_setting(f) not in priors:
        raise ValueError(f"flight {f.set_name}/{f.traj}: no fit flight has its launcher setting {launcher_setting(f)}")
    mean, cov = priors[launcher_setting(f)]
    return replace(options, spin_prior_mean_rad_s=mean, spin_prior_cov_rad2_s2=cov)


def launch_velocity(t_s: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(3,) velocity (m/s) at the first of the given samples, from a per-axis quadratic fit."""
    return np.polynomial.polynomial.polyfit(t_s - t_s[0], X, 2)[1]


def launch_velocity_model(flights: list[Flight], min_std_mps: float = 0.02) -> dict[tuple, tuple]:
    """Per launcher setting: ``(weight, mean (3,), std (3,))`` of the launch velocities of ``flights``'
    first ``N_OBSERVED`` samples (the fit set), std floored at ``min_std_mps``."""
    groups: dict[tuple, list] = {}
    for f in flights:
        groups.setdefault(launcher_setting(f), []).append(launch_velocity(f.t_s[:N_OBSERVED], f.X[:N_OBSERVED]))
    return {k: (len(v) / len(flights), np.mean(v, axis=0), np.maximum(np.std(v, axis=0), min_std_mps))
            for k, v in groups.items()}


def recognise_setting(t_s: np.ndarray, X: np.ndarray, model: dict) -> tuple:
    """The launcher setting whose launch-velocity Gaussian (``launch_velocity_model``) is most probable
    for these samples (largest posterior with the settings' shares as prior)."""
    v = launch_velocity(t_s, X)
    score = {k: np.log(w) - np.sum(np.log(sd) + 0.5 * ((v - mu) / sd) ** 2) for k, (w, mu, sd) in model.items()}
    return max(score, key=score.get)


def _truth_index(f: Flight, t_target: float) -> int | None:
    i = int(np.argmin(np.abs(f.t_s - t_target)))
    return i if abs(f.t_s[i] - t_target) <= MATCH_TOL_S else None


def whole_flight_spin(f: Flight, params: BallParams, table: TableGeometry, options: EstimatorOptions) -> np.ndarray:
    """The spin (rad/s, at the first sample) that best explains *all* of a flight's samples: what a
    predictor could at best know of the spin. Diagnostic only -- it uses the samples to be predicted."""
    whole = replace(options, spin_prior_std_rad_s=KNOWN_SPIN_PRIOR_STD_RAD_S, max_nfev=max(options.max_nfev, 100))
    _, info = fit_initial_state(f.t_s, f.X, params, table, whole)
    return info.state_t0[6:9]


def prediction_errors(flights: list[Flight], params: BallParams, table: TableGeometry, method: str,
                      options: EstimatorOptions, ekf_options: EKFOptions | None = None,
                      mixture: list | None = None, launcher_priors: dict | None = None,
                      launch_model: dict | None = None) -> dict:
    """Step 4: errors (m) per horizon over ``flights``; ``method`` is "map", "mixture", "ekf", "launcher"
    (MAP with the spin prior of the flight's launcher setting, ``launcher_priors`` from
    :func:`launcher_spin_priors`), "recognised" (the same with the setting recognised from the launch
    velocity, ``launch_model`` from :func:`launch_velocity_model`; ``recognised`` in the result counts the
    flights whose setting was recognised right) or "known-spin" (the diagnostic: position and velocity
    from the 20 samples, the spin from the whole flight)."""
    errors = {h: [] for h in HORIZONS_MS}
    skipped = {h: 0 for h in HORIZONS_MS}
    recognised = 0
    for f in flights:
        t_obs, X_obs = f.t_s[:N_OBSERVED], f.X[:N_OBSERVED]
        if method == "map":
            est, _ = fit_initial_state(t_obs, X_obs, params, table, options)
        elif method == "known-spin":  # diagnostic: the spin of the whole flight, held fixed
            spin = whole_flight_spin(f, params, table, options)
            est, _ = fit_initial_state(t_obs, X_obs, params, table, replace(
                options, estimate_spin=False, spin_prior_mean_rad_s=tuple(spin)))
        elif method == "launcher":
            est, _ = fit_initial_state(t_obs, X_obs, params, table, _launcher_options(f, launcher_priors, options))
        elif method == "recognised":
            setting = recognise_setting(t_obs, X_obs, launch_model)
            recognised += setting == launcher_setting(f)
            mean, cov = launcher_priors[setting]
            est, _ = fit_initial_state(t_obs, X_obs, params, table, replace(
                options, spin_prior_mean_rad_s=mean, spin_prior_cov_rad2_s2=cov))
        elif method == "mixture":
            est, _ = fit_initial_state_mixture(t_obs, X_obs, mixture, params, table, options)
        else:
            ekf = BallEKF(params, table, ekf_options or EKFOptions(estimator=options))
            for t, x in zip(t_obs, X_obs):
                est = ekf.update(float(t), x)
        idx = [_truth_index(f, t_obs[-1] + h / 1000.0) for h in HORIZONS_MS]
        have = [i for i in idx if i is not None]
        if have:
            pos, _ = est.predict(f.t_s[have])
        k = 0
        for h, i in zip(HORIZONS_MS, idx):
            if i is None:
                skipped[h] += 1
                continue
            errors[h].append(float(np.linalg.norm(pos[k] - f.X[i])))
            k += 1
    return {"errors_m": errors, "skipped": skipped, "recognised": recognised}


def summarise(model: str, result: dict) -> list[dict]:
    rows = []
    for h in HORIZONS_MS:
        e = np.asarray(result["errors_m"][h]) * 100.0
        rows.append({"model": model, "horizon_ms": h, "median_cm": round(float(np.median(e)), 3) if e.size else None,
                     "p90_cm": round(float(np.percentile(e, 90)), 3) if e.size else None, "n": int(e.size),
                     "skipped": int(result["skipped"][h])})
    return rows


def run_study(data: Path, seed: int, *, max_per_set: int | None = None, max_nfev: int = 200,
              progress: bool = True) -> dict:
    """The whole procedure; returns rows (for the table/JSON), fitted values and fit diagnostics."""
    flights = load_flights(data)
    fit, held = split_flights(flights, seed, max_per_set=max_per_set)
    out = {"seed": seed, "n_fit": len(fit), "n_held_out": len(held), "rows": [], "fits": {}}
    for model in ("baseline", "full"):
        values, info = fit_global(fit, model, max_nfev=max_nfev, progress=progress)
        out["fits"][model] = {"values": values, "info": info}
    # Baseline predictor: position + velocity, no spin, baseline physics.
    p_base, t_base = _model_params("baseline", out["fits"]["baseline"]["values"])
    base_opts = EstimatorOptions(estimate_spin=False)
    out["rows"] += summarise("baseline", prediction_errors(held, p_base, t_base, "map", base_opts))
    # Full predictor: spin prior chosen on the fit set (step 3).
    p_full, t_full = _model_params("full", out["fits"]["full"]["values"])
    scores = {}
    for sd in SPIN_PRIOR_GRID_RAD_S:
        res = prediction_errors(fit, p_full, t_full, "map", EstimatorOptions(spin_prior_std_rad_s=sd))
        scores[sd] = float(np.mean([np.median(res["errors_m"][h]) for h in HORIZONS_MS]))
    best = min(scores, key=scores.get)
    out["spin_prior_scores_cm"] = {str(k): round(v * 100, 3) for k, v in scores.items()}
    out["spin_prior_std_rad_s"] = best
    full_opts = EstimatorOptions(spin_prior_std_rad_s=best)
    fit_spins = out["fits"]["full"]["info"].pop("spins_rad_s")
    mixture = spin_mixture(fit_spins, N_SPIN_COMPONENTS, seed)
    out["fits"]["baseline"]["info"].pop("spins_rad_s")
    out["spin_mixture"] = [(round(w, 3), [round(m, 1) for m in mu], round(sd, 1)) for w, mu, sd in mixture]
    out["rows"] += summarise("full", prediction_errors(held, p_full, t_full, "mixture", full_opts, mixture=mixture))
    out["rows"] += summarise("full-iso", prediction_errors(held, p_full, t_full, "map", full_opts))
    out["rows"] += summarise("full-ekf", prediction_errors(held, p_full, t_full, "ekf", full_opts))
    # Spin prior of the launcher setting, from the fit set only; its floor chosen by leave-one-out there.
    loo = {}
    for sd in LAUNCHER_PRIOR_MIN_STD_GRID_RAD_S:
        errs = {h: [] for h in HORIZONS_MS}
        for i, f in enumerate(fit):
            res = prediction_errors([f], p_full, t_full, "launcher", EstimatorOptions(),
                                    launcher_priors=launcher_spin_priors(fit, fit_spins, sd, exclude=i))
            for h in HORIZONS_MS:
                errs[h] += res["errors_m"][h]
        loo[sd] = float(np.mean([np.median(errs[h]) for h in HORIZONS_MS]))
    min_std = min(loo, key=loo.get)
    out["launcher_prior_scores_cm"] = {str(k): round(v * 100, 3) for k, v in loo.items()}
    out["launcher_prior_min_std_rad_s"] = min_std
    priors = launcher_spin_priors(fit, fit_spins, min_std)
    out["launcher_spin_priors"] = [{"setting": dict(k), "mean_rad_s": [round(m, 1) for m in mean],
                                    "std_rad_s": [round(float(np.sqrt(cov[j][j])), 1) for j in range(3)]}
                                   for k, (mean, cov) in priors.items()]
    out["rows"] += summarise("full-launcher", prediction_errors(held, p_full, t_full, "launcher", EstimatorOptions(),
                                                                launcher_priors=priors))
    weights = {k: sum(launcher_setting(f) == k for f in fit) / len(fit) for k in priors}
    setting_mix = [(weights[k], mean, cov) for k, (mean, cov) in priors.items()]
    out["rows"] += summarise("full-launcher-mix", prediction_errors(held, p_full, t_full, "mixture", EstimatorOptions(),
                                                                    mixture=setting_mix))
    rec = prediction_errors(held, p_full, t_full, "recognised", EstimatorOptions(), launcher_priors=priors,
                            launch_model=launch_velocity_model(fit))
    out["rows"] += summarise("full-launcher-recognised", rec)
    out["launcher_recognised"] = f"{rec['recognised']}/{len(held)}"
    # Not a predictor: how good the 20-sample prediction gets when the spin is known (from the whole flight).
    out["rows"] += summarise("full-known-spin", prediction_errors(held, p_full, t_full, "known-spin", full_opts))
    out["params"] = {m: _model_params(m, out["fits"][m]["values"])[0] for m in ("baseline", "full")}
    return out


def format_report(out: dict) -> str:
    refs = {**REFERENCE_CM, "goal: spin estimated": SPIN_GOAL_CM}
    w = max(len(name) for name in [*refs, *(r["model"] for r in out["rows"])]) + 1
    lines = [f"fit-flight: {out['n_fit']} fit / {out['n_held_out']} held-out flights, seed {out['seed']}; "
             f"prediction from the first {N_OBSERVED} samples", "",
             f"{'model':<{w}}{'horizon_ms':>11}{'median_cm':>11}{'p90_cm':>9}{'n':>5}{'skipped':>9}"]
    for r in out["rows"]:
        med = "-" if r["median_cm"] is None else f"{r['median_cm']:.2f}"
        p90 = "-" if r["p90_cm"] is None else f"{r['p90_cm']:.2f}"
        lines.append(f"{r['model']:<{w}}{r['horizon_ms']:>11}{med:>11}{p90:>9}{r['n']:>5}{r['skipped']:>9}")
    for name, ref in refs.items():
        for h, v in zip(HORIZONS_MS, ref):
            lines.append(f"{name:<{w}}{h:>11}{v:>11.2f}{'':>9}")
    got = {r["horizon_ms"]: r["median_cm"] for r in out["rows"] if r["model"] == SPIN_GOAL_MODEL}
    verdict = ", ".join(f"+{h} ms {got[h]:.2f} {'<=' if got[h] <= g else '>'} {g:.2f}"
                        for h, g in zip(HORIZONS_MS, SPIN_GOAL_CM) if got.get(h) is not None)
    met = all(got.get(h) is not None and got[h] <= g for h, g in zip(HORIZONS_MS, SPIN_GOAL_CM))
    lines.append(f"goal of the spin estimate ({SPIN_GOAL_MODEL}, median cm): {verdict}: {'MET' if met else 'NOT MET'}")
    lines.append("")
    for model, fit in out["fits"].items():
        vals = ", ".join(f"{k}={v:.4g}" for k, v in fit["values"].items())
        res = ", ".join(f"{k}={v:.2f}" for k, v in fit["info"]["median_residual_mm"].items())
        lines.append(f"fitted {model}: {vals}")
        lines.append(f"  median whole-flight residual (mm): {res}")
        if fit["info"]["mean_spin_rad_s"]:
            spins = ", ".join(f"{k}={v}" for k, v in fit["info"]["mean_spin_rad_s"].items())
            lines.append(f"  mean fitted spin (rad/s): {spins}")
    lines.append(f"full-iso / full-ekf spin prior: zero mean, std {out['spin_prior_std_rad_s']} rad/s (chosen on the "
                 f"fit set; mean median cm per std: {out['spin_prior_scores_cm']})")
    lines.append(f"full spin prior: mixture (weight, mean rad/s, std rad/s) of the fit set's spins: {out['spin_mixture']}")
    lines.append(f"full-launcher spin prior per launcher setting (fit set; floor {out['launcher_prior_min_std_rad_s']} rad/s "
                 f"chosen by leave-one-out, mean median cm per floor: {out['launcher_prior_scores_cm']}):")
    for p in out["launcher_spin_priors"]:
        wheels = ", ".join(f"{k}={v:g}" for k, v in p["setting"].items())
        lines.append(f"  {wheels}: mean {p['mean_rad_s']} rad/s, std {p['std_rad_s']} rad/s")
    lines.append(f"full-launcher-recognised: the setting recognised from the launch velocity for "
                 f"{out['launcher_recognised']} held-out flights")
    return "\n".join(lines)


def save_params(out: dict, path: Path, command: str) -> None:
    """Write the full model's fitted parameters (lab defaults of simulator and policy) with provenance."""
    params: BallParams = out["params"]["full"]
    header = (
        "Ball flight and table-bounce parameters: the defaults of the simulator (harness.sim.physics) and the\n"
        "hitting policy (policies.ball_model.BallParams.load). Fitted to the 88 MPI-IS launcher flights\n"
        "(../shared/data/real/mpi_launcher_trajectories) by `rt2 sim fit-flight`; see docs/ball_physics.md.\n"
        "Units: SI (kg, m, s, rad). mass, radius, air density, C_L, inertia factor, gravity are published\n"
        "values held fixed; drag, spin drag, restitution, friction and spin transfer are fitted.\n"
        "`fit:` records provenance; the table height there is in the data's own frame, not the lab's.")
    extra = {"fit": {
        "command": command, "date": datetime.date.today().isoformat(), "seed": out["seed"],
        "n_fit_flights": out["n_fit"], "n_held_out_flights": out["n_held_out"],
        "data_frame_table_surface_z_m": round(out["fits"]["full"]["values"]["surface_z_m"], 5),
        "spin_prior_std_rad_s": out["spin_prior_std_rad_s"],
        "held_out_error_cm": [{k: r[k] for k in ("model", "horizon_ms", "median_cm", "p90_cm")} for r in out["rows"]],
    }}
    params.save(path, header=header, extra=extra)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the launcher flights")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fit / held-out split")
    parser.add_argument("--json", type=Path, help="write [{model, horizon_ms, median_cm, p90_cm, n, skipped}]")
    parser.add_argument("--save-params", type=Path, help="write the full model's fitted BallParams YAML here")
    parser.add_argument("--max-per-set", type=int, help="use at most this many flights per set (fast runs)")
    parser.add_argument("--max-nfev", type=int, default=200, help="evaluation budget of each global fit")


def run(args: argparse.Namespace) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the study, not after
    if args.max_per_set is not None and args.max_per_set < 2:
        raise ValueError(f"--max-per-set must be >= 2 (one fit, one held-out flight per set), got {args.max_per_set}")
    if args.max_nfev < 1:
        raise ValueError(f"--max-nfev must be >= 1, got {args.max_nfev}")
    out = run_study(args.data, args.seed, max_per_set=args.max_per_set, max_nfev=args.max_nfev)
    print(format_report(out))
    if args.json:
        atomic_write_json(args.json, out["rows"], "--json")
    if args.save_params:
        cmd = f"rt2 sim fit-flight --seed {args.seed} --save-params {args.save_params}"
        if args.max_per_set is not None:
            cmd += f" --max-per-set {args.max_per_set}"
        if args.max_nfev != 200:
            cmd += f" --max-nfev {args.max_nfev}"
        save_params(out, args.save_params, cmd)
        print(f"saved fitted parameters to {args.save_params}")
    return 0
