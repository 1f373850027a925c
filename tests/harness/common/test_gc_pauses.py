"""frozen_gc: what is alive at the start is frozen for the block and unfrozen after it; collections are counted."""

from __future__ import annotations

import gc

import pytest

from harness.common.gc_pauses import GcPauses, frozen_gc


def test_the_block_freezes_counts_and_restores():
    assert gc.get_freeze_count() == 0
    pauses = GcPauses()
    with frozen_gc(pauses) as got:
        assert got is pauses and gc.get_freeze_count() > 0
        gc.collect()  # a full collection inside the block is counted
    assert gc.get_freeze_count() == 0 and pauses.on_gc not in gc.callbacks
    s = pauses.summary()
    assert s["collections_per_generation"][2] >= 1 and s["pause_max_ms"] >= 0 and s["pause_total_ms"] >= s["pause_max_ms"]
    gc.collect()  # after the block: not counted
    assert pauses.summary()["collections_per_generation"] == s["collections_per_generation"]


def test_it_leaves_a_freeze_it_did_not_make_and_cleans_up_on_errors():
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with pytest.raises(RuntimeError), frozen_gc(GcPauses()):
            raise RuntimeError("the loop failed")
        # the caller's freeze stays: not unfrozen (0), not frozen again (the objects made since would join it); a frozen
        # object can still die (another thread's garbage, a test's leftovers), so the count may fall a little, never rise
        assert 0 < gc.get_freeze_count() <= frozen
        assert gc.get_freeze_count() > 0.9 * frozen
    finally:
        gc.unfreeze()
    with frozen_gc(GcPauses(), freeze=False):
        assert gc.get_freeze_count() == 0
