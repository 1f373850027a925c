"""``rt2 cache clear``: empty the disk cache of the simulated lab's slow parts (harness/common/disk_cache.py); the
next process that needs an entry computes it again."""

from __future__ import annotations

from harness.cli.cache_info import describe, megabytes
from harness.common import disk_cache

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    del parser  # no options


def run(args) -> int:
    del args
    before = disk_cache.clear()
    if before["location"] is None:
        print(describe(before))
        return 0
    n = sum(before.get("entries", {}).values())
    print(f"the disk cache at {before['location']}: {n} entries ({megabytes(before['bytes'])}) removed")
    return 0
