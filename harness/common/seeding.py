"""Randomness is passed in: a function that draws random numbers takes ``seed=`` or ``rng=``, never OS entropy.

    rng = rng_from(seed, rng, "BallLauncher")   # exactly one of the two, else ValueError naming the caller

Sweeps split their run seed per task index (``np.random.SeedSequence(seed).spawn(n)[i]`` or a
``spawn_key`` with the task's coordinates), never per worker, so the figures do not depend on how many
workers ran or on which backend (:mod:`harness.common.executor`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rng_from"]


def rng_from(seed, rng, who: str) -> np.random.Generator:
    """The generator of ``who``: ``rng`` itself, or ``np.random.default_rng(seed)``.

    seed : int >= 0 or a ``np.random.SeedSequence``; rng : ``np.random.Generator``. Exactly one must be
    given: with neither, the caller would silently draw from OS entropy and not be reproducible.
    """
    if rng is not None and seed is not None:
        raise ValueError(f"{who}: give either seed or rng, not both")
    if rng is not None:
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"{who}: rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return rng
    if seed is None:
        raise ValueError(f"{who}: a seed or an rng (numpy.random.Generator) is required, so that the run is reproducible")
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"{who}: seed must be an integer >= 0 or a numpy SeedSequence, got {seed!r}")
    return np.random.default_rng(int(seed))
