"""The tracer's per-vertex arithmetic in one compiled pass (:class:`~datagen.transport.multibounce.tracer.MultibounceTracer`).

:func:`continue_paths` is the compiled form of three numpy steps of the tracer, with the same formulas:

- the cosine-weighted direction about the normal: :func:`datagen.sampling.square_to_hemisphere` (``"cosine"``:
  Shirley & Chiu's concentric disk lifted by Malley's method) rotated by :func:`datagen.sampling.directions.to_world`
  (the tangent frame of Duff et al. 2017, :func:`datagen.scene.materials.tangent_frame`);
- the BRDF f(ω_in, ω_out) of :func:`datagen.scene.brdf_kernel.brdf_value` (each formula defined once there);
- the flux update Φ·f·π/q over the cosine density and Russian roulette with survival q
  (docs/physics.md §2, "Light of every order").

``tests/test_multibounce.py`` checks the directions against the numpy functions for the same uniforms, so the two
forms cannot drift apart.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...scene.brdf_kernel import brdf_value
from ..area.kernels import fov_target


@njit(cache=True)
def continue_paths(n_x, obj, w_in, u, v, r, flux, survival, mat):
    """Continue m paths from their vertices: a cosine-weighted direction about the normal, the flux over its
    density and the survival probability, and Russian roulette.

    Args:
        n_x (m, 3) unit normals on the side the light arrives from; obj (m,) int object ids; w_in (m, 3) unit
        directions toward where the light came from; u, v (m,) uniforms of the direction, r (m,) of the roulette;
        flux (m,) photons; survival (n_objects,) q per object; mat the material arrays
        (:func:`datagen.transport.area.kernels.material_arrays`).
    Returns:
        (w_out (m, 3) float64, flux_out (m,) float64 = flux·f·π/q (0 where q = 0), live (m,) bool: the roulette
        kept the path and its flux is > 0).
    """
    m = n_x.shape[0]
    w_out = np.empty((m, 3))
    flux_out = np.zeros(m)
    live = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        # concentric disk (Shirley & Chiu 1997), lifted to the cosine-weighted hemisphere (Malley)
        a, b = 2.0 * u[i] - 1.0, 2.0 * v[i] - 1.0
        if abs(a) > abs(b):
            rr, phi = a, (math.pi / 4) * (b / a)
        elif b != 0.0:
            rr, phi = b, math.pi / 2 - (math.pi / 4) * (a / b)
        else:
            rr, phi = b, 0.0
        z = math.sqrt(max(0.0, 1.0 - rr * rr))
        lx, ly = rr * math.cos(phi), rr * math.sin(phi)
        # tangent frame (Duff et al. 2017), t × b = n
        n0, n1, n2 = n_x[i, 0], n_x[i, 1], n_x[i, 2]
        sign = 1.0 if n2 >= 0.0 else -1.0
        aa = -1.0 / (sign + n2)
        bb = n0 * n1 * aa
        t0, t1, t2 = 1.0 + sign * n0 * n0 * aa, sign * bb, -sign * n0
        b0, b1, b2 = bb, sign + n1 * n1 * aa, -n1
        o0 = lx * t0 + ly * b0 + z * n0
        o1 = lx * t1 + ly * b1 + z * n1
        o2 = lx * t2 + ly * b2 + z * n2
        w_out[i, 0], w_out[i, 1], w_out[i, 2] = o0, o1, o2
        q = survival[obj[i]]
        if q > 0.0:
            f = brdf_value(mat, obj[i], n0, n1, n2, w_in[i, 0], w_in[i, 1], w_in[i, 2], o0, o1, o2)
            flux_out[i] = flux[i] * f * math.pi / q
        live[i] = r[i] < q and flux_out[i] > 0.0
    return w_out, flux_out, live


@njit(cache=True)
def brdf_many(mat, obj, n, w_in, w_out):
    """f(ω_in, ω_out) of :func:`~datagen.scene.brdf_kernel.brdf_value` at m points: obj (m,) int, n, w_in, w_out
    (m, 3) unit vectors (normals on the lit side, directions away from the surface) → (m,) float64 1/sr."""
    m = obj.shape[0]
    out = np.empty(m)
    for i in range(m):
        out[i] = brdf_value(mat, obj[i], n[i, 0], n[i, 1], n[i, 2], w_in[i, 0], w_in[i, 1], w_in[i, 2],
                            w_out[i, 0], w_out[i, 1], w_out[i, 2])
    return out


@njit(cache=True)
def fov_targets_ranged(x, n_x, first, count, ix, iy, jitter, fov):
    """One uniform FoV point in each pixel region that a vertex's laser point records, and the geometry of the pairs
    that face each other: :func:`datagen.transport.area.kernels.fov_targets` with one cell per pixel, over each
    vertex's own range of a pixel table (a confocal scan point records its own pixel only).

    Args:
        x, n_x: (B, 3) vertices and the normals of the side they connect from; first, count: (B,) int64 the range
            ``first … first + count − 1`` of the table rows that vertex b connects to; ix, iy: (T,) int64 pixel
            column and row of each table row; jitter: (B, J, 2) uniforms in [0, 1)², J ≥ max(count) (entry j of
            row b places the point in the range's j-th pixel); fov: as for ``fov_targets``.
    Returns:
        (bi (n,) int64, ti (n,) int64 table row, y (n, 3), w (n, 3) unit x → y, r (n,) |y − x|, cos_y (n,)) for
        the pairs with n_x·w > 0 and cosθ_y = −w·n_fov > 0, in (b, j) order.
    """
    nb = x.shape[0]
    cap = 0
    for b in range(nb):
        cap += count[b]
    bi = np.empty(cap, np.int64)
    ti = np.empty(cap, np.int64)
    y = np.empty((cap, 3))
    w = np.empty((cap, 3))
    r = np.empty(cap)
    cy = np.empty(cap)
    k = 0
    for b in range(nb):
        for j in range(count[b]):
            s = first[b] + j
            cu = ix[s] + (0.0 + jitter[b, j, 0] / 1.0)         # (as fov_targets with one cell per pixel)
            cv = iy[s] + (0.0 + jitter[b, j, 1] / 1.0)
            t0, t1, t2, rr, w0, w1, w2, cos_y, faces = fov_target(x, n_x, b, cu, cv, fov)
            if faces:
                bi[k], ti[k] = b, s
                y[k, 0], y[k, 1], y[k, 2] = t0, t1, t2
                w[k, 0], w[k, 1], w[k, 2] = w0, w1, w2
                r[k], cy[k] = rr, cos_y
                k += 1
    return bi[:k], ti[:k], y[:k], w[:k], r[:k], cy[:k]
