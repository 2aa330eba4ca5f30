"""Compiled deposit of one tent onto an accumulator's fine grid (numba), for compiled transport kernels.

:func:`deposit_tent` does for one tent what :meth:`datagen.timing.EnvelopeAccumulator.add_tents` does for many in
the fine-grid mode (Gaussian or ex-Gaussian IRF, not the direct mode): the tent's weight is added to the
component's total; a tent wholly outside the fine grid counts as beyond it; a tent spanning at least
``min_nodes`` nodes and clear of the grid's ends goes to the curvature array as the sixteen second differences of
:func:`datagen.timing.tents.tent_curvature` (:func:`datagen.timing.curvature.add_tent_curvature`); any
other tent puts on each node p it covers the second difference F2(p+1) − 2 F2(p) + F2(p−1) of its second
antiderivative :func:`datagen.timing.tents.tent_cdf2` (clamped at 0, the accumulator's per-node form), and a
tent cut by the grid's ends adds the mass it could not deposit to beyond. The grid's arrays come from
:meth:`datagen.timing.EnvelopeAccumulator.tent_grid`. ``tests/test_quadrature.py`` compares these deposits with
``add_tents`` to 1e-12.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .curvature import add_tent_curvature

__all__ = ["TentGrid", "deposit_tent", "sort3"]


class TentGrid(NamedTuple):
    """An accumulator's fine grid as plain arrays (:meth:`datagen.timing.EnvelopeAccumulator.tent_grid`).

    Attributes:
        t_start: seconds of the axis start; fine_step: seconds per node; shift: the node coordinate of t_start
            (node g sits at t_start + (g − shift) · fine_step); n_fine: nodes per component.
        min_nodes: tents spanning at least this many nodes go to ``curvature``.
        hist, curvature: (components · n_fine,) float64 views of the fine histogram and of its pending second
            differences, photons per pulse; total, beyond: (components,) float64 views of the weight added and
            the weight beyond the grid.
    """

    t_start: float
    fine_step: float
    shift: float
    n_fine: int
    min_nodes: float
    hist: np.ndarray
    curvature: np.ndarray
    total: np.ndarray
    beyond: np.ndarray
    bound: np.ndarray


@njit(cache=True, inline="always")
def sort3(a: float, b: float, c: float) -> tuple:
    """(a, b, c) in ascending order."""
    if a > b:
        a, b = b, a
    if b > c:
        b, c = c, b
    if a > b:
        a, b = b, a
    return a, b, c


@njit(cache=True, inline="always")
def _cdf2(y: float, t0: float, t1: float, t2: float) -> float:
    """:func:`datagen.timing.tents.tent_cdf2` at one point (the same branches)."""
    span, g0, g1 = t2 - t0, t1 - t0, t2 - t1
    if y > t0 and y < t1:
        return (y - t0) ** 3 / (3.0 * span * g0)
    if y >= t1 and y < t2:
        return (g0 * g0 - g1 * g1) / (3.0 * span) + (y - t1) + (t2 - y) ** 3 / (3.0 * span * g1)
    if y >= t2:
        return y - (t0 + t1 + t2) / 3.0
    return 0.0


@njit(cache=True, inline="always")
def deposit_tent(c0: float, c1: float, c2: float, w: float, comp: int, n_fine: int, min_nodes: float,
                 hist: np.ndarray, curvature: np.ndarray, total: np.ndarray, beyond: np.ndarray,
                 bound: np.ndarray) -> None:
    """Deposit the tent of weight ``w`` (photons per pulse) with sorted node coordinates c0 <= c1 <= c2 into
    component ``comp`` of the grid arrays (:class:`TentGrid`; module doc), widening the row's ``bound`` to the
    nodes [floor(c0) − 1, ceil(c2) + 9) it may write (the curvature deposits reach floor(c2) + 7 at most, the fold
    writes the histogram where the curvature is non-zero). w > 0 and finite coordinates are the caller's."""
    total[comp] += w
    lo = np.floor(c0)
    hi = np.ceil(c2)
    if not (hi >= 0.0 and lo <= n_fine - 1):
        beyond[comp] += w
        return
    row = comp * n_fine
    reach_lo = int(max(lo - 1.0, 0.0))
    reach_hi = int(min(hi + 9.0, float(n_fine)))
    if reach_lo < bound[comp, 0]:
        bound[comp, 0] = reach_lo
    if reach_hi > bound[comp, 1]:
        bound[comp, 1] = reach_hi
    if c2 - c0 >= min_nodes and lo >= 1.0 and hi + 2.0 <= n_fine - 1:
        add_tent_curvature(c0, c1, c2, w, row + 1, curvature)
        return
    first = int(max(lo, 0.0))
    last = int(min(hi, n_fine - 1.0))
    a0, a1, a2 = c0 - lo, c1 - lo, c2 - lo              # local coordinates (as the accumulator's)
    f_prev = _cdf2(first - 1 - lo, a0, a1, a2)
    f_here = _cdf2(first - lo, a0, a1, a2)
    deposited = 0.0
    for p in range(first, last + 1):
        f_next = _cdf2(p + 1 - lo, a0, a1, a2)
        m = (f_next - f_here) - (f_here - f_prev)
        if m > 0.0:
            hist[row + p] += m * w
            deposited += m * w
        f_prev, f_here = f_here, f_next
    if lo < 0.0 or hi > n_fine - 1:
        lost = w - deposited
        if lost > 0.0:
            beyond[comp] += lost
