"""Compiled transition of the free-running SPAD chain (datagen/spad/free_running.py, Rapp et al. 2019).

One transition applies, per pixel, a scatter of detection mass onto the cells where the detector is live again
and a decayed prefix sum over two laser periods. Both are sequential O(cells) loops: numba runs a transition
about 15 times faster than the equivalent numpy (sort, reduceat and blocked exponentials) for one pixel of
800 cells (11 against 180 µs), which is what a detector fit evaluates some 10⁴ times (docs/capture_io.md).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["scatter_rows", "wrapped_survival"]


@njit(cache=True)
def scatter_rows(values: np.ndarray, dest: np.ndarray) -> np.ndarray:
    """out[p, c] = Σ_{j: dest[j] = c} values[p, j].

    Args:
        values: float64 (pixels, cells) mass per source cell.
        dest: int64 (cells,) destination cell of each source cell, 0 ≤ dest < cells.
    Returns:
        float64 (pixels, cells).
    """
    n_pix, n_cells = values.shape
    out = np.zeros((n_pix, n_cells))
    for i in range(n_pix):
        for j in range(n_cells):
            out[i, dest[j]] += values[i, j]
    return out


@njit(cache=True)
def wrapped_survival(values: np.ndarray, dest: np.ndarray, decay: np.ndarray, one_minus_survival: np.ndarray
                     ) -> np.ndarray:
    """Survival mass at the start of each cell of mass entering the cells ``dest``, over all later periods.

    The mass of source cell j enters at the start of cell dest[j] and decays by decay[p, c] = e^{−q_c} across
    each cell c. U[t] = U[t − 1]·decay[t − 1] + entered[t] runs over two periods; the second period's mass
    continues in every later period with the survival factor e^{−Λ} per period, so it is summed geometrically
    (÷ (1 − e^{−Λ}); zero where Λ = 0, no detection possible).

    Args:
        values: float64 (pixels, cells) entering mass per source cell.
        dest: int64 (cells,) cell entered, 0 ≤ dest < cells.
        decay: float64 (pixels, cells) survival factor across each cell, in (0, 1].
        one_minus_survival: float64 (pixels,) 1 − e^{−Λ}, Λ the avalanches per period.
    Returns:
        float64 (pixels, cells): first-period survival plus the geometric sum of the later periods'.
    """
    n_pix, n_cells = values.shape
    out = scatter_rows(values, dest)
    for i in range(n_pix):
        u = 0.0
        for t in range(n_cells):
            u = u * decay[i, t - 1] + out[i, t] if t > 0 else out[i, 0]
            out[i, t] = u
        oms = one_minus_survival[i]
        if oms <= 0.0:
            continue
        for t in range(n_cells):
            u = u * decay[i, t - 1] if t > 0 else u * decay[i, n_cells - 1]
            out[i, t] += u / oms
    return out
