"""The paper's published numbers (Tables 1 and 2) and the goals of our studies, in one place.

Source: /work/shared/paper/rt2_reliable_ball_tracking.tex, Table 1 (``tab:sim_outliers``) and
Table 2 (``tab:outlier:runtime``). Rates are fractions, errors centimetres, times milliseconds.
"""

from __future__ import annotations

__all__ = [
    "BENCH_GOAL_MS",
    "GROSS_ERROR_M",
    "NAIVE_SPEEDUP_GOAL",
    "PAPER_TABLE1",
    "PAPER_TABLE2_MS",
    "failure_floor",
]

#: Table 1: (cameras c, outlier probability p_o) -> (mean error E in cm, failure rate F).
PAPER_TABLE1: dict[tuple[int, float], tuple[float, float]] = {
    (4, 0.01): (0.71, 0.001), (4, 0.05): (0.85, 0.005), (4, 0.10): (0.84, 0.020), (4, 0.25): (0.79, 0.097), (4, 0.50): (4.67, 0.377),
    (8, 0.01): (0.52, 0.0), (8, 0.05): (0.53, 0.0), (8, 0.10): (0.59, 0.0), (8, 0.25): (0.94, 0.001), (8, 0.50): (6.84, 0.045),
    (15, 0.01): (0.35, 0.0), (15, 0.05): (0.36, 0.0), (15, 0.10): (0.37, 0.0), (15, 0.25): (0.41, 0.0), (15, 0.50): (4.72, 0.0002),
    (30, 0.01): (0.24, 0.0), (30, 0.05): (0.25, 0.0), (30, 0.10): (0.25, 0.0), (30, 0.25): (0.28, 0.0), (30, 0.50): (0.35, 0.0),
}  # fmt: skip

#: Table 2: cameras -> run time of the paper's sequential C++ Algorithm 2, ms.
PAPER_TABLE2_MS: dict[int, float] = {4: 0.001, 8: 0.012, 15: 0.015, 30: 3.02, 50: 11.46}

#: Our goal for the median time of one ``estimate`` call (method "ours"), ms.
BENCH_GOAL_MS: dict[int, float] = {4: 0.02, 8: 0.05, 15: 0.1, 30: 0.3, 50: 1.0}
#: ... and at least this speed-up over the naive OpenCV loop for c >= 15.
NAIVE_SPEEDUP_GOAL = 20.0

#: An error above this counts as a gross error in Table 1.
GROSS_ERROR_M = 0.05


def failure_floor(cameras: int, outlier_rate: float) -> float:
    """P(fewer than 2 inliers) = p^c + c (1 - p) p^(c - 1): the failure rate of an ideal method
    that needs two correct observations and never reports a position without them."""
    p, c = outlier_rate, cameras
    return p**c + c * (1 - p) * p ** (c - 1)
