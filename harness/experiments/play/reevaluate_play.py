"""``rt2 reevaluate PLAY.mcap``: replay a playing session's logged observations through each ball filter and
measure, per ball, the error of the predicted hitting point against the logged true ball.

For every ball of the log (window ``[i, i + 1) x ball_slot_s`` of the timeline, harness/experiments/play/log.py) that
had a hitting plan, with t_hit the hitting time of its last plan:

* the observations (``/tracker/<tracker>/ball``) are fed to a fresh filter of each kind in capture order,
  each delivered at capture time + its logged latency, exactly as in the live session;
* at two decision times -- the ball's first plan (``t_plan_s`` of its first ``/figures/plan``) and the
  commit point (t_hit - ``commit_before_s``) -- the filter predicts the ball at t_hit from what had been
  delivered by then; the error is the distance to the true ball at t_hit (``/ground_truth/ball``,
  linearly interpolated). A filter without a prediction by then counts as "no prediction".

Prints a row per ball and the median / 90th percentile per filter and decision time; ``--json PATH``
writes the rows.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["hitting_point_errors", "run_reevaluate"]

FILTERS = ("raw", "ransac_kalman")


def _read(reader, slot_s: float):
    """Per ball index: {"obs": [BallObservation (session time)], "gt": (t (n,), X (n, 3)), "plans": [...], "ball": {...}}."""
    import dataclasses

    balls: dict[int, dict] = {}

    def get(i):
        return balls.setdefault(i, {"obs": [], "gt_t": [], "gt_x": [], "plans": [], "ball": None})

    topics = [t for t in reader.topics() if t.startswith("/tracker/")] + ["/ground_truth/ball", "/figures/plan", "/figures/ball"]
    for m in reader.messages([t for t in topics if t in reader.topics()]):
        i = int(np.floor(m.t_s / slot_s + 1e-9))
        t0 = i * slot_s
        if m.topic.startswith("/tracker/"):
            get(i)["obs"].append(dataclasses.replace(m.data, t_s=m.t_s - t0))  # log time = capture time
        elif m.topic == "/ground_truth/ball":
            get(i)["gt_t"].append(m.t_s - t0)
            get(i)["gt_x"].append(np.asarray(m.data.position_m, float))
        elif m.topic == "/figures/plan":
            get(i)["plans"].append(m.data)
        else:
            get(i)["ball"] = m.data
    return balls


def _truth_at(t_gt, X_gt, t):
    return np.array([np.interp(t, t_gt, X_gt[:, k]) for k in range(3)])


def _predict_at(filter_name, observations, t_decide, t_hit):
    from policies.filters import make_filter

    f = make_filter(filter_name)
    for obs in sorted(observations, key=lambda o: o.t_s):
        if obs.t_s + obs.latency_s > t_decide + 1e-12:
            break
        f.update(obs)
    state = f.state()
    if state is None or t_hit < state.t_s:
        return None
    pred = f.predict(np.array([t_hit]))
    return None if pred is None else pred.position_m[0]


def hitting_point_errors(reader, *, filters=FILTERS, commit_before_s: float = 0.06) -> list[dict]:
    """One row per ball with a plan: ball, outcome, t_hit_s, and per filter the errors (m, or None) of the
    hitting point predicted at the first plan and at the commit point."""
    meta = reader.metadata("session")
    slot = float(meta.get("ball_slot_s", 10.0))
    rows = []
    for i, b in sorted(_read(reader, slot).items()):
        if not b["plans"] or len(b["gt_t"]) < 2:
            continue
        t_hit = float(b["plans"][-1]["t_hit_s"])
        t_first = float(b["plans"][0]["t_plan_s"])
        t_gt, X_gt = np.asarray(b["gt_t"]), np.asarray(b["gt_x"])
        truth = _truth_at(t_gt, X_gt, t_hit)
        row = {"ball": i, "outcome": (b["ball"] or {}).get("outcome"), "t_hit_s": t_hit, "t_first_plan_s": t_first}
        for name in filters:
            for label, t_decide in (("first_plan", t_first), ("commit", t_hit - commit_before_s)):
                p = _predict_at(name, b["obs"], t_decide, t_hit)
                row[f"{name}_{label}_error_m"] = None if p is None else float(np.linalg.norm(p - truth))
        rows.append(row)
    return rows


def run_reevaluate(reader, args) -> int:
    """The ``rt2 reevaluate`` entry for play logs (dispatched on the log's kind "play")."""
    rows = hitting_point_errors(reader)
    meta = reader.metadata("session")
    cfg = meta.get("config", {})
    print(f"rt2 reevaluate {reader.path}: play session ({cfg.get('tracker')} + {cfg.get('filter')}, {cfg.get('source')}), "
          f"seed {meta.get('seed')}; {len(rows)} balls with a plan")
    print("error of the predicted hitting point vs the true ball at the planned hitting time (mm)")
    cols = [f"{f}_{w}_error_m" for f in FILTERS for w in ("first_plan", "commit")]
    print(f"{'ball':>5} {'outcome':<12} " + " ".join(f"{c.replace('_error_m', ''):>24}" for c in cols))
    for r in rows:
        vals = " ".join(f"{'-' if r[c] is None else format(1e3 * r[c], '.1f'):>24}" for c in cols)
        print(f"{r['ball']:>5} {str(r['outcome']):<12} {vals}")
    print("summary (mm): " + "; ".join(
        f"{c.replace('_error_m', '')} median {_q(rows, c, 50)} p90 {_q(rows, c, 90)} (no prediction {sum(r[c] is None for r in rows)})"
        for c in cols))
    if getattr(args, "json", None):
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def _q(rows, col, q):
    v = [r[col] for r in rows if r[col] is not None]
    return "-" if not v else f"{1e3 * np.percentile(v, q):.1f}"
