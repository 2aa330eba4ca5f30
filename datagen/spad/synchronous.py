"""Synchronous (re-armed every laser cycle) models: ``poisson``, ``pile_up`` (first photon, Coates 1968) and
``multi_stop``.  Exact samplers (sequential conditional binomials, or the same on a binary tree of bins) run
over fixed pixel chunks with independent child streams of the caller's generator, in threads, so the draws
depend only on the generator's state (docs/physics.md §6)."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from numba import njit

from .arrays import as_rates, exclusive_cumsum
from .config import DetectorConfig
from .models import DetectorModel, register_model

__all__ = [
    "SAMPLER_PIXEL_CHUNK",
    "POISSON_NORMAL_ABOVE",
    "MAX_EXPECTED_COUNTS",
    "detection_pmf",
    "first_photon_sequential",
    "first_photon_tree",
    "SEQUENTIAL_MAX_BINS",
    "SEQUENTIAL_MIN_PIXELS",
    "sample_first_photon",
    "multi_stop_dead_bins",
    "multi_stop_expected",
    "multi_stop_sample",
    "sample_poisson",
]


SAMPLER_PIXEL_CHUNK = 512
"""Pixels per independent random stream in the threaded samplers.  Fixed, so results do not depend on the
number of worker threads."""

POISSON_NORMAL_ABOVE = 1e12
"""Expected counts λ of a bin above which the ``poisson`` model draws round(N(λ, λ)), clipped at 0, instead of
``rng.poisson(λ)``. numpy's Poisson sampler (2.x) refuses λ ≳ 9.2e18 and is already wrong well below that: with
10⁶ draws its variance is off by +1.7 % at λ = 3e13 (12 standard errors), +4 % at 1e15 and +40–60 % at 1e16–1e17,
while it matches λ to 0.1 % up to 1e13. At λ ≥ 1e12 the normal approximation differs from Poisson(λ) by at most
≈ the Edgeworth skewness term 1/(6√λ) ≤ 1.7e-7 in the CDF; rounding shifts the mean by < 0.5 count and adds 1/12
to the variance (≤ 1e-12 relative): far below the relative noise 1/√λ ≤ 1e-6 itself."""

MAX_EXPECTED_COUNTS = 9.0e18
"""Largest expected counts n·r_i of one bin the ``poisson`` model accepts: counts are int64 (max 9.22e18); the
margin covers fluctuations (10σ = 3e10). Jitter after pile-up keeps a bin's expectation ≤ the largest one (its
kernel sums to 1), so it cannot overflow either."""


def _child_generators(rng: np.random.Generator, count: int) -> list[np.random.Generator]:
    """``count`` independent generators derived deterministically from ``rng`` (advances ``rng``)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    entropy = rng.integers(0, 2**63, size=4, dtype=np.int64)
    seeds = np.random.SeedSequence([int(x) for x in entropy]).spawn(count)
    return [np.random.Generator(type(rng.bit_generator)(s)) for s in seeds]


def _workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def _run_chunked(func, arrays: list[np.ndarray], rng: np.random.Generator) -> list:
    """Apply ``func(gen, *chunk_arrays)`` to fixed pixel chunks of 2-D ``arrays`` with one random stream per
    chunk, in threads (numpy's samplers release the GIL).  Deterministic whatever the thread count."""
    n_pix = arrays[0].shape[0]
    bounds = list(range(0, n_pix, SAMPLER_PIXEL_CHUNK)) + [n_pix] if n_pix else [0, 0]
    gens = _child_generators(rng, len(bounds) - 1)
    jobs = [(gens[k], *[a[bounds[k]:bounds[k + 1]] for a in arrays]) for k in range(len(bounds) - 1)]
    workers = min(_workers(), len(jobs))
    if workers <= 1:
        return [func(*job) for job in jobs]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(lambda job: func(*job), jobs))


