"""harness.logs: writing and reading session logs (MCAP), the plain mcap reader's view, `rt2 log info`."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

from harness.cli import main as rt2_main
from harness.logs import (
    BackgroundLogWriter,
    Detections,
    GroundTruthBall,
    JointStates,
    LogError,
    LogWriterOptions,
    SessionLogReader,
    SessionLogWriter,
)
from harness.logs.synthetic import camera_frame, make_session, write_session
from tracker import BallObservation, Status

SMALL = (64, 48)


def _session(seconds=0.5, rate_hz=40.0, seed=0, **kw):
    return make_session(seconds, rate_hz=rate_hz, n_cameras=2, image_size=SMALL, n_variants=3, seed=seed, **kw)


def _write(path, session=None, *, image_format="png", **kw):
    s = session or _session()
    with SessionLogWriter(path, metadata={"kind": "test", "seed": 0, "config": {"a": [1, 2]}}, image_format=image_format, **kw) as w:
        write_session(w, s)
    return s


class _JsonFactory(McapDecoderFactory):
    """What a plain reader needs for our JSON messages: json.loads (the schema is in the file)."""

    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


def _assert_obs_equal(a: BallObservation, b: BallObservation):
    assert (a.t_s, a.support, a.status, a.latency_s, a.tracker, a.notes) == (b.t_s, b.support, b.status, b.latency_s, b.tracker, b.notes)
    for f in ("position_m", "covariance_m2", "uv_px"):
        x, y = getattr(a, f), getattr(b, f)
        assert (x is None) == (y is None), f
        if x is not None:
            np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.inliers, b.inliers)


# -- smoke -------------------------------------------------------------------------------------------
def test_smoke_write_read_summary(tmp_path):
    s = _write(tmp_path / "s.mcap")
    with SessionLogReader(tmp_path / "s.mcap") as r:
        summ = r.summary()
        assert summ.finished_cleanly and r.recovery is None
        assert summ.session == {"kind": "test", "seed": 0, "config": {"a": [1, 2]}}
        assert summ.session_end["error"] is None
        assert summ.environment["packages"]["mcap"] and summ.environment["writer"]["image_format"] == "png"
        n = s.n_framesets
        assert summ.topics["/camera/cam0/image"].count == n
        assert summ.topics["/tracker/rt2/ball"].schema == "rt2.BallObservation"
        assert summ.n_messages == sum(t.count for t in summ.topics.values()) == len(list(r.messages(decode=False)))
        assert summ.start_s == 0 and summ.end_s == pytest.approx(s.t_s[-1])


# -- round trip of every message type ----------------------------------------------------------------
def test_round_trip_every_message_type(tmp_path, ewand_rig):
    rng = np.random.default_rng(3)
    img = camera_frame(SMALL, (20, 30), rng)
    obs_ok = BallObservation(t_s=0.25, position_m=np.array([0.1, -0.2, 1.0]), covariance_m2=np.diag([1e-6, 2e-6, 3e-6]),
                             support=3, inliers=np.array([True, False, True, True]), status=Status.OK, latency_s=0.0021,
                             tracker="rt2", uv_px=np.array([[1.5, 2.5], [np.nan, np.nan], [3.0, 4.0], [5.0, 6.0]]), notes=("x", "y"))
    obs_none = BallObservation(t_s=0.5, position_m=None, covariance_m2=None, support=0, inliers=np.zeros(4, bool),
                               status=Status.TOO_FEW_OBSERVATIONS, latency_s=0.001, tracker="rt2")
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.1, 0.2, 0.3]
    q, qd, qc = np.linspace(-1, 1, 7), np.linspace(0, 0.6, 7), np.linspace(-0.9, 1.1, 7)
    path = tmp_path / "all.mcap"
    with SessionLogWriter(path, metadata={"kind": "roundtrip"}, image_format="png") as w:
        w.attach_rig(ewand_rig)
        w.attach("weights.bin", b"\x00\x01weights", "application/octet-stream")
        w.write_metadata("config", {"threshold_px": 2.5, "names": ["a", "b"], "nested": {"k": None}})
        w.write_scene_static(0.0, ewand_rig)
        assert w.write_image(0.25, "cam0", img, 7)
        w.write_detections(0.25, "cam0", [[10.0, 20.0], [30.5, 40.25]], [0.9, 0.1], 7, areas_px=[52, 9])
        w.write_detections(0.25, "cam1", np.zeros((0, 2)), np.zeros(0), 7)
        w.write_observation(0.25, "rt2", obs_ok, 7)
        w.write_observation(0.5, "rt2", obs_none, 8)
        w.write_ground_truth(0.25, [0.1, -0.2, 1.001], q, qd, qc, 7)
        w.write_transforms(0.25, [("world", "link1", T)])
        w.write_scene_arm(0.25, [[0, 0, 0], [0, 0, 1], [0.5, 0, 1]])
        w.write_scene_balls(0.25, [0.1, -0.2, 1.0], {"rt2": [0.1, -0.2, 1.0], "rtblob": None})
        w.write_figures("accuracy", {"rmse_mm": np.float64(1.25), "per_cam": np.array([1.0, np.nan]), "n": np.int64(3)})
    with SessionLogReader(path) as r:
        by = {}
        for m in r.messages():
            by.setdefault(m.topic, []).append(m)
        np.testing.assert_array_equal(by["/camera/cam0/image"][0].data, img)  # png is lossless
        assert by["/camera/cam0/image"][0].sequence == 7 and by["/camera/cam0/image"][0].t_s == pytest.approx(0.25)
        det = by["/camera/cam0/detections"][0].data
        assert isinstance(det, Detections) and det.camera == "cam0" and det.frame_index == 7
        np.testing.assert_array_equal(det.uv_px, [[10.0, 20.0], [30.5, 40.25]])
        np.testing.assert_array_equal(det.scores, [0.9, 0.1])
        np.testing.assert_array_equal(det.areas_px, [52.0, 9.0])
        assert by["/camera/cam1/detections"][0].data.uv_px.shape == (0, 2)
        assert by["/camera/cam1/detections"][0].data.areas_px is None  # not given (RTBlob, logs before areas were logged)
        assert len(by["/camera/cam0/annotations"][0].data.circles) == 2
        obs = [m.data for m in by["/tracker/rt2/ball"]]
        _assert_obs_equal(obs[0], obs_ok)
        _assert_obs_equal(obs[1], obs_none)
        gt = by["/ground_truth/ball"][0].data
        assert isinstance(gt, GroundTruthBall) and gt.t_s == 0.25 and gt.frame_index == 7
        np.testing.assert_array_equal(gt.position_m, [0.1, -0.2, 1.001])
        js = by["/robot/joint_states"][0].data
        assert isinstance(js, JointStates) and js.names == tuple(f"joint_{i}" for i in range(1, 8))
        np.testing.assert_array_equal(js.position_rad, q)
        np.testing.assert_array_equal(js.velocity_rad_s, qd)
        cmd = by["/robot/command"][0].data
        np.testing.assert_array_equal(cmd.position_rad, qc)
        assert cmd.velocity_rad_s is None
        (parent, child, T_back), = by["/tf"][0].data
        assert (parent, child) == ("world", "link1")
        np.testing.assert_allclose(T_back, T, atol=1e-12)
        statics = by["/tf_static"][0].data
        assert [c for _, c, _ in statics] == ewand_rig.names
        for (_, _, T_cam), cam in zip(statics, ewand_rig):
            np.testing.assert_allclose(T_cam, cam.cam_to_world, atol=1e-6)  # the file's R is orthonormal to ~1e-7 only
        cal = by[f"/camera/{ewand_rig.names[0]}/calibration"][0].data
        np.testing.assert_array_equal(np.reshape(cal.K, (3, 3)), ewand_rig[0].K)
        assert {e.id for e in by["/scene/static"][0].data.entities} >= {"table", "net", f"camera/{ewand_rig.names[0]}"}
        balls = by["/scene/balls"][0].data
        assert [e.id for e in balls.entities] == ["ball/true", "ball/rt2"] and [d.id for d in balls.deletions] == ["ball/rtblob"]
        assert len(by["/scene/arm"][0].data.entities[0].lines[0].points) == 3
        assert r.figures() == {"accuracy": {"rmse_mm": 1.25, "per_cam": [1.0, None], "n": 3}}
        assert r.metadata("config") == {"threshold_px": 2.5, "names": ["a", "b"], "nested": {"k": None}}
        assert r.attachment("weights.bin") == b"\x00\x01weights"
        back = r.rig()
        assert back.names == ewand_rig.names
        for a, b in zip(back, ewand_rig):
            np.testing.assert_array_equal(a.K, b.K)
            np.testing.assert_array_equal(a.R_world_to_cam, b.R_world_to_cam)


@pytest.mark.parametrize("fmt,max_err", [("png", 0), ("raw", 0), ("jpeg", 4.0)])
def test_image_formats_decode_to_rgb(tmp_path, fmt, max_err):
    img = camera_frame(SMALL, (30, 20), np.random.default_rng(0))
    with SessionLogWriter(tmp_path / "i.mcap", metadata={"kind": "t"}, image_format=fmt) as w:
        w.write_image(0.0, "cam0", img)
    with SessionLogReader(tmp_path / "i.mcap") as r:
        (m,) = r.messages()
        assert m.data.shape == img.shape and m.data.dtype == np.uint8
        assert np.abs(m.data.astype(float) - img).mean() <= max_err
        assert m.schema == ("foxglove.RawImage" if fmt == "raw" else "foxglove.CompressedImage")


# -- what a plain mcap reader sees -------------------------------------------------------------------
def test_plain_mcap_reader_sees_schemas_topics_and_decodes(tmp_path):
    s = _write(tmp_path / "p.mcap", image_format="jpeg")
    with open(tmp_path / "p.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[ProtobufDecoderFactory(), _JsonFactory()])
        summary = reader.get_summary()
        schemas = {sc.name: sc.encoding for sc in summary.schemas.values()}
        assert schemas["foxglove.CompressedImage"] == "protobuf"
        assert schemas["foxglove.FrameTransforms"] == "protobuf"
        assert schemas["foxglove.SceneUpdate"] == "protobuf"
        assert schemas["foxglove.JointStates"] == "protobuf"
        for ours in ("rt2.Detections", "rt2.BallObservation", "rt2.GroundTruthBall"):
            assert schemas[ours] == "jsonschema"
        topics = {c.topic for c in summary.channels.values()}
        assert {"/camera/cam0/image", "/camera/cam1/detections", "/tracker/rt2/ball", "/tracker/rtblob/ball",
                "/ground_truth/ball", "/robot/joint_states", "/robot/command", "/tf", "/scene/arm", "/scene/balls"} <= topics
        n = 0
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            n += 1
            if schema.encoding == "jsonschema":  # every required field of the schema in the file is present
                required = json.loads(schema.data)["required"]
                assert set(required) <= set(decoded), (channel.topic, required)
            if channel.topic == "/camera/cam0/image":
                assert decoded.format == "jpeg" and decoded.data[:2] == b"\xff\xd8"
        assert n == summary.statistics.message_count
        # MCAP compresses per chunk: images in uncompressed chunks, state in zstd chunks, never mixed
        image_ids = {c.id for c in summary.channels.values() if c.topic.endswith("/image")}
        kinds = set()
        for ci in summary.chunk_indexes:
            ids = set(ci.message_index_offsets)
            assert ids <= image_ids or not ids & image_ids
            kinds.add((bool(ids & image_ids), ci.compression))
        assert kinds == {(True, ""), (False, "zstd")}
    assert s.n_framesets == summary.statistics.channel_message_counts[
        next(c.id for c in summary.channels.values() if c.topic == "/camera/cam0/image")]
    # a non-seeking reader walks every record to the closing magic, checking chunk CRCs on the way
    with open(tmp_path / "p.mcap", "rb") as f:
        records = list(StreamReader(f, validate_crcs=True).records)
    assert type(records[0]).__name__ == "Header" and type(records[-1]).__name__ == "Footer"
    assert sum(type(r).__name__ == "Message" for r in records) == summary.statistics.message_count


def test_raw_images_go_to_lz4_chunks(tmp_path):
    _write(tmp_path / "r.mcap", image_format="raw")
    with open(tmp_path / "r.mcap", "rb") as f:
        comps = {ci.compression for ci in make_reader(f).get_summary().chunk_indexes}
    assert comps == {"lz4", "zstd"}


# -- shapes, filters, options ------------------------------------------------------------------------
def test_messages_filters_by_topic_glob_and_time_in_log_time_order(tmp_path):
    s = _write(tmp_path / "f.mcap")
    with SessionLogReader(tmp_path / "f.mcap") as r:
        all_t = [m.log_time_ns for m in r.messages(decode=False)]
        assert all_t == sorted(all_t)
        imgs = list(r.messages("/camera/*/image"))
        assert {m.topic for m in imgs} == {"/camera/cam0/image", "/camera/cam1/image"}
        assert len(imgs) == 2 * s.n_framesets and all(m.data.shape == (48, 64, 3) for m in imgs)
        win = list(r.messages(["/tracker/rt2/ball", "/ground_truth/ball"], start_s=0.1, end_s=0.2))
        assert win and all(0.1 - 1e-12 <= m.t_s < 0.2 for m in win)
        assert len(win) == 2 * int(np.sum((s.t_s >= 0.1 - 1e-9) & (s.t_s < 0.2 - 1e-9)))


@pytest.mark.parametrize("log_images,expected", [("all", 20), (5, 4), ("3", 7), ("none", 0)])
def test_log_images_every_n(tmp_path, log_images, expected):
    s = make_session(0.5, rate_hz=40, n_cameras=1, image_size=SMALL, n_variants=2, seed=0)
    _write(tmp_path / "e.mcap", s, log_images=log_images)
    with SessionLogReader(tmp_path / "e.mcap") as r:
        topics = r.summary().topics
        assert topics.get("/camera/cam0/image").count if expected else "/camera/cam0/image" not in topics
        if expected:
            seqs = [m.sequence for m in r.messages("/camera/cam0/image", decode=False)]
            assert len(seqs) == expected and all(k % (1 if log_images == "all" else int(log_images)) == 0 for k in seqs)
        assert topics["/camera/cam0/detections"].count == s.n_framesets


# -- bad input ---------------------------------------------------------------------------------------
def test_bad_writer_arguments(tmp_path):
    p = tmp_path / "b.mcap"
    with pytest.raises(ValueError, match="'kind'"):
        SessionLogWriter(p, metadata={"seed": 1})
    with pytest.raises(ValueError, match="unknown image_format 'gif'"):
        SessionLogWriter(p, metadata={"kind": "t"}, image_format="gif")
    with pytest.raises(ValueError, match="log_images must be"):
        SessionLogWriter(p, metadata={"kind": "t"}, log_images="sometimes")
    with pytest.raises(ValueError, match="log_images must be"):
        SessionLogWriter(p, metadata={"kind": "t"}, log_images=0)
    with pytest.raises(ValueError, match="flush_period_s"):
        SessionLogWriter(p, metadata={"kind": "t"}, flush_period_s=0)
    with pytest.raises(ValueError, match="jpeg_quality"):
        LogWriterOptions(jpeg_quality=0)
    with pytest.raises(ValueError, match="cannot store a value of type object"):
        SessionLogWriter(p, metadata={"kind": "t", "x": object()})
    p.write_bytes(b"old")
    with pytest.raises(ValueError, match="exists; pass overwrite=True"):
        SessionLogWriter(p, metadata={"kind": "t"})
    assert p.read_bytes() == b"old"  # never lost


def test_bad_messages_raise_clear_errors(tmp_path):
    with SessionLogWriter(tmp_path / "m.mcap", metadata={"kind": "t"}) as w:
        with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8 RGB array, got shape \(48, 64\) dtype uint8"):
            w.write_image(0.0, "cam0", np.zeros((48, 64), np.uint8))
        with pytest.raises(ValueError, match="dtype float64"):
            w.write_image(0.0, "cam0", np.zeros((48, 64, 3)))
        with pytest.raises(ValueError, match="t_s must be a finite time"):
            w.write_ground_truth(-1.0, [0, 0, 1], None, None)
        with pytest.raises(ValueError, match="t_s must be a finite time"):
            w.write_ground_truth(float("nan"), [0, 0, 1], None, None)
        with pytest.raises(ValueError, match=r"ball_position_m must be a finite array of shape \(3,\), got shape \(3,\) with NaN"):
            w.write_ground_truth(0.0, [0, np.nan, 1], None, None)
        with pytest.raises(ValueError, match=r"q must be a finite array of shape \(7,\), got shape \(6,\)"):
            w.write_ground_truth(0.0, None, np.zeros(6), np.zeros(6))
        with pytest.raises(ValueError, match=r"uv_px must be \(k, 2\) and scores and areas_px \(k,\), got shapes \(2, 2\), \(3,\) and None"):
            w.write_detections(0.0, "cam0", np.zeros((2, 2)), np.zeros(3))
        with pytest.raises(ValueError, match=r"got shapes \(2, 2\), \(2,\) and \(3,\)"):
            w.write_detections(0.0, "cam0", np.zeros((2, 2)), np.zeros(2), areas_px=np.zeros(3))
        with pytest.raises(ValueError, match="camera must be a non-empty name"):
            w.write_detections(0.0, "cam 0/x", np.zeros((0, 2)), np.zeros(0))
        with pytest.raises(ValueError, match="obs must be a tracker.BallObservation, got dict"):
            w.write_observation(0.0, "rt2", {"position_m": [0, 0, 0]})
        with pytest.raises(ValueError, match="orthonormal"):
            w.write_transforms(0.0, [("world", "a", 2 * np.eye(4))])
        with pytest.raises(ValueError, match="frame_index must be an int >= 0"):
            w.write_image(0.0, "cam0", np.zeros((4, 4, 3), np.uint8), -1)
        with pytest.raises(ValueError, match=r"figures 'acc'.k: cannot store"):
            w.write_figures("acc", {"k": {1, 2}})
    with pytest.raises(ValueError, match="is closed"):
        w.write_ground_truth(0.0, [0, 0, 1], None, None)


def test_bad_files_and_names_for_the_reader(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"PK\x03\x04 a zip file")
    with pytest.raises(LogError, match=r"x.mcap is not an MCAP file: it starts with b'PK"):
        SessionLogReader(tmp_path / "x.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(LogError, match="is not an MCAP file: it is empty"):
        SessionLogReader(tmp_path / "empty.mcap")
    with pytest.raises(LogError, match="cannot open log"):
        SessionLogReader(tmp_path / "missing.mcap")
    _write(tmp_path / "ok.mcap")
    with SessionLogReader(tmp_path / "ok.mcap") as r:
        with pytest.raises(LogError, match=r"no topic matches '/tracker/nope/ball'; topics: \['/camera"):
            r.messages("/tracker/nope/ball")  # raised at the call, not at the first next()
        with pytest.raises(LogError, match="start_s must be a finite number"):
            r.messages(start_s=float("nan"))
        with pytest.raises(LogError, match="no metadata record 'cfg'"):
            r.metadata("cfg")
        with pytest.raises(LogError, match="no attachment 'rig.yaml'"):
            r.rig()


# -- determinism (seeded) ----------------------------------------------------------------------------
def test_same_seed_same_messages_different_seed_differs(tmp_path):
    def stream(path, seed):
        _write(path, _session(seed=seed))
        with SessionLogReader(path) as r:
            return [(m.topic, m.log_time_ns, m.sequence, m.data) for m in r.messages(decode=False)]

    a, b, c = stream(tmp_path / "a.mcap", 5), stream(tmp_path / "b.mcap", 5), stream(tmp_path / "c.mcap", 6)
    assert a == b
    assert a != c


# -- background writer -------------------------------------------------------------------------------
def test_background_writer_keeps_everything_when_it_keeps_up(tmp_path):
    s = _session()
    w = SessionLogWriter(tmp_path / "bg.mcap", metadata={"kind": "t"}, image_format="png")
    with BackgroundLogWriter(w, max_pending_images=10_000, max_pending=100_000) as bg:  # room for the whole burst
        write_session(bg, s)
    assert bg.dropped == {}
    with SessionLogReader(tmp_path / "bg.mcap") as r:
        summ = r.summary()
        assert summ.finished_cleanly and summ.session_end["dropped"] == {}
        assert summ.topics["/camera/cam1/image"].count == s.n_framesets
        assert summ.topics["/tracker/rt2/ball"].count == s.n_framesets


def test_background_writer_counts_drops_and_keeps_state(tmp_path, monkeypatch):
    import threading

    s = _session()
    w = SessionLogWriter(tmp_path / "d.mcap", metadata={"kind": "t"}, image_format="png")
    gate = threading.Event()
    real = w.write_image
    monkeypatch.setattr(w, "write_image", lambda *a, **k: (gate.wait(5), real(*a, **k))[1])  # a stalled encoder
    bg = BackgroundLogWriter(w, max_pending_images=3, max_pending=10_000)
    with pytest.warns(RuntimeWarning, match="cannot keep up; dropping image"):
        write_session(bg, s)
    gate.set()
    bg.close()
    n_img = 2 * s.n_framesets
    assert bg.submitted["image"] == n_img and bg.dropped["image"] >= n_img - 4 and set(bg.dropped) == {"image"}
    with SessionLogReader(tmp_path / "d.mcap") as r:
        summ = r.summary()
        got = summ.topics["/camera/cam0/image"].count + summ.topics["/camera/cam1/image"].count
        assert got == n_img - bg.dropped["image"]
        assert summ.topics["/tracker/rtblob/ball"].count == s.n_framesets  # state is not dropped
        assert summ.session_end["dropped"] == {"image": bg.dropped["image"]}


def test_background_writer_reraises_worker_errors(tmp_path):
    w = SessionLogWriter(tmp_path / "e.mcap", metadata={"kind": "t"})
    bg = BackgroundLogWriter(w)
    bg.write_ground_truth(0.0, [0.0, np.nan, 1.0], None, None)
    with pytest.raises(LogError, match="background log writer failed: ball_position_m"):
        bg.close()
    with SessionLogReader(tmp_path / "e.mcap") as r:
        assert "ball_position_m" in r.summary().session_end["error"]


# -- rt2 log info ------------------------------------------------------------------------------------
def test_log_info_table_and_json(tmp_path, capsys):
    s = _write(tmp_path / "i.mcap")
    assert rt2_main(["log", "info", str(tmp_path / "i.mcap")]) == 0
    out = capsys.readouterr().out
    assert "finished cleanly" in out and "session     test" in out and "seed=0" in out
    line = next(ln for ln in out.splitlines() if ln.startswith("/tracker/rt2/ball"))
    assert line.split()[1:3] == ["rt2.BallObservation", str(s.n_framesets)]
    assert rt2_main(["log", "info", str(tmp_path / "i.mcap"), "--json", "--verify"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["finished_cleanly"] and doc["verify_problems"] == []
    assert doc["topics"]["/camera/cam0/image"]["count"] == s.n_framesets
    assert doc["topics"]["/camera/cam0/image"]["rate_hz"] == pytest.approx(s.n_framesets / doc["duration_s"])
    assert doc["session"]["kind"] == "test"


def test_log_info_bad_file_is_one_line_error(tmp_path, capsys):
    (tmp_path / "bad.mcap").write_text("hello")
    assert rt2_main(["log", "info", str(tmp_path / "bad.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not an MCAP file" in err


def test_reader_warns_but_never_raises_on_damage(tmp_path):
    _write(tmp_path / "w.mcap")
    data = (tmp_path / "w.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a cut file is not "damaged": no warning, just a recovery report
        with SessionLogReader(tmp_path / "cut.mcap") as r:
            assert not r.finished_cleanly and r.recovery.lost_bytes > 0


def test_log_arguments_open_the_writer_they_describe(tmp_path):
    import argparse

    from harness.logs.args import add_log_arguments, open_log

    parser = argparse.ArgumentParser()
    add_log_arguments(parser)
    assert open_log(parser.parse_args([]), {"kind": "t"}) is None
    args = parser.parse_args(["--log", str(tmp_path / "a.mcap"), "--log-images", "4", "--log-image-format", "raw"])
    with open_log(args, {"kind": "t", "seed": 3}) as w:
        assert (w.image_every, w.image_format) == (4, "raw")
    with pytest.raises(ValueError, match="exists"):
        open_log(args, {"kind": "t"})
    args = parser.parse_args(["--log", str(tmp_path / "a.mcap"), "--log-images", "often", "--log-overwrite"])
    with pytest.raises(ValueError, match="log_images must be 'all', 'none' or a positive integer"):
        open_log(args, {"kind": "t"})


def test_bench_log_runs_and_reports_the_json_keys(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert rt2_main(["bench", "log", "--seconds", "0.05", "--size", "64x48", "--repeats", "1", "--formats", "jpeg,none",
                     "--live-seconds", "0.05", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["image_format"] for r in rows] == ["jpeg", "none"]
    for r in rows:
        assert {"image_format", "write_framesets_per_s", "read_framesets_per_s", "mb_per_s"} <= set(r)
        assert r["write_framesets_per_s"] > 0 and r["read_framesets_per_s"] > 0 and r["live_framesets"] == 10
    assert "write fs/s" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        rt2_main(["bench", "log", "--repeats"])
    assert rt2_main(["bench", "log", "--formats", "gif"]) == 2


def test_json_values_strict_for_logs_lenient_for_figures():
    import dataclasses

    from harness.logs import LogError
    from harness.logs.codecs import to_json_value

    @dataclasses.dataclass(frozen=True)
    class Counts:
        sent: int
        rate_hz: float

    figures = {"cams": (np.int64(2), np.bool_(True)), "counts": Counts(3, np.nan), "status": Status.OK}
    assert to_json_value(figures, "figures") == {"cams": [2, True], "counts": {"sent": 3, "rate_hz": None}, "status": "ok"}
    with pytest.raises(LogError, match=r"figures: keys must be strings, got 7"):
        to_json_value({7: 1.0}, "figures")
    with pytest.raises(LogError, match=r"figures.x: cannot store a value of type object in a log"):
        to_json_value({"x": object()}, "figures")
    marker = object()
    assert to_json_value({7: [np.float32(np.inf), marker]}, "figures", lenient=True) == {"7": [None, marker]}
