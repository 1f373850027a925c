"""The live view's port takes both Foxglove subprotocols: the front (harness/live/ws_subprotocols.py) in front
of Foxglove's own SDK server, checked with raw sockets (hostile requests), and end to end with Foxglove's own
classic client (npm ``@foxglove/ws-protocol-examples``: ``mcap-record``) against ``rt2 track`` as a separate
process, whose recording ``rt2 log info`` reads."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.live.spawn_track import TrackProcess
from harness.live.ws_subprotocols import CLASSIC, MAX_HEADER_BYTES, SDK, SubprotocolFront, offered, rename_protocol

ROOT = Path(__file__).resolve().parents[3]
# where `make setup` installs Foxglove's node clients (build/ is not tracked); RT2_WS_PROTOCOL_EXAMPLES overrides
EXAMPLES = Path(os.environ.get("RT2_WS_PROTOCOL_EXAMPLES", ROOT / "build" / "node" / "node_modules" / ".bin" / "ws-protocol-examples"))
KEY = "dGhlIHNhbXBsZSBub25jZQ=="  # RFC 6455's sample key
RECORD_S = 5.0  # the classic client's recording after it subscribed to every channel (the slowest of them comes every 1 s)


def _upgrade(protocols: str | None, path: str = "/") -> bytes:
    lines = [f"GET {path} HTTP/1.1", "Host: 127.0.0.1", "Upgrade: websocket", "Connection: Upgrade",
             f"Sec-WebSocket-Key: {KEY}", "Sec-WebSocket-Version: 13"]
    if protocols is not None:
        lines.append(f"Sec-WebSocket-Protocol: {protocols}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def _exchange(port: int, payload: bytes, *, half_close: bool = False, timeout_s: float = 10.0) -> bytes:
    """Send ``payload`` (optionally end our sending side), return the answer's header (or all that came)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
        if payload:
            s.sendall(payload)
        if half_close:
            s.shutdown(socket.SHUT_WR)
        buf = b""
        while b"\r\n\r\n" not in buf:
            try:
                chunk = s.recv(4096)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
        return buf.split(b"\r\n\r\n")[0]


@pytest.fixture(scope="module")
def front():
    import foxglove

    ctx = foxglove.Context()
    server = foxglove.start_server(name="rt2 test", host="127.0.0.1", port=0, context=ctx)
    f = SubprotocolFront("127.0.0.1", 0, server.port, header_timeout_s=0.5)
    yield f
    server.stop()
    f.close()


def _status(head: bytes) -> int:
    return int(head.split(b" ")[1]) if head.startswith(b"HTTP/1.1 ") else -1


def _chosen(head: bytes) -> list[str]:
    return offered(head)  # the response's Sec-WebSocket-Protocol lines, parsed the same way


