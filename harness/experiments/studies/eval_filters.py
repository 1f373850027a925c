"""``rt2 eval filters``: prediction error of the ball filters on real and simulated flights, clean and with outliers.

Flights (docs/filters.md, sec. 5):

* ``real`` -- the MPI-IS launcher flights (``../shared/data/real/mpi_launcher_trajectories``,
  BSD-3-Clause): by default (``--real-flights held-out``) the 29 of 88 that the shipped ball
  parameters were not fitted on (``rt2 sim fit-flight``'s split, seed from ``data/ball_params.yaml``),
  with ``--real-flights all`` every one; ~180 Hz, in their own frame (table top z = 0.744 m from ``rt2 sim fit-flight``,
  generous table extent, flight along +x); hitting plane ``x = --real-plane-x`` (2.4 m: before the
  bounce for the spin sets, after it for the others). Truth = the recorded samples.
* ``sim`` -- ``--sim N`` seeded launcher serves (``harness.sim.launcher``) in the lab frame, flown by
  the ball model at 180 Hz, observed with 2 mm isotropic noise; hitting plane ``x = -1.3 m``
  (after the bounce on the robot's half). Truth = the noise-free flight.

Per flight, filter and condition (clean, or each observation replaced with probability
``--outlier-rate`` by one 0.3-3 m away in a random direction, the same draws for both filters):

* ``+100/+200/+300 ms``: feed the first 20 observations, predict the position that long after the
  20th; truth = the sample nearest that time (within 3 ms), as in ``rt2 sim fit-flight``;
* ``cross@20``: from the same 20 observations, where and when the ball crosses the hitting plane;
* ``cross@-300ms``: from every observation until 300 ms before the true crossing (the time a
  robot needs to move), the same crossing.

With ``--spin-prior launcher`` each real flight's filters get the spin prior of its launcher setting
(wheel speeds and angles), learned from the flights the ball parameters were fitted on only: the
spins that fit each of those whole flights (shipped parameters), per setting their mean and
covariance plus (5 rad/s)^2 on the diagonal (``rt2 sim fit-flight``'s ``full-launcher`` estimator,
docs/ball_physics.md sec. 5); ``raw`` uses it as its initial fit's spin prior, ``ransac_kalman`` as the
prior of its unexplained acceleration. The simulated serves draw their spin at random (no launcher
setting to learn from): they keep the default, no spin prior.

Errors are Euclidean, cm (crossing: position in the plane; time error in ms). A filter with no
prediction (or no predicted crossing) counts as ``failed``. ``outliers_rejected`` / ``clean_rejected``:
fractions of the injected outliers / of the genuine observations that the filter did not accept, over
the observations with an immediate verdict (not ``pending``, i.e. not in ``ransac_kalman``'s RANSAC window).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from harness.common.progress import progress_bar

from checks.files import load_yaml_checked
from policies.ball_model import DEFAULT_PARAMS_PATH, BallParams, TableGeometry, simulate
from policies.filters import FILTERS, make_filter
from tracker.observation import BallObservation, Status

__all__ = ["REAL_FLIGHT_SETS", "Flight", "evaluate_flight", "inject_outliers", "real_flights", "run_study", "sim_flights", "time_filters"]

N_OBSERVED = 20
HORIZONS_MS = (100, 200, 300)
LEAD_MS = 300
MATCH_TOL_S = 0.003
SIM_RATE_HZ = 180.0
SIM_NOISE_M = 0.002
#: The MPI tracker's noise is ~0.5-0.8 mm (data README), but the ball model's residual on the real flights
#: is 2-4 mm (docs/ball_physics.md): the observations are reported with a 2 mm std, the filters' floor.
REAL_NOISE_M = 0.002
OUTLIER_RANGE_M = (0.3, 3.0)


@dataclass(frozen=True)
class Flight:
    """One flight: t_s (n,), X_true (n, 3) truth, X_obs (n, 3) what the tracker reported; frame of ``table``.

    noise_m : the tracker's position std, reported with every observation as its covariance.
    """

    source: str
    name: str
    t_s: np.ndarray
    X_true: np.ndarray
    X_obs: np.ndarray
    table: TableGeometry
    plane_x_m: float
    noise_m: float
    spin_prior: tuple | None = None  #: (mean (3,), cov (3, 3)) rad/s of the flight's launcher setting, or None


#: ``--spin-prior`` choices
SPIN_PRIORS = ("none", "launcher")
#: diagonal floor (rad/s) of the launcher-setting spin prior (``rt2 sim fit-flight``'s leave-one-out choice)
LAUNCHER_PRIOR_MIN_STD_RAD_S = 5.0


#: which real flights ``rt2 eval filters`` uses (``--real-flights``)
REAL_FLIGHT_SETS = ("held-out", "all")


def real_flights(folder: Path | None = None, plane_x_m: float = 2.4, which: str = "held-out",
                 spin_prior: str = "none") -> list[Flight]:
    """The launcher flights; the table height of their frame is the fit's (``data/ball_params.yaml``).

    which : "held-out" = the flights the shipped ball parameters were not fitted on (the split of
        ``rt2 sim fit-flight`` with the seed ``data/ball_params.yaml`` records, 29 of 88), "all" = every flight
    spin_prior : "none", or "launcher" = each flight carries the spin prior of its launcher setting
        learned from the fit flights (with ``which="held-out"`` only: "all" leaves no flights to learn from)
    """
    from harness.experiments.studies.fit_flight import (
        DEFAULT_DATA,
        data_table,
        launcher_spin_priors,
        launcher_setting,
        load_flights,
        split_flights,
        whole_flight_spin,
    )
    from policies.ball_estimation import EstimatorOptions

    if which not in REAL_FLIGHT_SETS:
        raise ValueError(f"real flights must be one of {list(REAL_FLIGHT_SETS)}, got {which!r}")
    if spin_prior not in SPIN_PRIORS:
        raise ValueError(f"spin prior must be one of {list(SPIN_PRIORS)}, got {spin_prior!r}")
    if spin_prior == "launcher" and which != "held-out":
        raise ValueError("--spin-prior launcher needs --real-flights held-out: the prior is learned from the "
                         "other (fit) flights")
    doc = load_yaml_checked(DEFAULT_PARAMS_PATH, "ball parameter file")
    fit = doc.get("fit", {})
    z = float(fit.get("data_frame_table_surface_z_m", 0.744))
    table = data_table(z)
    flights = load_flights(folder or DEFAULT_DATA)
    if which == "held-out":
        if "seed" not in fit or "n_held_out_flights" not in fit:
            raise ValueError(f"{DEFAULT_PARAMS_PATH}: no fit.seed / fit.n_held_out_flights recorded, so which flights the ball "
                             "parameters were fitted on is unknown; use --real-flights all")
        fit_set, flights = split_flights(flights, int(fit["seed"]))
        if len(flights) != int(fit["n_held_out_flights"]):
            raise ValueError(f"{DEFAULT_PARAMS_PATH}: fit.n_held_out_flights is {fit['n_held_out_flights']} but the split with "
                             f"fit.seed {fit['seed']} holds out {len(flights)}; use --real-flights all")
    priors = {}
    if spin_prior == "launcher":
        params = BallParams.load()
        spins = np.array([whole_flight_spin(f, params, table, EstimatorOptions()) for f in fit_set])
        priors = launcher_spin_priors(fit_set, spins, LAUNCHER_PRIOR_MIN_STD_RAD_S)
    return [Flight("real", f"{f.set_name}/{f.traj}", f.t_s, f.X, f.X, table, plane_x_m, REAL_NOISE_M,
                   priors.get(launcher_setting(f))) for f in flights]


def sim_flights(n: int, seed: int, params: BallParams | None = None, plane_x_m: float = -1.3) -> list[Flight]:
    """``n`` seeded launcher serves flown to 0.3 m past the hitting plane, observed with 2 mm noise."""
    from harness.sim.launcher import BallLauncher

    params = params or BallParams.load()
    rng = np.random.default_rng([seed, 1])
    launcher = BallLauncher(params, seed=seed)
    table = TableGeometry()
    out = []
    for i in range(n):
        serve = launcher.serve()
        t = np.arange(0.0, 1.5, 1.0 / SIM_RATE_HZ)
        states, _ = simulate(serve.state, t, params, table)
        keep = np.cumsum(states[:, 0] < plane_x_m - 0.3) == 0
        X = states[keep, 0:3]
        out.append(Flight("sim", f"serve{i}/{serve.spin_kind}", t[keep], X, X + rng.normal(0, SIM_NOISE_M, X.shape),
                          table, plane_x_m, SIM_NOISE_M))
    return out


def inject_outliers(X_obs: np.ndarray, rate: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Replace each row with probability ``rate`` by one 0.3-3 m away in a uniform direction -> (Z, mask)."""
    mask = rng.random(len(X_obs)) < rate
    d = rng.normal(size=(len(X_obs), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    Z = X_obs + np.where(mask[:, None], d * rng.uniform(*OUTLIER_RANGE_M, size=(len(X_obs), 1)), 0.0)
    return Z, mask


def _obs(t: float, z: np.ndarray, noise_m: float) -> BallObservation:
    return BallObservation(t_s=float(t), position_m=z, covariance_m2=np.eye(3) * noise_m**2, support=0,
                           inliers=np.zeros(0, bool), status=Status.OK, latency_s=0.0, tracker="eval")


def _true_crossing(f: Flight) -> tuple[float, np.ndarray] | None:
    d = f.X_true[:, 0] - f.plane_x_m
    hit = np.flatnonzero(d[:-1] * d[1:] <= 0.0)
    if hit.size == 0:
        return None
    i = int(hit[0])
    s = d[i] / (d[i] - d[i + 1]) if d[i] != d[i + 1] else 0.0
    return float(f.t_s[i] + s * (f.t_s[i + 1] - f.t_s[i])), f.X_true[i] + s * (f.X_true[i + 1] - f.X_true[i])


def evaluate_flight(f: Flight, filt, Z: np.ndarray, outlier_mask: np.ndarray) -> dict:
    """Errors of one filter on one flight (observations ``Z``); keys: metric -> value or None (skipped/failed)."""
    res: dict = {}
    cross = _true_crossing(f)
    n_feed = {"h": N_OBSERVED}
    if cross is not None:
        n_lead = int(np.searchsorted(f.t_s, cross[0] - LEAD_MS / 1000.0))
        if n_lead >= N_OBSERVED:  # else the crossing is too early to evaluate with a 300 ms lead
            n_feed["lead"] = n_lead
    filt.reset()
    accepted = np.zeros(len(f.t_s), bool)
    judged = np.zeros(len(f.t_s), bool)
    for k in range(max(n_feed.values())):
        upd = filt.update(_obs(f.t_s[k], Z[k], f.noise_m))
        accepted[k], judged[k] = upd.accepted, not upd.pending
        for tag, n in n_feed.items():
            if k + 1 != n:
                continue
            t_last = f.t_s[k]
            if tag == "h":
                idx = [int(np.argmin(np.abs(f.t_s - (t_last + h / 1000.0)))) for h in HORIZONS_MS]
                ok = [abs(f.t_s[i] - t_last - h / 1000.0) <= MATCH_TOL_S for i, h in zip(idx, HORIZONS_MS)]
                pred = filt.predict(f.t_s[idx]) if any(ok) else None
                for j, h in enumerate(HORIZONS_MS):
                    if ok[j]:
                        err = np.nan if pred is None else np.linalg.norm(pred.position_m[j] - f.X_true[idx[j]])
                        res[f"+{h}ms"] = float(err)
            if cross is not None and cross[0] > t_last:
                name = "cross@20" if tag == "h" else f"cross@-{LEAD_MS}ms"
                pred = filt.predict(np.arange(t_last, t_last + 1.5, 0.002))
                c = None if pred is None else pred.crossing(f.plane_x_m)
                res[name] = np.nan if c is None else float(np.linalg.norm(c[1] - cross[1]))
                res[name + " dt"] = np.nan if c is None else abs(c[0] - cross[0])
    out, clean = outlier_mask & judged, ~outlier_mask & judged
    res["outliers"] = int(out.sum())
    res["outliers_rejected"] = int((out & ~accepted).sum())
    res["clean"] = int(clean.sum())
    res["clean_rejected"] = int((clean & ~accepted).sum())
    return res


METRICS = tuple(f"+{h}ms" for h in HORIZONS_MS) + ("cross@20", f"cross@-{LEAD_MS}ms")


def summarise(results: list[dict], **keys) -> list[dict]:
    rows = []
    for m in METRICS:
        vals = np.array([r[m] for r in results if m in r], float)
        good = vals[np.isfinite(vals)]
        row = dict(keys, metric=m, n=int(vals.size), failed=int((~np.isfinite(vals)).sum()),
                   median_cm=round(float(np.median(good)) * 100, 2) if good.size else None,
                   p90_cm=round(float(np.percentile(good, 90)) * 100, 2) if good.size else None)
        if m.startswith("cross"):
            dts = np.array([r[m + " dt"] for r in results if m in r], float)
            dts = dts[np.isfinite(dts)]
            row["median_dt_ms"] = round(float(np.median(dts)) * 1000, 2) if dts.size else None
        rows.append(row)
    tot = {k: sum(r[k] for r in results) for k in ("outliers", "outliers_rejected", "clean", "clean_rejected")}
    for row in rows:
        row["outliers_rejected"] = round(tot["outliers_rejected"] / tot["outliers"], 3) if tot["outliers"] else None
        row["clean_rejected"] = round(tot["clean_rejected"] / tot["clean"], 3) if tot["clean"] else None
    return rows


def run_study(seed: int, outlier_rate: float, *, n_sim: int = 0, real: bool = True, filters=tuple(FILTERS),
              max_flights: int | None = None, real_flights_set: str = "held-out", spin_prior: str = "none",
              progress: bool = True) -> list[dict]:
    """Rows of {source, filter, outlier_rate, metric, n, failed, median_cm, p90_cm, ...}.

    real_flights_set : "held-out" (the real flights the ball parameters were not fitted on) or "all"
    spin_prior : "none" or "launcher" (real flights: the spin prior of their launcher setting)
    """
    params = BallParams.load()
    groups = []
    if real:
        groups.append(real_flights(which=real_flights_set, spin_prior=spin_prior))
    if n_sim:
        groups.append(sim_flights(n_sim, seed, params))
    rows = []
    rates = (0.0, outlier_rate) if outlier_rate > 0 else (0.0,)
    total = sum(len(g[:max_flights]) for g in groups) * len(rates) * len(filters)
    bar = progress_bar(total=total, desc="eval filters", unit="flight", file=sys.stderr, disable=not progress, leave=False)
    for flights in groups:
        flights = flights[:max_flights]
        for rate in rates:
            for name in filters:
                opts = {"seed": seed} if name == "ransac_kalman" else {}
                filt = make_filter(name, params=params, table=flights[0].table, options=opts)
                results = []
                for i, f in enumerate(flights):
                    if f.spin_prior is not None:  # this flight's launcher setting: a filter with its spin prior
                        filt = make_filter(name, params=params, table=f.table, options=dict(
                            opts, spin_prior_mean_rad_s=f.spin_prior[0], spin_prior_cov_rad2_s2=f.spin_prior[1]))
                    Z, mask = inject_outliers(f.X_obs, rate, np.random.default_rng([seed, i, int(rate * 1e6)]))
                    results.append(evaluate_flight(f, filt, Z, mask))
                    bar.update()
                rows += summarise(results, source=flights[0].source, filter=name, outlier_rate=rate)
    bar.close()
    return rows


def time_filters(flight: Flight, filters=tuple(FILTERS), repeats: int = 20) -> dict:
    """Median ms per ``update`` (after initialisation), of the initialising update, and per ``predict`` of a
    1.2 s, 2 ms grid, per filter."""
    import time

    out = {}
    for name in filters:
        filt = make_filter(name, table=flight.table)
        t_upd, t_init = [], []
        for rep in range(4):  # the first pass compiles/warms up
            filt.reset()
            for k in range(len(flight.t_s)):
                t0 = time.perf_counter()
                upd = filt.update(_obs(flight.t_s[k], flight.X_obs[k], flight.noise_m))
                dt = time.perf_counter() - t0
                if rep > 0 and upd.reason.startswith("initialised"):
                    t_init.append(dt)
                elif rep > 0 and k >= 30 and not upd.pending:
                    t_upd.append(dt)
        grid = np.arange(flight.t_s[-1], flight.t_s[-1] + 1.2, 0.002)
        t_pred = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            filt.predict(grid)
            t_pred.append(time.perf_counter() - t0)
        out[name] = {"update_ms": float(np.median(t_upd)) * 1e3, "init_ms": float(np.median(t_init)) * 1e3,
                     "predict_600_ms": float(np.median(t_pred)) * 1e3}
    return out


def format_table(rows: list[dict]) -> str:
    head = (f"{'source':<6}{'filter':<15}{'outliers':>9}{'metric':>14}{'median_cm':>11}{'p90_cm':>9}{'dt_ms':>7}"
            f"{'n':>5}{'failed':>7}{'out_rej':>9}{'clean_rej':>10}")
    lines = [head]
    fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    for r in rows:
        lines.append(f"{r['source']:<6}{r['filter']:<15}{r['outlier_rate']:>9.2f}{r['metric']:>14}"
                     f"{fmt(r['median_cm'], '.2f'):>11}{fmt(r['p90_cm'], '.2f'):>9}"
                     f"{fmt(r.get('median_dt_ms'), '.1f'):>7}{r['n']:>5}{r['failed']:>7}"
                     f"{fmt(r['outliers_rejected'], '.3f'):>9}{fmt(r['clean_rejected'], '.3f'):>10}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="seed of the outliers, the simulated serves and RANSAC")
    parser.add_argument("--outlier-rate", type=float, default=0.05,
                        help="probability that an observation is an outlier")
    parser.add_argument("--sim", type=int, default=0, metavar="N", help="also N simulated launcher serves (lab frame)")
    parser.add_argument("--no-real", action="store_true", help="skip the real launcher flights")
    parser.add_argument("--real-flights", choices=REAL_FLIGHT_SETS, default="held-out",
                        help="held-out: the 29 real flights the ball parameters were not fitted on (default); all: all 88")
    parser.add_argument("--spin-prior", choices=SPIN_PRIORS, default="none",
                        help="launcher: give each held-out real flight's filters the spin prior of its launcher "
                             "setting, learned from the fit flights (default none)")
    parser.add_argument("--filters", nargs="+", default=list(FILTERS), help=f"filters to evaluate, of {list(FILTERS)}")
    parser.add_argument("--max-flights", type=int, help="at most this many flights per source (fast runs)")
    parser.add_argument("--json", type=Path, help="write the rows as a JSON list of objects")


def run(args: argparse.Namespace) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the study, not after
    if not 0.0 <= args.outlier_rate < 1.0:
        raise ValueError(f"--outlier-rate must be in [0, 1), got {args.outlier_rate}")
    if args.sim < 0 or (args.no_real and args.sim == 0):
        raise ValueError(f"need flights: --sim must be >= 1 with --no-real, got --sim {args.sim}")
    bad = sorted(set(args.filters) - set(FILTERS))
    if bad:
        raise ValueError(f"unknown filter(s) {bad}; valid: {list(FILTERS)}")
    if args.max_flights is not None and args.max_flights < 1:
        raise ValueError(f"--max-flights must be >= 1, got {args.max_flights}")
    if args.spin_prior == "launcher" and args.no_real:
        raise ValueError("--spin-prior launcher applies to the real flights; it cannot go with --no-real")
    rows = run_study(args.seed, args.outlier_rate, n_sim=args.sim, real=not args.no_real, filters=tuple(args.filters),
                     max_flights=args.max_flights, real_flights_set=args.real_flights, spin_prior=args.spin_prior)
    print(f"ball filters: prediction from the first {N_OBSERVED} observations (+h, cross@20) and from all until "
          f"{LEAD_MS} ms before the hitting-plane crossing; seed {args.seed}; spin prior of the real flights: "
          f"{args.spin_prior}")
    print(format_table(rows))
    flight = sim_flights(1, args.seed)[0] if args.no_real else real_flights()[0]
    times = time_filters(flight, tuple(args.filters))
    print("run time (median ms, one thread; noisy on a loaded machine): " + "; ".join(
        f"{k}: update {v['update_ms']:.3f}, initialising update {v['init_ms']:.2f}, predict 600 points "
        f"{v['predict_600_ms']:.2f}" for k, v in times.items()))
    if args.json:
        atomic_write_json(args.json, rows, "--json")
    return 0
