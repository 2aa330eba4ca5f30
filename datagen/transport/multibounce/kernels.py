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
