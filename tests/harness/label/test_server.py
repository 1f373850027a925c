"""rt2 label's server over real sockets on 127.0.0.1: labels on disk in COCO, undo, resume, hostile requests, bad sources."""

from __future__ import annotations

import http.client
import json
import socket

import numpy as np
import pytest

from harness.cli import main as rt2_main
from harness.experiments.detector.coco import read_coco
from harness.experiments.studies.eval_detector import DEFAULT_MODEL
from harness.label.frames import open_frames
from harness.label.server import MAX_BODY_BYTES, LabelServer
from harness.label.session import LabelOptions, LabelSession
from tracker import BallSegmentationModel


@pytest.fixture()
def serve(tmp_path):
    """``serve(source, out=None, **open_kw) -> (server, session)``; closed after the test."""
    started = []

    def start(source, out=None, **kw):
        out = out or tmp_path / "labels"
        frames = open_frames(source, out, **kw)
        session = LabelSession(frames, out, BallSegmentationModel.load(DEFAULT_MODEL), DEFAULT_MODEL, LabelOptions(min_train_labels=4))
        server = LabelServer(session, 0).start()
        started.append((server, session))
        return server, session

    yield start
    for server, session in started:
        server.close()
        session.close()


def request(server, method, path, body=None, headers=None, raw=None):
    """(status, parsed JSON or bytes) of one request on a fresh connection."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    h = {"Content-Type": "application/json"} if body is not None or raw is not None else {}
    h.update(headers or {})
    data = raw if raw is not None else (None if body is None else json.dumps(body))
    conn.request(method, path, body=data, headers=h)
    r = conn.getresponse()
    payload = r.read()
    conn.close()
    ctype = r.getheader("Content-Type", "")
    return r.status, json.loads(payload) if ctype.startswith("application/json") else payload


# -- labels on disk ---------------------------------------------------------------------------------
def test_labels_no_ball_and_undo_are_on_disk_after_each_answer(serve, ball_folder, ball_truth):
    server, session = serve(ball_folder)
    keys = [f.key for f in session.frames.frames]
    box = ball_truth[keys[0]][0].tolist()
    assert request(server, "POST", "/api/label", {"frame": 0, "boxes": [box]})[0] == 200
    assert request(server, "POST", "/api/label", {"frame": 4, "boxes": []})[0] == 200
    on_disk = {li.path.name: li for li in read_coco(session.store.json_path)}
    assert list(on_disk) == [keys[0], keys[4]]
    np.testing.assert_allclose(on_disk[keys[0]].boxes_xywh, [box])
    assert on_disk[keys[4]].n_balls == 0  # "no ball" = an image without annotations
    assert (session.out_dir / "images" / keys[0]).is_file()
    status, body = request(server, "POST", "/api/undo", {})
    assert status == 200 and body["frame"] == 4
    assert [li.path.name for li in read_coco(session.store.json_path)] == [keys[0]]
    status, body = request(server, "GET", "/api/frame/4")
    assert body["labels"] is None and body["width"] == 128 and body["height"] == 96


def test_restart_resumes_from_the_file_and_keeps_labels_of_other_sources(serve, ball_folder, ball_truth, tmp_path):
    out = tmp_path / "labels"
    server, session = serve(ball_folder, out)
    key = session.frames.frames[1].key
    request(server, "POST", "/api/label", {"frame": 1, "boxes": [ball_truth[key][0].tolist()]})
    server.close()
    session.close()  # lets go of the folder: one writer at a time
    # a second source into the same folder: the first source's label is kept, the new one appended
    other = tmp_path / "other"
    other.mkdir()
    (other / "x.png").write_bytes((ball_folder / key).read_bytes())
    server2, session2 = serve(other, out)
    assert session2.store.counts()["kept_from_file"] == 1
    request(server2, "POST", "/api/label", {"frame": 0, "boxes": []})
    assert [li.path.name for li in read_coco(out)] == [key, "x.png"]
    server2.close()
    session2.close()
    _, session3 = serve(ball_folder, out)
    assert session3.store.counts()["labelled"] == 1 and session3.store.counts()["kept_from_file"] == 1
    np.testing.assert_allclose(session3.store.boxes(1), ball_truth[key])


def test_a_coco_file_of_another_tool_is_continued_its_fields_kept_and_the_original_copied(ball_folder, tmp_path):
    import json

    out = tmp_path / "theirs"
    out.mkdir()
    doc = json.loads((ball_folder / "annotations.json").read_text())
    doc["info"] = {"description": "exported by another tool", "contributor": "lab"}
    doc["images"][0]["camera"] = "cam3"
    for ann in doc["annotations"]:
        ann["reviewer"] = "ana"
    (out / "annotations.json").write_text(json.dumps(doc))
    for p in ball_folder.glob("*.png"):
        (out / p.name).write_bytes(p.read_bytes())
    before = (out / "annotations.json").read_bytes()
    session = LabelSession(open_frames(out, out), out, BallSegmentationModel.load(DEFAULT_MODEL), DEFAULT_MODEL)
    try:
        n = len(doc["images"])
        assert session.store.counts()["labelled"] == n and session.store.counts()["kept_from_file"] == 0
        assert (out / "annotations.before-rt2-label.json").read_bytes() == before
        last = len(session.frames) - 1
        relabelled = session.frames.frames[last].key
        session.label({"frame": last, "boxes": []})  # a person's change: that image's boxes lose the file's per-box fields
    finally:
        session.close()
    after = json.loads((out / "annotations.json").read_text())
    first = next(im for im in after["images"] if im["file_name"] == doc["images"][0]["file_name"])
    assert after["info"]["contributor"] == "lab" and first["camera"] == "cam3"
    kept = [a for a in after["annotations"] if a.get("reviewer") == "ana"]
    theirs = [a for a in doc["annotations"] if not doc["images"][a["image_id"] - 1]["file_name"].endswith(relabelled)]
    assert len(kept) == len(theirs) > 0
    assert sorted(li.path.name for li in read_coco(out)) == sorted(li.path.name for li in read_coco(ball_folder))


def test_a_set_round_tripped_by_rt2_labels_convert_is_continued(serve, ball_folder, ball_truth, tmp_path):
    out = tmp_path / "labels"
    server, session = serve(ball_folder, out)
    for i in (0, 1):
        key = session.frames.frames[i].key
        request(server, "POST", "/api/label", {"frame": i, "boxes": [b.tolist() for b in ball_truth[key]]})
    server.close()
    session.close()
    assert rt2_main(["labels", "convert", str(out), "--to", "yolo", "--out", str(tmp_path / "yolo")]) == 0
    assert rt2_main(["labels", "convert", str(tmp_path / "yolo"), "--to", "coco", "--out", str(tmp_path / "back")]) == 0
    server2, session2 = serve(ball_folder, tmp_path / "back")
    assert session2.store.counts()["labelled"] == 2 and session2.store.counts()["kept_from_file"] == 0
    for i in (0, 1):
        np.testing.assert_allclose(session2.store.boxes(i), ball_truth[session2.frames.frames[i].key], atol=0.01)
    assert request(server2, "POST", "/api/label", {"frame": 5, "boxes": []})[0] == 200
    assert len(read_coco(tmp_path / "back")) == 3


# -- one writer, tabs, undo per tab -------------------------------------------------------------------
def test_a_second_writer_on_one_folder_is_refused_in_one_line(ball_folder, tmp_path, capsys):
    from harness.common.spawn import ReadyProcess

    out = tmp_path / "labels"
    first = ReadyProcess(["label", str(ball_folder), "--out", str(out), "--port", "0"], what="rt2 label", timeout_s=180)
    try:
        assert rt2_main(["label", str(ball_folder), "--out", str(out), "--port", "0"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"another rt2 label (pid {first.ready['pid']}) is writing this folder" in err[0], err
    finally:
        first.kill()  # SIGKILL: the kernel's lock goes with the process
        first.stop()
    again = LabelSession(open_frames(ball_folder, out), out, BallSegmentationModel.load(DEFAULT_MODEL), DEFAULT_MODEL)  # free again
    again.close()


def test_a_change_on_an_old_revision_is_refused_and_undo_is_per_tab(serve, ball_folder, ball_truth):
    server, session = serve(ball_folder)
    keys = [f.key for f in session.frames.frames]
    _, state = request(server, "GET", "/api/state")
    rev = state["revision"]
    box = ball_truth[keys[0]][0].tolist()
    status, a = request(server, "POST", "/api/label", {"frame": 0, "boxes": [box], "tab": "A", "revision": rev})
    assert status == 200 and a["revision"] == rev + 1
    # tab B still shows the old revision: its change of frame 0 is refused, the file keeps A's box
    status, b = request(server, "POST", "/api/label", {"frame": 0, "boxes": [], "tab": "B", "revision": rev})
    assert status == 409 and b["conflict"] and b["revision"] == rev + 1 and "changed in another tab" in b["error"]
    np.testing.assert_allclose(read_coco(session.store.json_path)[0].boxes_xywh, [box])
    # B reloaded: labels frame 4; undo in A takes back A's change only, B's label stays
    status, b = request(server, "POST", "/api/label", {"frame": 4, "boxes": [], "tab": "B", "revision": rev + 1})
    assert status == 200
    status, u = request(server, "POST", "/api/undo", {"tab": "A", "revision": b["revision"]})
    assert status == 200 and u["frame"] == 0
    assert [li.path.name for li in read_coco(session.store.json_path)] == [keys[4]]
    status, u = request(server, "POST", "/api/undo", {"tab": "A", "revision": u["revision"]})
    assert status == 200 and u["frame"] is None  # nothing more of A's: B's label is not A's to undo
    # B's undo of frame 4 after A changed frame 4: refused, A's label stays
    status, a = request(server, "POST", "/api/label", {"frame": 4, "boxes": [box], "tab": "A", "revision": u["revision"]})
    status, u = request(server, "POST", "/api/undo", {"tab": "B", "revision": a["revision"]})
    assert status == 409 and "was changed since, in another tab" in u["error"]
    np.testing.assert_allclose(read_coco(session.store.json_path)[0].boxes_xywh, [box])


# -- unreadable images ---------------------------------------------------------------------------------
def test_unreadable_images_are_skipped_and_listed(serve, ball_folder, tmp_path):
    import cv2

    src = tmp_path / "mixed"
    src.mkdir()
    names = sorted(p.name for p in ball_folder.glob("*.png"))
    for name in names[:4]:
        (src / name).write_bytes((ball_folder / name).read_bytes())
    ok, jpg = cv2.imencode(".jpg", cv2.imread(str(ball_folder / names[0])))
    (src / "whole.jpg").write_bytes(jpg.tobytes())
    (src / "truncated.jpg").write_bytes(jpg.tobytes()[: len(jpg) * 15 // 100])  # OpenCV decodes it, the rest grey
    assert cv2.imread(str(src / "truncated.jpg")) is not None
    (src / "truncated.png").write_bytes((ball_folder / names[1]).read_bytes()[:-40])
    (src / "notanimage.png").write_bytes(b"\x89PNG not really")
    server, session = serve(src)
    assert sorted(f.key for f in session.frames.frames) == sorted(names[:4] + ["whole.jpg"])
    _, state = request(server, "GET", "/api/state")
    skipped = {s["file"]: s["why"] for s in state["skipped"]}
    assert set(skipped) == {"truncated.jpg", "truncated.png", "notanimage.png"}
    assert "JPEG file is truncated" in skipped["truncated.jpg"] and "PNG file is truncated" in skipped["truncated.png"]


def test_the_page_trains_on_the_chosen_colour_and_reports_a_failure_line(serve, ball_folder, ball_truth):
    import time

    server, session = serve(ball_folder)
    for i, f in enumerate(session.frames.frames):
        request(server, "POST", "/api/label", {"frame": i, "boxes": [b.tolist() for b in ball_truth[f.key]]})
    status, body = request(server, "POST", "/api/train", {})
    assert status == 400 and "choose the ball colour" in body["error"]
    status, body = request(server, "POST", "/api/train", {"ball_colour": "purple"})
    assert status == 400 and "choose the ball colour" in body["error"]
    (session.out_dir / "model.npz").mkdir()  # rt2 train refuses to write its model there: a real failure of the child
    status, body = request(server, "POST", "/api/train", {"ball_colour": "white"})
    assert status == 200 and body["ball_colour"] == "white"
    deadline = time.monotonic() + 120
    while (t := request(server, "GET", "/api/train")[1])["state"] == "running" and time.monotonic() < deadline:
        time.sleep(0.2)
    assert t["state"] == "failed" and t["returncode"] == 2
    assert t["error"].startswith("rt2 train: error: --out") and "model.npz" in t["error"], t
    assert "--ball-colour white" in (session.out_dir / "train.log").read_text().splitlines()[0]
    assert session.ball_colour() == "white"  # remembered in the file for the next start
def test_suggestions_skip_labelled_frames_and_state_reports_counts(serve, ball_folder):
    server, session = serve(ball_folder)
    _, state = request(server, "GET", "/api/state")
    first = state["suggestions"][0]
    assert len(state["suggestions"]) == 10 and state["n_frames"] == 12 and not state["can_train"]
    _, body = request(server, "POST", "/api/label", {"frame": first, "boxes": []})
    assert first not in body["suggestions"] and body["counts"]["no_ball"] == 1


def test_video_and_log_frames_are_extracted_and_keyed(serve, ball_video, ball_log, tmp_path):
    _, video = serve(ball_video, tmp_path / "v", every=2)
    assert [f.key for f in video.frames.frames] == [f"rally_f{i:06d}" for i in range(0, 12, 2)]
    assert all(f.image_path.is_file() and (f.width, f.height) == (128, 96) for f in video.frames.frames)
    _, log = serve(ball_log, tmp_path / "l1", camera="cam1")
    assert [f.key for f in log.frames.frames] == [f"cam1_s{k:06d}" for k in range(6)]
    _, both = serve(ball_log, tmp_path / "l2")
    assert len(both.frames) == 12


# -- hostile requests -------------------------------------------------------------------------------
HOSTILE = [
    # (method, path, body (JSON value) or raw bytes, extra headers, status, message part)
    ("GET", "/api/frame/999", None, {}, 404, "no frame 999: frames are numbered 0 to 11"),
    ("GET", "/api/frame/-1", None, {}, 404, "no frame '-1'"),
    ("GET", "/api/image/abc", None, {}, 404, "no frame 'abc'"),
    ("GET", "/api/frame/99999999999999999999", None, {}, 404, "no frame"),
    ("GET", "/nothing", None, {}, 404, "no page '/nothing'"),
    ("GET", "/static/../../../etc/passwd", None, {}, 404, "no page"),
    ("GET", "/%2e%2e/%2e%2e/etc/passwd", None, {}, 404, "no page"),
    ("GET", "/static/app.js/../../server.py", None, {}, 404, "no page"),
    ("POST", "/api/label", b"{frame: 1", {}, 400, "not valid JSON"),
    ("POST", "/api/label", b"\xff\xfe", {}, 400, "not valid JSON"),
    ("POST", "/api/label", [1, 2], {}, 400, "must be a JSON object"),
    ("POST", "/api/label", {"frame": 1}, {}, 400, "exactly the fields 'frame' and 'boxes'"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "x": 1}, {}, 400, "exactly the fields"),
    ("POST", "/api/label", {"frame": "1", "boxes": []}, {}, 400, "'frame' must be a frame index"),
    ("POST", "/api/label", {"frame": 1.5, "boxes": []}, {}, 400, "'frame' must be a frame index"),
    ("POST", "/api/label", {"frame": True, "boxes": []}, {}, 400, "'frame' must be a frame index"),
    ("POST", "/api/label", {"frame": 12, "boxes": []}, {}, 404, "no frame 12"),
    ("POST", "/api/label", {"frame": 1, "boxes": "all"}, {}, 400, "'boxes' must be a list"),
    ("POST", "/api/label", {"frame": 1, "boxes": [[1, 2, 3]]}, {}, 400, r"boxes\[0\] must be 4 finite numbers"),
    ("POST", "/api/label", b'{"frame": 1, "boxes": [[NaN, 2, 3, 4]]}', {}, 400, r"boxes\[0\] must be 4 finite numbers"),
    ("POST", "/api/label", {"frame": 1, "boxes": [[120, 10, 20, 20]]}, {}, 400, "lies outside the 128x96 image"),
    ("POST", "/api/label", {"frame": 1, "boxes": [[-3, 10, 20, 20]]}, {}, 400, "lies outside the 128x96 image"),
    ("POST", "/api/label", {"frame": 1, "boxes": [[10, 10, 0, 20]]}, {}, 400, "at least 1 px wide"),
    ("POST", "/api/label", {"frame": 1, "boxes": [[1, 1, 2, 2]] * 33}, {}, 400, "at most 32 boxes"),
    ("POST", "/api/label", b"x" * (MAX_BODY_BYTES + 1), {}, 413, f"at most {MAX_BODY_BYTES} are taken"),
    ("POST", "/api/label", {"frame": 1, "boxes": []}, {"Content-Type": "text/plain"}, 415, "application/json"),
    ("PUT", "/api/label", {"frame": 1, "boxes": []}, {}, 405, "method PUT is not used"),
    ("GET", "/api/label", None, {}, 405, "takes POST"),
    ("POST", "/api/state", {}, {}, 405, "takes GET"),
    ("POST", "/api/frame/1", {}, {}, 405, "takes GET"),
    ("GET", "/api/state", None, {"Host": "evil.example:80"}, 403, "is not this server's address"),
    ("POST", "/api/train", {}, {}, 409, "label at least 4 frames"),
    ("POST", "/api/train", {"ball_colour": "white", "x": 1}, {}, 400, "the request body must be"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "tab": "a b"}, {}, 400, "'tab' must be a name"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "tab": "x" * 65}, {}, 400, "'tab' must be a name"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "revision": -1}, {}, 400, "'revision' must be a non-negative integer"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "revision": "0"}, {}, 400, "'revision' must be a non-negative integer"),
    ("POST", "/api/label", {"frame": 1, "boxes": [], "revision": 7}, {}, 409, "changed in another tab"),
    ("POST", "/api/undo", {"revision": 3}, {}, 409, "changed in another tab"),
    ("POST", "/api/undo", {"frame": 1}, {}, 400, "takes only the optional fields"),
]


@pytest.mark.parametrize("option, value", [("--train-epochs", "0"), ("--train-learned-steps", "0"), ("--port", "70000"),
                                           ("--train-seed", "-1"), ("--suggestions", "0"), ("--min-train", "2"), ("--confirm-below", "1.5")])
def test_hostile_options_are_one_line_exit_2(ball_folder, tmp_path, capsys, option, value):
    assert rt2_main(["label", str(ball_folder), "--out", str(tmp_path / "o"), option, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{option} must be" in err[0], err
    assert not (tmp_path / "o").exists()  # refused before the label folder is made


@pytest.mark.parametrize("method, path, body, headers, status, message", HOSTILE, ids=[f"{c[0]} {c[1][:30]} {c[4]}" for c in HOSTILE])
def test_hostile_request_gets_a_clear_error_and_changes_nothing(serve, ball_folder, method, path, body, headers, status, message):
    import re

    server, session = serve(ball_folder)
    raw = body if isinstance(body, bytes) else None
    got, answer = request(server, method, path, None if raw is not None else body, headers, raw=raw)
    assert got == status, answer
    assert re.search(message, answer["error"]), answer["error"]
    assert not session.store.json_path.exists()  # nothing labelled
    assert request(server, "GET", "/api/state")[0] == 200  # still serving


def test_a_request_without_content_length_is_refused(serve, ball_folder):
    server, _ = serve(ball_folder)
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
        s.sendall(f"POST /api/label HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\nContent-Type: application/json\r\n\r\n".encode())
        chunks = []
        while chunk := s.recv(4096):  # the server closes the connection after an error
            chunks.append(chunk)
        head = b"".join(chunks).decode()
    assert head.startswith("HTTP/1.1 411") and "Content-Length header" in head


def test_static_files_come_from_the_package_with_no_outside_urls(serve, ball_folder):
    server, _ = serve(ball_folder)
    for path in ("/", "/static/app.js", "/static/app.css"):
        status, body = request(server, "GET", path)
        assert status == 200
        assert b"http://" not in body and b"https://" not in body and b"//cdn" not in body


# -- bad sources on the command line ----------------------------------------------------------------
@pytest.fixture()
def bad_sources(tmp_path, ball_log):
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "notes.txt").write_text("not a video")
    (tmp_path / "junk.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    (tmp_path / "broken.png").write_bytes(b"\x89PNG not really")
    bad_png = tmp_path / "badpng"
    bad_png.mkdir()
    (bad_png / "a.png").write_bytes(b"\x89PNG not really")
    from harness.logs import SessionLogWriter

    with SessionLogWriter(tmp_path / "noimages.mcap", metadata={"kind": "test"}) as w:
        w.write_detections(0.0, "cam0", np.zeros((1, 2)), np.ones(1), 0)
    return tmp_path


BAD_SOURCES = [
    (["nowhere"], "'.*nowhere': no such folder, video or session log"),
    (["empty"], "'.*empty': no images"),
    (["notes.txt"], "'.*notes.txt': OpenCV cannot open this file as a video"),
    (["badpng"], r"none of its 1 images can be read; the first: .*a.png: cannot read the image"),
    (["junk.mcap"], "junk.mcap"),
    (["noimages.mcap"], "holds no camera images"),
    (["LOG", "--camera", "cam7"], r"--camera 'cam7': .* has images of \['cam0', 'cam1'\] only"),
    (["empty", "--camera", "cam0"], "--camera is for session logs"),
    (["LOG", "--every", "0"], "--every must be a positive integer"),
    (["LOG", "--model", "missing.npz"], "missing.npz"),
    (["LOG", "--port", "70000"], r"--port must be in \[0, 65535\]"),
    (["LOG", "--min-train", "1"], r"--min-train must be >= 3 \(rt2 train holds out frames for validation\), got 1"),
]


@pytest.mark.parametrize("args, message", BAD_SOURCES, ids=[" ".join(a) for a, _ in BAD_SOURCES])
def test_bad_source_is_one_line_and_exit_2(bad_sources, ball_log, capsys, args, message):
    import re

    files = ("nowhere", "empty", "notes.txt", "badpng", "junk.mcap", "noimages.mcap")
    argv = ["label", "--out", str(bad_sources / "out"), "--port", "0"]
    argv += [str(ball_log) if a == "LOG" else (str(bad_sources / a) if a in files else a) for a in args]
    assert rt2_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("rt2 label: error: ") and re.search(message, err), err


def test_a_port_in_use_is_refused(ball_folder, tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert rt2_main(["label", str(ball_folder), "--out", str(tmp_path / "o"), "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err


# -- a fixed camera's recording: what moved is proposed first ---------------------------------------------------
def _fixed_camera_folder(folder, n=8):
    """A fixed camera's frames in name order: a still ball-sized orange lamp (larger than the ball) and an orange ball
    moving 5 px a frame, on a still background with a camera's noise; returns the ball's centres."""
    import cv2

    from tracker.detection.synthetic import draw_disk

    folder.mkdir()
    back = np.random.default_rng(0).integers(60, 140, (120, 160, 3)).astype(np.float64)
    balls = []
    for f in range(n):
        img = np.clip(back + np.random.default_rng([1, f]).normal(0, 2, back.shape), 0, 255).astype(np.uint8)
        draw_disk(img, (40.0, 40.0), 14.0, (245, 120, 20))
        ball = (70.0 + 5 * f, 80.0)
        draw_disk(img, ball, 10.0, (245, 120, 20))
        cv2.imwrite(str(folder / f"frame_{f:04d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        balls.append(ball)
    return balls


def _first_and_all(session, i):
    props = session.frame(i)["proposals"]
    centres = [(p["box"][0] + p["box"][2] / 2 - 0.5, p["box"][1] + p["box"][3] / 2 - 0.5) for p in props]
    return centres[0] if centres else None, centres


@pytest.mark.parametrize("cue", [False, True])
def test_motion_cue_proposes_what_moved_first_and_keeps_the_still_lamp(tmp_path, cue):
    from tracker.detection.synthetic import hand_made_model

    balls = _fixed_camera_folder(tmp_path / "cam")
    model = hand_made_model().save(tmp_path / "hand.npz")
    out = tmp_path / "labels"
    session = LabelSession(open_frames(tmp_path / "cam", out), out, BallSegmentationModel.load(model), model,
                           LabelOptions(min_train_labels=4, motion_cue=cue))
    try:
        assert session.state()["motion_cue"] is cue
        firsts = []
        for i, ball in enumerate(balls):
            first, every = _first_and_all(session, i)
            assert any(np.hypot(u - 40, v - 40) < 3 for u, v in every)  # the lamp is proposed in every frame, never dropped
            assert any(np.hypot(u - ball[0], v - ball[1]) < 3 for u, v in every)
            firsts.append(np.hypot(first[0] - ball[0], first[1] - ball[1]) < 3)
        if cue:
            assert all(firsts[1:])  # after the first frame (the background), the ball that moved comes first
        else:
            assert not any(firsts)  # the detector alone ranks the larger lamp first
    finally:
        session.close()


def test_rt2_label_motion_cue_serves_what_moved_first(tmp_path):
    """The command as a user runs it, a separate process on a real socket: ``rt2 label DIR --motion-cue``."""
    import urllib.request

    from harness.common.spawn import ReadyProcess
    from tracker.detection.synthetic import hand_made_model

    balls = _fixed_camera_folder(tmp_path / "cam", n=5)
    model = hand_made_model().save(tmp_path / "hand.npz")
    proc = ReadyProcess(["label", str(tmp_path / "cam"), "--out", str(tmp_path / "labels"), "--port", "0", "--model", str(model),
                         "--motion-cue"], what="rt2 label", timeout_s=180)
    try:
        url = proc.ready["url"].rstrip("/")
        state = json.loads(urllib.request.urlopen(f"{url}/api/state", timeout=10).read())
        assert state["motion_cue"] is True
        frame = json.loads(urllib.request.urlopen(f"{url}/api/frame/3", timeout=10).read())
        x, y, w, h = frame["proposals"][0]["box"]
        assert np.hypot(x + w / 2 - 0.5 - balls[3][0], y + h / 2 - 0.5 - balls[3][1]) < 3
    finally:
        proc.stop()


def test_a_folder_is_shown_in_time_order_not_name_order(tmp_path):
    """A Roboflow export's split prefixes and hashes (the real rally frames' names) and unpadded numbers: the frames come
    in the order of their numbers, as ``--time-range`` takes them, so a fixed camera's frames are in time order."""
    import cv2

    src = tmp_path / "export"
    src.mkdir()
    names = ["valid_IMG_MOV-0012_jpg.rf.aa.jpg", "train_IMG_MOV-0002_jpg.rf.bb.jpg", "test_IMG_MOV-0010_jpg.rf.cc.jpg",
             "train_IMG_MOV-0001_jpg.rf.dd.jpg"]
    for n in names:
        cv2.imwrite(str(src / n), np.full((8, 8, 3), 100, np.uint8))
    frames = open_frames(src, tmp_path / "labels")
    assert [f.key for f in frames.frames] == [names[3], names[1], names[2], names[0]]
    plain = tmp_path / "plain"
    plain.mkdir()
    for n in ("frame_10.png", "frame_2.png", "frame_1.png"):
        cv2.imwrite(str(plain / n), np.full((8, 8, 3), 100, np.uint8))
    assert [f.key for f in open_frames(plain, tmp_path / "l2").frames] == ["frame_1.png", "frame_2.png", "frame_10.png"]
