"""The smoothing of the tracer's deep orders across a confocal scan's points (:mod:`.smoothing`): a separable tent
over neighbouring scan points, continued past the grid's edges by point reflection, and its variance (whose ratio at
h and 2h turns the spread at 2h into the estimate of its bias). docs/scans.md.
"""
from __future__ import annotations

import numpy as np
from numba import njit


def neighbourhood_max(values: np.ndarray, scan: tuple[int, int, int]) -> np.ndarray:
    """The largest of ``values`` (ny·nx,) over the scan points within h − 1 pitches along each axis of each point
    (those :func:`spread_scan` adds its masses to with a positive weight, at the edges too): (ny·nx,) float64."""
    from scipy.ndimage import maximum_filter
    ny, nx, h = scan
    return maximum_filter(np.asarray(values, dtype=np.float64).reshape(ny, nx), size=2 * h - 1,
                          mode="nearest").reshape(-1)


def tent_weights(h: int) -> np.ndarray:
    """The discrete tent of half-width h pitches: (2h − 1,) float64 weights ∝ h − |k| for |k| < h, summing to 1."""
    k = np.arange(-h + 1, h)
    w = (h - np.abs(k)).astype(np.float64)
    return w / w.sum()


def tent_variance(h: int) -> float:
    """Σ w_k k² of :func:`tent_weights` (pitches²): the bias of the spread grows with it."""
    k = np.arange(-h + 1, h)
    return float((tent_weights(h) * k * k).sum())


def spread_scan(masses: np.ndarray, scan: tuple[int, int, int]) -> np.ndarray:
    """Spread masses (ny·nx, m) over an (ny, nx) scan grid by the separable tent of half-width h pitches
    (:func:`tent_weights`): (ny·nx, m) float64.

    Beyond the grid's edges the masses are continued by point reflection about the edge point
    (x₋ₖ = 2x₀ − xₖ), so the spread keeps every linear field, at the edges too, and its bias is ∝ h² ∇²L everywhere
    (which is what :meth:`DeepSmoothing.bias` estimates). A one-sided mean at the edges would move them by ∝ h ∇L,
    a bias of first order that the Richardson estimate misses (half of the tracer's bias on a 32 × 32 confocal scan
    came from its outer ring). At h = 2 an edge point keeps its own mass along that axis; at larger h a node next to
    an edge can come out below zero where the masses fall steeply towards it (:meth:`DeepSmoothing.flush` clips at
    zero)."""
    ny, nx, h = scan
    w = tent_weights(h)
    if min(ny, nx) >= h:                       # (the compiled pass: the same sums in the same order)
        return _spread_grid(np.ascontiguousarray(masses, dtype=np.float64).reshape(ny, nx, -1), w, h
                            ).reshape(masses.shape)
    grid = masses.reshape(ny, nx, -1)
    for axis in (0, 1):
        pad = [(0, 0)] * 3
        pad[axis] = (h - 1, h - 1)
        wide = np.pad(grid, pad, mode="reflect", reflect_type="odd")
        n = grid.shape[axis]
        out = np.zeros_like(grid)
        for k, wk in enumerate(w):
            out += wk * np.take(wide, np.arange(k, k + n), axis=axis)
        grid = out
    return grid.reshape(masses.shape)


@njit(cache=True)
def _spread_grid(grid, w, h):
    """:func:`spread_scan` of a grid (ny, nx, m) with ny, nx ≥ h: :func:`_spread_axis` along axis 0, then along axis 1
    (the numpy form's order)."""
    mid = _spread_axis(grid, w, h)
    return _spread_axis(mid.transpose(1, 0, 2), w, h).transpose(1, 0, 2)


@njit(cache=True)
def _spread_axis(grid, w, h):
    """Along axis 0 of a grid (n, k, m), n ≥ h: each output the sum Σ_j w_j x_{i−h+1+j} in order of j, with
    x₋ⱼ = 2x₀ − xⱼ and x_{n−1+j} = 2x_{n−1} − x_{n−1−j} beyond the edges (numpy's odd reflection, as the numpy form
    pads). Returns a new C-ordered (n, k, m) array."""
    n, nk, m = grid.shape
    out = np.empty((n, nk, m))
    for i in range(n):
        for j in range(nk):
            for c in range(m):
                acc = 0.0
                for k in range(w.shape[0]):
                    p = i - h + 1 + k
                    if p < 0:
                        v = 2 * grid[0, j, c] - grid[-p, j, c]
                    elif p >= n:
                        v = 2 * grid[n - 1, j, c] - grid[2 * (n - 1) - p, j, c]
                    else:
                        v = grid[p, j, c]
                    acc += w[k] * v
                out[i, j, c] = acc
    return out
