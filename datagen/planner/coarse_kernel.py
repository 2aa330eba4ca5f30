"""Compiled (numba) passes of the planner's coarse quadrature (:func:`datagen.planner.coarse.coarse_one_laser`).

The sums over (hidden element, FoV cell) and (lit element, partner element, FoV cell) of docs/physics.md §2 at the
planner's coarse resolution, one loop per pair instead of numpy arrays of every pair; the BRDF is the transport's
scalar form (:func:`datagen.scene.brdf_kernel.brdf_value`, equal to
:meth:`~datagen.scene.materials.MaterialTable.evaluate` to 1e-12, ``tests/test_area_kernels.py``). Shadow rays
stay with Embree between the passes: :func:`secondary_candidates` lists the pairs that face each other,
:func:`secondary_energy` sums the visible ones.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..scene.brdf_kernel import SIN_THETA, abs_sin_azimuth, brdf_value, sin_theta_scale
from ..transport.physics import geometry_term

__all__ = ["outgoing_sums", "primary_energy", "secondary_candidates", "secondary_energy"]


@njit(cache=True)
def primary_energy(lit, irradiance, area, obj, n_lit, w_lx, side, s_xy, w_xy, geo, mat):
    """Σ over lit elements x and FoV cells y (on x's lit side) of E_l(x) dA_x f_x(→spot, →y) geo(x, y).

    Args:
        lit: (L,) int64 lit element rows; irradiance, area: (M,) photons/m² and m²; obj: (M,) int object ids;
        n_lit: (M, 3) normals on the side facing the spot; w_lx: (M, 3) unit spot → x; side: (M,) ±1 side of the
        geometric normal facing the spot; s_xy: (M, K) ±1 side of x that sees cell y; w_xy: (M, K, 3) unit
        x → y; geo: (M, K) FoV-leg weight (0: not seen); mat: :func:`datagen.transport.material_arrays`.
    Returns:
        float, photons per pulse.
    """
    total = 0.0
    for j in range(lit.shape[0]):
        a = lit[j]
        s = 0.0
        for k in range(geo.shape[1]):
            if s_xy[a, k] == side[a] and geo[a, k] != 0.0:
                s += brdf_value(mat, obj[a], n_lit[a, 0], n_lit[a, 1], n_lit[a, 2], -w_lx[a, 0], -w_lx[a, 1],
                                -w_lx[a, 2], w_xy[a, k, 0], w_xy[a, k, 1], w_xy[a, k, 2]) * geo[a, k]
        total += irradiance[a] * area[a] * s
    return total


@njit(cache=True)
def secondary_candidates(lit, sees, x, n_lit, n_geo, tol):
    """Pairs (x_a lit, x_b that sees the FoV) facing each other: cos_a = n_lit(a)·w > 0, cos_b = |n(b)·w| > 0 and
    r > tol, w the unit direction a → b.

    Args:
        lit, sees: (La,), (Lb,) int64 element rows; x: (M, 3) m; n_lit: (M, 3); n_geo: (M, 3) geometric normals;
        tol: float, m.
    Returns:
        (xa, xb) (n,) int64, w (n, 3), r (n,) m, cos_a, cos_b (n,), side_b (n,) ±1 (the side of b facing a),
        row-major in (a, b).
    """
    cap = lit.shape[0] * sees.shape[0]
    xa = np.empty(cap, np.int64)
    xb = np.empty(cap, np.int64)
    w = np.empty((cap, 3))
    r = np.empty(cap)
    cos_a = np.empty(cap)
    cos_b = np.empty(cap)
    side_b = np.empty(cap)
    n = 0
    for i in range(lit.shape[0]):
        a = lit[i]
        for j in range(sees.shape[0]):
            b = sees[j]
            d0, d1, d2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
            dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            inv = 1.0 / max(dist, 1e-300)
            u0, u1, u2 = d0 * inv, d1 * inv, d2 * inv
            ca = n_lit[a, 0] * u0 + n_lit[a, 1] * u1 + n_lit[a, 2] * u2
            nb = n_geo[b, 0] * u0 + n_geo[b, 1] * u1 + n_geo[b, 2] * u2
            if not (ca > 0.0 and nb != 0.0 and dist > tol):
                continue
            xa[n], xb[n], r[n], cos_a[n], cos_b[n] = a, b, dist, ca, abs(nb)
            w[n, 0], w[n, 1], w[n, 2] = u0, u1, u2
            side_b[n] = -1.0 if nb > 0.0 else 1.0
            n += 1
    return xa[:n], xb[:n], w[:n], r[:n], cos_a[:n], cos_b[:n], side_b[:n]


@njit(cache=True)
def outgoing_sums(obj, n_geo, s_xy, w_xy, geo, mat):
    """Per element and side, the part of Σ_y f(→x', →y) geo(x', y) that does not depend on the incoming
    direction, for the BRDFs that factor: constant f (Lambertian) f·Σ geo; sin θ ½ρ·Σ |sin φ_out| geo (times
    |sin φ_in| per pair, :func:`secondary_energy`); NaN for the others (Phong: summed per pair).

    Args: as :func:`primary_energy` (n_geo: (M, 3) geometric normals). Returns: (M, 2) float64, column 0 for the
    side −n_geo, column 1 for +n_geo.
    """
    kind, albedo, _, _, axis, const_f, _ = mat
    out = np.zeros((obj.shape[0], 2))
    for b in range(obj.shape[0]):
        o = obj[b]
        for j in range(2):
            sb = 2.0 * j - 1.0
            if not math.isnan(const_f[o]):
                scale = const_f[o]
            elif kind[o] == SIN_THETA:
                scale = sin_theta_scale(albedo[o])
            else:
                out[b, j] = np.nan
                continue
            s = 0.0
            for k in range(geo.shape[1]):
                if s_xy[b, k] == sb and geo[b, k] != 0.0:
                    if kind[o] == SIN_THETA and math.isnan(const_f[o]):
                        s += abs_sin_azimuth(sb * n_geo[b, 0], sb * n_geo[b, 1], sb * n_geo[b, 2], axis[o, 0],
                                             axis[o, 1], axis[o, 2], w_xy[b, k, 0], w_xy[b, k, 1],
                                             w_xy[b, k, 2]) * geo[b, k]
                    else:
                        s += geo[b, k]
            out[b, j] = scale * s
    return out


@njit(cache=True)
def secondary_energy(pairs, irradiance, area, obj, n_lit, w_lx, n_geo, s_xy, w_xy, geo, mat, table):
    """Σ over visible pairs (a, b) of E_l(a) dA_a f_a(→spot, →b) cos_a cos_b / r² dA_b Σ_y f_b(→a, →y) geo(b, y),
    the cells y on b's side facing a (``pairs`` = (xa, xb, w, r, cos_a, cos_b, side_b) as
    :func:`secondary_candidates` returns them, restricted to the visible pairs; the rest as :func:`primary_energy`);
    ``table`` (M, 2): the y-sums of factoring BRDFs, :func:`outgoing_sums` (the same for every laser point).
    Returns float, photons per pulse."""
    xa, xb, w, r, cos_a, cos_b, side_b = pairs
    kind, _, _, _, axis, const_f, _ = mat
    total = 0.0
    for p in range(xa.shape[0]):
        a, b = xa[p], xb[p]
        f_a = brdf_value(mat, obj[a], n_lit[a, 0], n_lit[a, 1], n_lit[a, 2], -w_lx[a, 0], -w_lx[a, 1], -w_lx[a, 2],
                         w[p, 0], w[p, 1], w[p, 2])
        transfer = irradiance[a] * area[a] * f_a * geometry_term(cos_a[p], cos_b[p], r[p]) * area[b]
        if transfer == 0.0:
            continue
        sb = side_b[p]
        n0, n1, n2 = sb * n_geo[b, 0], sb * n_geo[b, 1], sb * n_geo[b, 2]
        o = obj[b]
        s = table[b, 1 if sb > 0.0 else 0]
        if math.isnan(s):                  # no factoring: the BRDF per cell
            s = 0.0
            for k in range(geo.shape[1]):
                if s_xy[b, k] == sb and geo[b, k] != 0.0:
                    s += brdf_value(mat, o, n0, n1, n2, -w[p, 0], -w[p, 1], -w[p, 2], w_xy[b, k, 0], w_xy[b, k, 1],
                                    w_xy[b, k, 2]) * geo[b, k]
        elif kind[o] == SIN_THETA and math.isnan(const_f[o]):
            s *= abs_sin_azimuth(n0, n1, n2, axis[o, 0], axis[o, 1], axis[o, 2], -w[p, 0], -w[p, 1], -w[p, 2])
        total += transfer * s
    return total
