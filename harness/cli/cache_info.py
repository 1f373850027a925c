"""``rt2 cache info [--json]``: what the disk cache of the simulated lab's slow parts holds
(harness/common/disk_cache.py; README "The disk cache")."""

from __future__ import annotations

import json

from harness.common import disk_cache

__all__ = ["add_arguments", "describe", "megabytes", "run"]


def megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def describe(s: dict) -> str:
    """One line for a :func:`harness.common.disk_cache.summary`."""
    if s["location"] is None:
        return (f"the disk cache is off ({s['off_by']}): every process ray-casts the simulated lab and draws the "
                f"launcher's flights itself")
    kinds = ", ".join(f"{n} {kind}" for kind, n in s["entries"].items()) or "nothing"
    return (f"the disk cache at {s['location']}: {kinds}; {megabytes(s['bytes'])} of at most {megabytes(s['limit_bytes'])} "
            f"({disk_cache.CACHE_MAX_MB_ENV})")


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args) -> int:
    s = disk_cache.summary()
    print(json.dumps(s, indent=1) if args.json else describe(s))
    return 0
