"""Tent densities: the exact time profile of a triangle whose path time is linear over it (docs/physics.md §5).

The pushforward of the uniform area measure of a triangle under a path time that is linear on it is a
piecewise-linear "tent" density between the sorted vertex times t0 <= t1 <= t2 (peak 2/(t2-t0) at t1, unit
mass). The hidden-surface quadrature deposits whole sub-triangles as tents
(:meth:`datagen.timing.accumulator.EnvelopeAccumulator.add_tents`), exactly, from these closed forms:
:func:`tent_cdf` (piecewise quadratic), its antiderivative :func:`tent_cdf2` (piecewise cubic; the
linear-splatting weights of a fine grid) and :func:`tent_irf_cdf`, the CDF of the tent convolved with an
:class:`~datagen.timing.irf.Irf` (from the IRF's partial moments E[(c-X)_+] and E[(c-X)_+^2]/2, closed forms
for the Gaussian, the ex-Gaussian and the two-tail mixture). All functions work elementwise on arrays of one shape.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr
from scipy.stats import exponnorm

from .irf import Irf

__all__ = ["NARROW_SIDE", "TENT_SMALL_SIGMAS", "TENT_GAP_SMALL_SIGMAS", "tent_cdf", "tent_cdf2",
           "tent_curvature", "tent_irf_cdf"]

NARROW_SIDE = 1e-3
"""Fine-grid mode (:func:`tent_curvature`): a tent side narrower than this many fine nodes takes the divided
difference of B3 without cancellation; a wider one the B3 values at its two ends, divided by the side. Their
difference cancels: the result carries ~1e-16 / side of the tent's scale (≤ 1e-13 here; measured against the
divided difference in ``tests/test_quadrature.py``), and one side in ~10⁴ of a fine-grid tent of tens of nodes
is narrower (the per-node divided difference costs several times the two ends)."""

TENT_SMALL_SIGMAS = 1e-4
"""Direct mode: a tent narrower than this many IRF sigmas is deposited as an impulse at its mean (the error,
~(span/sigma)^2 / 36 of its weight, is below 1e-9, while the exact formula would lose more to cancellation)."""

TENT_GAP_SMALL_SIGMAS = 1e-2
"""Direct mode: a tent side narrower than this many IRF sigmas takes the mean of E[(c-X)_+] over the side from
a two-term Taylor expansion (error ~(gap/sigma)^4 / 1920 < 1e-11) instead of a difference quotient that
cancels."""


def tent_cdf(y: np.ndarray, t0: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """P(T < y) for T with the unit-mass tent density between t0 <= t1 <= t2 (peak at t1) (arrays alike).

    Piecewise quadratic: (y-t0)^2 / (L g0) on [t0, t1], 1 - (t2-y)^2 / (L g1) on [t1, t2], L = t2 - t0,
    g0 = t1 - t0, g1 = t2 - t1. Degenerate sides (g = 0) are never divided by: their piece is empty.
    """
    span, g0, g1 = t2 - t0, t1 - t0, t2 - t1
    rise = (y > t0) & (y < t1)
    fall = (y >= t1) & (y < t2)
    out = ((y > t2) | ((y >= t2) & (span > 0))).astype(np.float64)     # P(T < y): a zero-span tent at y is above
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(rise, (y - t0) ** 2 / (span * g0), out)
        out = np.where(fall, 1.0 - (t2 - y) ** 2 / (span * g1), out)
    return out


def tent_cdf2(y: np.ndarray, t0: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Second antiderivative of the unit-mass tent, integral of its CDF from -inf to y (piecewise cubic).

    0 before t0; (y-t0)^3 / (3 L g0) on [t0, t1]; g0^2/(3L) + (y-t1) - g1^2/(3L) + (t2-y)^3 / (3 L g1) on
    [t1, t2]; y - (t0+t1+t2)/3 after t2 (the tent's mean). Zero-span tents give (y - t0)_+.
    """
    span, g0, g1 = t2 - t0, t1 - t0, t2 - t1
    rise = (y > t0) & (y < t1)
    fall = (y >= t1) & (y < t2) & ~rise
    out = np.where(y >= t2, y - (t0 + t1 + t2) / 3.0, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(rise, (y - t0) ** 3 / (3.0 * span * g0), out)
        out = np.where(fall, (g0 ** 2 - g1 ** 2) / (3.0 * span) + (y - t1) + (t2 - y) ** 3 / (3.0 * span * g1), out)
    return out


def _partial_moments(irf: Irf, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M1, M2) = (E[(c-X)_+], E[(c-X)_+^2]/2) of the IRF delay X at c (seconds), i.e. the first and second
    antiderivatives of its CDF. Gaussian: sigma*A1(z), sigma^2*A2(z), z = c/sigma, A1 = z Phi + phi,
    A2 = ((z^2+1) Phi + z phi)/2. Ex-Gaussian (X = N(0, sigma^2) + Exp(mean tau)): M1 = sigma A1 - tau F_X(c),
    M2 = sigma^2 A2 - tau sigma A1 + tau^2 F_X(c) (integrating F_X = Phi(z) - e^{-c/tau + sigma^2/2tau^2}
    Phi(z - sigma/tau) by parts; F_X from scipy.stats.exponnorm). Two-tail IRF: the partial moments are linear in
    the distribution, so its mixture's are the weighted sums of its components' at c - delay."""
    if irf.kind == "two_tail":
        m1, m2 = np.zeros(np.shape(c)), np.zeros(np.shape(c))
        for w, tau, d in irf.components:
            if w > 0:
                a, b = _component_moments(irf.sigma, tau, c - d)
                m1, m2 = m1 + w * a, m2 + w * b
        return m1, m2
    return _component_moments(irf.sigma, None if irf.kind == "gaussian" else float(irf.tail), c)


def _component_moments(s: float, tau: float | None, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M1, M2) of :func:`_partial_moments` for N(0, s²) (``tau`` None) or N(0, s²) + Exp(mean ``tau``)."""
    z = c / s
    cdf = ndtr(z)
    pdf = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    a1 = z * cdf + pdf
    a2 = 0.5 * ((z * z + 1.0) * cdf + z * pdf)
    if tau is None:
        return s * a1, s * s * a2
    fx = exponnorm.cdf(c, tau / s, scale=s)
    return s * a1 - tau * fx, s * s * a2 - tau * s * a1 + tau * tau * fx


def _irf_pdf(irf: Irf, c: np.ndarray) -> np.ndarray:
    if irf.kind == "gaussian":
        return np.exp(-0.5 * (c / irf.sigma) ** 2) / (math.sqrt(2.0 * math.pi) * irf.sigma)
    if irf.kind == "two_tail":
        return irf.pdf(c)
    return exponnorm.pdf(c, irf.tail / irf.sigma, scale=irf.sigma)


def tent_irf_cdf(irf: Irf, e: np.ndarray, t0: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """P(T + X < e) for T the unit-mass tent (t0 <= t1 <= t2) and X the IRF delay (sigma > 0).

    With ρ'' = (2/L)[δ(t-t0)/g0 - δ(t-t1)(1/g0 + 1/g1) + δ(t-t2)/g1], G = ρ * F_X = (2/L)[DD(e-t0, g0) -
    DD(e-t1, g1)], DD(c, g) = (M2(c) - M2(c-g))/g the mean of M1 over [c-g, c] (:func:`_partial_moments`); a
    side narrower than TENT_GAP_SMALL_SIGMAS·sigma uses M1(c-g/2) + g^2/24 f_X(c-g/2), and a tent narrower than
    TENT_SMALL_SIGMAS·sigma is an impulse at its mean."""
    span = t2 - t0
    narrow = span < TENT_SMALL_SIGMAS * irf.sigma

    def mean_m1(c, g):
        small = g < TENT_GAP_SMALL_SIGMAS * irf.sigma
        m1_mid, _ = _partial_moments(irf, c - 0.5 * g)
        taylor = m1_mid + g * g / 24.0 * _irf_pdf(irf, c - 0.5 * g)
        _, m2_hi = _partial_moments(irf, c)
        _, m2_lo = _partial_moments(irf, c - g)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(small, taylor, (m2_hi - m2_lo) / np.where(small, 1.0, g))

    c0, g0 = e - t0, t1 - t0                    # one rounding of e − t0 shared by both sides
    with np.errstate(divide="ignore", invalid="ignore"):
        full = 2.0 / np.where(narrow, 1.0, span) * (mean_m1(c0, g0) - mean_m1(c0 - g0, t2 - t1))
    return np.where(narrow, irf.cdf(e - (t0 + t1 + t2) / 3.0), np.clip(full, 0.0, 1.0))


def _cubic_bspline_weights(c: np.ndarray) -> np.ndarray:
    """(n, 4) values B3(floor(c) - 1 + j - c), j = 0..3, of the centred cubic B-spline B3 = hat * hat at the four
    nodes around each c (n,) (f = c - floor(c): (1-f)³/6, (4 - 6f² + 3f³)/6, (1 + 3f + 3f² - 3f³)/6, f³/6)."""
    f = c - np.floor(c)
    f2 = f * f
    f3 = f2 * f
    return np.stack([(1.0 - f) ** 3, 4.0 - 6.0 * f2 + 3.0 * f3, 1.0 + 3.0 * (f + f2 - f3), f3], axis=1) / 6.0


_BINOMIAL4 = (1.0, -4.0, 6.0, -4.0, 1.0)


def _cubic_bspline_slope(ua: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """(B3(ua) - B3(ub)) / (ua - ub) for ua >= ub (B3'(ua) when equal), without cancellation: B3 is
    (1/6) Σ_j (-1)^j C(4, j) (u + 2 - j)_+^3 and the divided difference of (u - k)_+^3 is p² + pq + q² (both
    ends past the knot, p, q their distances) or p³ / (p - q) (only the upper end past it)."""
    out = np.zeros(np.broadcast(ua, ub).shape)
    for j, coef in enumerate(_BINOMIAL4):
        p, q = ua + 2.0 - j, ub + 2.0 - j
        with np.errstate(divide="ignore", invalid="ignore"):
            part = np.where(q >= 0, p * p + p * q + q * q, np.where(p > 0, p ** 3 / (p - q), 0.0))
        out += coef * part
    return np.where((ub >= 2.0) | (ua <= -2.0), 0.0, out / 6.0)


def tent_curvature(coord: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Second differences of a tent's linear-splatting deposits, O(1) per tent whatever its span.

    For the unit tent with sorted vertex coordinates c0 <= c1 <= c2 (in fine-node units, span L = c2 - c0 > 0),
    the deposit on node g is D(g) = ∫ tent(y) hat(y - g) dy (hat(u) = max(0, 1 - |u|), the linear splatting
    weight). Its second difference is D(g+1) - 2 D(g) + D(g-1) = (tent'' * B3)(g), with B3 = hat * hat the
    cubic B-spline and tent'' = (2/L) [(δ(c0) - δ(c1)) / g0 - (δ(c1) - δ(c2)) / g1] (g0 = c1 - c0, g1 = c2 - c1),
    i.e. (2/L) times the divided differences (B3(g - c0) - B3(g - c1)) / g0 - (B3(g - c1) - B3(g - c2)) / g1.
    A side of at least :data:`NARROW_SIDE` nodes gives B3 values at four nodes around each end (their
    difference cancels to ~1e-16 / side of the scale); a narrower one its divided difference at five nodes,
    evaluated without cancellation (the side's limit as g → 0 is B3'). Summing the
    returned values twice along the nodes (``np.cumsum`` twice from node 0) gives D exactly: B3 reproduces
    constants and lines, so D returns to zero after c2 + 1; float round-off leaves ~1e-16 · (nodes summed) of
    the weight.

    Args:
        coord: (n, 3) float64 sorted vertex coordinates, c2 - c0 > 0.
    Returns:
        (node, value): (n, 16) int64 node indices (the second difference at g is stored at g + 1, so that two
        cumulative sums from node 0 give D(g) at g) and (n, 16) float64 values per unit tent weight; they touch
        nodes floor(c0) .. floor(c2) + 3.
    """
    c0, c1, c2 = coord[:, 0], coord[:, 1], coord[:, 2]
    scale = 2.0 / (c2 - c0)
    nodes, values = [], []
    for a, b, sign in ((c0, c1, 1.0), (c1, c2, -1.0)):
        factor = (sign * scale)[:, None]
        narrow = (b - a < NARROW_SIDE)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            quotient = factor / np.where(narrow, 1.0, (b - a)[:, None])
        first = np.floor(a)[:, None] + np.arange(-1.0, 3.0)                # (n, 4) nodes around a
        second = np.where(narrow, first + 4.0, np.floor(b)[:, None] + np.arange(-1.0, 3.0))
        few = np.flatnonzero(narrow[:, 0])
        for node, end, sgn in ((first, a, 1.0), (second, b, -1.0)):
            value = sgn * quotient * _cubic_bspline_weights(end)
            value[few] = factor[few] * _cubic_bspline_slope(node[few] - a[few, None], node[few] - b[few, None])
            nodes.append(node.astype(np.int64) + 1)
            values.append(value)
    return np.concatenate(nodes, axis=1), np.concatenate(values, axis=1)
