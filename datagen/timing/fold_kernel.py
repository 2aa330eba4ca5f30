"""Compiled fold and binning of an accumulator's fine histogram, row by row over the nodes that hold weight (numba).

A fine-histogram row of a scanned capture holds weight on a few hundred of its thousands of nodes (one laser point's
returns); :class:`datagen.timing.EnvelopeAccumulator` folds its pending second differences (:func:`fold_rows`) and
convolves it with the fine-cell-integrated IRF and sums ``oversample`` nodes per output bin (:func:`bin_rows`) only
from each row's first to its last non-zero node, reaching out by the kernel's length. The sums run in the same
order as ``numpy.cumsum`` and as ``numpy.convolve(row, kernel, mode="valid")`` written out; nothing is
approximated (docs/physics.md §5).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["bin_rows", "fold_rows"]


@njit(cache=True, inline="always")
def _span(a, r) -> tuple:
    """[lo, hi): row r of ``a`` from its first to its last non-zero entry ((0, 0) if none)."""
    n = a.shape[1]
    lo = 0
    while lo < n and a[r, lo] == 0.0:
        lo += 1
    hi = n
    while hi > lo and a[r, hi - 1] == 0.0:
        hi -= 1
    return lo, hi


@njit(cache=True)
def fold_rows(hist: np.ndarray, curvature: np.ndarray) -> None:
    """hist[r] += the running sum of the running sum of curvature[r], for every row r of the (R, N) float64 arrays,
    from the row's first to its last non-zero second difference (beyond it the double sum of complete tents' second
    differences is zero, round-off aside). In place; ``curvature`` is left as it is."""
    for r in range(hist.shape[0]):
        lo, hi = _span(curvature, r)
        first = 0.0
        second = 0.0
        for j in range(lo, hi):
            first += curvature[r, j]
            second += first
            hist[r, j] += second


@njit(cache=True)
def bin_rows(hist: np.ndarray, rows: np.ndarray, kernel: np.ndarray, oversample: int, out: np.ndarray) -> None:
    """out[i, b] = Σ over the ``oversample`` fine cells c of bin b of (hist[rows[i]] ⋆ kernel)[c], the valid-mode
    convolution ``numpy.convolve(hist[row], kernel, "valid")`` (length N − K + 1 = n_bins · oversample), evaluated
    only where the row's non-zero nodes reach. hist (R, N) float64, rows (k,) int64, kernel (K,) float64, out
    (k, n_bins) float64 (written)."""
    k_len = kernel.shape[0]
    n_bins = out.shape[1]
    n_cells = n_bins * oversample
    for i in range(rows.shape[0]):
        r = rows[i]
        for b in range(n_bins):
            out[i, b] = 0.0
        lo, hi = _span(hist, r)
        for c in range(max(0, lo - k_len + 1), min(hi, n_cells)):
            s = 0.0
            for t in range(max(0, lo - c), min(k_len, hi - c)):
                s += hist[r, c + t] * kernel[k_len - 1 - t]
            out[i, c // oversample] += s
