"""The simulated world: net, table edges, floor and racket contact (harness.sim.physics)."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim.physics import BallWorld, EventKind, RacketState, WorldOptions, classify_return
from policies import BallParams, make_state

STILL_AIR = BallParams(air_density_kg_m3=0.0)


def _kinds(world):
    return [e.kind for e in world.events]


# --------------------------------------------------------------------------- smoke / shapes
def test_smoke_run_shapes():
    w = BallWorld()
    w.reset(make_state([1.8, 0.0, 1.0], [-5.0, 0.0, 0.5]))
    t, states = w.run(0.5)
    assert states.shape == (len(t), 9) and t[-1] == pytest.approx(0.5)


# --------------------------------------------------------------------------- bad input
def test_bad_input():
    with pytest.raises(ValueError, match="shape"):
        BallWorld().reset(np.zeros((2, 9)))
    with pytest.raises(ValueError, match="normal"):
        RacketState(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        RacketState.from_pose(np.eye(3))
    with pytest.raises(ValueError, match="dt_s"):
        WorldOptions(dt_s=0.5)


# --------------------------------------------------------------------------- synthetic scenes
def test_low_ball_hits_net_and_loses_speed():
    w = BallWorld()
    w.reset(make_state([0.6, 0.0, 0.84], [-6.0, 0.0, 0.0]))
    w.run(0.3)
    net = [e for e in w.events if e.kind == EventKind.NET]
    assert net and abs(net[0].velocity_after_mps[0]) < 0.5
    assert net[0].position_m[0] == pytest.approx(BallParams().radius_m)


def test_high_ball_clears_net():
    w = BallWorld()
    w.reset(make_state([0.6, 0.0, 1.1], [-6.0, 0.0, 0.0]))
    w.run(0.3)
    assert EventKind.NET not in _kinds(w)


def test_ball_beyond_table_edge_falls_to_floor():
    w = BallWorld()
    w.reset(make_state([-1.2, 0.0, 1.0], [-3.0, 0.0, 0.0]))  # lands past x = -1.37
    w.run(1.5)
    assert _kinds(w) == [EventKind.FLOOR] and w.done


def test_static_racket_reflects_with_restitution():
    opts = WorldOptions()
    w = BallWorld(STILL_AIR, opts)
    w.reset(make_state([-1.0, 0.0, 1.2], [-4.0, 0.0, 0.0]))
    racket = RacketState([-1.3, 0.0, 1.2], [1.0, 0.0, 0.0])
    w.run(0.2, racket=lambda t: racket)
    hit = [e for e in w.events if e.kind == EventKind.RACKET]
    assert len(hit) == 1
    assert hit[0].position_m[0] == pytest.approx(-1.3 + BallParams().radius_m, abs=1e-6)
    assert hit[0].velocity_after_mps[0] == pytest.approx(4.0 * opts.racket.restitution, rel=1e-3)


def test_moving_racket_adds_its_velocity():
    opts = WorldOptions()
    e = opts.racket.restitution
    w = BallWorld(STILL_AIR, opts)
    w.reset(make_state([-1.0, 0.0, 1.2], [-4.0, 0.0, 0.0]))
    u = np.array([3.0, 0.0, 0.0])
    w.run(0.2, racket=lambda t: RacketState(np.array([-1.4, 0.0, 1.2]) + u * t, [1.0, 0.0, 0.0], u))
    hit = [ev for ev in w.events if ev.kind == EventKind.RACKET][0]
    # relative normal velocity reverses with restitution in the racket's frame
    assert hit.velocity_after_mps[0] == pytest.approx(3.0 + e * (4.0 + 3.0), rel=1e-3)


def test_swept_contact_at_high_speed_and_miss_outside_disk():
    opts = WorldOptions(dt_s=0.005)  # 5 ms ticks: the racket moves 5 cm, the ball 7.5 cm per tick
    w = BallWorld(STILL_AIR, opts)
    w.reset(make_state([-1.0, 0.0, 1.2], [-15.0, 0.0, 0.0]))
    u = np.array([10.0, 0.0, 0.0])
    w.run(0.05, racket=lambda t: RacketState(np.array([-1.35, 0.0, 1.2]) + u * t, [1.0, 0.0, 0.0], u))
    assert EventKind.RACKET in _kinds(w) and w.state[3] > 0
    w2 = BallWorld(STILL_AIR, opts)
    w2.reset(make_state([-1.0, 0.2, 1.2], [-15.0, 0.0, 0.0]))  # 20 cm off-axis: misses a 7.5 cm disk
    w2.run(0.05, racket=lambda t: RacketState(np.array([-1.35, 0.0, 1.2]) + u * t, [1.0, 0.0, 0.0], u))
    assert EventKind.RACKET not in _kinds(w2)


def test_return_classified_landed_in():
    # the racket face points along the desired return and moves along its normal (u (1 + e) out)
    d = np.array([5.0, 0.0, 1.6]) / np.linalg.norm([5.0, 0.0, 1.6])
    outcomes = []
    for speed in (1.0, 2.8, 6.0):  # too soft (own side / net), right, too hard (long)
        w = BallWorld()
        w.reset(make_state([-1.2, 0.0, 1.0], [-0.5, 0.0, 0.0]))
        u = d * speed
        w.run(1.5, racket=lambda t: RacketState(np.array([-1.3, 0.0, 1.0]) + u * t, d, u))
        outcomes.append(classify_return(w.events))
    assert outcomes[1] == "landed_in"
    assert outcomes[0] in ("own_side", "net") and outcomes[2] == "missed_table"
    assert classify_return([]) == "no_hit"