def detection_pmf(rates: Any) -> np.ndarray:
    """First-detection probabilities of one synchronous laser cycle (Coates 1968; docs/physics.md §6).

    ``pmf[..., i] = exp(−C_i)·(−expm1(−r_i))`` for ``i < bins`` and ``pmf[..., bins] = exp(−Λ)`` (no
    detection), with ``C_i`` the exclusive float64 cumulative sum.  Sums to 1 (to ~1e-13) for any rates,
    including zeros, 1e-300 and Λ ~ 1e4 (no NaN/inf: exp underflows to 0).

    Args:
        rates: (..., bins) expected avalanches per cycle per bin, ≥ 0 (float32 accepted).
    Returns:
        float64 (..., bins + 1).
    Raises:
        ValueError: NaN, inf or negative rates.
    """
    r = as_rates(rates)
    c, lam = exclusive_cumsum(r)
    out = np.empty(r.shape[:-1] + (r.shape[-1] + 1,))
    np.multiply(np.exp(-c), -np.expm1(-r), out=out[..., :-1])
    out[..., -1] = np.exp(-lam)
    return out


def first_photon_sequential(gen: np.random.Generator, r: np.ndarray, n: int) -> np.ndarray:
    """Exact first-photon (pile-up) counts of ``n`` synchronous laser cycles by sequential conditional binomials
    ``N_i ~ Bin(D_i, 1 − e^{−r_i})``, ``D_0 = n``, ``D_{i+1} = D_i − N_i`` (docs/physics.md §6), bin by bin over all
    pixels of the chunk (compiled; the same draws as one vectorised ``gen.binomial`` call per bin).

    Args:
        gen: numpy Generator (advanced by the call).
        r: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0 (not checked).
        n: number of laser cycles (int ≥ 0).
    Returns:
        int64 (pixels, bins) counts; each row sums to at most ``n``.  Same distribution as
        :func:`first_photon_tree` (but other draws for the same ``gen``).
    """
    return _sequential_binomials(gen, -np.expm1(-r), int(n))


@njit(cache=True, nogil=True)
def _sequential_binomials(gen, p, n):
    """The draws of :func:`first_photon_sequential`, compiled: for each bin i in turn, ``gen.binomial(D_j, p[j, i])``
    for pixels j = 0, 1, … (numba's binomial is numpy's algorithm: the same numbers, in the same order, as one
    vectorised ``gen.binomial(D, p[:, i])`` call per bin, without a Python call per bin). p (pixels, bins) float64."""
    n_pix, bins = p.shape
    out = np.zeros((n_pix, bins), dtype=np.int64)
    remaining = np.full(n_pix, n, dtype=np.int64)
    for i in range(bins):
        left = False
        for j in range(n_pix):
            k = gen.binomial(remaining[j], p[j, i])
            out[j, i] = k
            remaining[j] -= k
            left = left or remaining[j] > 0
        if not left:
            break
    return out


def first_photon_tree(gen: np.random.Generator, r: np.ndarray, n: int) -> np.ndarray:
    """The same multinomial drawn top-down on a binary tree of bin blocks: the number of cycles detecting in a
    block is split between its halves with ``P(left | block) = (1 − e^{−R_left}) / (1 − e^{−R_block})`` (the
    e^{−C} factors cancel, so no cancellation; block sums are pairwise).  Exact; log2(bins) vectorised calls,
    which is what makes 10^6 bins fast.

    Args:
        gen: numpy Generator (advanced by the call).
        r: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0 (not checked).
        n: number of laser cycles (int ≥ 0).
    Returns:
        int64 (pixels, bins) counts; each row sums to at most ``n``.
    """
    n_pix, bins = r.shape
    size = 1 << max(0, (bins - 1).bit_length())
    leaf = np.zeros((n_pix, size))
    leaf[:, :bins] = r
    levels = [leaf]
    while levels[-1].shape[1] > 1:
        levels.append(levels[-1].reshape(n_pix, -1, 2).sum(axis=-1))
    counts = gen.binomial(n, -np.expm1(-levels[-1][:, 0]))[:, None].astype(np.int64)
    for lev in range(len(levels) - 2, -1, -1):
        child = levels[lev].reshape(n_pix, -1, 2)
        parent = -np.expm1(-levels[lev + 1])
        left = -np.expm1(-child[..., 0])
        p = np.divide(left, parent, out=np.zeros_like(left), where=parent > 0)
        np.minimum(p, 1.0, out=p)
        n_left = gen.binomial(counts, p)
        counts = np.stack([n_left, counts - n_left], axis=-1).reshape(n_pix, -1)
    return counts[:, :bins]


