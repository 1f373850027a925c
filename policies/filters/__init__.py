"""Ball filters: from tracker observations to a ball state and a predicted trajectory (docs/filters.md).

One interface (:class:`BallFilter`), two implementations chosen by name:

* ``raw`` -- every observation accepted (the paper's RT2 configuration, "no heuristics at all");
  state from the physical ball model fitted to all observations since reset.
* ``ransac_kalman`` -- the paper's RTBlob heuristics: RANSAC of a second-order polynomial on the
  first observations, then a Kalman filter rejecting observations beyond 3 standard deviations,
  with the table bounce and re-initialisation of lost balls.

Usage (docs/filters.md)::

    f = make_filter("ransac_kalman")      # or "raw"; params=, table=, options=
    for obs in observations:              # tracker.BallObservation, in arrival order
        f.update(obs)                     # -> FilterUpdate(accepted, reason, distance_sigma, pending)
    f.state()                             # FilterState, or None before enough data
    f.predict(t_query_s)                  # BallTrajectoryPrediction, or None before enough data
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from policies.ball_model import BallParams, TableGeometry
from policies.filters._base import BallFilter, BallTrajectoryPrediction, FilterState, FilterUpdate
from policies.filters._ransac import RansacInfo
from policies.filters.ransac_kalman import RansacKalmanFilter, RansacKalmanOptions
from policies.filters.raw import RawFilter, RawOptions

__all__ = [
    "FILTERS",
    "BallFilter",
    "BallTrajectoryPrediction",
    "FilterState",
    "FilterUpdate",
    "RansacInfo",
    "RansacKalmanFilter",
    "RansacKalmanOptions",
    "RawFilter",
    "RawOptions",
    "make_filter",
]

#: filter name -> (class, options class)
FILTERS: dict[str, tuple[type, type]] = {
    "raw": (RawFilter, RawOptions),
    "ransac_kalman": (RansacKalmanFilter, RansacKalmanOptions),
}


def make_filter(name: str, *, params: BallParams | None = None, table: TableGeometry | None = None,
                options=None) -> BallFilter:
    """A new ball filter by name.

    params : ball physics (default: the fitted ``data/ball_params.yaml``)
    table : table surface in the observations' frame (default: the lab table, top at z = 0.76 m)
    options : the filter's options dataclass (``RawOptions`` / ``RansacKalmanOptions``), or a mapping
        of option overrides, or None for the defaults
    Unknown names, options of the other filter, and unknown option keys raise ``ValueError``.
    """
    if name not in FILTERS:
        raise ValueError(f"unknown ball filter {name!r}; valid: {list(FILTERS)}")
    cls, opt_cls = FILTERS[name]
    if params is not None and not isinstance(params, BallParams):
        raise ValueError(f"params must be a BallParams, got {type(params).__name__}")
    if table is not None and not isinstance(table, TableGeometry):
        raise ValueError(f"table must be a TableGeometry, got {type(table).__name__}")
    if options is None:
        options = opt_cls()
    elif isinstance(options, Mapping):
        names = {f.name for f in dataclasses.fields(opt_cls)}
        bad = sorted(set(options) - names)
        if bad:
            raise ValueError(f"unknown {opt_cls.__name__} field(s) {bad} for filter {name!r}; valid: {sorted(names)}")
        options = opt_cls(**options)
    elif not isinstance(options, opt_cls):
        raise ValueError(f"filter {name!r} takes options of type {opt_cls.__name__} (or a mapping), "
                         f"got {type(options).__name__}")
    return cls(params, table, options)
