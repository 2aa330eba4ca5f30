"""Detector timing response and optical crosstalk.

* Bin-integrated timing kernels: Gaussian avalanche/electronic/TDC jitter (applied AFTER pile-up) and the
  SPAD diffusion tail (applied BEFORE pile-up, in :func:`datagen.spad.rates.rates_from_envelope`); see
  docs/physics.md §6 for the order.  :func:`instrument_response` is the low-flux IRF (docs/physics.md §5).
* Prompt optical crosstalk to 4-neighbours in a synchronous (``pile_up``) array, by event simulation.

Gating and TDC non-linearity (DNL) act on the rates: :mod:`datagen.spad.rates`; afterpulsing depends on the
recorded history and lives in the free-running event simulation (:mod:`datagen.spad.free_running`).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from scipy import special

from ..timing.irf import ex_gaussian_cdf
from .arrays import as_rates, check_event_count, row_search
from .config import DetectorConfig

__all__ = [
    "GAUSS_TAIL_SIGMAS",
    "EXP_TAIL_LENGTHS",
    "MAX_KERNEL_TAPS",
    "DIRECT_CONVOLUTION_TAPS",
    "gaussian_kernel",
    "exponential_kernel",
    "convolve_last",
    "apply_jitter_before",
    "apply_jitter_after",
    "jitter_counts",
    "instrument_response",
    "sample_pile_up_crosstalk",
]


GAUSS_TAIL_SIGMAS = 9.0
"""Gaussian kernels are truncated at ±9σ (lost mass < 1e-18) and renormalised."""

EXP_TAIL_LENGTHS = 45.0
"""Exponential kernels are truncated after 45 time constants (lost mass < 3e-20) and renormalised."""

MAX_KERNEL_TAPS = 1_000_001
"""Refuse kernels longer than this (a jitter larger than ~ the whole histogram is a configuration error)."""

DIRECT_CONVOLUTION_TAPS = 64
"""Kernels up to this length are applied by exact shift-and-add (no FFT round-off); longer ones by FFT."""


def _second_difference_kernel(antiderivative, offsets: np.ndarray, width: float) -> np.ndarray:
    """``K_k = [G((k+1)Δ) − 2G(kΔ) + G((k−1)Δ)]/Δ``: the bin-to-bin kernel of a CDF with antiderivative G for
    a source uniform within its bin (exact for piecewise-constant rates)."""
    x = offsets * width
    return (antiderivative(x + width) - 2.0 * antiderivative(x) + antiderivative(x - width)) / width


def gaussian_kernel(sigma: float, bin_width: float) -> tuple[np.ndarray, int]:
    """Bin-integrated zero-mean Gaussian kernel for piecewise-constant (binned) input.

    Args:
        sigma: standard deviation in s (≥ 0); bin_width: s (> 0).
    Returns:
        ``(kernel, first_offset)``: float64 taps summing to 1 for bin offsets ``first_offset, first_offset+1, …``
        (output bin = input bin + offset).  ``sigma == 0`` gives ``([1.0], 0)``.
    Raises:
        ValueError: negative sigma, non-positive bin width, or a kernel longer than MAX_KERNEL_TAPS.
    """
    if sigma < 0 or bin_width <= 0:
        raise ValueError(f"need sigma >= 0 and bin_width > 0, got sigma={sigma!r}, bin_width={bin_width!r}")
    if sigma == 0:
        return np.ones(1), 0
    half = int(math.ceil(GAUSS_TAIL_SIGMAS * sigma / bin_width)) + 1
    if 2 * half + 1 > MAX_KERNEL_TAPS:
        raise ValueError(f"jitter sigma={sigma!r} s is too wide for bin_width={bin_width!r} s")
    offsets = np.arange(-half, half + 1, dtype=np.float64)

    def antiderivative(x):  # ∫ Φ(x/σ) dx
        z = x / sigma
        return x * special.ndtr(z) + sigma * np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)

    k = np.maximum(_second_difference_kernel(antiderivative, offsets, bin_width), 0.0)
    return k / k.sum(), -half


def exponential_kernel(tau: float, bin_width: float, fraction: float = 1.0) -> tuple[np.ndarray, int]:
    """Bin-integrated causal kernel ``(1 − fraction)·δ(t) + fraction·Exp(mean tau)`` (SPAD diffusion tail).

    Args:
        tau: exponential time constant in s (≥ 0); bin_width: s (> 0); fraction in [0, 1].
    Returns:
        ``(kernel, 0)``: float64 taps summing to 1 for offsets 0, 1, …
    Raises:
        ValueError: invalid arguments or a kernel longer than MAX_KERNEL_TAPS.
    """
    if tau < 0 or bin_width <= 0 or not 0 <= fraction <= 1:
        raise ValueError(f"need tau >= 0, bin_width > 0, 0 <= fraction <= 1; got {tau!r}, {bin_width!r}, {fraction!r}")
    if tau == 0 or fraction == 0:
        return np.ones(1), 0
    n = int(math.ceil(EXP_TAIL_LENGTHS * tau / bin_width)) + 2
    if n > MAX_KERNEL_TAPS:
        raise ValueError(f"diffusion_tail={tau!r} s is too long for bin_width={bin_width!r} s")
    offsets = np.arange(n, dtype=np.float64)

    def antiderivative(x):  # ∫ (1 − e^{−x/τ}) dx for x ≥ 0
        xp = np.maximum(x, 0.0)
        return xp + tau * np.expm1(-xp / tau)

    k = np.maximum(_second_difference_kernel(antiderivative, offsets, bin_width), 0.0)
    k = fraction * k / k.sum()
    k[0] += 1.0 - fraction
    return k, 0


@njit(cache=True)
def _shift_and_add(x: np.ndarray, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """:func:`convolve_last`'s exact path for rows ``x`` (rows, bins) float64: each tap in turn adds its weight
    times the shifted row (one product and one sum per element and tap, in tap order)."""
    n_rows, n = x.shape
    out = np.zeros((n_rows, n))
    for r in range(n_rows):
        for k in range(kernel.shape[0]):
            shift = first_offset + k
            w = kernel[k]
            for i in range(max(shift, 0), min(n, n + shift)):
                out[r, i] += w * x[r, i - shift]
    return out


def convolve_last(x: np.ndarray, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """out[..., i] = Σ_k kernel[k]·x[..., i − (first_offset + k)], truncated to the input's bins.

    Kernels up to DIRECT_CONVOLUTION_TAPS taps are applied by exact shift-and-add, longer ones by FFT
    (``scipy.signal.oaconvolve``, negative round-off clamped to 0).

    Args:
        x: float64 (..., bins) rates or expected counts per bin.
        kernel: float64 (taps,) weights per bin offset, e.g. from :func:`gaussian_kernel`.
        first_offset: bin offset of ``kernel[0]`` (output bin = input bin + offset).
    Returns:
        float64 (..., bins); mass shifted outside the window is lost.
    """
    n = x.shape[-1]
    if kernel.size == 1 and first_offset == 0:
        return x * kernel[0]
    if kernel.size <= DIRECT_CONVOLUTION_TAPS:
        rows = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, n)
        return _shift_and_add(rows, np.asarray(kernel, dtype=np.float64), int(first_offset)).reshape(x.shape)
    from scipy.signal import oaconvolve

    kern = kernel.reshape((1,) * (x.ndim - 1) + (-1,))
    full = oaconvolve(x, kern, mode="full", axes=-1)
    # full[m] = Σ_j x[j] kernel[m − j]; output index i = m + first_offset.
    start = -first_offset
    idx = np.arange(n) + start
    valid = (idx >= 0) & (idx < full.shape[-1])
    out = np.zeros_like(x)
    out[..., valid] = full[..., idx[valid]]
    return np.maximum(out, 0.0)  # FFT round-off


def apply_jitter_before(rates: Any, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """Convolve per-cycle avalanche rates with a timing kernel BEFORE pile-up (laser pulse shape, diffusion tail).

    Use it for processes that delay photons before the first-photon race is decided.  Compared with
    :func:`apply_jitter_after` at the same kernel the result agrees to O(Λ) at low flux; at high flux the
    before-order keeps the pile-up skew of the blurred rates (the histogram shape is
    ``e^{-C}(1-e^{-r})`` of the blurred rates), whereas the after-order blurs an already skewed histogram.
    Both preserve the total detection probability ``1 − e^{−Λ}`` when no mass leaves the window.

    Args:
        rates: (..., bins) expected avalanches per cycle per bin.
        kernel, first_offset: from :func:`gaussian_kernel` / :func:`exponential_kernel`.
    Returns:
        float64 (..., bins); mass shifted outside the window is lost.
    """
    return convolve_last(as_rates(rates), np.asarray(kernel, dtype=np.float64), int(first_offset))


def apply_jitter_after(histogram: Any, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """Convolve an expected histogram with a timing kernel AFTER pile-up (electronic/TDC jitter).

    Args:
        histogram: (..., bins) expected counts (float64 result).
        kernel, first_offset: from :func:`gaussian_kernel`.
    Returns:
        float64 (..., bins); counts shifted outside the window are lost.
    """
    h = np.asarray(histogram, dtype=np.float64)
    return convolve_last(h, np.asarray(kernel, dtype=np.float64), int(first_offset))


def jitter_counts(counts: np.ndarray, kernel: np.ndarray, first_offset: int,
                   rng: np.random.Generator) -> np.ndarray:
    """Move every count by an independent kernel-distributed bin offset (exact multinomial redistribution
    drawn as sequential conditional binomials over the taps).

    Args:
        counts: int64 (..., bins) counts of one exposure.
        kernel: float64 (taps,) probabilities of the bin offsets, summing to 1 (:func:`gaussian_kernel`).
        first_offset: bin offset of ``kernel[0]`` (output bin = input bin + offset).
        rng: numpy Generator (advanced by the call; not used for a one-tap kernel).
    Returns:
        int64 (..., bins); counts moved outside the window are lost.  A one-tap kernel returns ``counts``
        itself.
    """
    if kernel.size == 1:
        return counts
    n = counts.shape[-1]
    out = np.zeros_like(counts)
    remaining = counts.copy()
    tail = np.cumsum(kernel[::-1])[::-1]  # mass of taps k..end
    for k, w in enumerate(kernel):
        if k == kernel.size - 1:
            moved = remaining
        else:
            prob = min(1.0, w / tail[k]) if tail[k] > 0 else 0.0
            moved = rng.binomial(remaining, prob)
            remaining = remaining - moved
        shift = first_offset + k
        if shift >= n or -shift >= n:
            continue
        if shift >= 0:
            out[..., shift:] += moved[..., : n - shift]
        else:
            out[..., : n + shift] += moved[..., -shift:]
    return out


def instrument_response(config: DetectorConfig, n_bins: int, first_bin: int = 0) -> np.ndarray:
    """Low-flux instrument response of the detector for a photon arriving uniformly in bin ``first_bin``.

    This is the continuous ex-Gaussian (``scipy.stats.exponnorm``: Gaussian σ = ``config.jitter`` convolved
    with the diffusion tail) mixed with the pure Gaussian core for ``1 − diffusion_fraction``, integrated over
    the bins (docs/physics.md §5).  At low flux :func:`expected_histogram` of a one-bin envelope equals
    ``n_cycles × r × instrument_response`` up to the piecewise-constant approximation inside bins.

    Args:
        config: detector description (uses jitter, diffusion_tail, diffusion_fraction, bin_width).
        n_bins: length of the returned histogram; first_bin: bin in which the photon arrives.
    Returns:
        float64 (n_bins,) probabilities (sum ≤ 1; mass outside the window is lost).
    """
    dt = config.bin_width
    sigma, tau, f = config.jitter, config.diffusion_tail, config.diffusion_fraction
    nodes, weights = np.polynomial.legendre.leggauss(64)
    s = (nodes + 1.0) * 0.5 * dt  # source position within its bin
    w = weights * 0.5
    edges = (np.arange(n_bins + 1) - first_bin) * dt

    def cdf(x):
        if sigma == 0 and tau == 0:
            return (x >= 0).astype(float)
        if tau == 0 or f == 0:
            core = special.ndtr(x / sigma) if sigma > 0 else (x >= 0).astype(float)
            return core
        if sigma == 0:
            tail = np.where(x > 0, -np.expm1(-np.maximum(x, 0) / tau), 0.0)
            return (1 - f) * (x >= 0) + f * tail
        tail = ex_gaussian_cdf(x, sigma, tau)
        return (1 - f) * special.ndtr(x / sigma) + f * tail

    c = np.zeros(n_bins + 1)
    for si, wi in zip(s, w):
        c += wi * cdf(edges - si)
    return np.maximum(np.diff(c), 0.0)


def _neighbour_table(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(neighbours (h·w, 4) flat indices padded with -1, count (h·w,)) of the 4-neighbourhood."""
    idx = np.arange(h * w).reshape(h, w)
    nb = np.full((h, w, 4), -1, dtype=np.int64)
    nb[1:, :, 0] = idx[:-1, :]
    nb[:-1, :, 1] = idx[1:, :]
    nb[:, 1:, 2] = idx[:, :-1]
    nb[:, :-1, 3] = idx[:, 1:]
    nb = nb.reshape(h * w, 4)
    order = np.argsort(nb < 0, axis=1, kind="stable")  # valid neighbours first
    nb = np.take_along_axis(nb, order, axis=1)
    return nb, (nb >= 0).sum(axis=1)


