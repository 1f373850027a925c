"""Start ``rt2 track`` as a separate process and wait for its ready line (the bound stream addresses).

Used by ``rt2 accuracy --live`` (the one-command local run: bridge, tracker and experiment as three
processes) and by its tests.
"""

from __future__ import annotations

from harness.common.spawn import ReadyProcess

__all__ = ["TrackProcess"]


class TrackProcess(ReadyProcess):
    """A running ``rt2 track ... --ready-json`` process; ``streams`` maps ``tennicam`` / ``rt2`` to their addresses.

    args : ``rt2 track`` options (``--publish`` defaults to a free port on 127.0.0.1); ``timeout_s``: how long
    its start (rig, tracker warm-up, renderer) may take before it counts as failed. :meth:`stop` sends
    SIGTERM (rt2 track finishes its log and prints its summary) and returns what it printed.
    """

    def __init__(self, *args: str, timeout_s: float = 600.0):
        cmd = ["track", "--ready-json", *args]
        if "--publish" not in args:
            cmd += ["--publish", "tcp://127.0.0.1:0"]
        super().__init__(cmd, what="rt2 track", timeout_s=timeout_s, stop_timeout_s=20.0)
        self.streams = self.ready["streams"]
