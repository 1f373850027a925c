"""Per-tracker timing and error profiles of the playing sessions: frame rate, latency, and (for the
``synthetic`` observation source) noise, misses and outliers.

Timing (both sources): a tracker of rate f captures frame sets at t_k = phase + k / f (phase drawn per
ball); the observation of frame set k reaches the filter at t_k + latency. Defaults: RT2 ~180 Hz
(the MPI-IS tracker's rate, /work/shared/data/real/mpi_launcher_trajectories, median dt 5.6 ms), RTBlob a third of that (the paper, sec. 4.2: RT2's frame rate "is about
3 times as high as that of the RTBlob implementation"). The paper gives no latency; both use 10 ms by
default (so the comparison isolates rate and errors), configurable with ``--latency-ms``.

Errors (``synthetic`` source only; the ``vision`` source renders images and runs the real tracker):

* the ball is observable only where at least ``min_cameras`` cameras of the rig see it whole
  (``harness.sim.lab.coverage``) -- elsewhere the observation has no position (status
  too_few_observations);
* a visible ball is missed (no position) with probability ``p_miss``;
* else an outlier with probability ``p_outlier``: the true position plus an offset of length
  uniform in ``outlier_offset_m`` in a random direction (the paper's RTBlob second error mode,
  25-30 cm: "one of the four cameras reported an incorrect ball position"); with probability
  ``p_wild`` instead a wild position anywhere in ``wild_box_m`` (the paper's "tens of metres with
  probability around 0.1 %": RTBlob only);
* else the true position plus N(0, noise_std_m^2 I), with covariance noise_std_m^2 I reported.

Two sets of numbers (``rt2 play --profiles``):

* ``vision`` (default, :data:`PROFILES`): measured from the vision source on 2026-11-22 with
  ``rt2 play profile --balls 50 --seed 0 --trackers rt2 rt2-paper rtblob`` (rendered lab4_vga cameras,
  default play scene, RTBlob set up by ``harness.experiments.play.rtblob_setup``; 6862 / 6863 / 2342 frame sets
  where >= 2 cameras see the ball): what the trackers do in our simulated lab;
* ``paper`` (:data:`PAPER_PROFILES`): the defaults before 2026-11-22, assumptions taken from the
  paper's real-robot figures (sec. 4.2): RTBlob's second error mode at 25-30 cm (5 %) and ~0.1 % errors
  of tens of metres, which our rendered lab does not produce (docs/play.md, section 3).

``--profile-json`` replaces single fields of the chosen set with measured ones.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from checks.files import MAX_CONFIG_BYTES, read_text_capped

__all__ = ["PAPER_PROFILES", "PROFILES", "PROFILE_SETS", "TrackerProfile", "load_profiles", "profile_for"]


@dataclass(frozen=True)
class TrackerProfile:
    """Timing and synthetic error model of one tracker (SI units; module docstring)."""

    tracker: str
    rate_hz: float
    latency_s: float = 0.010
    noise_std_m: float = 0.002
    p_miss: float = 0.01
    p_outlier: float = 0.0
    outlier_offset_m: tuple = (0.25, 0.30)
    p_wild: float = 0.0
    wild_box_m: tuple = ((-10.0, -10.0, -5.0), (10.0, 10.0, 10.0))
    min_cameras: int = 2

    def __post_init__(self):
        if not isinstance(self.tracker, str) or not self.tracker:
            raise ValueError(f"TrackerProfile.tracker must be a tracker name, got {self.tracker!r}")
        for name in ("rate_hz", "noise_std_m"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
                raise ValueError(f"TrackerProfile.{name} must be a finite number > 0, got {v!r}")
        if not isinstance(self.latency_s, (int, float)) or not 0 <= self.latency_s < 1.0:
            raise ValueError(f"TrackerProfile.latency_s must be in [0, 1) s, got {self.latency_s!r}")
        for name in ("p_miss", "p_outlier", "p_wild"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not 0 <= v <= 1:
                raise ValueError(f"TrackerProfile.{name} must be a probability in [0, 1], got {v!r}")
        if self.p_miss + self.p_outlier + self.p_wild > 1:
            raise ValueError(f"TrackerProfile: p_miss + p_outlier + p_wild must be <= 1, got {self}")
        lo, hi = self.outlier_offset_m
        if not 0 <= lo <= hi:
            raise ValueError(f"TrackerProfile.outlier_offset_m must be (low, high) with 0 <= low <= high, got {self.outlier_offset_m!r}")
        if not isinstance(self.min_cameras, int) or self.min_cameras < 2:
            raise ValueError(f"TrackerProfile.min_cameras must be an integer >= 2, got {self.min_cameras!r}")

    def with_timing(self, rate_hz: float | None = None, latency_s: float | None = None) -> "TrackerProfile":
        """The same profile with another frame rate and/or latency (None keeps the value)."""
        changes = {k: v for k, v in (("rate_hz", rate_hz), ("latency_s", latency_s)) if v is not None}
        return dataclasses.replace(self, **changes)


#: default profiles by tracker name: measured from the vision source (module docstring; rates are the
#: timing defaults, not measured). rt2: noise 0.87 mm, misses 1.14 %, no error > 10 cm; rt2-paper:
#: 0.90 mm, 0.15 %, 0.06 % outliers (4 frame sets, 10-100 cm); rtblob: 2.11 mm, 1.32 %, no error > 10 cm.
PROFILES = {
    "rt2": TrackerProfile("rt2", rate_hz=180.0, noise_std_m=0.00087, p_miss=0.0114),
    "rt2-paper": TrackerProfile("rt2-paper", rate_hz=180.0, noise_std_m=0.00090, p_miss=0.0015, p_outlier=0.0006),
    "rtblob": TrackerProfile("rtblob", rate_hz=60.0, noise_std_m=0.00211, p_miss=0.0132),
}

#: the assumptions from the paper's real-robot figures (the defaults before 2026-11-22)
PAPER_PROFILES = {
    # the paper: RT2 never reported an error > 10 cm; simulated RT2 errors are millimetres
    "rt2": TrackerProfile("rt2", rate_hz=180.0, noise_std_m=0.002, p_miss=0.01),
    "rt2-paper": TrackerProfile("rt2-paper", rate_hz=180.0, noise_std_m=0.002, p_miss=0.02, p_outlier=0.002),
    # the paper: a second error mode at 25-30 cm and ~0.1 % errors of tens of metres
    "rtblob": TrackerProfile("rtblob", rate_hz=60.0, noise_std_m=0.004, p_miss=0.02, p_outlier=0.05, p_wild=0.001),
}

#: ``--profiles`` name -> profile set
PROFILE_SETS = {"vision": PROFILES, "paper": PAPER_PROFILES}


def profile_for(tracker: str, profiles: dict | None = None) -> TrackerProfile:
    """The profile of ``tracker`` (unknown names raise and list the valid ones)."""
    table = PROFILES if profiles is None else profiles
    if tracker not in table:
        raise ValueError(f"unknown tracker {tracker!r}; valid: {sorted(table)}")
    return table[tracker]


def load_profiles(path, base: dict | None = None) -> dict:
    """Profiles from a JSON file ``{tracker: {field: value}}`` (as ``rt2 play profile --json`` writes);
    fields not given keep those of ``base`` (default :data:`PROFILES`). Unknown trackers or fields raise
    ValueError naming the file."""
    path = Path(path)
    try:
        data = json.loads(read_text_capped(path, MAX_CONFIG_BYTES, "profiles file"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from None
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected an object {{tracker: {{field: value}}}}, got {type(data).__name__}")
    base = PROFILES if base is None else base
    out = dict(base)
    valid = {f.name for f in dataclasses.fields(TrackerProfile)} - {"tracker"}
    for name, fields in data.items():
        if name not in base or not isinstance(fields, dict):
            raise ValueError(f"{path}: unknown tracker {name!r} or not a mapping; valid: {sorted(base)}")
        bad = sorted(set(fields) - valid)
        if bad:
            raise ValueError(f"{path}: tracker {name!r}: unknown field(s) {bad}; valid: {sorted(valid)}")
        fields = {k: tuple(map(tuple, v)) if k == "wild_box_m" else (tuple(v) if isinstance(v, list) else v)
                  for k, v in fields.items()}
        try:
            out[name] = dataclasses.replace(base[name], **fields)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: tracker {name!r}: {exc}") from exc
    return out
