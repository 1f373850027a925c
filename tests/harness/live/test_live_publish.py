"""The ZeroMQ streams of rt2 track: addresses, the tennicam message read by a plain SUB socket in
another process, bind errors, and a slow subscriber that must never stall the publisher."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import zmq

from harness.live.publish import Publisher, parse_address, tennicam_message

# A subscriber exactly as tennicam_client's driver connects (SUB, subscribe "", one JSON text per
# message), in its own process: prints the first N messages as JSON lines.
SUBSCRIBER = textwrap.dedent("""
    import json, sys, zmq
    addr, n, rcvhwm, sleep_s = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
    ctx = zmq.Context()
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.RCVHWM, rcvhwm)
    s.connect(addr)
    s.setsockopt(zmq.SUBSCRIBE, b"")
    print("ready", flush=True)
    import time
    for _ in range(n):
        if not s.poll(20000):
            break
        msg = s.recv()
        print(json.dumps(json.loads(msg.decode())), flush=True)
        time.sleep(sleep_s)
""")


def _subscriber(addr: str, n: int, *, rcvhwm: int = 1000, sleep_s: float = 0.0) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, addr, str(n), str(rcvhwm), str(sleep_s)],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    return p


# -- addresses ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, want", [
    ("tcp://127.0.0.1:7660", "tcp://127.0.0.1:7660"),
    ("127.0.0.1:9000", "tcp://127.0.0.1:9000"),
    (":9000", "tcp://127.0.0.1:9000"),
    ("9000", "tcp://127.0.0.1:9000"),
    ("*", "tcp://*:7660"),
    ("localhost", "tcp://localhost:7660"),
])
def test_parse_address(text, want):
    assert parse_address(text) == want


@pytest.mark.parametrize("text, match", [
    ("udp://127.0.0.1:1", "only tcp"),
    ("127.0.0.1:99999", "port must be 0..65535"),
    ("", "publish address"),
    ("1.2.3.4:5:6", "not HOST:PORT"),
    ("bad host!:1", "not HOST:PORT"),
])
def test_parse_address_rejects(text, match):
    with pytest.raises(ValueError, match=match):
        parse_address(text)


# -- the tennicam message ---------------------------------------------------------------------------
def test_tennicam_message_fields():
    m = tennicam_message(3, 123_456_789, 0.0012, np.array([1.0, 2.0, 3.0]))
    assert m == {"num": 3, "time": 123_456_789, "proc_time": 0.0012, "obs": [1.0, 2.0, 3.0]}
    assert tennicam_message(4, 5, 0.1, None)["obs"] is None
    assert json.loads(json.dumps(m)) == m


def test_plain_zmq_subscriber_in_another_process_reads_tennicam_json():
    with Publisher("tcp://127.0.0.1:0", None) as pub:
        addr = pub.addresses["tennicam"]
        sub = _subscriber(addr, 5)
        # PUB/SUB joins late: publish until the subscriber has its 5 messages
        k = 0
        deadline = time.monotonic() + 20
        while sub.poll() is None and time.monotonic() < deadline:
            pos = None if k % 2 else [0.1 * k, 0.2, 1.0]
            pub.publish(tennicam_message(k, time.monotonic_ns(), 0.001, pos))
            k += 1
            time.sleep(0.01)
        out, _ = sub.communicate(timeout=10)
    msgs = [json.loads(line) for line in out.splitlines()]
    assert len(msgs) == 5
    nums = [m["num"] for m in msgs]
    assert nums == list(range(nums[0], nums[0] + 5))  # consecutive: nothing lost once joined
    for m in msgs:
        assert set(m) == {"num", "time", "proc_time", "obs"}
        assert isinstance(m["time"], int) and m["proc_time"] == 0.001
        assert m["obs"] == (None if m["num"] % 2 else [0.1 * m["num"], 0.2, 1.0])


# -- bad addresses ------------------------------------------------------------------------------------
def test_port_in_use_is_one_clear_error():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    try:
        with pytest.raises(ValueError, match=rf"cannot publish the tennicam stream on tcp://127.0.0.1:{port}: Address already in use"):
            Publisher(f"tcp://127.0.0.1:{port}", "tcp://127.0.0.1:0")
    finally:
        s.close()


def test_address_not_on_this_host_is_one_clear_error():
    # 192.0.2.1 is TEST-NET-1 (never assigned): binding fails locally, no packet leaves the machine
    with pytest.raises(ValueError, match=r"cannot publish the rt2 stream on tcp://192.0.2.1:7661"):
        Publisher("tcp://127.0.0.1:0", "tcp://192.0.2.1:7661")


# -- slow and late subscribers ---------------------------------------------------------------------------
def test_slow_subscriber_never_stalls_the_publisher():
    """A subscriber in another process that reads one message every 50 ms, with a queue of 1 message;
    the publisher sends 20,000 frame sets' messages as fast as it can: no send blocks."""
    with Publisher("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", sndhwm=10) as pub:
        sub = _subscriber(pub.addresses["tennicam"], 10, rcvhwm=1, sleep_s=0.05)
        time.sleep(0.3)  # let it join
        rich = {"num": 0, "payload": "x" * 800, "t_first_host_s": 0.0, "t_publish_s": 0.0}
        worst = 0.0
        t0 = time.perf_counter()
        for k in range(20_000):
            t = time.perf_counter()
            rich["t_publish_s"] = time.monotonic()
            pub.publish(tennicam_message(k, k, 0.0, [1.0, 2.0, 3.0]), rich)
            worst = max(worst, time.perf_counter() - t)
        total = time.perf_counter() - t0
        assert pub.sent == {"tennicam": 20_000, "rt2": 20_000}
        sub.communicate(timeout=30)
    # a blocking send would wait for a reader that has stopped reading: forever
    assert total < 20.0, f"20,000 publications took {total:.1f} s"
    assert worst < 1.0, f"one publication took {worst * 1e3:.0f} ms"


