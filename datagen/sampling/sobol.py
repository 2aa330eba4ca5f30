"""Scrambled Sobol sets, remembered across runs that draw the same set.

A scrambled Sobol set (:class:`scipy.stats.qmc.Sobol` with ``scramble=True, seed=rng``) is a function of its
generator's seed sequence alone: scipy spawns one child of ``rng``'s :class:`numpy.random.SeedSequence` to scramble
with and draws nothing from ``rng`` itself. A generator whose sequence is in the same state (entropy, spawn key,
pool size, children spawned so far) gets the same points. A capture sequence's changes draw from the same streams in
every frame (common random numbers, :mod:`datagen.simulation.sequence`), so their sets repeat frame after frame, and
scrambling one (about 0.25 ms) costs more than a small run's samples. :func:`scrambled_sobol` scrambles each set
once and, when a set repeats, spawns the child the scrambling would have spawned: the points and every later draw
are the same to the bit.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import qmc

MEMO_SETS = 32
"""Sets remembered (the oldest forgotten first): a sequence's change repeats three (area points, FoV paths, spot
samples)."""

MEMO_POINTS = 4096
"""Only sets of at most this many points are remembered (at most 160 KiB each): a change's are small; a full
simulation's replicas each draw their own sets, which never repeat."""

_memo: dict[tuple, np.ndarray] = {}


def scrambled_sobol(d: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """A scrambled Sobol set of ``samples`` points of [0,1]^d rounded up to a power of two, taken from the memo when
    ``rng``'s seed sequence is where it was when the set was scrambled (module docstring).

    Args:
        d: dimension (≥ 1).
        samples: requested count; the set has 2^ceil(log2(samples)) points (1 for samples ≤ 1).
        rng: the generator whose seed sequence scrambles the set.
    Returns:
        (2^m, d) float64, a new array.
    """
    m = max(0, int(np.ceil(np.log2(max(samples, 1)))))
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if not isinstance(seq, np.random.SeedSequence):
        return qmc.Sobol(d=d, scramble=True, seed=rng).random_base2(m)
    entropy = seq.entropy if isinstance(seq.entropy, int) else tuple(np.atleast_1d(seq.entropy).tolist())
    key = (d, m, type(rng.bit_generator).__name__, entropy, tuple(seq.spawn_key), seq.pool_size,
           seq.n_children_spawned)
    points = _memo.get(key)
    if points is not None:
        seq.spawn(1)                              # the child the scrambling spawns: later spawns stay in step
        return points.copy()
    points = qmc.Sobol(d=d, scramble=True, seed=rng).random_base2(m)
    if len(points) <= MEMO_POINTS:
        if len(_memo) >= MEMO_SETS:
            del _memo[next(iter(_memo))]
        _memo[key] = points.copy()
    return points
