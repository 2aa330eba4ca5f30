"""The area sampler's points of the unit square, its scrambled Sobol sets remembered across runs that draw the same.

A scrambled Sobol set of :func:`~datagen.sampling.surfaces.unit_square_points` is a function of its generator's seed
sequence alone: scipy's ``Sobol(seed=rng)`` spawns one child of ``rng``'s :class:`numpy.random.SeedSequence` to
scramble with and draws nothing from ``rng`` itself. A generator whose sequence is in the same state (entropy,
spawn key, pool size, children spawned so far) gets the same points. A capture sequence's changes draw from the same
streams in every frame (common random numbers, :mod:`datagen.simulation.sequence`), so their sets repeat frame after
frame, and scrambling one (about 0.25 ms, twice a run) costs more than a small run's samples. :func:`square_points`
scrambles each set once and, when a set repeats, spawns the child the scrambling would have spawned: the points and
every later draw are the same to the bit.
"""
from __future__ import annotations

import numpy as np

from ...sampling.surfaces import AreaSampling, unit_square_points

MEMO_SETS = 32
"""Sobol sets remembered (the oldest forgotten first): a sequence's change repeats two (FoV paths, spot samples)."""

MEMO_POINTS = 4096
"""Only sets of at most this many points are remembered (128 KiB each): a change's are small; a full simulation's
replicas each draw their own sets, which never repeat."""

_memo: dict[tuple, np.ndarray] = {}


def square_points(samples: int, method: AreaSampling, rng: np.random.Generator) -> np.ndarray:
    """:func:`~datagen.sampling.surfaces.unit_square_points` (``samples`` points of [0,1]⁴ by ``method``), a
    "sobol" set taken from the memo when ``rng``'s seed sequence is where it was when the set was scrambled (module
    docstring). Returns (n, 4) float64, a new array."""
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if method != "sobol" or not isinstance(seq, np.random.SeedSequence):
        return unit_square_points(samples, method, rng)
    entropy = seq.entropy if isinstance(seq.entropy, int) else tuple(np.atleast_1d(seq.entropy).tolist())
    key = (int(samples), type(rng.bit_generator).__name__, entropy, tuple(seq.spawn_key), seq.pool_size,
           seq.n_children_spawned)
    points = _memo.get(key)
    if points is not None:
        seq.spawn(1)                              # the child the scrambling spawns: later spawns stay in step
        return points.copy()
    points = unit_square_points(samples, method, rng)
    if len(points) <= MEMO_POINTS:
        if len(_memo) >= MEMO_SETS:
            del _memo[next(iter(_memo))]
        _memo[key] = points.copy()
    return points
