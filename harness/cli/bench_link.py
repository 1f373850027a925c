"""``rt2 bench link-flood``: a hostile peer floods `rt2 robot serve --sim` while a good client reads joint states.

Starts the simulated bridge in its own process on free 127.0.0.1 ports (``--batch`` ticks per wake), then
:func:`harness.link.flood.measure_flood`: ``--big`` frames of 4 MiB (the protocol's limit), ``--small`` small
malformed frames and ``--oversize`` frames of 50 MB from one peer. Prints the good client's state rate
(share of nominal), its largest gap, whether the link was lost, and the bridge's memory peak over idle.
"""

from __future__ import annotations

import argparse
import json

from harness.link.flood import measure_flood
from harness.link.spawn_bridge import SimBridgeProcess

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--big", type=int, default=64, help="frames of 4 MiB (default 64)")
    parser.add_argument("--small", type=int, default=2000, help="small malformed frames (default 2000)")
    parser.add_argument("--oversize", type=int, default=8, help="frames of 50 MB, over the limit (default 8)")
    parser.add_argument("--batch", type=int, default=1, help="the bridge's ticks per wake (default 1: every state "
                                                              "as its tick comes)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    for name in ("big", "small", "oversize"):
        if not 0 <= getattr(args, name) <= 100000:
            raise ValueError(f"--{name} must be in [0, 100000], got {getattr(args, name)!r}")
    with SimBridgeProcess("--batch", str(args.batch)) as bridge:
        res = measure_flood(bridge.address, bridge.ready["pid"], n_big=args.big, n_small=args.small,
                            n_oversize=args.oversize, seed=args.seed)
        log = bridge.stop()
    res["bridge_log_lines"] = len(log.splitlines())
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"link flood: {res['n_big']} x {res['big_bytes']} B + {res['n_small']} small + {res['n_oversize']} x "
          f"{res['oversize_bytes']} B from one peer, over {res['flood_s']:.2f} s")
    for key, label in (("rate_share", "good client's states / nominal"), ("max_gap_ms", "largest gap (ms)"),
                       ("p99_gap_ms", "p99 gap (ms)"), ("link_lost", "link lost"),
                       ("rss_peak_over_idle_mb", "bridge RSS peak over idle (MB)"),
                       ("bridge_log_lines", "bridge log lines")):
        print(f"  {label:34} {res[key]}")
    return 0
