"""Compiled splat of impulses onto an accumulator's fine grid (numba): :meth:`EnvelopeAccumulator.add`'s inner loop.

:func:`splat_nodes` does in one pass what the accumulator's numpy splat did in a dozen (component sums, the node
coordinate, the window test, the two neighbour weights, two ``np.add.at``), with the same float operations in the
same order, so the histogram is bit-identical to that code (the per-component totals are summed in sequence, as
``np.bincount`` did). Impulse i at time t goes to fractional node x = (t − t_start)/fine_step + n_left − ½ (node g
sits at ``t_start + (g − n_left + ½)·fine_step``, docs/physics.md §5): linear (cloud-in-cell) weights on nodes
⌊x⌋ and ⌊x⌋ + 1 for a Gaussian or ex-Gaussian IRF; for the delta IRF the whole weight on the node of the fine
cell that contains t. Impulses off the grid count in ``beyond``. ``tests/test_irf.py`` checks the deposits.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["splat_nodes"]


@njit(cache=True)
def splat_nodes(flat, total, beyond, t, w, comp, comp0, t_start, fine_step, n_left, n_fine, delta):
    """Add impulses (times ``t`` s, weights ``w`` photons per pulse, both (n,) float64, finite, w ≥ 0) to the
    fine histogram ``flat`` ((n_components · n_fine,) float64, row c holds component c), their weights to
    ``total`` and, for those off the grid, to ``beyond`` ((n_components,) float64 each). ``comp``: (n,) int64
    component ids, or an empty array for all in ``comp0``. ``delta``: nearest cell instead of linear weights.
    Zero weights add nothing. Returns None (the arrays are updated in place)."""
    n = t.shape[0]
    per_impulse = comp.shape[0] > 0
    sums = np.zeros(total.shape[0])
    out = np.zeros(total.shape[0])
    shift = n_left - 0.5
    last = float(n_fine - 2)
    lefts = np.empty(n, np.int64)
    rights = np.empty(n)
    for k in range(n):                         # totals, window test, node and weights (first np.add.at pass)
        c = comp[k] if per_impulse else comp0
        wk = w[k]
        sums[c] += wk
        lefts[k] = -1
        if wk == 0.0:
            continue
        if delta:
            g = math.floor((t[k] - t_start) / fine_step) + n_left
            if not (g >= 0.0 and g < n_fine):
                out[c] += wk
                continue
            flat[c * n_fine + int(g)] += wk
            continue
        x = (t[k] - t_start) / fine_step + shift
        if not (x >= 0.0 and x <= n_fine - 1):
            out[c] += wk
            continue
        i = min(math.floor(x), last)
        w_right = wk * (x - i)
        idx = c * n_fine + int(i)
        flat[idx] += wk - w_right
        lefts[k] = idx
        rights[k] = w_right
    if not delta:
        for k in range(n):                     # the right neighbours after all left ones (the second np.add.at)
            if lefts[k] >= 0:
                flat[lefts[k] + 1] += rights[k]
    for c in range(total.shape[0]):
        total[c] += sums[c]
        beyond[c] += out[c]
