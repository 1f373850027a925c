"""Start ``rt2 robot serve --sim`` as a separate process on free ports and wait for its ready line
(:class:`harness.common.spawn.ReadyProcess`).

Used by ``rt2 accuracy --robot sim`` and ``rt2 play --live`` (the one-command local runs) and by the tests.
"""

from __future__ import annotations

from harness.common.spawn import ReadyProcess

__all__ = ["ReadyProcess", "SimBridgeProcess"]


class SimBridgeProcess(ReadyProcess):
    """A running simulated-WAM bridge process; ``ready`` is its ready line (endpoints, pid, clock epoch),
    ``address`` its command endpoint. ``extra``: more ``rt2 robot serve`` options (``--seed 3`` ...)."""

    def __init__(self, *extra: str, bind: str = "tcp://127.0.0.1:*", state_bind: str | None = None,
                 timeout_s: float = 60.0):
        args = ["robot", "serve", "--sim", "--bind", bind, "--ready-json", *extra]
        if state_bind:
            args += ["--state-bind", state_bind]
        super().__init__(args, what="the simulated robot bridge", timeout_s=timeout_s)
        self.address = self.ready["command"]