def test_late_subscriber_gets_the_current_stream():
    with Publisher("tcp://127.0.0.1:0", None) as pub:
        for k in range(1000):  # nobody listening yet: sent into the void, never queued forever
            pub.publish(tennicam_message(k, k, 0.0, None))
        ctx = zmq.Context.instance()
        s = ctx.socket(zmq.SUB)
        s.connect(pub.addresses["tennicam"])
        s.setsockopt(zmq.SUBSCRIBE, b"")
        got = None
        for k in range(1000, 3000):
            pub.publish(tennicam_message(k, k, 0.0, None))
            if s.poll(5):
                got = json.loads(s.recv())
                break
        s.close(linger=0)
    assert got is not None and got["num"] >= 1000


def test_candidates_without_blob_areas_are_sent_with_a_null_area():
    """rtblob's PipelineInfo has no areas (None): its candidates still go out, with a null area."""
    from types import SimpleNamespace

    from harness.live.publish import _candidates

    uv = np.array([[[10.0, 20.0]], [[np.nan, np.nan]]])
    got = _candidates(SimpleNamespace(uv_candidates_px=uv, scores=np.array([[0.9], [np.nan]]), areas_px=None))
    assert got == [[[10.0, 20.0, 0.9, None]], []]
    json.dumps(got, allow_nan=False)  # strict JSON, as the publisher encodes it
    with_areas = _candidates(SimpleNamespace(uv_candidates_px=uv, scores=np.array([[0.9], [np.nan]]), areas_px=np.array([[12.0], [np.nan]])))
    assert with_areas[0] == [[10.0, 20.0, 0.9, 12.0]]


def test_the_live_service_runs_the_rtblob_tracker():
    from harness.live.config import TrackConfig
    from harness.live.run import open_service

    import threading

    # Run until a few frame sets went through (not for a fixed time: a loaded CI machine may need seconds for
    # the first frame set); the generous cap only ends a hung run.
    with open_service(TrackConfig(tracker="rtblob", publish=None, prerender_s=0.1, duration_s=60.0), status=None) as live:
        assert live.service.tracker.kind == "rtblob"
        stop = threading.Event()

        def watch():
            while not stop.wait(0.02):
                if live.service.stats.n >= 3:
                    stop.set()

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        live.assembler.start()
        summary = live.service.run(live.assembler, stop=stop, duration_s=60.0)
        stop.set()
        watcher.join()
    assert summary["frame_sets"] >= 3 and summary["tracker"] == "rtblob"
