"""Compiled (numba) passes of the area sampler between its ray batches: the same formulas, fewer array passes.

The area sampler (:mod:`datagen.transport.area`, :mod:`datagen.transport.area.secondary`) casts its rays in
batches (Embree); between them it used to run dozens of numpy passes over (hidden sample × FoV point) and
(connection × partner) arrays. The kernels here do that arithmetic in one pass each and take every random
number pre-drawn by the caller, so the random streams are those of the numpy code. The formulas are those of
:mod:`datagen.transport.physics` and :class:`datagen.scene.materials.MaterialTable` (docs/physics.md §2):

- :func:`~datagen.scene.brdf_kernel.brdf_value` (re-exported here): f(ω_in, ω_out) of one point, every BRDF kind
  from the formula functions of :mod:`datagen.scene.brdf_kernel` (0 where a direction lies below the surface);
- :func:`fov_targets`: the stratified FoV points of :meth:`AreaSampler._connect` and their geometry;
  :func:`lobe_directions`: its FoV direction rays at retroreflective points, drawn from their BRDF;
- :func:`partner_geometry` / :func:`partner_irradiance`: the x' → x geometry of the secondary's partners and
  the MIS irradiance term E(x') f_x' G / Σ_t P_t p_t(x');
- :func:`secondary_pairs`: every (FoV connection, partner) pair's time, weight (per-connection weight × partner
  irradiance × BRDF at x × e^{−μ·path}) and component.

``tests/test_area_kernels.py`` compares each kernel with the numpy formulas of :mod:`datagen.transport.physics`
and :class:`~datagen.scene.materials.MaterialTable` (relative 1e-12). The kernels compile once per process
(``cache=True`` stores them next to this file, or in numba's user-wide cache when the package is read-only).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...scene.brdf_kernel import RETROREFLECTIVE, abs_sin_azimuth, brdf_value, sample_directions, sampling_ratio
from ...units import SPEED_OF_LIGHT
from ..leg_kernels import fov_target, material_arrays, sensor_collection, toward  # noqa: F401 (shared)
from ..physics import attenuation_term, emission_term, fov_term, geometry_term, irradiance_term
from ...vectors import norm

__all__ = ["abs_sin_azimuth", "brdf_value", "fov_targets", "lobe_directions", "material_arrays", "partner_geometry",
           "partner_irradiance", "secondary_pairs"]


@njit(cache=True)
def fov_targets(x, n_x, ix, iy, corner, jitter, cells, fov):
    """Stratified FoV points of every hidden point and the geometry of the pairs that face each other.

    Args:
        x, n_x: (B, 3) hidden points and the normals of the side they connect from.
        ix, iy: (S,) int pixel column and row of each target cell; corner: (S, 2) the cell's corner inside
            its pixel (in pixel units); jitter: (B, S, 2) or (B, 1, 2) shift in [0, 1)² of each cell (or of
            all cells of a row); cells: (mu, mv) cells per pixel.
        fov: (center (3,), u (3,), v (3,), normal (3,), size (2,), pixels (2,)) of the sensor grid
            (:meth:`datagen.scene.capture.Capture.fov_points`).
    Returns:
        (bi (n,) int64, si (n,) int64, y (n, 3), w (n, 3) unit x → y, r (n,) |y − x|, cos_y (n,)) for the
        pairs with n_x·w > 0 and cosθ_y = −w·n_fov > 0, row-major in (b, s) as ``np.nonzero``.
    """
    mu, mv = cells
    nb, ns = x.shape[0], ix.shape[0]
    shared = jitter.shape[1] == 1
    cap = nb * ns
    bi = np.empty(cap, np.int64)
    si = np.empty(cap, np.int64)
    y = np.empty((cap, 3))
    w = np.empty((cap, 3))
    r = np.empty(cap)
    cy = np.empty(cap)
    k = 0
    for b in range(nb):
        for s in range(ns):
            j = 0 if shared else s
            cu = ix[s] + (corner[s, 0] + jitter[b, j, 0] / mu)
            cv = iy[s] + (corner[s, 1] + jitter[b, j, 1] / mv)
            t0, t1, t2, rr, w0, w1, w2, cos_y, faces = fov_target(x, n_x, b, cu, cv, fov)
            if faces:
                bi[k], si[k] = b, s
                y[k, 0], y[k, 1], y[k, 2] = t0, t1, t2
                w[k, 0], w[k, 1], w[k, 2] = w0, w1, w2
                r[k], cy[k] = rr, cos_y
                k += 1
    return bi[:k], si[:k], y[:k], w[:k], r[:k], cy[:k]


@njit(cache=True)
def partner_geometry(x, nf, pos, neg, p_tot, points, normals, found, min_distance):
    """Geometry of the partners x' (n·P rows, owner-major) of the n hidden points x (secondary_paths).

    Args:
        x, nf: (n, 3) hidden points and their face normals; pos, neg: (n,) bool, x has FoV connections on its
            +normal / −normal side; p_tot: P partners per point; points, normals: (n·P, 3) partners and their
            face normals; found: (n·P,) bool; min_distance: metres below which a pair is dropped.
    Returns:
        rp (m,) |x − x'|; wpx (m, 3) unit x' → x; cos_p, cos_x (m,) |cos| at x' and x; on_pos (m,) bool, x' on
        x's +normal side; keep (m,) bool (found, farther than ``min_distance``, both cosines > 0, x has
        connections on that side); n_px (m, 3) x' normal facing x; n_xp (m, 3) x normal facing x'.
    """
    m = points.shape[0]
    rp = np.empty(m)
    wpx = np.empty((m, 3))
    cos_p = np.empty(m)
    cos_x = np.empty(m)
    on_pos = np.empty(m, np.bool_)
    keep = np.empty(m, np.bool_)
    n_px = np.empty((m, 3))
    n_xp = np.empty((m, 3))
    for i in range(m):
        o = i // p_tot
        r, w0, w1, w2 = toward(points[i, 0], points[i, 1], points[i, 2], x[o, 0], x[o, 1], x[o, 2])
        pw = normals[i, 0] * w0 + normals[i, 1] * w1 + normals[i, 2] * w2
        xw = nf[o, 0] * w0 + nf[o, 1] * w1 + nf[o, 2] * w2
        rp[i] = r
        wpx[i, 0], wpx[i, 1], wpx[i, 2] = w0, w1, w2
        cos_p[i], cos_x[i] = abs(pw), abs(xw)
        on_pos[i] = xw < 0.0
        covered = pos[o] if xw < 0.0 else neg[o]
        keep[i] = found[i] and r > min_distance and abs(pw) > 0.0 and abs(xw) > 0.0 and covered
        sp = -1.0 if pw < 0.0 else 1.0
        sx = 1.0 if xw < 0.0 else -1.0
        for k in range(3):
            n_px[i, k] = sp * normals[i, k]
            n_xp[i, k] = sx * nf[o, k]
    return rp, wpx, cos_p, cos_x, on_pos, keep, n_px, n_xp


@njit(cache=True)
def partner_irradiance(keep, e_p, geo_p, cos_p, cos_x, rp, n_sides, p_tot, hidden_w, counts, obj, n_px, w_sp,
                       wpx, mat):
    """MIS irradiance term of each kept partner: E(x') f_x'(ω→x_l, ω→x) G / (P_l p_l + P_d p_d + P_a p_a), 0 for
    the others (m,).

    G = cosθ_x' cosθ_x / r², p_l = geo/π (cosine directions from the spot), p_d = G / (π · sides of x)
    (cosine directions from x), p_a = ``hidden_w`` (1/A_hidden on hidden faces, else 0); ``counts`` =
    (P_l, P_d, P_a); f from :func:`brdf_value` with the x' normal facing x ``n_px``, ω_in = ``w_sp`` toward
    the spot, ω_out = ``wpx`` toward x; ``n_sides`` (n,) per owner (row // ``p_tot``).
    """
    pl, pd, pa = counts
    m = keep.shape[0]
    irr = np.zeros(m)
    for i in range(m):
        if not keep[i]:
            continue
        g = geometry_term(cos_p[i], cos_x[i], rp[i])
        p_spot = geo_p[i] / np.pi
        p_dir = g / (np.pi * n_sides[i // p_tot])
        f = brdf_value(mat, obj[i], n_px[i, 0], n_px[i, 1], n_px[i, 2], w_sp[i, 0], w_sp[i, 1], w_sp[i, 2],
                       wpx[i, 0], wpx[i, 1], wpx[i, 2])
        irr[i] = e_p[i] * f * g / (pl * p_spot + pd * p_dir + pa * hidden_w[i])
    return irr


@njit(cache=True)
def secondary_pairs(inv, side, p_tot, partners, conns, obj_x, mat, legs, comp0):
    """Every (FoV connection, partner of its hidden point) pair whose partner irradiance is > 0 and whose light
    leaves x on the side it arrived from: arrival times (s), weights (photons) and component ids.

    Args:
        inv: (c,) owner row of each connection; side: (c,) bool, the connection leaves x's +normal side;
            p_tot: partners per owner (partner j of owner o is row o·P + j of the ``partners`` arrays).
        partners: (irr, on_pos, wpx, r_lp, rp): irr (m,) :func:`partner_irradiance`; on_pos (m,) bool; wpx (m, 3)
            unit x' → x; r_lp, rp (m,) metres x_l → x' and x' → x.
        conns: (normal, direction, weight, phys, time, channel), the connections (:class:`~.base.Connections`
            fields and the side's normal at x); obj_x (c,) the object of each connection's x; mat:
            :func:`material_arrays`.
        legs: (μ 1/m, emitter leg m, laser leg counted in the time m); comp0: first secondary component id.
    Returns:
        (t (k,), w (k,), comp (k,) int64), connection-major, partners in row order. Weight =
        max(n·ω, 0)·weight · irr · f_x(ω_in = x → x', ω_out) · e^{−μ(emitter leg + r_lp + rp + phys)} (no factor
        when μ = 0); time = (laser leg + r_lp + rp)/c + time.
    """
    irr, on_pos, wpx, r_lp, rp = partners
    normal, direction, weight, phys, time, channel = conns
    mu, emitter_leg, laser_leg = legs
    const_f = mat[5]
    nc = inv.shape[0]
    cap = nc * p_tot
    t_out = np.empty(cap)
    w_out = np.empty(cap)
    c_out = np.empty(cap, np.int64)
    k = 0
    for c in range(nc):
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        o0, o1, o2 = direction[c, 0], direction[c, 1], direction[c, 2]
        per_conn = max(n0 * o0 + n1 * o1 + n2 * o2, 0.0) * weight[c]
        f_const = const_f[obj_x[c]]
        for j in range(inv[c] * p_tot, (inv[c] + 1) * p_tot):
            if not (irr[j] > 0.0 and on_pos[j] == side[c]):
                continue
            f = f_const
            if math.isnan(f):
                f = brdf_value(mat, obj_x[c], n0, n1, n2, -wpx[j, 0], -wpx[j, 1], -wpx[j, 2], o0, o1, o2)
            w = per_conn * irr[j] * f
            if mu > 0.0:
                w = w * attenuation_term(mu, emitter_leg + r_lp[j] + rp[j] + phys[c])
            t_out[k] = (laser_leg + r_lp[j] + rp[j]) / SPEED_OF_LIGHT + time[c]
            w_out[k] = w
            c_out[k] = comp0 + channel[c]
            k += 1
    return t_out[:k], w_out[:k], c_out[:k]


@njit(cache=True)
def _spot_geometry(points, normals, rows, spot, spot_n, tol):
    n = points.shape[0]
    r = np.zeros(n)
    w = np.zeros((n, 3))
    cos_in = np.zeros(n)
    cos_l = np.zeros(n)
    lit = np.zeros(n, np.bool_)
    n_lit = np.zeros((n, 3))
    for i in rows:
        rr, w0, w1, w2 = toward(points[i, 0], points[i, 1], points[i, 2], spot[0], spot[1], spot[2])
        nfw = normals[i, 0] * w0 + normals[i, 1] * w1 + normals[i, 2] * w2
        r[i] = rr
        w[i, 0], w[i, 1], w[i, 2] = w0, w1, w2
        cos_in[i] = abs(nfw)
        cos_l[i] = -(w0 * spot_n[0] + w1 * spot_n[1] + w2 * spot_n[2])
        lit[i] = cos_l[i] > 0.0 and abs(nfw) > 0.0 and rr > tol
        sign = -1.0 if nfw < 0.0 else 1.0
        for k in range(3):
            n_lit[i, k] = sign * normals[i, k]
    return r, w, cos_in, cos_l, lit, n_lit


@njit(cache=True)
def _spot_terms(idx, r, w, cos_in, cos_l, photons, mat, obj, spot_n, w_e):
    n = r.shape[0]
    e = np.zeros(n)
    geo = np.zeros(n)
    for i in idx:
        o0, o1, o2 = -w[i, 0], -w[i, 1], -w[i, 2]
        cos = max(spot_n[0] * o0 + spot_n[1] * o1 + spot_n[2] * o2, 0.0)
        f = brdf_value(mat, obj, spot_n[0], spot_n[1], spot_n[2], w_e[0], w_e[1], w_e[2], o0, o1, o2)
        geo[i] = geometry_term(cos_l[i], cos_in[i], r[i])
        e[i] = irradiance_term(photons, emission_term(f, cos), cos_in[i], r[i])
    return e, geo


def spot_irradiance(physics, points: np.ndarray, face_normals: np.ndarray, laser: int,
                    rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`datagen.transport.physics.LegPhysics.irradiance` of ``physics`` in two compiled passes around its
    shadow-ray batch: the same returns (E photons/m² (n,), r m (n,), unit direction to the spot (n, 3), geo
    1/m² (n,)) for points (n, 3) with face normals (n, 3), lit on the side facing laser point ``laser``; E =
    Φ f_l cosθ_l cosθ_in / r² V (:func:`~datagen.transport.physics.laser_irradiance` of
    :meth:`~datagen.transport.physics.LegPhysics.spot_emission`). ``rows`` (int64 indices): evaluate only
    those points, the others get zeros (as if they were not passed)."""
    c = physics.capture
    spot, spot_n = c.spots[laser], c.spot_normals[laser]
    points, face_normals = np.ascontiguousarray(points), np.ascontiguousarray(face_normals)
    rows = np.arange(len(points)) if rows is None else rows
    r, w, cos_in, cos_l, lit, n_lit = _spot_geometry(points, face_normals, rows, spot, spot_n, physics.tol)
    idx = np.flatnonzero(lit)
    if physics.settings.shadow_spot and len(idx):
        physics.stats.shadow_rays += len(idx)
        idx = idx[physics.caster.visible(points[idx], n_lit[idx], spot, spot_n)]
    w_e = c.emitter - spot
    w_e = w_e / norm(w_e)
    e, geo = _spot_terms(idx, r, w, cos_in, cos_l, float(c.photons), material_arrays(physics),
                         int(c.spot_objects[laser]), spot_n, w_e)
    return e, r, w, geo


@njit(cache=True)
def primary_impulses(b, primary, e_x, obj, w_spot, r_lx, normal, direction, weight, phys, time, channel,
                     component, n_channels, mat, legs):
    """Primary impulses of FoV connections (rows ``b`` into the hidden samples) that leave x on the side the spot
    lights (``primary``) from a lit x (E > 0): times (s), weights (photons), component ids, in connection order.

    Weight = E(x) · f_x(ω→x_l, ω) · max(n·ω, 0) · weight · e^{−μ(emitter leg + r_lx + phys)} (no factor when
    μ = 0), time = laser leg / c + r_lx / c + time, component = component[obj]·n_channels + channel; ``legs`` =
    (μ 1/m, emitter leg m, laser leg counted in the time m); ``mat`` from :func:`material_arrays`; e_x, obj,
    w_spot (toward the spot), r_lx per hidden sample; the rest per connection.
    """
    mu, emitter_leg, laser_leg = legs
    laser_t = laser_leg / SPEED_OF_LIGHT
    nc = b.shape[0]
    t_out = np.empty(nc)
    w_out = np.empty(nc)
    c_out = np.empty(nc, np.int64)
    k = 0
    for c in range(nc):
        x = b[c]
        if not (primary[c] and e_x[x] > 0.0):
            continue
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        o0, o1, o2 = direction[c, 0], direction[c, 1], direction[c, 2]
        f = brdf_value(mat, obj[x], n0, n1, n2, w_spot[x, 0], w_spot[x, 1], w_spot[x, 2], o0, o1, o2)
        w = e_x[x] * f * max(n0 * o0 + n1 * o1 + n2 * o2, 0.0) * weight[c]
        if mu > 0.0:
            w = w * attenuation_term(mu, emitter_leg + r_lx[x] + phys[c])
        t_out[k] = laser_t + r_lx[x] / SPEED_OF_LIGHT + time[c]
        w_out[k] = w
        c_out[k] = component[obj[x]] * n_channels + channel[c]
        k += 1
    return t_out[:k], w_out[:k], c_out[:k]


@njit(cache=True)
def partner_rays(keep, e_p, n_px, w_sp, p_tot, first_hits):
    """Keep (in place) the partners x' lit by the laser (E > 0) that reflect toward x from their lit side
    (n_px·w_sp > 0), and return the rows among them that need an x' ↔ x shadow ray: all but the slots
    [first_hits[0], first_hits[1]) of each owner's ``p_tot`` (first hits of rays from x, visible by construction)."""
    lo, hi = first_hits
    m = keep.shape[0]
    idx = np.empty(m, np.int64)
    k = 0
    for i in range(m):
        if keep[i]:
            keep[i] = e_p[i] > 0.0 and n_px[i, 0] * w_sp[i, 0] + n_px[i, 1] * w_sp[i, 1] + n_px[i, 2] * w_sp[i, 2] > 0.0
        slot = i % p_tot
        if keep[i] and not (lo <= slot < hi):
            idx[k] = i
            k += 1
    return idx[:k]


@njit(cache=True)
def connection_weights(b, n_x, rho_x, w, r, cos_y, collect, d_ys, consts, obj, w_in, mat):
    """Weights, times and path lengths of FoV connections (hidden point ``b`` → FoV point y): the balance heuristic
    of :meth:`datagen.transport.area.AreaSampler._connect` times
    :func:`~datagen.transport.physics.fov_connection_weight`,

        weight = cosθ_y / r² · collection / (ρ_x (ρ_a + D p_d s) + (M_f/A_FoV) p_d)   (0 where the density is 0),
        p_d = cosθ_x cosθ_y / (π r²),  cosθ_x = n_x[b]·ω,

    s the density of the point's direction sampler over the cosine density toward y
    (:func:`~datagen.scene.brdf_kernel.sampling_ratio` for light from ω_in = w_in[b]: exactly 1 but at
    retroreflective points). time = (r + d_ys if the sensor leg counts, else r) / c, phys = r + d_ys. b (n,) rows of
    n_x (B, 3), rho_x (B,), obj (B,) int and w_in (B, 3) (unit, toward the laser point); w (n, 3) unit x → y; r,
    cos_y, collect, d_ys (n,); consts = (ρ_a 1/m², D, M_f/A_FoV 1/m², sensor leg counted 1.0 or 0.0); mat the
    material arrays."""
    rho_a, n_dir, fov_density, count_sensor = consts
    n = b.shape[0]
    weight = np.empty(n)
    time = np.empty(n)
    phys = np.empty(n)
    for i in range(n):
        k = b[i]
        r2 = r[i] ** 2
        cos_x = n_x[k, 0] * w[i, 0] + n_x[k, 1] * w[i, 1] + n_x[k, 2] * w[i, 2]
        p_d = cos_x * cos_y[i] / (np.pi * r2)
        s = sampling_ratio(mat, obj[k], n_x[k, 0] * w_in[k, 0] + n_x[k, 1] * w_in[k, 1] + n_x[k, 2] * w_in[k, 2],
                           cos_x, w_in[k, 0] * w[i, 0] + w_in[k, 1] * w[i, 1] + w_in[k, 2] * w[i, 2])
        density = rho_x[k] * (rho_a + n_dir * p_d * s) + fov_density * p_d
        inverse = 1.0 / density if density > 0.0 else 0.0
        weight[i] = inverse * fov_term(cos_y[i], r[i], collect[i])
        time[i] = (r[i] + d_ys[i] if count_sensor else r[i]) / SPEED_OF_LIGHT
        phys[i] = r[i] + d_ys[i]
    return weight, time, phys


def lobe_directions(dirs: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_spot: np.ndarray, uv: tuple,
                    mat: tuple) -> None:
    """Redraw, in place, the FoV direction rays ``dirs`` (B, D, 3) of :meth:`AreaSampler._connect` at the points
    whose material samples a lobe (retroreflective, lit from above the side n_x (B, 3) connects from:
    :func:`~datagen.scene.brdf_kernel.samples_lobe`, light from the unit directions ``w_spot`` (B, 3) toward the
    laser point; objects ``obj`` (B,) int) from their BRDF (:func:`~datagen.scene.brdf_kernel.sample_direction`),
    with the same uniforms ``uv`` = (u, v), each (B, D); the other rows keep their cosine directions and their bits.
    :func:`connection_weights` weighs both by the density they were drawn from."""
    kind, specular = mat[0], mat[2]
    rows = np.flatnonzero((kind[obj] == RETROREFLECTIVE) & (specular[obj] > 0)
                          & (np.einsum("ij,ij->i", n_x, w_spot) > 0))
    if not len(rows):
        return
    u, v = uv
    d = dirs.shape[1]
    dirs[rows] = sample_directions(np.repeat(n_x[rows], d, 0), np.repeat(obj[rows], d), np.repeat(w_spot[rows], d, 0),
                                   u[rows].ravel(), v[rows].ravel(), mat).reshape(len(rows), d, 3)
