"""``rt2 play profile``: measure each tracker's synthetic-profile numbers from the vision source.

Plays ``--balls`` served balls per tracker with the vision source (rendered cameras + the real tracker,
filter ``raw``) and compares every observation with the true ball at its capture time, over the frames
where at least two cameras see the whole ball (``harness.sim.lab.coverage``):

* ``p_miss``: share without a position; ``p_outlier``: share with an error > ``outlier_m`` (10 cm, the
  paper's bound for RT2) but < 1 m; ``p_wild``: share with an error >= 1 m;
* ``noise_std_m``: the per-axis RMS error of the other observations (robust: 1.4826 x the median
  absolute error per axis);
* ``outlier_offset_m``: the 10th and 90th percentile of the outliers' errors (only with >= 5 outliers;
  else the profile keeps its default).

``--json PATH`` writes ``{tracker: {noise_std_m, p_miss, p_outlier, p_wild}}``, which
``rt2 play --profile-json PATH`` reads back as the synthetic source's profiles.
"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np

from harness.common.progress import progress_bar
from harness.sim.lab import coverage
from harness.experiments.play.experiment import PlayConfig, build_session, play_ball

__all__ = ["RecordingSource", "measure_profile", "record_balls", "run_profile"]

OUTLIER_M = 0.10
WILD_M = 1.0


class RecordingSource:
    """Wraps an observation source and keeps (t_s, true ball (3,), observation) of every frame set."""

    def __init__(self, inner):
        self.inner, self.rig, self.name = inner, inner.rig, inner.name
        self.samples: list = []

    def reset(self, seed, **kw):
        self.inner.reset(seed, **kw)

    def observe(self, frame_index, t_s, ball_m, ball_velocity_mps, q_true):
        obs = self.inner.observe(frame_index, t_s, ball_m, ball_velocity_mps, q_true)
        self.last_images = getattr(self.inner, "last_images", None)
        self.samples.append((float(t_s), np.asarray(ball_m, float).copy(), obs))
        return obs


def measure_profile(samples, rig) -> dict:
    """Profile numbers (module docstring) from [(t_s, true ball (3,), BallObservation)]."""
    if not samples:
        raise ValueError("no frame sets to measure")
    truth = np.array([s[1] for s in samples])
    seen = coverage(rig, truth).n_seeing >= 2
    errs, miss, n = [], 0, int(seen.sum())
    for (t, x, obs), ok in zip(samples, seen):
        if not ok:
            continue
        if obs.position_m is None:
            miss += 1
        else:
            errs.append(np.asarray(obs.position_m, float) - x)
    E = np.array(errs).reshape(-1, 3)
    d = np.linalg.norm(E, axis=1)
    good = E[d <= OUTLIER_M]
    std = float(np.mean(1.4826 * np.median(np.abs(good), axis=0))) if len(good) else float("nan")
    outl = d[(d > OUTLIER_M) & (d < WILD_M)]
    extra = {"outlier_offset_m": [float(np.percentile(outl, 10)), float(np.percentile(outl, 90))]} if len(outl) >= 5 else {}
    return {"frames_seen": n, "noise_std_m": std, "p_miss": miss / max(n, 1), **extra,
            "p_outlier": float(np.sum((d > OUTLIER_M) & (d < WILD_M))) / max(n, 1),
            "p_wild": float(np.sum(d >= WILD_M)) / max(n, 1),
            "error_median_mm": float(1e3 * np.median(d)) if len(d) else float("nan"),
            "error_p99_mm": float(1e3 * np.percentile(d, 99)) if len(d) else float("nan")}


def record_balls(config: PlayConfig, *, balls: int, seed: int, progress: bool = True) -> RecordingSource:
    """Play ``balls`` balls of ``config`` in this process (the same balls as :func:`run_configuration` plays),
    recording every observation of its source; returns the recording."""
    built = build_session(config, wrap_source=RecordingSource)
    bar = progress_bar(total=balls, desc=f"profile {config.tracker}", file=sys.stderr, disable=not progress, leave=False)
    with bar:
        for index in range(balls):
            play_ball(built, seed, index)
            bar.update(1)
    return built["session"].source


def run_profile(args, profiles) -> int:
    out = {}
    for tracker in args.trackers:
        config = PlayConfig(tracker, "raw", "vision", profiles[tracker], str(args.promp), scene=args.scene)
        rec = record_balls(config, balls=args.balls, seed=args.seed, progress=not args.quiet)
        out[tracker] = measure_profile(rec.samples, rec.rig)
    print(f"rt2 play profile: vision source, {args.balls} balls per tracker, seed {args.seed}")
    print(f"{'tracker':<10} {'frames':>7} {'noise mm':>9} {'p_miss':>8} {'p_outlier':>10} {'p_wild':>8} {'err med mm':>11} "
          f"{'p99 mm':>8}  outlier offset (p10-p90)")
    for k, r in out.items():
        off = "{:.2f}-{:.2f} m".format(*r["outlier_offset_m"]) if "outlier_offset_m" in r else "-"
        print(f"{k:<10} {r['frames_seen']:>7} {1e3 * r['noise_std_m']:>9.2f} {r['p_miss']:>8.4f} {r['p_outlier']:>10.4f} "
              f"{r['p_wild']:>8.4f} {r['error_median_mm']:>11.2f} {r['error_p99_mm']:>8.1f}  {off}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        fields = {f.name for f in dataclasses.fields(profiles[args.trackers[0]])}
        args.json.write_text(json.dumps({k: {f: v for f, v in r.items() if f in fields} for k, r in out.items()}, indent=1))
    return 0
