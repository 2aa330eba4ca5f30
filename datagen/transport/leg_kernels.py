"""Compiled leg pieces shared by the estimators (the area sampler, the light tracer and its eye vertices): the
material table as the kernels take it, a FoV target and its geometry, and the sensor collection in one pass. The
formulas are those of :mod:`datagen.transport.physics` and :class:`datagen.scene.materials.MaterialTable`
(docs/physics.md §2); ``tests/test_area_kernels.py`` compares them with the numpy formulas (relative 1e-12).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..scene.brdf_kernel import brdf_value
from .physics import collection_term

__all__ = ["fov_target", "material_arrays", "sensor_collection", "toward"]


def material_arrays(physics) -> tuple:
    """The material table of a :class:`~datagen.transport.physics.LegPhysics` as the tuple the kernels take:
    (kind int8, albedo, specular, exponent, axis (n, 3), constant f, lobe width) per object id, where constant f is
    :meth:`~datagen.transport.physics.LegPhysics.constant_brdf` (ρ/π without angle work, NaN: evaluate) and lobe
    width the retroreflective kind's α."""
    m = physics.materials
    ids = np.arange(len(m.kind))
    return (m.kind, m.albedo, m.specular, m.exponent, np.ascontiguousarray(m.axis),
            np.ascontiguousarray(physics.constant_brdf(ids), dtype=np.float64), m.width)


@njit(cache=True, inline="always")
def toward(p0, p1, p2, q0, q1, q2):
    """|q − p| and the unit direction p → q (the numpy code's ``d / max(|d|, 1e-300)``)."""
    d0, d1, d2 = q0 - p0, q1 - p1, q2 - p2
    r = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    s = max(r, 1e-300)
    return r, d0 / s, d1 / s, d2 / s


@njit(cache=True, inline="always")
def fov_target(x, n_x, b, cu, cv, fov):
    """The FoV point at sensor-grid coordinates (cu, cv) (pixel index + position inside it) and its pair with
    vertex b of x: (y0, y1, y2, |y − x|, unit x → y (3 floats), cosθ_y = −w·n_fov, whether the pair faces each
    other: n_x·w > 0 and cosθ_y > 0)."""
    center, fu, fv, fn, size, pixels = fov
    a = (cu / pixels[0] - 0.5) * size[0]
    c = (cv / pixels[1] - 0.5) * size[1]
    t0 = center[0] + a * fu[0] + c * fv[0]
    t1 = center[1] + a * fu[1] + c * fv[1]
    t2 = center[2] + a * fu[2] + c * fv[2]
    rr, w0, w1, w2 = toward(x[b, 0], x[b, 1], x[b, 2], t0, t1, t2)
    cos_y = -(w0 * fn[0] + w1 * fn[1] + w2 * fn[2])
    faces = n_x[b, 0] * w0 + n_x[b, 1] * w1 + n_x[b, 2] * w2 > 0.0 and cos_y > 0.0
    return t0, t1, t2, rr, w0, w1, w2, cos_y, faces


@njit(cache=True)
def _sensor_terms(points, normals, obj, w_in, sensor, ap_n, scale, mat):
    n = points.shape[0]
    shared = ap_n.shape[0] == 1
    out = np.empty(n)
    d = np.empty(n)
    w_s = np.empty((n, 3))
    for i in range(n):
        t0, t1, t2 = sensor[0] - points[i, 0], sensor[1] - points[i, 1], sensor[2] - points[i, 2]
        dd = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        s0, s1, s2 = t0 / dd, t1 / dd, t2 / dd
        n0, n1, n2 = normals[i, 0], normals[i, 1], normals[i, 2]
        f = brdf_value(mat, obj[i], n0, n1, n2, w_in[i, 0], w_in[i, 1], w_in[i, 2], s0, s1, s2)
        a = 0 if shared else i
        cos_out = max(n0 * s0 + n1 * s1 + n2 * s2, 0.0)
        cos_ap = max(-(s0 * ap_n[a, 0] + s1 * ap_n[a, 1] + s2 * ap_n[a, 2]), 0.0)
        pde, area = scale
        out[i] = collection_term(pde, f, cos_out, area, cos_ap, dd)
        d[i] = dd
        w_s[i, 0], w_s[i, 1], w_s[i, 2] = s0, s1, s2
    return out, d, w_s


def sensor_collection(physics, points: np.ndarray, normals: np.ndarray, object_id: np.ndarray, w_in: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`datagen.transport.physics.LegPhysics.sensor_collection` of ``physics`` for the aperture convention
    (q f_y(ω_in, ω_s) cosθ_y,out A_ap cosθ_ap / d² · V(y, x_s), and d) with the arithmetic in one compiled pass
    before its shadow-ray batch; points, normals, w_in (n, 3), object_id (n,) → two (n,) float64 arrays."""
    c = physics.capture
    points = np.ascontiguousarray(points)
    ap_n = np.ascontiguousarray(np.asarray(c.aperture_normals(points), dtype=np.float64).reshape(-1, 3))
    out, d, w_s = _sensor_terms(points, np.ascontiguousarray(normals), np.ascontiguousarray(object_id),
                                np.ascontiguousarray(w_in), c.sensor, ap_n,
                                (float(physics.settings.pde), float(c.aperture_area)), material_arrays(physics))
    if physics.settings.shadow_sensor:
        physics.sensor_shadows(out, points, normals, w_s, d)
    return out, d
