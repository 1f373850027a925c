"""The subscriber of ``rt2 bench live``, run in its own process:
``python -m harness.live._bench_subscriber ADDR OUT.json [FIRST_TIMEOUT_S]``.

Connects a plain SUB socket to rt2's rich stream, prints ``ready``, and for every message records its
number, frame id, status, position, the frame set's first host arrival stamp and its own receive stamp ``time.monotonic()``
(one host: both processes read the same CLOCK_MONOTONIC). Stops at the ``{"end": true}`` message
or after 10 s without any message (``FIRST_TIMEOUT_S``, default 300, before the first), then writes ``{"num": [...], "frame_id": [...], "status": [...], "position_m": [...], "t_first_host_s": [...],
"t_recv_s": [...]}``.
"""

from __future__ import annotations

import json
import sys
import time


def main(argv: list[str]) -> int:
    import zmq

    addr, out = argv[:2]
    first_timeout_ms = int(float(argv[2]) * 1000) if len(argv) > 2 else 300_000
    ctx = zmq.Context()
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.RCVHWM, 1_000_000)
    s.connect(addr)
    s.setsockopt(zmq.SUBSCRIBE, b"")
    print("ready", flush=True)
    num, t_first, t_recv, frame_id, status, position = [], [], [], [], [], []
    while s.poll(10_000 if num else first_timeout_ms):
        msg = s.recv()
        t = time.monotonic()
        doc = json.loads(msg)
        if doc.get("end"):
            break
        if doc.get("num", -1) < 0:  # join probes
            continue
        num.append(doc["num"])
        t_first.append(doc["t_first_host_s"])
        t_recv.append(t)
        frame_id.append(doc.get("frame_id", -1))
        status.append(doc.get("status"))
        position.append(doc.get("position_m"))
    with open(out, "w") as f:
        json.dump({"num": num, "frame_id": frame_id, "status": status, "position_m": position, "t_first_host_s": t_first,
                   "t_recv_s": t_recv}, f)
    s.close(linger=0)
    ctx.term()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
