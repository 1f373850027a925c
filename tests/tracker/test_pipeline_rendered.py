"""tracker.Tracker on frames rendered by the simulated lab (harness.sim.render): accuracy with shading,
a served ball, motion blur with the trained model, seeded sensor noise, a real launcher flight, and
``rt2 bench pipeline``. tracker's own tests (tests/tracker/test_pipeline.py) draw their frames without harness.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.tracker._tracker_scenes import FLIGHT_DT_S, FLIGHT_V_MPS, FLIGHT_X0_M
from tracker import FrameSet, Status, Tracker
from tracker.pipeline import TrackerOptions


DT_S, X0_M, V_MPS = FLIGHT_DT_S, FLIGHT_X0_M, FLIGHT_V_MPS


@pytest.fixture(scope="module")
def renderer(rig):
    from harness.sim.render import Renderer

    return Renderer(rig, seed=0)


def _scene(X, v=V_MPS, f=0):
    """One orange ball in the empty lab; gain 2 makes it as bright as the hand-made model wants."""
    from harness.sim.render import Ball, Exposure, Scene

    return Scene(balls=(Ball(X, velocity_mps=v, colour="orange"),), exposure=Exposure(gain=2.0), frame_index=f)


@pytest.fixture(scope="module")
def flight(renderer):
    """12 frame sets of a ball flying at constant velocity (clean lab, nominal exposure), and its truth."""
    X = X0_M + V_MPS * DT_S * np.arange(12)[:, None]
    sets = [FrameSet(f * DT_S, tuple(renderer.render(_scene(X[f], f=f))), f) for f in range(12)]
    return sets, X


def test_rt2_accuracy_on_a_clean_flight(rig, model, flight):
    sets, X = flight
    obs = [Tracker(rig, model=model).process(fs) for fs in sets]
    err = np.array([np.linalg.norm(o.position_m - x) for o, x in zip(obs, X)])
    assert (err < 0.02).all(), err  # a few px of shading bias at ~3 m; the estimator itself is sub-mm
    assert all(o.support == 4 for o in obs)


def test_rt2_confirms_a_served_ball_as_it_leaves_the_launcher(rig, model, renderer):
    """The lab rig sees the whole flight (workspace x up to 2.0 m): a ball just out of the launcher
    (x 1.6-2.0 m, flying at 5 m/s toward the robot) is confirmed from the first frame set on, and the
    window search then follows it (no full-frame retry)."""
    X0, v = np.array([1.85, 0.05, 1.1]), np.array([-5.0, -0.1, 0.8])
    trk = Tracker(rig, model=model)
    for f in range(6):
        X = X0 + v * DT_S * f
        o = trk.process(FrameSet(f * DT_S, tuple(renderer.render(_scene(X, v=v, f=f))), f))
        assert o.status is Status.OK and o.support >= 2, (f, o.notes)
        assert np.linalg.norm(o.position_m - X) < 0.02
    assert trk.stats.full_frame_retries == 0 and trk.stats.roi_searches >= 4 * 4


def test_size_test_keeps_fast_blurred_balls_with_the_trained_model(rig, renderer):
    # The shipped model on rendered balls flying at up to 8 m/s with a 3 ms shutter (the longest
    # smear of the data sets): the blob grows along the motion but stays under the threshold.
    from harness.sim.render import Ball, Exposure, Scene

    trk = Tracker(rig, roi=False)
    ratios = []
    for f, v in enumerate(([0.0, 0.0, 0.0], [-4.0, 0.5, 1.0], [-8.0, 0.0, 0.0], [0.0, 8.0, 0.0], [-5.0, 5.0, 3.0])):
        scene = Scene(balls=(Ball(X0_M, velocity_mps=v, colour="orange"),), exposure=Exposure(exposure_s=0.003, gain=0.7), frame_index=f)
        trk.reset()
        o, info = trk.process_with_info(FrameSet(f * 1.0, tuple(renderer.render(scene)), f))
        assert o.status is Status.OK and np.linalg.norm(o.position_m - X0_M) < 0.03, (v, o)
        ratios.append(info.size_ratio)
    assert trk.stats.size_rejections == 0 and max(ratios) < TrackerOptions().max_size_ratio, ratios


def test_rendered_ball_sized_sphere_is_rejected_and_the_ball_kept(rig, renderer):
    # The same on rendered frames with the shipped model: an orange sphere of 30 mm radius on the
    # table, where the wrong OK positions of `rt2 eval framesets --rig lab4_vga` were.
    from harness.sim.render import Ball, Scene
    from harness.sim.render.scene_state import Sphere

    X_sphere = np.array([0.5, 0.3, 0.79])
    sphere = Sphere(X_sphere, 0.03, "orange", 0.2)
    alone = FrameSet(0.0, tuple(renderer.render(Scene(spheres=(sphere,), frame_index=0))), 0)
    before = Tracker(rig, roi=False, blob_edge_px=0.0, max_size_ratio=1.2)
    o, info = before.process_with_info(alone)
    assert o.status is Status.OK and np.linalg.norm(o.position_m - X_sphere) < 0.02 and info.size_ratio < 1.2
    trk = Tracker(rig, roi=False)
    o, info = trk.process_with_info(alone)
    assert o.position_m is None and trk.stats.size_rejections == 1 and "times as wide as a ball" in o.notes[0]
    both = FrameSet(1.0, tuple(renderer.render(Scene(balls=(Ball(X0_M, colour="orange"),), spheres=(sphere,), frame_index=1))), 1)
    trk.reset()
    o, info = trk.process_with_info(both)
    assert o.status is Status.OK and np.linalg.norm(o.position_m - X0_M) < 0.02
    assert 0.8 < info.size_ratio < 1.2


# -- statistics -------------------------------------------------------------------------------------
def test_detection_noise_statistics(rig, model, renderer):
    """Seeded sensor noise: 8 renders of one still ball; the positions scatter by far less than a
    centimetre and the reported covariance is not wildly off that scatter."""
    from harness.sim.render import Renderer

    X = np.array([-1.2, -0.2, 1.1])
    pos, covs = [], []
    for seed in range(8):
        r = Renderer(rig, seed=seed)
        o = Tracker(rig, model=model).process(FrameSet(0.0, tuple(r.render(_scene(X, v=np.zeros(3))))))
        assert o.status is Status.OK
        pos.append(o.position_m)
        covs.append(o.covariance_m2)
    pos = np.array(pos)
    spread = pos.std(axis=0)
    assert (spread < 0.003).all(), spread
    sigma_pred = np.sqrt(np.diag(np.mean(covs, axis=0)))
    assert (spread < 3 * sigma_pred).all(), (spread, sigma_pred)


# -- real data: a real launcher flight ----------------------------------------------------------------
def test_roi_follows_a_real_launcher_flight(rig, model, renderer, real_data):
    """Ball positions and timestamps of a real flight (MPI launcher, ~180 Hz, uneven dt, a table
    bounce; docs in shared/data/real/README.md) mapped into the lab frame toward the robot, rendered,
    tracked: the window search must follow it through the bounce."""
    d = np.genfromtxt(real_data / "mpi_launcher_trajectories" / "no_spin_robot_simple.csv", delimiter=",", names=True)
    m = d["traj"] == 0
    X = np.stack([1.0 - d["x_m"][m], -d["y_m"][m], d["z_m"][m]], axis=1)  # launcher at x = +1, toward -x
    V = np.stack([-d["vx_mps"][m], -d["vy_mps"][m], d["vz_mps"][m]], axis=1)
    t = d["t_s"][m]
    keep = (X[:, 0] < 0.3) & (X[:, 0] > -2.2)  # inside the lab4 workspace
    X, V, t = X[keep], V[keep], t[keep]
    assert len(t) > 60 and np.ptp(np.diff(t)) > 1e-3  # really uneven sampling
    trk = Tracker(rig, model=model)
    err = []
    for f in range(len(t)):
        fs = FrameSet(float(t[f]), tuple(renderer.render(_scene(X[f], v=V[f], f=f))), f)
        o = trk.process(fs)
        assert o.status is Status.OK, (f, o.notes)
        err.append(np.linalg.norm(o.position_m - X[f]))
    assert np.median(err) < 0.02
    st = trk.stats
    assert st.roi_searches >= 0.95 * 4 * (len(t) - 1), st
    assert st.full_frame_retries == 0


# -- benchmark --------------------------------------------------------------------------------------
def test_tracking_sequence_is_seeded():
    from harness.experiments.studies.bench_pipeline import tracking_sequence

    a = tracking_sequence(5, 60)
    b = tracking_sequence(5, 60)
    c = tracking_sequence(6, 60)
    np.testing.assert_array_equal(a[2], b[2])
    assert [s.balls[0].position_m.tolist() for s in a[1]] == [s.balls[0].position_m.tolist() for s in b[1]]
    assert [len(s.capsules) + len(s.spheres) + len(s.boxes) for s in a[1]] == [len(s.capsules) + len(s.spheres) + len(s.boxes) for s in b[1]]
    assert not np.array_equal(a[2], c[2])
    from harness.sim import lab

    assert ((a[2] >= lab.LAB4_WORKSPACE_M[0]) & (a[2] <= lab.LAB4_WORKSPACE_M[1])).all()
    assert (np.diff(a[0]) > 0).all()


def test_bench_rows(rig, model, renderer):
    from harness.experiments.studies.bench_pipeline import bench, tracking_sequence

    t_s, scenes, X, flight = tracking_sequence(1, 40)
    sets = [FrameSet(float(t), tuple(renderer.render(s)), i) for i, (t, s) in enumerate(zip(t_s, scenes))]
    rows = bench(rig, model, sets, X, flight, workers_list=(1,), repeats=1, warmup=2, progress=False)
    assert {(r["tracker"], r["mode"], r["variant"]) for r in rows} == {("rt2", "full", ""), ("rt2", "roi", ""), ("rt2-paper", "full", ""), ("rtblob", "full", "rgb"), ("rtblob", "full", "chromaticity")}
    assert all(r["workers"] == 1 for r in rows)
    for r in rows:
        assert {"mode", "framesets_per_s", "p50_ms", "p99_ms", "tracker", "workers"} <= set(r)
        assert r["framesets_per_s"] > 0 and 0 < r["p50_ms"] <= r["p99_ms"] and r["cpu_per_wall"] > 0 and r["cpu_ms_per_set"] > 0
    json.dumps(rows)


def test_bench_cli_rejects_bad_arguments(capsys):
    from harness.cli import main

    assert main(["bench", "pipeline", "--frames", "3"]) == 2
    assert "--frames must be >= 30, got 3" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_cli_writes_json(tmp_path, capsys):
    from harness.cli import main

    out = tmp_path / "bench.json"
    assert main(["bench", "pipeline", "--frames", "30", "--repeats", "1", "--workers", "1", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) == 5 and all({"mode", "framesets_per_s", "p50_ms", "p99_ms", "tracker", "workers"} <= set(r) for r in rows)
    text = capsys.readouterr().out
    assert "goal rt2 full workers=1" in text and "goal rt2 roi workers=1" in text


def test_the_coarse_to_fine_full_frame_search_on_the_simulated_labs_frames(renderer):
    """On rendered lab frames (VGA, the launcher's balls of 5-12 px among the lab's clutter, people and the arm) the
    coarse-to-fine full-frame search (``DetectorOptions.coarse_full_frame``, the default) gives the candidates of the
    search that computes every pixel, to the bit."""
    import dataclasses

    from harness.live.sources.sim import LauncherFlights
    from tracker import BallDetector, DetectorOptions
    from tracker.pipeline import load_model

    flights = LauncherFlights(3)
    model = load_model(None)
    exact = BallDetector(model, DetectorOptions(coarse_full_frame=False))
    coarse = BallDetector(model, DetectorOptions())
    n = 0
    for k in range(0, 400, 25):
        for image in renderer.render(dataclasses.replace(flights(k / 200), frame_index=k)):
            a, b = exact.detect(image), coarse.detect(image)
            assert a.uv_px.tobytes() == b.uv_px.tobytes() and a.areas_px.tobytes() == b.areas_px.tobytes()
            n += len(a)
    assert n >= 20