HOSTILE = [
    # (case, bytes sent, end our side after sending, expected status, expected chosen subprotocol)
    ("classic only", _upgrade(CLASSIC), False, 101, [CLASSIC]),
    ("sdk only", _upgrade(SDK), False, 101, [SDK]),
    ("classic and sdk offered", _upgrade(f"{CLASSIC}, {SDK}"), False, 101, [SDK]),
    ("classic among unknown ones", _upgrade(f"x.v9, {CLASSIC}"), False, 101, [CLASSIC]),
    ("unknown subprotocol", _upgrade("mqtt"), False, 400, []),
    ("no subprotocol", _upgrade(None), False, 400, []),
    ("garbage, then the client's side ends", b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03", True, 400, []),
    ("header never ends (more than the cap)", b"GET / HTTP/1.1\r\n" + b"X-Pad: " + b"a" * (MAX_HEADER_BYTES + 10), False, 400, []),
    ("silence (slower than the header timeout)", b"", False, 400, []),
    ("half a request, then the client's side ends", b"GET / HTTP/1.1\r\nHost: x\r\n", True, 400, []),
]


@pytest.mark.parametrize("case,payload,half_close,status,chosen", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_front_answers_each_request(front, case, payload, half_close, status, chosen):
    head = _exchange(front.port, payload, half_close=half_close)
    assert _status(head) == status, (case, head[:200])
    assert _chosen(head) == chosen, (case, head[:300])


def test_front_still_serves_after_hostile_requests(front):
    for _, payload, half_close, _, _ in HOSTILE:
        _exchange(front.port, payload, half_close=half_close)
    assert _status(_exchange(front.port, _upgrade(CLASSIC))) == 101
    assert front.connections["refused"] >= 4 and front.connections["classic"] >= 1


def test_header_parsing_and_renaming():
    head = _upgrade(f"a, {CLASSIC}").replace(b"Sec-WebSocket-Protocol", b"sec-websocket-protocol") + b""
    head = head[:-2] + b"Sec-WebSocket-Protocol: b\r\n\r\n"  # a second header line adds to the first
    assert offered(head) == ["a", CLASSIC, "b"]
    renamed = rename_protocol(head, CLASSIC, SDK)
    assert offered(renamed) == ["a", SDK, "b"] and renamed.endswith(b"\r\n\r\n")
    assert b"Sec-WebSocket-Key: " + KEY.encode() in renamed  # only the protocol lines change
    assert offered(b"HTTP/1.1 400 Bad Request\r\n\r\n") == []


def test_front_refuses_a_port_in_use(front):
    with pytest.raises(OSError):
        SubprotocolFront("127.0.0.1", front.port, 1)


def _node_client_missing() -> str | None:
    if shutil.which("node") is None:
        return "node is not installed (Foxglove's classic client runs under node)"
    if not EXAMPLES.exists():
        return (f"Foxglove's classic client is not installed at {EXAMPLES} "
                "(`make setup` installs it with npm: npm install --prefix build/node @foxglove/ws-protocol-examples@0.10.0)")
    return None


@pytest.mark.skipif(_node_client_missing() is not None, reason=str(_node_client_missing()))
def test_foxglove_classic_client_records_every_channel_of_rt2_track(tmp_path):
    """Foxglove's own ws-protocol client (it offers only ``foxglove.websocket.v1``) subscribes to every channel
    ``rt2 track --source sim --foxglove`` advertises and records an MCAP; ``rt2 log info`` reads it and every
    advertised topic has messages with its schema."""
    import threading

    out = tmp_path / "classic.mcap"
    names = ("cam0", "cam1", "cam2", "cam3")
    expected = {f"/camera/{c}/{k}" for c in names for k in ("image", "annotations", "calibration")}
    expected |= {"/scene/balls", "/scene/static", "/tf_static", "/tracker/rt2/ball"}
    lines: list[str] = []
    all_subscribed = threading.Event()

    def subscribed() -> set:
        return {ln.split("subscribing to ")[1].split(" (channel")[0] for ln in list(lines) if "subscribing to " in ln}

    def read(stream):
        for line in stream:
            lines.append(line.rstrip("\n"))
            if subscribed() >= expected:
                all_subscribed.set()
        all_subscribed.set()  # the client ended (its output says why)

    # pre-rendered (a looped 0.1 s clip): the images come from this process, not from a renderer process that
    # otherwise takes a second core for the whole run. Not a fixed --duration (a client that was slow to start missed
    # its end): the service runs until the client has subscribed to every channel and recorded RECORD_S more (the
    # calibration, /tf_static and /scene/static are sent every second), then stops on SIGTERM, which closes the
    # connection as the end of a --duration does; --duration only caps a hung run
    track = TrackProcess("--source", "sim", "--prerender", "0.1", "--foxglove", "0", "--publish-rt2", "none", "--duration", "300",
                         "--status-period", "0", timeout_s=300)
    rec = None
    try:
        rec = subprocess.Popen([str(EXAMPLES), "mcap-record", track.ready["live_view"], "-o", str(out)], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
        reader = threading.Thread(target=read, args=(rec.stdout,), daemon=True)
        reader.start()
        all_subscribed.wait(timeout=120)
        if rec.poll() is None and subscribed() >= expected:
            time.sleep(RECORD_S)
    finally:
        track.stop()
        if rec is not None:
            try:
                rec.wait(timeout=120)  # it ends when the service closes the connection
            finally:
                if rec.poll() is None:
                    rec.kill()
                    rec.wait()
            reader.join(timeout=10)
    printed = "\n".join(lines)
    assert "Unexpected server response" not in printed and "connection failed" not in printed, printed[-2000:]
    assert "server disconnected" in printed, printed[-2000:]  # the recording ended as the service closed, not cut
    info = subprocess.run([sys.executable, "-m", "harness.cli", "log", "info", "--json", str(out)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert info.returncode == 0, info.stderr
    topics = json.loads(info.stdout)["topics"]
    assert subscribed() == expected, printed[-2000:]
    assert set(topics) == expected and all(t["count"] > 0 for t in topics.values()), topics
    assert topics["/camera/cam0/image"]["schema"] == "foxglove.CompressedImage"
    assert topics["/scene/balls"]["schema"] == "foxglove.SceneUpdate"


def test_first_frames_follow_the_handshake_apart(front):
    """The server's serverInfo comes microseconds after its 101; the front holds it back 50 ms, so a client that
    attaches its handlers on the open event (Foxglove's mcap-record) never reads both in one chunk and loses it."""
    with socket.create_connection(("127.0.0.1", front.port), timeout=10) as s:
        s.sendall(_upgrade(CLASSIC))
        buf = b""
        while b"\r\n\r\n" not in buf:
            buf += s.recv(4096)
        t_head = time.monotonic()
        assert buf.endswith(b"\r\n\r\n")  # nothing of the first frame with the handshake
        first = s.recv(4096)
        assert time.monotonic() - t_head >= 0.03 and first[:1] == b"\x81"  # a text frame: serverInfo
        assert b"serverInfo" in first