SEQUENTIAL_MAX_BINS = 4096
"""Histograms with up to this many bins are drawn by sequential binomials (fastest for image-sized arrays);
longer ones by the binary tree (log2(bins) Python calls instead of bins)."""

SEQUENTIAL_MIN_PIXELS = 64
"""Below this many pixels the per-bin Python calls of the sequential draw dominate (a single-pixel 1536-bin
draw took 14 ms), so the binary tree is used whatever the bin count (~0.3 ms)."""


def sample_first_photon(rates2d: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exact multinomial first-photon counts of (pixels, bins) rates over n cycles (int64).

    Draws with :func:`first_photon_sequential` (at least SEQUENTIAL_MIN_PIXELS pixels and at most
    SEQUENTIAL_MAX_BINS bins) or :func:`first_photon_tree`, in fixed chunks of SAMPLER_PIXEL_CHUNK pixels with
    independent child streams of ``rng``, in threads (the result does not depend on the thread count).

    Args:
        rates2d: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0.
        n: number of laser cycles.
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) counts.
    """
    sequential = rates2d.shape[1] <= SEQUENTIAL_MAX_BINS and rates2d.shape[0] >= SEQUENTIAL_MIN_PIXELS
    draw = first_photon_sequential if sequential else first_photon_tree
    return np.concatenate(_run_chunked(lambda gen, rr: draw(gen, rr, n), [rates2d], rng), axis=0)


def multi_stop_dead_bins(config: DetectorConfig) -> int:
    """Bins blocked after a detection in the ``multi_stop`` model: ``d = round(dead_time / bin_width)`` (int ≥ 0)."""
    return int(round(config.dead_time / config.bin_width))


def multi_stop_expected(r2: np.ndarray, n: int, d: int) -> np.ndarray:
    """Exact expected counts of the discrete multi-stop model: ``E[N_i] = L_i p_i``,
    ``L_{i+1} = L_i − E[N_i] + E[N_{i−d}]``, ``L_0 = n``.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0.
        n: number of laser cycles; d: dead bins (:func:`multi_stop_dead_bins`).
    Returns:
        float64 (pixels, bins) expected counts over the ``n`` cycles.
    """
    p = -np.expm1(-r2)
    bins = r2.shape[1]
    out = np.zeros_like(r2)
    live = np.full(r2.shape[0], float(n))
    for i in range(bins):
        out[:, i] = live * p[:, i]
        live = live - out[:, i]
        if i - d >= 0:
            live = live + out[:, i - d]
    return out


def multi_stop_sample(r2: np.ndarray, n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    """Exact sampler of the discrete multi-stop model: the cycles are exchangeable, so it suffices to track
    how many are live: ``N_i ~ Bin(L_i, p_i)``, ``L_{i+1} = L_i − N_i + N_{i−d}``.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0.
        n: number of laser cycles; d: dead bins (:func:`multi_stop_dead_bins`).
        rng: numpy Generator (advanced by the call); pixels are drawn in chunks of SAMPLER_PIXEL_CHUNK with
            independent child streams, in threads.
    Returns:
        int64 (pixels, bins) counts.
    """
    p = -np.expm1(-r2)

    def draw(gen, pp):
        out = np.zeros(pp.shape, dtype=np.int64)
        live = np.full(pp.shape[0], n, dtype=np.int64)
        for i in range(pp.shape[1]):
            ni = gen.binomial(live, pp[:, i])
            out[:, i] = ni
            live -= ni
            if i - d >= 0:
                live += out[:, i - d]
        return out

    return np.concatenate(_run_chunked(draw, [p], rng), axis=0)


def sample_poisson(lam: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """int64 counts ~ Poisson(lam) for (pixels, bins) expected counts; round(N(λ, λ)) clipped at 0 where
    λ > POISSON_NORMAL_ABOVE (the same draws as ``rng.poisson(lam)`` when no bin is that large).

    Args:
        lam: float64 (pixels, bins) expected counts over the exposure (``n_cycles × rates``), ≥ 0.
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) counts.
    Raises:
        ValueError: a bin expects more than MAX_EXPECTED_COUNTS counts (int64 overflow).
    """
    if np.any(lam > MAX_EXPECTED_COUNTS):
        raise ValueError(
            f"poisson detector: a bin expects {float(lam.max()):.3g} counts per exposure (n_cycles × rate), "
            f"more than int64 counts can hold (limit {MAX_EXPECTED_COUNTS:.3g}): the flux is too high. Lower the "
            f"laser's photons_per_pulse (or pulse_energy), the PDE, the aperture, n_cycles or the exposure")
    big = lam > POISSON_NORMAL_ABOVE
    if not big.any():
        return rng.poisson(lam).astype(np.int64, copy=False)
    counts = rng.poisson(np.where(big, 0.0, lam)).astype(np.int64)
    lam_big = lam[big]
    counts[big] = np.maximum(np.rint(lam_big + np.sqrt(lam_big) * rng.standard_normal(lam_big.size)),
                             0.0).astype(np.int64)
    return counts


# -- registry entries (datagen/spad/models.py): (..., T) rates in, (..., T) counts out ------------------------

def _rows(rates: np.ndarray) -> np.ndarray:
    return rates.reshape(-1, rates.shape[-1])


def _poisson_expected(rates: np.ndarray, config: DetectorConfig) -> np.ndarray:
    return config.cycles * rates


def _poisson_sample(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    return sample_poisson(config.cycles * _rows(rates), rng).reshape(rates.shape)


def _pile_up_expected(rates: np.ndarray, config: DetectorConfig) -> np.ndarray:
    return (config.cycles * detection_pmf(_rows(rates))[:, :-1]).reshape(rates.shape)


def _pile_up_sample(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    if config.crosstalk_probability > 0:             # event simulation of the (…, H, W) array
        from .effects import sample_pile_up_crosstalk
        return sample_pile_up_crosstalk(rates, config, rng).reshape(rates.shape)
    return sample_first_photon(_rows(rates), config.cycles, rng).reshape(rates.shape)


def _multi_stop_expected(rates: np.ndarray, config: DetectorConfig) -> np.ndarray:
    return multi_stop_expected(_rows(rates), config.cycles, multi_stop_dead_bins(config)).reshape(rates.shape)


def _multi_stop_sample(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    return multi_stop_sample(_rows(rates), config.cycles, multi_stop_dead_bins(config), rng).reshape(rates.shape)


register_model(DetectorModel("poisson", _poisson_expected, _poisson_sample, dead_time="none", torch_noise=True,
                             fittable=True, description="low-flux limit: independent Poisson counts per bin"))
register_model(DetectorModel("pile_up", _pile_up_expected, _pile_up_sample, dead_time="synchronous",
                             torch_noise=True, fittable=True, crosstalk=True,
                             description="synchronous first photon per cycle (Coates 1968)"))
register_model(DetectorModel("multi_stop", _multi_stop_expected, _multi_stop_sample, dead_time="synchronous",
                             description="several detections per cycle, a dead time in bins after each"))
