"""Clock offsets: the NTP-style robot offset on synthetic exchanges (seeded), and a
5 ms skew injected into the robot bridge (its own process) found to within 0.5 ms; joint states paired
with camera times through the estimate give the same figures as a clock without skew."""

from __future__ import annotations

import time

import numpy as np
import pytest

from harness.link import RoundTripClock, WamClient
from harness.link.clock import ClockEstimate, pair_joint_states
from robot_models import WamKinematics
from tests.harness.link.robot_link_util import BridgeProcess, STARVED_OK


# -- synthetic ------------------------------------------------------------------------------------
def test_round_trip_offset_within_its_uncertainty():
    rng = np.random.default_rng(0)
    offset = 123_456_789.0  # robot - harness, ns
    clock = RoundTripClock(window=64, best=8)
    t = 1_000_000_000
    for _ in range(64):
        up, down, work = rng.exponential(80_000, 3) + 20_000  # asymmetric, queueing-like delays, ns
        t0 = t
        t1 = t0 + up + offset
        t2 = t1 + work
        t3 = t2 - offset + down
        clock.add(t0, int(t1), int(t2), int(t3))
        t += 10_000_000
    est = clock.estimate()
    assert abs(est.offset_ns - offset) <= est.uncertainty_ns and est.uncertainty_ns < 100_000
    assert est.n_samples == 64 and est.delay_ns > 0


def test_bad_clock_input():
    with pytest.raises(ValueError, match="out of order"):
        RoundTripClock().add(10, 5, 4, 20)
    with pytest.raises(ValueError, match="no clock exchange yet"):
        RoundTripClock().estimate()
    with pytest.raises(ValueError, match="best <= window"):
        RoundTripClock(window=4, best=8)
    est = ClockEstimate(0.0, 0.0, 1, 0.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        pair_joint_states([0.0], [1.0, 1.0], np.zeros((2, 7)), est)
    q = pair_joint_states([0.5, 5.0], [0.0, 1.0], np.stack([np.zeros(7), np.ones(7)]), est)
    assert np.allclose(q[0], 0.5) and np.isnan(q[1]).all()


# -- against bridge processes ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def bridges():
    plain = BridgeProcess("--seed", "1", "--publish-truth")
    skewed = BridgeProcess("--seed", "1", "--publish-truth", "--clock-skew-ms", "5")
    yield plain, skewed
    plain.stop()
    skewed.stop()


def _true_offset_ns(bridge) -> int:
    """robot clock - harness clock, from the bridge's ready line (simulation truth, never seen by the client)."""
    return bridge.ready["clock_skew_ns"] - bridge.ready["epoch_monotonic_ns"]


def test_injected_skew_found_within_half_a_millisecond(bridges):
    found = []
    for bridge in bridges:
        with WamClient(bridge.address, **STARVED_OK) as wam:
            est = wam.sync_clock(32)
        err_ns = est.offset_ns - _true_offset_ns(bridge)
        assert abs(err_ns) < 0.5e6 and abs(err_ns) <= est.uncertainty_ns + 50_000, (err_ns, est)
        found.append(est.offset_ns + bridge.ready["epoch_monotonic_ns"])  # the skew as the estimate sees it
    assert found[1] - found[0] == pytest.approx(5e6, abs=0.5e6)


def test_pairing_with_the_estimate_matches_a_clock_without_skew(bridges):
    """A camera sees the end effector at harness times; joint states are paired to them (a) through the
    estimated offset of the 5 ms-skewed robot, (b) through the true offset (a clock without skew), and
    (c) ignoring the skew. Figures: ball-position error of the paired reported joints against the truth."""
    kin = WamKinematics.default()
    bridge = bridges[1]
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        est = wam.sync_clock(32)
        st = wam.read_state()
        q1 = st.q.copy()
        q1[0] += 0.6
        q1[1] -= 0.4
        # rest to rest within the acceleration limits (the motion-safety rule): a cubic Hermite over 0.8 s
        wam.command_trajectory([st.t_s + 0.05, st.t_s + 0.85], np.stack([st.q, q1]), np.zeros((2, 7)))
        wam.advance_to(st.t_s)
        s = wam.advance_to(st.t_s + 0.8)
        t_true, q_true = wam.take_sim_truth()
    truth = ClockEstimate(float(_true_offset_ns(bridge)), 0.0, 1, 0.0)
    unskewed = ClockEstimate(truth.offset_ns - 5e6, 0.0, 1, 0.0)  # what a harness that ignores the skew assumes
    t_cam = (np.linspace(st.t_s + 0.1, st.t_s + 0.6, 200) * 1e9 - truth.offset_ns) * 1e-9  # harness clock, s
    ball_true = kin.positions(pair_joint_states(t_cam, t_true, q_true, truth))

    def figures(clock):
        ball = kin.positions(pair_joint_states(t_cam, s.t_s, s.q, clock), check_limits=False)
        err_mm = np.linalg.norm(ball - ball_true, axis=1) * 1e3
        return ball, {"median_mm": float(np.median(err_mm)), "p95_mm": float(np.percentile(err_mm, 95))}

    b_est, f_est = figures(est)
    b_ref, f_ref = figures(truth)
    b_ign, f_ign = figures(unskewed)
    assert np.linalg.norm(b_est - b_ref, axis=1).max() < 0.5e-3  # < 0.5 mm apart, frame by frame
    assert f_est["median_mm"] == pytest.approx(f_ref["median_mm"], abs=0.1)
    assert f_est["p95_mm"] == pytest.approx(f_ref["p95_mm"], abs=0.2)
    assert np.median(np.linalg.norm(b_ign - b_ref, axis=1)) > 2e-3  # ignoring the skew costs millimetres
