"""The effect planner's coarse area quadrature of the primary and secondary energy (photons per pulse).

A fourth estimator of the transient path integral (docs/physics.md §2), deliberately coarse (≈ 160 hidden
elements × 5×5 FoV cells, shadow rays on every leg): its only job is to tell whether the secondary or pile-up
can matter at the planner's tolerance. The per-leg weights are those of :mod:`datagen.transport.physics`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..sampling.surfaces import subdivide_triangles, subdivisions
from ..transport.leg_kernels import material_arrays
from ..transport.physics import fov_connection_weight, laser_irradiance
from .coarse_kernel import outgoing_sums, primary_energy, secondary_candidates, secondary_energy
from .geometry import PlanGeometry
from ..vectors import matmul

COARSE_ELEMENTS = 160
"""Target number of hidden-surface elements of the coarse quadrature (cost ∝ elements²: ~0.01 s for the
demo room with the compiled sums of :mod:`.coarse_kernel`; 256 elements moved its ratio by 6 % for 3× the time)."""

COARSE_ELEMENTS_MAX = 250
"""Hard cap on coarse elements; meshes with more triangles are sampled by area instead of subdivided."""

COARSE_FOV = (5, 5)
"""FoV cells of the coarse quadrature."""

PLANNER_SEED = 20240520
"""Seed of the area sampling used only when a mesh has more than ``COARSE_ELEMENTS_MAX`` triangles, so
the plan of a scene is always the same."""


@dataclass(frozen=True)
class CoarseEnergies:
    """Coarse quadrature energies (expected detected photons per pulse) per representative laser point."""

    primary_per_laser: np.ndarray      # (A,) primary (three-bounce) energy
    secondary_per_laser: np.ndarray    # (A,) energy of paths with two hidden vertices
    elements: int

    @property
    def primary(self) -> float:
        return float(self.primary_per_laser.max(initial=0.0))

    @property
    def secondary(self) -> float:
        return float(self.secondary_per_laser.max(initial=0.0))

    @property
    def ratio(self) -> float:
        """max over laser points of secondary / primary (inf when a point has secondary but no primary)."""
        p, s = self.primary_per_laser, self.secondary_per_laser
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(s > 0, s / p, 0.0)
        return float(r.max(initial=0.0))

    @property
    def signal(self) -> float:
        return self.primary

    @property
    def signal_with_secondary(self) -> float:
        return float((self.primary_per_laser + self.secondary_per_laser).max(initial=0.0))


def hidden_elements(g: PlanGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints (M, 3), geometric unit normals (M, 3), areas (M,) and object ids (M,) of hidden elements.

    Hidden triangles are split into k² congruent sub-triangles (:func:`datagen.sampling.subdivide_triangles`)
    with the edge length chosen for about ``COARSE_ELEMENTS`` elements; when the mesh has more than
    ``COARSE_ELEMENTS_MAX`` triangles, ``COARSE_ELEMENTS_MAX`` points are drawn by area instead (seeded).
    """
    faces = np.flatnonzero(g.hidden)
    if len(faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    tri = g.tri[faces]
    area = g.caster.face_area[faces]
    if len(faces) > COARSE_ELEMENTS_MAX:
        rng = np.random.default_rng(PLANNER_SEED)
        pick = rng.choice(len(faces), size=COARSE_ELEMENTS_MAX, p=area / area.sum())
        u, v = rng.random((2, COARSE_ELEMENTS_MAX))
        flip = u + v > 1
        u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
        t = tri[pick]
        pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
        return pts, g.normal[faces[pick]], np.full(len(pick), area.sum() / len(pick)), g.object[faces[pick]]
    h = math.sqrt(4.0 * area.sum() / COARSE_ELEMENTS)
    while np.sum(subdivisions(tri, h) ** 2) > COARSE_ELEMENTS_MAX:
        h *= 1.25
    pts, areas, parent = subdivide_triangles(tri, h)
    return pts, g.normal[faces[parent]], areas, g.object[faces[parent]]


def coarse_energies(g: PlanGeometry) -> CoarseEnergies:
    """Midpoint area quadrature of docs/physics.md §2 for the primary and the secondary energy (photons/pulse).

    Hidden elements (≤ COARSE_ELEMENTS_MAX) × FoV cells (COARSE_FOV; for point radiance up to that many
    sensor points, per unit area, as the transport connects them) with shadow rays on every leg, for each
    representative laser point; the per-leg weights are the transport's own (``spot_emission``,
    ``sensor_collection``). Surfaces are two-sided: each vertex reflects on the side the light comes from.
    """
    c, tol, caster, tr = g.capture, g.tol, g.caster, g.physics
    x, n_geo, area, obj = hidden_elements(g)
    zero = np.zeros(len(g.lasers))
    # FoV cells (point radiance: sensor points, per unit area) that lie on a surface the sensor looks at
    if c.convention == "point_radiance":
        points = c.sensor_points()
        iy = np.unique(np.linspace(0, points.shape[0] - 1, COARSE_FOV[1]).round().astype(int))
        ix = np.unique(np.linspace(0, points.shape[1] - 1, COARSE_FOV[0]).round().astype(int))
        y, area_y = points[np.ix_(iy, ix)].reshape(-1, 3), 1.0
    else:
        nu, nv = COARSE_FOV
        uu, vv = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv, indexing="ij")
        y = c.fov_points(uu.reshape(-1) * c.fov_pixels[0], vv.reshape(-1) * c.fov_pixels[1])
        area_y = c.fov_size[0] * c.fov_size[1] / (nu * nv)
    d_sy = y - c.sensor
    probe = caster.intersect(np.broadcast_to(c.sensor, y.shape), d_sy / np.linalg.norm(d_sy, axis=1)[:, None])
    on = probe.hit & (np.linalg.norm(probe.hit_points() - y, axis=1) < tol)
    y, obj_y = y[on], probe.object_id[on]
    if len(x) == 0 or len(y) == 0:
        return CoarseEnergies(zero, zero, len(x))
    # element → FoV cell → sensor: geometry × collection, for the side of the element facing the cell
    d_xy = y[None] - x[:, None]                                            # (M, K, 3)
    r_xy = np.linalg.norm(d_xy, axis=-1)
    w_xy = d_xy / np.maximum(r_xy, 1e-300)[..., None]
    s_xy = np.sign(np.einsum("mk,mjk->mj", n_geo, w_xy))                  # side of x that sees y
    cos_xo = np.abs(np.einsum("mk,mjk->mj", n_geo, w_xy))
    cos_yi = matmul(-w_xy, c.fov_normal)
    mi, ki = np.nonzero((cos_xo > 0) & (cos_yi > 0) & (r_xy > tol))
    geo = np.zeros(r_xy.shape)
    if len(mi):
        vis = caster.visible(x[mi], s_xy[mi, ki][:, None] * n_geo[mi], y[ki], c.fov_normal)
        mi, ki = mi[vis], ki[vis]
        collect, _ = tr.sensor_collection(y[ki], np.broadcast_to(c.fov_normal, (len(ki), 3)), obj_y[ki],
                                          -w_xy[mi, ki])
        geo[mi, ki] = fov_connection_weight(cos_xo[mi, ki] * cos_yi[mi, ki], r_xy[mi, ki], area_y * collect)
    sees_fov = geo.sum(axis=1) > 0
    mat = material_arrays(g.physics)
    table = outgoing_sums(obj, n_geo, s_xy, w_xy, geo, mat)     # y-sums of the factoring BRDFs, every laser
    primary, secondary = zero.copy(), zero.copy()
    for i, laser in enumerate(g.lasers):
        primary[i], secondary[i] = coarse_one_laser(g, int(laser), x, n_geo, area, obj, w_xy, s_xy, geo,
                                                     sees_fov, mat, table)
    return CoarseEnergies(primary, secondary, len(x))


