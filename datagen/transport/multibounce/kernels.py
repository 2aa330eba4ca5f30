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
from ..physics import geometry_term


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


@njit(cache=True)
def eye_pairs(x, n_x, e, z, n_z, ok):
    """The pairs (light vertex x_b, its path's eye vertex z_{e[b]}) that face each other (:mod:`.eye`).

    Args:
        x, n_x: (m, 3) light vertices and their normals on the lit side; e: (m,) int64 each one's row of the eye
        vertices z, n_z (E, 3) (normals facing the FoV); ok: (E,) bool the eye vertices that exist.
    Returns:
        (rows (k,) int64 into x, w (k, 3) unit x → z, d (k,) |z − x| m, cos_x (k,), cos_z (k,) = −n_z·w) for the
        pairs with d > 0, n_x·w > 0 and n_z·(x − z) > 0.
    """
    m = x.shape[0]
    rows = np.empty(m, np.int64)
    w = np.empty((m, 3))
    d = np.empty(m)
    cx = np.empty(m)
    cz = np.empty(m)
    k = 0
    for b in range(m):
        j = e[b]
        if not ok[j]:
            continue
        t0, t1, t2 = z[j, 0] - x[b, 0], z[j, 1] - x[b, 1], z[j, 2] - x[b, 2]
        dd = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if dd <= 0.0:
            continue
        t0, t1, t2 = t0 / dd, t1 / dd, t2 / dd
        c_x = n_x[b, 0] * t0 + n_x[b, 1] * t1 + n_x[b, 2] * t2
        c_z = -(n_z[j, 0] * t0 + n_z[j, 1] * t1 + n_z[j, 2] * t2)
        if c_x > 0.0 and c_z > 0.0:
            rows[k] = b
            w[k, 0], w[k, 1], w[k, 2] = t0, t1, t2
            d[k], cx[k], cz[k] = dd, c_x, c_z
            k += 1
    return rows[:k], w[:k], d[:k], cx[:k], cz[:k]


@njit(cache=True)
def eye_weights(mat, obj, n_x, w_in, w, e, eye, survival, flux, d, cos_x, cos_z, p_a):
    """The weights (k,) photons, before attenuation, of visible eye connections (:mod:`.eye`; docs/physics.md §2):
    the radiant intensity of x toward z f_x cosθ_x, its irradiance at z (G = cosθ_x cosθ_z / d²,
    :func:`~datagen.transport.physics.geometry_term`), z's intensity toward y f_z cosθ_zy, the FoV leg ``fov``; over
    the eye vertex's density b = (p_A / n_rec) g times its balance weight b / (a + b + c), a = p_light p_A, c = p_light
    q_z g, p_light = q_x G / π (the FoV leg carries A_pixel = 1 / p_A).

    Args (per pair, k rows): obj (k,) x's object; n_x, w_in, w (k, 3) its normal, the direction light came from, unit
    x → z; e (k,) the eye row; eye: (obj, n_z, w_zy, g, n_rec, fov) per eye row (:class:`~.eye.EyeVertices`);
    survival (n_objects,) q; flux (k,); d, cos_x, cos_z (k,) from :func:`eye_pairs`; p_a: 1 / A_pixel, 1/m².
    """
    obj_z, n_z, w_zy, g, n_rec, fov = eye
    k = obj.shape[0]
    out = np.empty(k)
    for i in range(k):
        j = e[i]
        f_x = brdf_value(mat, obj[i], n_x[i, 0], n_x[i, 1], n_x[i, 2], w_in[i, 0], w_in[i, 1], w_in[i, 2],
                         w[i, 0], w[i, 1], w[i, 2])
        f_z = brdf_value(mat, obj_z[j], n_z[j, 0], n_z[j, 1], n_z[j, 2], -w[i, 0], -w[i, 1], -w[i, 2],
                         w_zy[j, 0], w_zy[j, 1], w_zy[j, 2])
        cos_zy = n_z[j, 0] * w_zy[j, 0] + n_z[j, 1] * w_zy[j, 1] + n_z[j, 2] * w_zy[j, 2]
        geo = geometry_term(cos_x[i], cos_z[i], d[i])
        p_light = survival[obj[i]] * geo / math.pi
        b = p_a / n_rec[j] * g[j]
        mis_over_pdf = p_a / (p_light * p_a + b + p_light * survival[obj_z[j]] * g[j])
        out[i] = flux[i] * f_x * geo * f_z * cos_zy * fov[j] * mis_over_pdf
    return out
