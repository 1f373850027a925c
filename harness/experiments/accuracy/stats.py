"""Error statistics of the accuracy experiment, the table printed beside the paper's figures, and the goals.

Per tracker, over the evaluation frames (the part of the run not used for registration):

* a frame is *missing* when the tracker reported no position (``frac_missing`` = missing / frames);
* the error of a frame with a position is the distance to the registered ground truth; ``mean_cm``,
  ``median_cm``, ``p90_cm``, ``p99_cm`` (linear-interpolated percentiles, ``numpy.percentile``),
  ``max_cm`` and ``frac_over_10cm`` (share of frames *with a position* whose error exceeds 10 cm) are over
  those frames only. With no position at all they are None.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BASELINE_WORDS", "JSON_KEYS", "PAPER", "TRACKER_KINDS", "check_baseline", "check_goals", "rt2_goals", "error_stats", "fmt", "format_goals", "format_table", "mode_shares"]

#: keys of each object of ``rt2 accuracy --json`` (one object per tracker)
JSON_KEYS = ("tracker", "mean_cm", "median_cm", "p90_cm", "p99_cm", "max_cm", "frac_over_10cm", "frac_missing")
#: trackers in the order of the tables
TRACKER_KINDS = ("rt2", "rt2-paper", "rtblob")
#: what the paper reports for its real-robot run (Sec. 3.2, error histogram figure)
PAPER = {
    "rt2": "mass in 0-5 cm; never > 10 cm",
    "rt2-paper": "(the paper's RT2 is this system)",
    "rtblob": "modes < 7 cm and 25-30 cm; tens of m ~0.1 %",
}


def _r(x, nd: int):
    return None if x is None or not np.isfinite(x) else round(float(x), nd)


def error_stats(tracker: str, errors_m) -> dict:
    """One ``--json`` object. errors_m : (n,) error per evaluation frame in metres, NaN = no position."""
    e = np.asarray(errors_m, dtype=float)
    if e.ndim != 1 or e.size == 0:
        raise ValueError(f"errors_m must be a non-empty 1-D array (one entry per frame), got shape {e.shape}")
    if (e[np.isfinite(e)] < 0).any() or np.isinf(e).any():
        raise ValueError("errors_m must be distances >= 0 (NaN where the tracker gave no position)")
    have = e[np.isfinite(e)] * 100.0
    out = {"tracker": tracker}
    if have.size:
        p50, p90, p99 = np.percentile(have, [50, 90, 99])
        vals = (have.mean(), p50, p90, p99, have.max(), float(np.mean(have > 10.0)))
    else:
        vals = (None,) * 6
    for key, v in zip(JSON_KEYS[1:7], vals):
        out[key] = _r(v, 6 if key == "frac_over_10cm" else 4)
    out["frac_missing"] = round(float(1.0 - have.size / e.size), 6)
    return out


def mode_shares(errors_m) -> dict:
    """Shares of the frames with a position in the paper's error bands: < 5 cm, 5-10 cm, 20-35 cm (RTBlob's
    second mode), > 1 m, > 10 m."""
    e = np.asarray(errors_m, float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {k: None for k in ("under_5cm", "5_to_10cm", "20_to_35cm", "over_1m", "over_10m")}
    return {
        "under_5cm": round(float(np.mean(e < 0.05)), 6),
        "5_to_10cm": round(float(np.mean((e >= 0.05) & (e <= 0.10))), 6),
        "20_to_35cm": round(float(np.mean((e >= 0.20) & (e <= 0.35))), 6),
        "over_1m": round(float(np.mean(e > 1.0)), 6),
        "over_10m": round(float(np.mean(e > 10.0)), 6),
    }


def fmt(v, spec: str) -> str:
    """``format(v, spec)``, or "-" for None (a figure that could not be measured)."""
    return "-" if v is None else format(v, spec)



def format_table(rows: list[dict]) -> str:
    """The per-tracker table with the paper's reported characteristics beside ours."""
    head = f"{'tracker':10} {'mean':>7} {'median':>7} {'p90':>7} {'p99':>7} {'max':>9} {'>10cm':>7} {'missing':>7}   paper (Sec. 3.2)"
    lines = [head, f"{'':10} {'cm':>7} {'cm':>7} {'cm':>7} {'cm':>7} {'cm':>9} {'%':>7} {'%':>7}"]
    for r in rows:
        over = None if r["frac_over_10cm"] is None else 100 * r["frac_over_10cm"]
        lines.append(f"{r['tracker']:10} {fmt(r['mean_cm'], '7.2f')} {fmt(r['median_cm'], '7.2f')} {fmt(r['p90_cm'], '7.2f')} "
                     f"{fmt(r['p99_cm'], '7.2f')} {fmt(r['max_cm'], '9.2f')} {fmt(over, '7.2f')} "
                     f"{100 * r['frac_missing']:7.2f}   {PAPER.get(r['tracker'], '')}")
    return "\n".join(lines)


def check_goals(rows: list[dict]) -> list[tuple[str, bool | None, str]]:
    """(goal, met or None when not measurable, what was measured) per accuracy goal (docs/accuracy.md): rt2's
    own goals, then the baseline's published failure mode (:func:`check_baseline`), in the order of the JSON."""
    return rt2_goals(rows) + check_baseline(rows)


def rt2_goals(rows: list[dict]) -> list[tuple[str, bool | None, str]]:
    """The goals rt2 is held to: (goal, met or None when not measurable, what was measured)."""
    rt2 = {r["tracker"]: r for r in rows}.get("rt2")
    if rt2 is None:
        return []
    p99, mx = rt2["p99_cm"], rt2["max_cm"]
    return [("rt2 p99 <= 1.5 cm", None if p99 is None else p99 <= 1.5, f"p99 {fmt(p99, '.2f')} cm"),
            ("rt2 max < 5 cm", None if mx is None else mx < 5.0, f"max {fmt(mx, '.2f')} cm")]


def check_baseline(rows: list[dict]) -> list[tuple[str, bool | None, str]]:
    """Whether this run shows the paper's observation about RTBlob (errors > 10 cm, more often than rt2): not a
    goal of rt2, a property of the scene (a clean scene gives RTBlob no chance to fail)."""
    by = {r["tracker"]: r for r in rows}
    blob, rt2 = by.get("rtblob"), by.get("rt2")
    if blob is None:
        return []
    ref = 0.0 if rt2 is None or rt2["frac_over_10cm"] is None else rt2["frac_over_10cm"]
    f = blob["frac_over_10cm"]
    seen = None if f is None else (f > ref and blob["max_cm"] > 10.0)
    return [("rtblob failure mode visible (errors > 10 cm, more often than rt2)", seen,
             f"rtblob > 10 cm in {fmt(None if f is None else 100 * f, '.2f')} % of frames with a position, "
             f"max {fmt(blob['max_cm'], '.1f')} cm")]


def format_goals(goals, words=None) -> str:
    word = words or {True: "met", False: "NOT met", None: "not measured"}
    return "\n".join(f"  [{word[ok]:>12}] {goal}: {measured}" for goal, ok, measured in goals)


#: how :func:`format_goals` words the baseline's observation: seen or not, never "met"
BASELINE_WORDS = {True: "seen", False: "not seen", None: "not measured"}
