"""A brute-force oracle of the primary envelope, deliberately independent of the transport code.

:func:`primary_area_quadrature` is the tests' deterministic check of the primary (three-bounce) envelope of
docs/physics.md §2: every triangle split into sub-triangles of edge ≤ ``h_hidden``, the FoV into squares of side
≤ ``h_fov``, a midpoint sum over every (hidden element, FoV element) pair with explicit shadow rays. Its error
is the midpoint rule's, O(h²) away from kernel singularities (surfaces touching the FoV), which tests control
by halving h.

It writes every leg's weight out again on purpose — it does **not** use :mod:`datagen.transport.physics` — so
that a mistake in the shared per-leg formulas cannot hide from the tests. Keep it separate from the estimators.
"""
from __future__ import annotations

import numpy as np

from ..sampling.surfaces import subdivide_triangles
from ..scene import RayCaster, Scene, resolve_capture
from ..scene.capture import FOV_PLANE_TOL
from ..timing import EnvelopeAccumulator, Irf, TimeAxis
from ..units import SPEED_OF_LIGHT


def primary_area_quadrature(scene: Scene, axis: TimeAxis, irf: Irf, h_hidden: float, h_fov: float,
                            pde: float = 1.0, count_sensor_leg: bool = True, chunk: int = 1 << 20,
                            caster: RayCaster | None = None) -> tuple[np.ndarray, float]:
    """Binned primary envelope (n_bins,) and its total (expected detections per pulse), single pixel.

    Midpoint rule over sub-triangles of edge ≤ ``h_hidden`` (m) and FoV squares of side ≤ ``h_fov`` (m), with a
    shadow ray for every pair (module docstring).
    """
    caster = caster or RayCaster(scene)
    cap = resolve_capture(scene, caster)
    mats = scene.materials
    tri = caster.vertices[caster.faces]
    x, dA_x, face = subdivide_triangles(tri, h_hidden)
    n_face = caster.face_normals[face]
    obj = caster.face_object[face]
    # orient normals toward the laser spot and keep elements the spot can light
    to_spot = cap.spot - x
    r_lx = np.linalg.norm(to_spot, axis=1)
    n_x = np.where((np.einsum("ij,ij->i", n_face, to_spot) < 0)[:, None], -n_face, n_face)
    w_lx = -to_spot / r_lx[:, None]
    cos_l = w_lx @ cap.spot_normal
    cos_x_in = np.einsum("ij,ij->i", n_x, to_spot) / r_lx
    keep = (cos_l > 1e-12) & (cos_x_in > 1e-12)
    keep[keep] = caster.visible(x[keep], n_x[keep], cap.spot, cap.spot_normal)
    x, dA_x, n_x, obj, r_lx, w_lx = x[keep], dA_x[keep], n_x[keep], obj[keep], r_lx[keep], w_lx[keep]
    w_e = (cap.emitter - cap.spot) / cap.emitter_leg
    f_l = mats.evaluate(np.full(len(x), cap.spot_object), cap.spot_normal[None], w_e[None], w_lx)
    flux = cap.photons * f_l * (w_lx @ cap.spot_normal) * np.einsum("ij,ij->i", n_x, -w_lx) / r_lx ** 2 * dA_x
    # FoV elements on the relay wall, seen by the sensor
    nu = int(np.ceil(cap.fov_size[0] / h_fov))
    nv = int(np.ceil(cap.fov_size[1] / h_fov))
    gu = ((np.arange(nu) + 0.5) / nu - 0.5) * cap.fov_size[0]
    gv = ((np.arange(nv) + 0.5) / nv - 0.5) * cap.fov_size[1]
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    y_target = cap.fov_center + uu.reshape(-1, 1) * cap.fov_u + vv.reshape(-1, 1) * cap.fov_v
    d_dir = y_target - cap.sensor
    probe = caster.intersect(np.broadcast_to(cap.sensor, d_dir.shape), d_dir / np.linalg.norm(d_dir, axis=1)[:, None])
    tol = FOV_PLANE_TOL * caster.offset
    on = probe.hit & (np.linalg.norm(np.nan_to_num(probe.points) - y_target, axis=1) < tol)
    y, n_y, obj_y = y_target[on], probe.normals[on], probe.object_id[on]
    dA_y = (cap.fov_size[0] / nu) * (cap.fov_size[1] / nv)
    to_s = cap.sensor - y
    d_ys = np.linalg.norm(to_s, axis=1)
    w_ys = to_s / d_ys[:, None]
    cos_ap = np.maximum(-np.sum(w_ys * cap.aperture_normals(y), axis=-1), 0.0)
    sensor_geo = pde * np.einsum("ij,ij->i", n_y, w_ys) * cap.aperture_area * cos_ap / d_ys ** 2
    acc = EnvelopeAccumulator(axis, irf, 1)
    step = max(1, chunk // max(len(y), 1))
    for s in range(0, len(x), step):
        xs = slice(s, s + step)
        d = y[None] - x[xs, None]                          # (a, b, 3)
        r = np.linalg.norm(d, axis=-1)
        w = d / r[..., None]
        cos_xo = np.einsum("ik,ijk->ij", n_x[xs], w)
        cos_yi = -np.einsum("jk,ijk->ij", n_y, w)
        ok = (cos_xo > 0) & (cos_yi > 0)
        ia, ib = np.nonzero(ok)
        if len(ia) == 0:
            continue
        vis = caster.visible(x[xs][ia], n_x[xs][ia], y[ib], n_y[ib])
        ia, ib = ia[vis], ib[vis]
        w_ab = w[ia, ib]
        f_x = mats.evaluate(obj[xs][ia], n_x[xs][ia], -w_lx[xs][ia], w_ab)
        f_y = mats.evaluate(obj_y[ib], n_y[ib], -w_ab, w_ys[ib])
        weight = (flux[xs][ia] * f_x * cos_xo[ia, ib] * cos_yi[ia, ib] / r[ia, ib] ** 2 * dA_y
                  * f_y * sensor_geo[ib])
        t = r_lx[xs][ia] + r[ia, ib] + (d_ys[ib] if count_sensor_leg else 0.0)
        acc.add(t / SPEED_OF_LIGHT, weight, 0)
    return acc.binned()[0], float(acc.total_weight()[0])
