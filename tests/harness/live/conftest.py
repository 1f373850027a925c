"""Fixtures of the live service's tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def first_serve_only(monkeypatch):
    """The sim source's default scene (:class:`~harness.live.sources.sim.LauncherFlights`) with its first launcher serve
    alone instead of 8 drawn up front (~0.25 s each: 2 of the ~2.5 s a service took to open). For services that loop a
    pre-rendered clip shorter than that serve (1.3-1.5 s for seeds 0-5): their images, and ``rt2 bench live``'s truth (the
    clip's frame ids), come from the first serve only, the same as with 8. Checked: asking for a time past the first
    serve (where 8 serves would give another) fails the test."""
    from harness.live.sources import sim

    class FirstServe(sim.LauncherFlights):
        def __init__(self, seed, **kw):
            kw.setdefault("n_serves", 1)
            super().__init__(seed, **kw)

        def ball_state(self, t_s):
            assert 0 <= t_s < self.cycle_s, f"scene time {t_s} s is past the first serve ({self.cycle_s} s): use the 8 serves"
            return super().ball_state(t_s)

    monkeypatch.setattr(sim, "LauncherFlights", FirstServe)
    return FirstServe