def coarse_one_laser(g, laser, x, n_geo, area, obj, w_xy, s_xy, geo, sees_fov, mat, table) -> tuple[float, float]:
    """(primary, secondary) energy of laser point ``laser`` (photons per pulse): the spot leg and its shadow rays
    here, the sums over element pairs and FoV cells in :mod:`.coarse_kernel`."""
    c, tol, caster = g.capture, g.tol, g.caster
    spot, spot_n = c.spots[laser], c.spot_normals[laser]
    # laser spot → element: irradiance E_l (photons/m²) on the side facing the spot
    d_lx = x - spot
    r_lx = np.linalg.norm(d_lx, axis=1)
    w_lx = d_lx / np.maximum(r_lx, 1e-300)[:, None]
    side = np.sign(np.einsum("ij,ij->i", n_geo, -d_lx))
    n_lit = side[:, None] * n_geo
    cos_in = np.einsum("ij,ij->i", n_lit, -w_lx)
    ok = (matmul(w_lx, spot_n) > 0) & (cos_in > 0) & (r_lx > tol)
    ok[ok] = caster.visible(x[ok], n_lit[ok], spot, spot_n)
    lit = np.flatnonzero(ok)
    if len(lit) == 0:
        return 0.0, 0.0
    irradiance = np.zeros(len(x))
    irradiance[lit] = laser_irradiance(c.photons, g.physics.spot_emission(w_lx[lit], laser), cos_in[lit], r_lx[lit])
    # primary: E_l dA_x f_x(→spot, →y) geo
    primary = primary_energy(lit, irradiance, area, obj, n_lit, w_lx, side, s_xy, w_xy, geo, mat)
    # secondary: E_l dA_x f_x(→spot, →x') cos cos'/r² V dA_x' f_x'(→x, →y) geo
    xa, xb, w, r, cos_a, cos_b, side_b = secondary_candidates(lit, np.flatnonzero(sees_fov), x, n_lit, n_geo, tol)
    vis = caster.visible(x[xa], n_lit[xa], x[xb], side_b[:, None] * n_geo[xb])
    if not vis.any():
        return primary, 0.0
    secondary = secondary_energy((xa[vis], xb[vis], w[vis], r[vis], cos_a[vis], cos_b[vis], side_b[vis]), irradiance,
                                 area, obj, n_lit, w_lx, n_geo, s_xy, w_xy, geo, mat, table)
    return float(primary), float(secondary)
