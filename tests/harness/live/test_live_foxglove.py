"""The Foxglove live view, checked with a real WebSocket client on 127.0.0.1: it connects with the
Foxglove protocol, subscribes to channels and receives the ball scene and a camera image."""

from __future__ import annotations

import asyncio
import json
import threading
import time

import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from harness.live.foxglove_view import LiveView, ViewOptions
from tests.harness.live._live_frames import assembled, lab_rig, rendered_images
from tracker import Tracker

websockets = pytest.importorskip("websockets")
SUBPROTOCOL = "foxglove.sdk.v1"


async def _receive(port: int, topics: list[str] | None, timeout_s: float = 20.0, subprotocol: str = SUBPROTOCOL) -> dict:
    """Connect offering ``subprotocol``, wait for the advertised channels, subscribe to ``topics`` (None: every
    advertised one); returns {topic: payload bytes} of the first message of each, the channels and the
    subprotocol the server chose."""
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[subprotocol]) as ws:
        channels = {}
        while not channels or (topics is not None and not all(t in channels for t in topics)):
            msg = await asyncio.wait_for(ws.recv(), timeout_s)
            if isinstance(msg, str):
                doc = json.loads(msg)
                if doc["op"] == "advertise":
                    channels.update({c["topic"]: c for c in doc["channels"]})
        topics = sorted(channels) if topics is None else topics
        subs = {i + 1: t for i, t in enumerate(topics)}
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()]}))
        got = {}
        while len(got) < len(topics):
            msg = await asyncio.wait_for(ws.recv(), timeout_s)
            if isinstance(msg, bytes) and msg[0] == 0x01:  # message data: op, subscription id (u32), log time (u64), payload
                sub = int.from_bytes(msg[1:5], "little")
                got.setdefault(subs[sub], msg[13:])
        return {"payloads": got, "channels": channels, "subprotocol": ws.subprotocol}


def _fed_view(rig, topics, subprotocol=SUBPROTOCOL) -> dict:
    """A live view fed by the tracker on rendered frames while a client offering ``subprotocol`` receives ``topics``."""
    view = LiveView(rig, "rt2", ViewOptions(port=0, image_rate_hz=20))
    stop = threading.Event()

    def feed():
        with Tracker(rig, "rt2") as tr:
            for afs in assembled(100_000, pace=True, rate_hz=100):
                if stop.is_set():
                    return
                obs, info = tr.process_with_info(afs.frameset)
                view.update(afs.frame_id, afs, obs, info)

    th = threading.Thread(target=feed)
    th.start()
    try:
        return asyncio.run(_receive(view.port, topics, subprotocol=subprotocol))
    finally:
        stop.set()
        th.join()
        view.close()


def test_websocket_client_subscribes_and_receives_scene_and_image():
    rendered_images()
    rig = lab_rig()
    r = _fed_view(rig, ["/scene/balls", "/camera/cam0/image", "/scene/static"])
    ch = r["channels"]
    assert ch["/scene/balls"]["schemaName"] == "foxglove.SceneUpdate" and ch["/scene/balls"]["encoding"] == "protobuf"
    assert {f"/camera/{c}/annotations" for c in rig.names} <= set(ch) and "/tracker/rt2/ball" in ch
    balls = SceneUpdate.FromString(r["payloads"]["/scene/balls"])
    ids = {e.id for e in balls.entities}
    assert "ball/rt2" in ids and "track/rt2" in ids
    sphere = next(e for e in balls.entities if e.id == "ball/rt2").spheres[0]
    assert -1.7 < sphere.pose.position.x < -0.9 and abs(sphere.pose.position.z - 1.1) < 0.02
    img = CompressedImage.FromString(r["payloads"]["/camera/cam0/image"])
    assert img.format == "jpeg" and img.frame_id == "cam0" and img.data[:2] == b"\xff\xd8"
    table = SceneUpdate.FromString(r["payloads"]["/scene/static"])
    assert {"table", "net"} <= {e.id for e in table.entities}


def test_live_view_binds_loopback_and_reports_a_port_in_use():
    rig = lab_rig()
    with LiveView(rig, "rt2", ViewOptions(port=0)) as view:
        with pytest.raises(ValueError, match=rf"cannot start the Foxglove live view on 127.0.0.1:{view.port}"):
            LiveView(rig, "rt2", ViewOptions(port=view.port))
    with pytest.raises(ValueError, match="port must be 0..65535"):
        ViewOptions(port=70000)


def test_view_without_clients_costs_the_loop_nothing():
    """update() only hands a reference over: 2000 calls take well under a second, clients or not."""
    rendered_images()
    rig = lab_rig()
    with LiveView(rig, "rt2", ViewOptions(port=0)) as view, Tracker(rig, "rt2") as tr:
        afs = next(assembled(1))
        obs, info = tr.process_with_info(afs.frameset)
        t0 = time.perf_counter()
        for k in range(2000):
            view.update(k, afs, obs, info)
        assert time.perf_counter() - t0 < 0.5


@pytest.mark.parametrize("subprotocol", ["foxglove.sdk.v1", "foxglove.websocket.v1"])
def test_each_subprotocol_receives_every_advertised_channel(subprotocol):
    """Foxglove's current apps offer ``foxglove.sdk.v1``; Lichtblick and the ws-protocol clients offer only the
    classic ``foxglove.websocket.v1``: both are accepted on the one port, answered with the name they offered,
    and a client subscribed to every advertised channel receives a message on each."""
    rendered_images()
    rig = lab_rig()
    r = _fed_view(rig, None, subprotocol)
    assert r["subprotocol"] == subprotocol
    expected = {f"/camera/{c}/{k}" for c in rig.names for k in ("image", "annotations", "calibration")}
    expected |= {"/scene/balls", "/scene/static", "/tf_static", "/tracker/rt2/ball"}
    assert set(r["channels"]) == expected
    assert set(r["payloads"]) == expected and all(len(p) > 0 for p in r["payloads"].values())


def test_bad_clients_are_logged_prefixed_and_rate_limited(capfd):
    """40 clients that fail the WebSocket handshake: a few prefixed lines and a count, not 40 bare stderr lines."""
    import socket

    def bad_client(port):
        with socket.create_connection(("127.0.0.1", port)) as s:
            s.sendall(b"garbage\r\n\r\n")
            s.settimeout(2.0)
            try:
                s.recv(100)
            except OSError:
                pass

    view = LiveView(lab_rig(), "rt2", ViewOptions(port=0))
    try:
        for _ in range(40):
            bad_client(view.port)
        time.sleep(1.2)
        bad_client(view.port)  # one more, in the next second: the summary
        time.sleep(0.3)
    finally:
        view.close()
    lines = [ln for ln in capfd.readouterr().err.splitlines() if "client" in ln]
    assert lines and all(ln.startswith("rt2 live view: ") for ln in lines), lines
    assert len(lines) <= 12, lines
    assert any("more Foxglove messages in" in ln for ln in lines), lines
