"""``rt2 robot record --robot ADDR --log PATH``: record a robot's joint states over the link to a session log.

A listener (it never commands and never sends heartbeats, so it cannot keep a robot moving whose
commanding process has died). Joint states go to ``/robot/joint_states`` on the session clock (the
harness clock through each segment's robot clock-offset estimate, docs/robot_link.md). When the link is
lost the states up to the loss are kept; with ``--reconnect S`` the recorder tries to reach the robot
again for up to S seconds and goes on in a new segment of the same session. SIGINT / SIGTERM, the end of
``--duration`` or a loss without reconnection finish the log cleanly. Exit code 0, or 1 when the
recording ended by a link loss (2: bad input or no robot at the address).
"""

from __future__ import annotations

import argparse
import signal
import time

from harness.common.outputs import check_output_file
from harness.link.client import LinkLostError
from harness.link.session import LinkSession

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="tcp://127.0.0.1:7650", metavar="ADDR",
                        help="the bridge's command endpoint (default tcp://127.0.0.1:7650)")
    parser.add_argument("--log", required=True, metavar="PATH", help="session log to write (.mcap)")
    parser.add_argument("--log-overwrite", action="store_true", help="replace an existing log file")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds of session time (default: until Ctrl-C)")
    parser.add_argument("--reconnect", type=float, default=0.0, metavar="S",
                        help="after a link loss, try to reach the robot again for up to S seconds (default 0: stop)")


def _connect(session: LinkSession, address: str, give_up_s: float, stop) -> bool:
    deadline = time.monotonic() + give_up_s
    while not stop["now"]:
        try:
            session.connect(address, heartbeat_s=None, connect_timeout_s=1.0)
            return True
        except LinkLostError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.2)
    return False


def run(args) -> int:
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be > 0 s, got {args.duration!r}")
    if not 0 <= args.reconnect <= 3600:
        raise ValueError(f"--reconnect must be in [0, 3600] s, got {args.reconnect!r}")
    path = check_output_file(args.log, "--log", overwrite=args.log_overwrite)
    stop = {"now": False}
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.update(now=True))
    session = LinkSession(path, metadata={"robot": args.robot}, overwrite=args.log_overwrite)
    try:
        try:
            session.connect(args.robot, heartbeat_s=None)
        except LinkLostError as exc:
            session.loss = str(exc)
            raise ValueError(f"robot link: {exc}") from None
        print(f"recording {args.robot} ({session.client.robot_info['robot']}, {session.client.control_rate_hz:g} Hz) "
              f"to {path}", flush=True)
        while not stop["now"] and (args.duration is None or session.now_s() < args.duration):
            try:
                session.advance_to(session.client.t_s + 0.1)
            except LinkLostError as exc:
                print(f"segment {len(session.segments) - 1}: {exc}", flush=True)
                if args.reconnect <= 0 or not _connect(session, args.robot, args.reconnect, stop):
                    break
                print(f"segment {len(session.segments) - 1}: reconnected (bridge {session.client.bridge_id})", flush=True)
    finally:
        session.close()
    n = sum(s["states"] for s in session.segments)
    print(f"{n} joint states in {len(session.segments)} segment(s) written to {path}"
          + (f"; ended by: {session.loss}" if session.loss else ""))
    return 0 if session.loss is None else 1
