"""Compiled fold and binning of an accumulator's fine histogram, row by row over the nodes that hold weight (numba).

A fine-histogram row of a scanned capture holds weight on a few hundred of its thousands of nodes (one laser point's
returns), and a sub-scan's grid holds weight in few of its rows. Each kernel takes per row a ``bound`` [lo, hi) of
nodes (int64 (rows, 2)) outside which the row is known to hold zeros (:func:`full_bounds`: the whole row), and reads
only inside it (:func:`bin_rows`: and the windows of the bins it reaches, Q · oversample nodes beyond): rows no
deposit touched are never read, so their pages are never mapped.
:class:`datagen.timing.EnvelopeAccumulator` folds its pending second differences (:func:`fold_rows`) and
convolves it with the fine-cell-integrated IRF and sums ``oversample`` nodes per output bin (:func:`bin_rows`: per bin
the row's non-zero span reaches, the dot product of the nodes of its window with a precomputed row of weights from
:func:`bin_weights`). The fold runs in the order of ``numpy.cumsum``; the binning is the valid convolution regrouped
by output bin, each bin's terms in node order; nothing is approximated (docs/physics.md §5).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange
from scipy.signal import oaconvolve

from .. import threads  # noqa: F401  (numba's threading layer, before any parallel kernel)

__all__ = ["bin_rows", "bin_weights", "convolve_rows", "fold_rows", "full_bounds", "nonzero_rows", "rows_dot"]


def full_bounds(rows: int, nodes: int) -> np.ndarray:
    """(rows, 2) int64 bounds [0, nodes) for every row: nothing known, every node read."""
    out = np.zeros((rows, 2), dtype=np.int64)
    out[:, 1] = nodes
    return out


@njit(cache=True, inline="always")
def _span(a, r, bound) -> tuple:
    """[lo, hi): row r of ``a`` from its first to its last non-zero entry, read within ``bound[r]`` (the row holds
    zeros outside it); lo == hi if none."""
    n = min(bound[r, 1], a.shape[1])
    lo = min(max(bound[r, 0], 0), n)
    while lo < n and a[r, lo] == 0.0:
        lo += 1
    hi = n
    while hi > lo and a[r, hi - 1] == 0.0:
        hi -= 1
    return lo, hi


@njit(cache=True, parallel=True)
def fold_rows(hist: np.ndarray, curvature: np.ndarray, bound: np.ndarray) -> None:
    """hist[r] += the running sum of the running sum of curvature[r], for every row r of the (R, N) float64 arrays,
    from the row's first to its last non-zero second difference (beyond it the double sum of complete tents' second
    differences is zero, round-off aside), read within ``bound`` ((R, 2) int64, module doc). In place; ``curvature``
    is left as it is. The rows run on numba's threads, each row in one thread in node order: the same result for
    any number of threads."""
    for r in prange(hist.shape[0]):
        lo, hi = _span(curvature, r, bound)
        first = 0.0
        second = 0.0
        for j in range(lo, hi):
            first += curvature[r, j]
            second += first
            hist[r, j] += second


def bin_weights(kernel: np.ndarray, oversample: int) -> np.ndarray:
    """(oversample, Q) float64 table of what a fine node adds to the output bins: node j = oversample·m + p adds
    hist[j] · table[p, q] to bin m − q, the sum of the kernel taps k[K − 1 − t] over the t in [0, K) whose fine cell
    j − t lies in that bin (the valid-mode convolution of :func:`bin_rows` regrouped by node; Q =
    ceil((K − 1)/oversample) + 1)."""
    k_len = len(kernel)
    q_len = -(-(k_len - 1) // oversample) + 1
    table = np.zeros((oversample, q_len))
    p, t = np.meshgrid(np.arange(oversample), np.arange(k_len), indexing="ij")
    np.add.at(table, (p, -((p - t) // oversample)), np.broadcast_to(kernel[::-1], p.shape))   # in (p, t) order
    return table


@njit(cache=True, parallel=True)
def bin_rows(hist: np.ndarray, rows: np.ndarray, table: np.ndarray, out: np.ndarray, row_max: np.ndarray,
             bound: np.ndarray) -> None:
    """out[i, b] = Σ over the ``oversample`` fine cells c of bin b of (hist[rows[i]] ⋆ kernel)[c], the valid-mode
    convolution ``numpy.convolve(hist[row], kernel, "valid")`` (length n_bins · oversample), as the dot product of
    the Q · oversample nodes from b · oversample on (bins out of reach of the row's non-zero span are 0) with the
    weights of :func:`bin_weights` (``table``, (oversample, Q)) in node order: node j = oversample·m + p adds hist[j] ·
    table[p, m − b]; row_max[i] = max |hist[rows[i]]|. hist (R, N) float64, rows (k,) int64, out (k, n_bins) and
    row_max (k,) float64 (written); ``bound`` (R, 2) int64 per row of hist (module doc). The rows run on numba's
    threads, each in one thread: the same result for any number of threads."""
    oversample, q_len = table.shape
    n_bins = out.shape[1]
    width = q_len * oversample
    weights = np.empty(width)                      # weights[q · oversample + p] = table[p, q]: node order
    for q in range(q_len):
        for p in range(oversample):
            weights[q * oversample + p] = table[p, q]
    n = hist.shape[1]
    for i in prange(rows.shape[0]):
        r = rows[i]
        lo, hi = _span(hist, r, bound)
        peak = 0.0
        for j in range(lo, hi):
            peak = max(peak, abs(hist[r, j]))
        row_max[i] = peak
        # the bins whose nodes reach [lo, hi); the others are 0. A node outside [lo, hi) holds ±0.0 and adds +0.0 or
        # −0.0 to a sum that started at +0.0: no change, so the sums run over whole windows, four bins at once
        # (four independent chains, each in node order).
        b_lo = min(max(0, (lo - width) // oversample + 1), n_bins) if hi > lo else n_bins
        b_hi = max(b_lo, min(n_bins, -(-hi // oversample))) if hi > lo else n_bins
        for b in range(b_lo):
            out[i, b] = 0.0
        for b in range(b_hi, n_bins):
            out[i, b] = 0.0
        b = b_lo
        while b + 3 < b_hi and (b + 3) * oversample + width <= n:
            s0 = b * oversample
            s1 = s0 + oversample
            s2 = s1 + oversample
            s3 = s2 + oversample
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            t3 = 0.0
            for k in range(width):
                w = weights[k]
                t0 += hist[r, s0 + k] * w
                t1 += hist[r, s1 + k] * w
                t2 += hist[r, s2 + k] * w
                t3 += hist[r, s3 + k] * w
            out[i, b] = t0
            out[i, b + 1] = t1
            out[i, b + 2] = t2
            out[i, b + 3] = t3
            b += 4
        for bb in range(b, b_hi):
            start = bb * oversample
            total = 0.0
            for j in range(start, min(start + width, n)):
                total += hist[r, j] * weights[j - start]
            out[i, bb] = total


@njit(cache=True, parallel=True)
def nonzero_rows(a: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """The indices (k,) int64, ascending, of the rows of a (rows, n) float64 array that hold a non-zero entry
    (``numpy.flatnonzero(a.any(axis=1))``, each row read within ``bound`` ((rows, 2) int64, module doc) up to its
    first non-zero entry, the rows on numba's threads)."""
    hit = np.zeros(a.shape[0], dtype=np.bool_)
    for i in prange(a.shape[0]):
        n = min(bound[i, 1], a.shape[1])
        j = min(max(bound[i, 0], 0), n)
        while j < n and a[i, j] == 0.0:
            j += 1
        hit[i] = j < n
    return np.flatnonzero(hit)


@njit(cache=True, parallel=True)
def rows_dot(a: np.ndarray, v: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """a @ v (rows,) float64 for a (rows, n) float64 and v (n,) ≥ 0, each row in one of numba's threads: over the
    nodes where v is non-zero when they are fewer than half (an IRF's window fractions: zero inside the window beyond
    its support), else from the row's first to its last non-zero entry; within ``bound`` ((rows, 2) int64, module
    doc) either way. The terms left out add ±0.0, so the sums are the same either way and for any number of threads.
    A BLAS gemv here starts OpenBLAS's threads, whose spinning afterwards cost a tal capture 0.09 s of CPU for a
    0.2 ms product."""
    nodes = np.nonzero(v)[0]
    sparse = 2 * nodes.shape[0] < v.shape[0]
    out = np.zeros(a.shape[0])
    for i in prange(a.shape[0]):
        s = 0.0
        if sparse:
            for k in range(nodes.shape[0]):
                if bound[i, 0] <= nodes[k] < bound[i, 1]:
                    s += a[i, nodes[k]] * v[nodes[k]]
        else:
            lo, hi = _span(a, i, bound)
            for j in range(lo, hi):
                s += a[i, j] * v[j]
        out[i] = s
    return out


CONVOLVE_ROWS = 256
"""Fine-histogram rows binned in one batch (one FFT call for a long kernel) by :func:`convolve_rows`."""


def convolve_rows(hist: np.ndarray, bound: np.ndarray, kernel: np.ndarray, table: np.ndarray | None, oversample: int,
                  n_bins: int, clamp_rtol: float, select: np.ndarray | None = None) -> np.ndarray:
    """(rows, n_bins) float64: rows of the (R, N) fine histogram ``hist`` convolved with the fine-cell-integrated IRF
    ``kernel`` and summed ``oversample`` nodes per bin (:class:`datagen.timing.EnvelopeAccumulator`'s ``binned``,
    docs/physics.md §5), the non-zero rows in batches of ``CONVOLVE_ROWS``: :func:`bin_rows` with ``table``
    (:func:`bin_weights`), or for ``table`` None (a long kernel) one overlap-add FFT per batch over the bins its
    non-zero nodes reach. Rows are found and binned within their ``bound`` ((R, 2) int64, module doc; the FFT path
    reads its batch's non-zero rows whole); ``select``: ascending distinct row indices, the output's rows (default:
    every row). Negatives within ``clamp_rtol`` of a row's max(|fine histogram|, |envelope|) are round-off and set
    to 0.

    Raises:
        RuntimeError: a value more negative than that (cannot happen for weights >= 0; would indicate a bug).
    """
    hist = np.ascontiguousarray(hist, dtype=np.float64)
    place = None
    if select is not None:
        place = np.full(len(hist), -1, dtype=np.int64)
        place[select] = np.arange(len(select))
        bound = bound.copy()
        bound[place < 0] = 0                              # rows not selected: nothing to read
    out = np.zeros((len(hist) if select is None else len(select), n_bins), dtype=np.float64)
    rows = nonzero_rows(hist, bound)
    for start in range(0, len(rows), CONVOLVE_ROWS):
        ks = rows[start:start + CONVOLVE_ROWS]
        block = np.empty((len(ks), n_bins))
        if table is not None:                             # compiled, over each row's non-zero nodes only
            peak = np.empty(len(ks))
            bin_rows(hist, ks.astype(np.int64), table, block, peak, bound)
        else:   # a long kernel by overlap-add FFT, over the bins the batch's non-zero nodes reach
            span = kernel.size - 1
            part = hist[ks]
            cols = np.flatnonzero(part.any(axis=0))
            lo, hi = (int(cols[0]), int(cols[-1]) + 1) if len(cols) else (0, 0)
            b0 = max(0, lo - span) // oversample
            b1 = min(n_bins, -(-hi // oversample))
            part = part[:, b0 * oversample:b1 * oversample + span]
            conv = oaconvolve(part, kernel[None], mode="valid", axes=1)
            block[:] = 0.0
            block[:, b0:b1] = conv.reshape(len(ks), b1 - b0, oversample).sum(axis=2)
            peak = np.abs(part).max(axis=1)
        scale = np.maximum(np.abs(block).max(axis=1), peak)
        low = block.min(axis=1) < -clamp_rtol * scale
        if low.any():
            i = int(np.flatnonzero(low)[0])
            raise RuntimeError(f"component {int(ks[i])}: envelope value {block[i].min()!r} below "
                               f"-{clamp_rtol} * max(|fine histogram|, |envelope|) ({scale[i]!r})")
        out[ks if place is None else place[ks]] = np.maximum(block, 0.0)
    return out
