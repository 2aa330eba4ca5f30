"""Compiled deposit of wide tents through their second differences (numba).

:func:`deposit_curvature` adds, for every tent, the sixteen values of :func:`datagen.timing.tents.tent_curvature`
(the same formulas: cubic B-spline weights B3 at the four nodes around each end of a side, scaled by
±(2/L)/gap, or the side's divided difference of B3 without cancellation when the side is narrower than
:data:`datagen.timing.tents.NARROW_SIDE` nodes)
times the tent's weight into a flat (components · nodes) array, in one compiled pass with no temporaries.
``tests/test_quadrature.py`` compares it with :func:`~datagen.timing.tents.tent_curvature` to 1e-12.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .tents import NARROW_SIDE

__all__ = ["add_tent_curvature", "b3", "b3_slope", "deposit_curvature"]


@njit(cache=True, inline="always")
def b3(u: float) -> float:
    """Centred cubic B-spline B3 = hat * hat at u (support [-2, 2])."""
    a = abs(u)
    if a < 1.0:
        return 2.0 / 3.0 - u * u + 0.5 * a * a * a
    if a < 2.0:
        return (2.0 - a) ** 3 / 6.0
    return 0.0


@njit(cache=True, inline="always")
def b3_slope(ua: float, ub: float) -> float:
    """(B3(ua) - B3(ub)) / (ua - ub), ua >= ub, from B3 = (1/6) Σ_j (-1)^j C(4, j) (u + 2 - j)_+³
    (as :func:`datagen.timing.tents.tent_curvature`)."""
    if ub >= 2.0 or ua <= -2.0:
        return 0.0
    out = 0.0
    coef = (1.0, -4.0, 6.0, -4.0, 1.0)
    for j in range(5):
        p = ua + 2.0 - j
        q = ub + 2.0 - j
        if q >= 0.0:
            out += coef[j] * (p * p + p * q + q * q)
        elif p > 0.0:
            out += coef[j] * p * p * p / (p - q)
    return out / 6.0


@njit(cache=True, inline="always")
def _kink(x: float, q: float, start: int, flat: np.ndarray) -> None:
    """Add q × B3(node − x) to the four nodes around x (floor(x) − 1 … floor(x) + 2), the cubic B-spline's four
    weights at the fraction t = x − floor(x) in closed form (as :func:`b3` at those nodes)."""
    fx = np.floor(x)
    t = x - fx
    s = 1.0 - t
    base = start + int(fx) - 1
    flat[base] += q * (s * s * s / 6.0)
    flat[base + 1] += q * (2.0 / 3.0 - t * t + 0.5 * t * t * t)
    flat[base + 2] += q * (2.0 / 3.0 - s * s + 0.5 * s * s * s)
    flat[base + 3] += q * (t * t * t / 6.0)


@njit(cache=True, inline="always")
def add_tent_curvature(c0: float, c1: float, c2: float, w: float, start: int, flat: np.ndarray) -> None:
    """Add ``w`` × the sixteen second differences of the unit tent with sorted node coordinates c0 <= c1 <= c2 to
    ``flat[start + node]`` (``start``: the component's row offset + 1, the second difference at g being stored at
    g + 1). When both sides span NARROW_SIDE or more, the two sides' terms at c1 are added as one (:func:`_kink`:
    twelve values, the same sum)."""
    g0 = c1 - c0
    g1 = c2 - c1
    if g0 >= NARROW_SIDE and g1 >= NARROW_SIDE:     # three kinks, the middle one shared by both sides: 12 values
        r = 2.0 * w / ((c2 - c0) * g0 * g1)         # one division: q0 = (2/L)·w/g0, q1 = −(2/L)·w/g1
        q0 = r * g1
        q1 = -r * g0
        _kink(c0, q0, start, flat)
        _kink(c1, q1 - q0, start, flat)
        _kink(c2, -q1, start, flat)
        return
    scale = 2.0 / (c2 - c0) * w
    for side in range(2):
        a = c0 if side == 0 else c1
        b = c1 if side == 0 else c2
        factor = scale if side == 0 else -scale
        gap = b - a
        fa = np.floor(a)
        if gap < NARROW_SIDE:                      # one group of 8 nodes around a: exact divided difference
            for j in range(8):
                node = fa - 1.0 + j
                flat[start + int(node)] += factor * b3_slope(node - a, node - b)
        else:
            q = factor / gap
            fb = np.floor(b)
            for j in range(4):
                na = fa - 1.0 + j
                nb = fb - 1.0 + j
                flat[start + int(na)] += q * b3(na - a)
                flat[start + int(nb)] -= q * b3(nb - b)


@njit(cache=True)
def _deposit(coord, w, comp, n_fine, flat):
    for i in range(coord.shape[0]):
        add_tent_curvature(coord[i, 0], coord[i, 1], coord[i, 2], w[i], comp[i] * n_fine + 1, flat)


def deposit_curvature(coord: np.ndarray, weights: np.ndarray, comp: np.ndarray, n_fine: int,
                      flat: np.ndarray) -> None:
    """Add ``weights`` × the second differences of the unit tents with sorted node coordinates ``coord``
    (:func:`datagen.timing.tents.tent_curvature`) to ``flat``, the (components · n_fine) curvature array.

    Args:
        coord: (n, 3) float64 sorted vertex coordinates in fine nodes, c2 - c0 > 0, floor(c0) >= 1 and
            floor(c2) + 3 < n_fine (the caller's wide-tent selection).
        weights: (n,) float64 photons per pulse; comp: (n,) int64 component ids.
        n_fine: nodes per component; flat: C-contiguous float64 array, updated in place.
    """
    _deposit(np.ascontiguousarray(coord, dtype=np.float64), np.ascontiguousarray(weights, dtype=np.float64),
             np.ascontiguousarray(comp, dtype=np.int64), int(n_fine), flat)