def sample_pile_up_crosstalk(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Pile-up histograms of an (..., H, W, bins) array with prompt optical crosstalk, by event simulation of
    the cycles in which something happens.

    Per pixel, the set of cycles with a primary avalanche is a uniformly random subset of size
    ``K ~ Bin(n, 1 − e^{−Λ})``; in each, the first primary avalanche time is drawn from the piecewise-constant
    intensity (continuous time).  Every avalanche triggers, with ``crosstalk_probability``, an avalanche at the
    same instant in one uniformly chosen 4-neighbour; each pixel records its earliest avalanche of the cycle
    (primary or crosstalk) and is then held until the next cycle.  Cascades are followed to a fixed point.
    Cost O(avalanches), so low-flux exposures of 10^6 cycles are cheap.

    Args:
        rates: float64 (..., H, W, bins) expected avalanches per laser cycle per bin of an H×W array.
        config: detector description (cycles, bin widths in s, crosstalk_probability).
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (..., H, W, bins) counts over ``config.cycles`` cycles, before the after-pile-up jitter.
    Raises:
        ValueError: ``rates`` has fewer than 3 dimensions; more cycles with an avalanche than
            MAX_SIMULATED_EVENTS (:func:`datagen.spad.arrays.check_event_count`).
    """
    if rates.ndim < 3:
        raise ValueError(f"crosstalk_probability > 0 models a pixel array and needs rates of shape (..., H, W, bins), "
                         f"got {rates.shape}; use a detector without crosstalk for a single-pixel capture")
    h, w, bins = rates.shape[-3:]
    n_pix = h * w
    n = config.cycles
    check_event_count(float(-np.expm1(-rates.sum(axis=-1)).sum()) * n, "pile_up crosstalk event simulation")
    widths = config.widths(bins)
    edges = np.concatenate([[0.0], np.cumsum(widths)])
    neighbours, n_nb = _neighbour_table(h, w)
    frames = rates.reshape(-1, n_pix, bins)
    out = np.zeros(frames.shape, dtype=np.int64)
    p_ct = config.crosstalk_probability

    def draw_destinations(pixels):
        sends = rng.random(pixels.size) < p_ct
        choice = np.minimum((rng.random(pixels.size) * n_nb[pixels]).astype(np.int64), 3)
        dest = neighbours[pixels, choice]
        return np.where(sends & (n_nb[pixels] > 0), dest, -1)

    for f in range(frames.shape[0]):
        q = frames[f]
        cum = np.zeros((n_pix, bins + 1))
        np.cumsum(q, axis=1, out=cum[:, 1:])
        lam = cum[:, -1]
        p_hit = -np.expm1(-lam)
        k = rng.binomial(n, p_hit)
        cycles = np.concatenate([rng.choice(n, size=int(kk), replace=False) for kk in k]) if k.sum() else \
            np.zeros(0, dtype=np.int64)
        pix = np.repeat(np.arange(n_pix), k)
        target = -np.log1p(-rng.random(pix.size) * p_hit[pix])  # Exp(1) truncated to (0, Λ)
        target = np.clip(target, np.finfo(float).tiny, lam[pix])
        b = row_search(cum, pix, target)
        t = edges[b] + (target - cum[pix, b]) / q[pix, b] * widths[b]
        keys = cycles.astype(np.int64) * n_pix + pix
        order = np.argsort(keys)
        keys, t, pix = keys[order], t[order], pix[order]
        dest = draw_destinations(pix)
        changed = np.ones(keys.size, dtype=bool)
        while True:
            src = np.flatnonzero(changed & (dest >= 0))
            if src.size == 0:
                break
            cand_key = (keys[src] // n_pix) * n_pix + dest[src]
            cand_t = t[src]
            pos = np.searchsorted(keys, cand_key)
            exists = (pos < keys.size) & (keys[np.minimum(pos, keys.size - 1)] == cand_key)
            changed = np.zeros(keys.size, dtype=bool)
            # existing avalanches made earlier by crosstalk
            ep, et = pos[exists], cand_t[exists]
            earlier = et < t[ep]
            if earlier.any():
                np.minimum.at(t, ep[earlier], et[earlier])
                changed[ep[earlier]] = True
            # new avalanches in pixels that had none in that cycle
            new_key, new_t = cand_key[~exists], cand_t[~exists]
            if new_key.size:
                uniq, first = np.unique(new_key, return_index=True)
                best = np.full(uniq.size, np.inf)
                np.minimum.at(best, np.searchsorted(uniq, new_key), new_t)
                new_pix = uniq % n_pix
                keys = np.concatenate([keys, uniq])
                t = np.concatenate([t, best])
                pix = np.concatenate([pix, new_pix])
                dest = np.concatenate([dest, draw_destinations(new_pix)])
                changed = np.concatenate([changed, np.ones(uniq.size, dtype=bool)])
                order = np.argsort(keys, kind="stable")
                keys, t, pix, dest, changed = keys[order], t[order], pix[order], dest[order], changed[order]
        tb = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
        out[f] = np.bincount(pix * bins + tb, minlength=n_pix * bins).reshape(n_pix, bins)
    return out.reshape(rates.shape)
