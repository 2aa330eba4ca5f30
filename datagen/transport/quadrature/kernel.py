"""Compiled (numba) primary of the hidden-surface quadrature: one pass per (sub-triangle, connection) pair.

For each pair of a block of connections (laser point l, target y, channel) and each sub-triangle T (centroid x,
face normal n, area A) the kernel evaluates what :meth:`datagen.transport.quadrature.Quadrature._primary` builds
from the per-leg functions of :mod:`datagen.transport.physics` (the documented source of every factor), for
Lambertian, Phong or retroreflective hidden surfaces, Lambertian laser points and relay wall (``brdf_angles`` off;
the wall's collection then does not depend on the incoming direction):

- laser leg (:meth:`~datagen.transport.physics.LegPhysics.irradiance`): E = Φ (ρ_l/π) cosθ_l cosθ_x,in / r_l²,
  lit on the side of T facing x_l, when cosθ_l > 0, cosθ_x,in > 0 and r_l > tol;
- target leg (:func:`~datagen.transport.physics.fov_connection_weight`): G = |cosθ_x,out| cosθ_y / r_y² ·
  collection(y) dA_y, on the side facing y;
- weight A · E · f · G (· e^{−μ·path}), f = ρ/π, Phong's or the retroreflective kind's
  (:meth:`datagen.scene.materials.MaterialTable.evaluate`),
  when both legs reach the same side; path lengths at the vertices of T and the tent shift of the module doc of
  :mod:`datagen.transport.quadrature`; the tent (and the coarse rule's tent for the error estimate) goes to the
  accumulator's fine grid by :func:`datagen.timing.tent_kernel.deposit_tent`.

Per connection the legs (without the hidden BRDF) and the sorted tent nodes of every sub-triangle are first
computed in loops with no branch on a pair's values (:func:`_cell_legs`, :func:`_cell_nodes`: SIMD lanes, ≈ 5 ns
per pair), then the contributing pairs are deposited one by one (the BRDF, visibility and tents).

Visibility of the laser leg (``shadow``): only the triangles that may cross a segment from T's face to the laser
points (the separating-plane test per face), grouped in runs of one object with a bounding sphere and in chunks
of eight with spheres of their own (a face of a curved mesh has dozens to hundreds of candidates), are tested,
exactly in float64 (:func:`_blocked`): a segment that misses them all by more than ``margin`` is visible, one that
crosses a triangle more than ``margin`` inside its edges is blocked, and only the rest (within ``margin`` of an
edge) is listed for an Embree shadow ray (:func:`candidates`) and deposited after it (:func:`deposit_pairs`).
Embree's float32 rays leak through shared edges now and then (measured: a segment 0.5–2 mm inside a box's face
4.7 m from its start, reported unblocked); the exact test does not, so the compiled envelope differs from the
numpy path's by such pairs (2e-8 relative on a confocal room scan). Where ``face_ray`` (per hidden face) each lit
pair gets its ray; with every face so, the two paths agree to round-off (``tests/test_quadrature_kernel.py``: 1e-9). The
inner side of a closed outward surface (``closed``, :func:`datagen.transport.quadrature.primary.closed_outward`) is never
lit: no test, no ray (Embree's pushed-off rays call a few such points within an offset of a convex edge lit: 1e-6 of
a coarse torus's envelope). Visibility of the hidden → FoV leg (``shadow_fov``: targets other than the laser
points) comes from a map of one shadow ray per (target, sub-triangle) from its centroid, as the numpy path's
(:meth:`datagen.transport.quadrature.Quadrature.target_leg`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ... import threads  # noqa: F401  (numba's threading layer, before any parallel kernel)
from ...scene.brdf_kernel import (PHONG, RETROREFLECTIVE, phong_cos_alpha, phong_power, phong_value, retro_cos_h,
                                  retro_value)
from ...timing.tent_kernel import deposit_tent, sort3
from ..physics import attenuation_term, emission_term, fov_term, irradiance_term

__all__ = ["candidates", "channel_groups", "deposit_pairs", "face_candidates", "occluder_planes"]


def occluder_planes(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes of triangles (k, 3, 3) for the kernel's segment test: (k, 4) unit normal and offset n·p₀, and
    (k, 3, 4) in-plane inward edge normals and offsets (distance of a point of the plane to edge i, metres,
    positive inside). Degenerate triangles get a zero normal (never crossed)."""
    e = np.roll(tri, -1, axis=1) - tri                                   # edge i: v_i → v_{i+1}
    n = np.cross(e[:, 0], e[:, 1])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 0
    n = np.where(ok[:, None], n / np.where(ok, norm, 1.0)[:, None], 0.0)
    plane = np.concatenate([n, np.einsum("ij,ij->i", n, tri[:, 0])[:, None]], axis=1)
    m = np.cross(n[:, None, :], e)                                        # points inward for a CCW edge
    mn = np.linalg.norm(m, axis=2, keepdims=True)
    m = np.where(mn > 0, m / np.where(mn > 0, mn, 1.0), 0.0)
    edges = np.concatenate([m, np.einsum("ijk,ijk->ij", m, tri)[..., None]], axis=2)
    return plane, edges


@njit(cache=True, inline="always")
def _dist(a, i, b, j) -> float:
    """|a[i] − b[j]| for rows of two (n, 3) arrays (scalar indexing: no array views in the inner loops)."""
    d0, d1, d2 = a[i, 0] - b[j, 0], a[i, 1] - b[j, 1], a[i, 2] - b[j, 2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True, inline="always")
def _misses(spheres, r, x0, x1, x2, e0, e1, e2, length2, margin) -> bool:
    """Whether the segment x → x + e (``length2`` = |e|²) passes farther than ``margin`` from sphere r of
    ``spheres`` (R, 4): centre and radius, metres."""
    c0, c1, c2 = spheres[r, 0] - x0, spheres[r, 1] - x1, spheres[r, 2] - x2
    u = min(max((c0 * e0 + c1 * e1 + c2 * e2) / length2, 0.0), 1.0)
    q0, q1, q2 = c0 - u * e0, c1 - u * e1, c2 - u * e2
    reach = spheres[r, 3] + margin
    return q0 * q0 + q1 * q1 + q2 * q2 > reach * reach


@njit(cache=True, inline="always")
def _blocked(centroid, m, spots, l, run_ptr, f, run_chunk, chunk_ptr, spheres, chunk_spheres, idx, plane, edges,
             margin) -> int:
    """Whether a candidate triangle of hidden face f (its runs, each inside a bounding sphere, in chunks of at most
    ``RUN_CHUNK`` triangles inside spheres of their own: :func:`datagen.transport.quadrature.primary.run_chunks`)
    blocks the segment centroid[m] → spots[l]: 0 no (every one is missed by more than ``margin``, or an end lies on
    its plane: its own surface, which the ray's pushed-off end clears), 1 yes (one is crossed with both ends more
    than ``margin`` off its plane and the crossing more than ``margin`` inside its edges: Embree's ray meets it too),
    2 within ``margin`` (a shadow ray decides). The verdict does not depend on the order of the triangles."""
    x0, x1, x2 = centroid[m, 0], centroid[m, 1], centroid[m, 2]
    s0, s1, s2 = spots[l, 0], spots[l, 1], spots[l, 2]
    e0, e1, e2 = s0 - x0, s1 - x1, s2 - x2
    length2 = e0 * e0 + e1 * e1 + e2 * e2
    out = 0
    for r in range(run_ptr[f], run_ptr[f + 1]):
        if _misses(spheres, r, x0, x1, x2, e0, e1, e2, length2, margin):
            continue                                 # the segment misses the run's bounding sphere
        several = run_chunk[r + 1] - run_chunk[r] > 1
        for c in range(run_chunk[r], run_chunk[r + 1]):
            if several and _misses(chunk_spheres, c, x0, x1, x2, e0, e1, e2, length2, margin):
                continue                             # … or the chunk's (its triangles grown by 2·margin)
            for i in range(chunk_ptr[c], chunk_ptr[c + 1]):
                k = idx[i]
                n0, n1, n2, o = plane[k, 0], plane[k, 1], plane[k, 2], plane[k, 3]
                d0 = n0 * x0 + n1 * x1 + n2 * x2 - o
                d1 = n0 * s0 + n1 * s1 + n2 * s2 - o
                if abs(d0) <= margin or abs(d1) <= margin or (d0 > 0.0) == (d1 > 0.0):
                    continue
                t = d0 / (d0 - d1)
                p0 = x0 + t * e0
                p1 = x1 + t * e1
                p2 = x2 + t * e2
                inner = np.inf
                for j in range(3):
                    inner = min(inner, edges[k, j, 0] * p0 + edges[k, j, 1] * p1 + edges[k, j, 2] * p2 - edges[k, j, 3])
                if inner > margin:
                    return 1
                if inner >= -margin:
                    out = 2
    return out


@njit(cache=True, inline="always")
def _cell_legs(m, l, t, same, soa, spots, spot_n, spot_f, photons, targets, fov_n, collect_t, tol, out) -> None:
    """The legs of pair (cell m, connection (l, t)) without the hidden BRDF: out[0, m] = A · E · G / f (module doc;
    0: no contribution), out[1, m] = r_l, out[2, m] = r_y; ``same``: the target is the laser point (confocal),
    whose leg is then the laser leg; ``soa``: per cell, one contiguous row each (:data:`SOA`). No branch on the
    pair's values (the conditions are selects), so a loop of it over every cell runs in SIMD lanes; the inner side
    of a closed surface is never lit."""
    w0, w1, w2 = spots[l, 0] - soa[0, m], spots[l, 1] - soa[1, m], spots[l, 2] - soa[2, m]
    r_l = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    inv_l = 1.0 / max(r_l, 1e-300)
    nfw = (soa[3, m] * w0 + soa[4, m] * w1 + soa[5, m] * w2) * inv_l
    cos_in = abs(nfw)
    cos_l = -(w0 * spot_n[l, 0] + w1 * spot_n[l, 1] + w2 * spot_n[l, 2]) * inv_l
    if same:
        d0, d1, d2, r_y, inv_y, nw = w0, w1, w2, r_l, inv_l, nfw
    else:
        d0, d1, d2 = targets[t, 0] - soa[0, m], targets[t, 1] - soa[1, m], targets[t, 2] - soa[2, m]
        r_y = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        inv_y = 1.0 / max(r_y, 1e-300)
        nw = (soa[3, m] * d0 + soa[4, m] * d1 + soa[5, m] * d2) * inv_y
    cos_y = -(d0 * fov_n[0] + d1 * fov_n[1] + d2 * fov_n[2]) * inv_y
    e = irradiance_term(photons, emission_term(spot_f[l], cos_l), cos_in, r_l)
    g = fov_term(abs(nw) * cos_y, r_y, collect_t)
    lit = ((cos_l > 0.0) & (cos_in > 0.0) & (r_l > tol) & (abs(nw) > 0.0) & (cos_y > 0.0) & (r_y > tol)
           & ((nw > 0.0) == (nfw > 0.0)) & ~((soa[7, m] > 0.0) & (nfw < 0.0)))
    out[0, m] = soa[6, m] * e * g if lit else 0.0
    out[1, m] = r_l
    out[2, m] = r_y


@njit(cache=True, inline="always")
def _cell_brdf(m, l, t, same, soa, spots, targets, cell_brdf) -> float:
    """The hidden BRDF f of pair (cell m, connection (l, t)) (row m of ``cell_brdf``: :data:`CELL_BRDF`): ρ/π, or
    Phong's or the retroreflective kind's with the lit-side normal (:mod:`datagen.scene.brdf_kernel`) from the
    directions to the laser point and the target."""
    f = cell_brdf[m, 0]
    kind = cell_brdf[m, 1]
    if kind == PHONG or kind == RETROREFLECTIVE:
        n0, n1, n2 = soa[3, m], soa[4, m], soa[5, m]
        w0, w1, w2 = spots[l, 0] - soa[0, m], spots[l, 1] - soa[1, m], spots[l, 2] - soa[2, m]
        inv_l = 1.0 / max(math.sqrt(w0 * w0 + w1 * w1 + w2 * w2), 1e-300)
        w0, w1, w2 = w0 * inv_l, w1 * inv_l, w2 * inv_l
        if same:
            d0, d1, d2 = w0, w1, w2
        else:
            d0, d1, d2 = targets[t, 0] - soa[0, m], targets[t, 1] - soa[1, m], targets[t, 2] - soa[2, m]
            inv_y = 1.0 / max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-300)
            d0, d1, d2 = d0 * inv_y, d1 * inv_y, d2 * inv_y
        nfw = n0 * w0 + n1 * w1 + n2 * w2
        sgn = 1.0 if nfw > 0.0 else -1.0
        if kind == PHONG:
            expo = cell_brdf[m, 4]
            f = phong_value(cell_brdf[m, 2], cell_brdf[m, 3], expo,
                            phong_power(phong_cos_alpha(abs(nfw), sgn * n0, sgn * n1, sgn * n2, w0, w1, w2, d0, d1,
                                                        d2), expo))
        else:
            cos_out = sgn * (n0 * d0 + n1 * d1 + n2 * d2)
            if not (cos_out > 0.0 and nfw != 0.0):
                return 0.0
            cos_h = retro_cos_h(abs(nfw), cos_out, w0 * d0 + w1 * d1 + w2 * d2)
            f = retro_value(cell_brdf[m, 2], cell_brdf[m, 3], cell_brdf[m, 5], cell_brdf[m, 4], abs(nfw), cos_out,
                            cos_h)
    return f


@njit(cache=True, inline="always")
def _tent_nodes(paths, v0, v1, v2, centre, offset, per_metre, origin):
    """The sorted fine-grid nodes (c0 ≤ c1 ≤ c2) of the tent of triangle (v0, v1, v2) (vertex path lengths
    ``paths``, one connection's), shifted to the triangle rule's mean (module doc of :mod:`.quadrature`): node
    (path / speed − t_start) / step + shift as path · ``per_metre`` + ``origin`` (:func:`_node_map`)."""
    p0, p1, p2 = paths[v0], paths[v1], paths[v2]
    shift_path = 0.75 * (centre - (p0 + p1 + p2) / 3.0) + offset
    c0 = (p0 + shift_path) * per_metre + origin
    c1 = (p1 + shift_path) * per_metre + origin
    c2 = (p2 + shift_path) * per_metre + origin
    return sort3(c0, c1, c2)


@njit(cache=True, inline="always")
def _cell_nodes(m, cells, paths, leg_rows, offset, per_metre, origin, nodes) -> None:
    """nodes[:, m] = the sorted fine-grid nodes of cell m's tent (:func:`_tent_nodes`, centre r_l + r_y from
    ``leg_rows``: :func:`_cell_legs`)."""
    c0, c1, c2 = _tent_nodes(paths, cells[m, 0], cells[m, 1], cells[m, 2], leg_rows[1, m] + leg_rows[2, m], offset,
                             per_metre, origin)
    nodes[0, m] = c0
    nodes[1, m] = c1
    nodes[2, m] = c2


@njit(cache=True, inline="always")
def _node_map(speed, t_start, step, shift):
    """(fine nodes per metre of path, node of path 0) of a grid: node = (path / speed − t_start) / step + shift
    with one multiplication per vertex instead of two divisions."""
    return 1.0 / (speed * step), shift - t_start / step


SOA = ("x", "y", "z", "n_x", "n_y", "n_z", "area", "dark_inside")
"""Rows of the pair kernel's per-cell array (8, M) float64: centroid, unit normal, area (m²), and 1.0 where the inner
side of a closed outward surface is never lit (the laser leg is shadow-tested and the cell is ``closed``), else 0."""
CELL_BRDF = ("f_lamb", "kind", "rho", "ks", "expo", "width")
"""Columns of the kernel's per-sub-triangle BRDF array (M, 6) float64: constant f = ρ/π (Lambertian), the kind
code (:data:`datagen.scene.brdf_kernel.PHONG` …), albedo, specular fraction, Phong exponent (the retroreflective
kind's entrance-angle exponent m) and retroreflective lobe width of its object."""
WORK = ("ray_cell", "ray_count", "visible", "group_ptr", "group_conn")
GEO = ("vertices", "cells", "area", "comp_base", "coarse_of", "coarse_cells")
POSE = ("centroid", "normal", "cell_face", "closed", "spot_n", "spot_f", "photons", "fov_n", "collect", "tol",
        "cell_brdf")
CONN = ("conn_laser", "conn_target", "conn_channel", "conn_same")
LEGS = ("spots", "targets", "emitter_leg", "laser_off", "d_y", "sensor_off", "mu", "speed", "stride")
GRID = ("t_start", "step", "shift", "n_fine", "min_nodes", "hist", "curv", "total", "beyond", "bound")
OCC = ("shadow", "run_ptr", "run_lo", "run_hi", "spheres", "run_chunk", "chunk_ptr", "chunk_spheres", "occ_idx",
       "plane", "edges", "margin", "face_ray")
SHADE = ("use_flags", "flags", "laser_col", "use_fov", "fov_visible")
"""The kernel's inputs by group (tuples; :func:`datagen.transport.quadrature.primary.run_compiled` builds them). The
kernel unpacks every group once before its loops: arrays taken out of a tuple inside numba's inner loop cost an
atomic reference count each (measured ~100 ns per pair)."""


@njit(cache=True, parallel=True)
def _pairs(listed, block, work, geo, pose, conn, legs, grid, has_coarse, coarse, occ, shade):
    """Both passes (module doc) over the connections ``block`` = [b0, b1), in groups of one channel each
    (connections ``group_conn[group_ptr[g]:group_ptr[g + 1]]``, ascending), the groups in parallel: a channel's rows
    of the grids are written by its group only, in the same order for any number of threads. ``listed`` False:
    every pair, listing those that need a shadow ray (connection b's in ``ray_cell[(b − b0)·M:]``,
    ``ray_count[b − b0]`` of them); True: the listed pairs whose ray found the laser point ``visible`` (same
    slots). The groups of arguments: :data:`WORK`, :data:`GEO`, :data:`POSE`, :data:`CONN`, :data:`LEGS`,
    :data:`GRID` (``grid``, and ``coarse`` for the rule at 2h when ``has_coarse``), :data:`OCC`, :data:`SHADE`
    (where ``use_flags``, a pair (m, l) with ``flags[laser_col[l], m]`` 0 is not blocked without the exact test:
    :func:`datagen.transport.quadrature.shadow.shadow_flags`; where ``use_fov``, a pair (m, target t) with
    ``fov_visible[t, m]`` 0 has its FoV leg blocked)."""
    b0, b1 = block
    ray_cell, ray_count, visible, group_ptr, group_conn = work
    vertices, cells, area, comp_base, coarse_of, coarse_cells = geo
    centroid, normal, cell_face, closed, spot_n, spot_f, photons, fov_n, collect, tol, cell_brdf = pose
    conn_laser, conn_target, conn_channel, conn_same = conn
    spots, targets, emitter_leg, laser_off, d_y, sensor_off, mu, speed, stride = legs
    t_start, step, shift, n_fine, min_nodes, hist, curv, total, beyond, bound = grid
    ct_start, cstep, cshift, cn_fine, cmin_nodes, chist, ccurv, ctotal, cbeyond, cbound = coarse
    shadow, run_ptr, run_lo, run_hi, spheres, run_chunk, chunk_ptr, chunk_spheres, occ_idx, plane, edges, margin, \
        face_ray = occ
    use_flags, flags, laser_col, use_fov, fov_visible = shade
    M = centroid.shape[0]
    per_metre, origin = _node_map(speed, t_start, step, shift)
    cper_metre, corigin = _node_map(speed, ct_start, cstep, cshift)
    soa = np.empty((8, M))
    soa[:3] = centroid.T
    soa[3:6] = normal.T
    soa[6] = area
    for m in range(M):
        soa[7, m] = 1.0 if shadow and closed[m] else 0.0
    n_groups = len(group_ptr) - 1
    group_tents = np.zeros(n_groups, dtype=np.int64)
    for grp in prange(n_groups):
        tents = 0
        paths = np.empty(vertices.shape[0])
        leg_rows = np.empty((3, M))             # per cell of one connection: A · E · G / f, r_l, r_y (_cell_legs)
        nodes = np.empty((3, M))
        for gi in range(group_ptr[grp], group_ptr[grp + 1]):
            b = group_conn[gi]
            row = b - b0
            slot = row * M
            n_items = ray_count[row] if listed else M
            if listed and n_items == 0:
                continue                        # no listed pair: its row of vertex paths is not needed
            n_rays = 0
            l, t, ch = conn_laser[b], conn_target[b], conn_channel[b]
            same = conn_same[b] != 0
            _vertex_paths(vertices, spots, targets, l, t, same, paths)
            offset = 0.0 + laser_off[l] + sensor_off[t]
            if listed:                          # the legs and nodes of the listed cells
                for i in range(n_items):
                    if visible[slot + i]:
                        m = ray_cell[slot + i]
                        _cell_legs(m, l, t, same, soa, spots, spot_n, spot_f, photons, targets, fov_n, collect[t], tol,
                                   leg_rows)
                        _cell_nodes(m, cells, paths, leg_rows, offset, per_metre, origin, nodes)
            elif same:                          # every cell's, in SIMD lanes (a constant ``same`` per loop)
                for m in range(M):
                    _cell_legs(m, l, t, True, soa, spots, spot_n, spot_f, photons, targets, fov_n, collect[t], tol,
                               leg_rows)
            else:
                for m in range(M):
                    _cell_legs(m, l, t, False, soa, spots, spot_n, spot_f, photons, targets, fov_n, collect[t], tol,
                               leg_rows)
            if not listed:
                for m in range(M):
                    _cell_nodes(m, cells, paths, leg_rows, offset, per_metre, origin, nodes)
            for i in range(n_items):
                if listed:
                    if not visible[slot + i]:
                        continue
                    m = ray_cell[slot + i]
                else:
                    m = i
                if not leg_rows[0, m] > 0.0 or (use_fov and fov_visible[t, m] == 0):
                    continue
                weight = leg_rows[0, m] * _cell_brdf(m, l, t, same, soa, spots, targets, cell_brdf)
                if not weight > 0.0:
                    continue
                if shadow and not listed:
                    f = cell_face[m]
                    if face_ray[f]:
                        blocked = 2
                    elif use_flags and flags[laser_col[l], m] == 0:
                        blocked = 0                     # no candidate's shadow reaches this laser point
                    else:
                        blocked = _blocked(centroid, m, spots, l, run_ptr, f, run_chunk, chunk_ptr, spheres,
                                           chunk_spheres, occ_idx, plane, edges, margin)
                    if blocked == 1:
                        continue
                    if blocked == 2:
                        ray_cell[slot + n_rays] = m
                        n_rays += 1
                        continue
                if mu > 0.0:
                    weight = weight * attenuation_term(mu, emitter_leg[l] + leg_rows[1, m] + leg_rows[2, m] + d_y[t])
                    if not weight > 0.0:
                        continue
                deposit_tent(nodes[0, m], nodes[1, m], nodes[2, m], weight, comp_base[m] + ch, n_fine, min_nodes,
                             hist, curv, total, beyond, bound)
                tents += 1
                k = coarse_of[m]
                if has_coarse and k >= 0 and ch % stride == 0:      # the rule at 2h (error estimate)
                    c0, c1, c2 = _tent_nodes(paths, coarse_cells[k, 0], coarse_cells[k, 1], coarse_cells[k, 2],
                                             leg_rows[1, m] + leg_rows[2, m], offset, cper_metre, corigin)
                    deposit_tent(c0, c1, c2, 4.0 * weight, ch, cn_fine, cmin_nodes, chist, ccurv, ctotal, cbeyond,
                                 cbound)
            if not listed:
                ray_count[row] = n_rays
        group_tents[grp] = tents
    return group_tents.sum()


@njit(cache=True, inline="always")
def _vertex_paths(vertices, spots, targets, l, t, same, out) -> None:
    """out[v] = |v − x_l| + |v − y_t| (metres) for every vertex v of connection (laser l, target t); 2·|v − x_l|
    where ``same`` (the target is the laser point). One connection's row, computed where its pairs use it."""
    if same:
        for v in range(vertices.shape[0]):
            out[v] = 2.0 * _dist(vertices, v, spots, l)
    else:
        for v in range(vertices.shape[0]):
            out[v] = _dist(vertices, v, spots, l) + _dist(vertices, v, targets, t)


def channel_groups(conn_channel: np.ndarray, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """The connections [start, stop) in groups of one channel each: (group_ptr (G + 1,), group_conn (stop − start,))
    int64, each group's connections ascending (a stable sort by channel)."""
    ch = conn_channel[start:stop]
    order = np.argsort(ch, kind="stable")
    new = np.ones(len(order), dtype=bool)
    new[1:] = ch[order][1:] != ch[order][:-1]
    return (np.append(np.flatnonzero(new), len(order)).astype(np.int64), (order + start).astype(np.int64))


def candidates(block, geo, pose, conn, legs, grid, coarse, has_coarse, occ, ray_cell, ray_count, groups,
               shade) -> int:
    """Deposit every contributing pair of the connections ``block`` (start, stop) that needs no shadow ray and
    list the others: connection b's cells in ``ray_cell[(b − start)·M:]`` (capacity cells × connections),
    ``ray_count[b − start]`` of them. ``groups``: :func:`channel_groups`; the groups of arguments: :data:`GEO`,
    :data:`POSE`, :data:`CONN`, :data:`LEGS`, :data:`GRID` (``grid``, ``coarse``), :data:`OCC`, :data:`SHADE`.
    Returns the tents deposited."""
    none = np.zeros(1, dtype=np.uint8)
    return _pairs(False, (int(block[0]), int(block[1])), (ray_cell, ray_count, none, *groups), geo, pose,
                  conn, legs, grid, bool(has_coarse), coarse, occ, shade)


def deposit_pairs(block, ray_cell, ray_count, visible, groups, geo, pose, conn, legs, grid, coarse,
                  has_coarse, occ, shade) -> int:
    """Deposit the listed pairs (of the connections ``block``, slots as :func:`candidates` left them) whose shadow
    ray found the laser point visible (``visible`` uint8 per slot). Returns the tents deposited."""
    return _pairs(True, (int(block[0]), int(block[1])), (ray_cell, ray_count, visible, *groups), geo, pose,
                  conn, legs, grid, bool(has_coarse), coarse, occ, shade)


@njit(cache=True, parallel=True)
def face_candidates(tri, plane, faces, front, front_plane, hull_n, hull_o, hull_valid, hull_v, tol, cap, out):
    """Per hidden face i (``faces[i]``: its row of ``tri``, or −1) the triangles of ``tri`` (k, 3, 3) (planes
    ``plane`` (k, 4), :func:`occluder_planes`) that may meet the convex hull of that face and the laser points
    (outward planes ``hull_n`` (F, P, 3), ``hull_o`` (F, P), ``hull_valid`` (F, P), vertices ``hull_v`` (F, V, 3)):
    the separating planes of :func:`datagen.scene.separation.may_meet` (the hull's face planes and the triangle's own
    plane; touching within ``tol`` counts as apart; a face never meets itself) and, where ``front[i]`` (only the side
    its normal points to is lit: a closed outward surface), the face's own plane ``front_plane[i]`` (unit normal,
    offset n·p₀; (F, 4)): a segment from the face to a laser point in front of it lies in front of that plane, so a
    triangle wholly behind it (within ``tol``) cannot meet it. Writes up to ``cap`` of them into ``out[i]`` (F, cap)
    and returns their counts (F,) int64 (``cap`` + 1: more than ``cap``, the rest not listed)."""
    n_faces, k = len(faces), tri.shape[0]
    count = np.zeros(n_faces, dtype=np.int64)
    for i in prange(n_faces):
        c = 0
        for j in range(k):
            if j == faces[i]:
                continue
            apart = False
            if front[i]:
                apart = True
                for a in range(3):
                    if (front_plane[i, 0] * tri[j, a, 0] + front_plane[i, 1] * tri[j, a, 1]
                            + front_plane[i, 2] * tri[j, a, 2] - front_plane[i, 3]) > tol:
                        apart = False
                        break
            for p in range(hull_n.shape[1]):
                if apart:
                    break
                if not hull_valid[i, p]:
                    continue
                apart = True
                for a in range(3):
                    if (hull_n[i, p, 0] * tri[j, a, 0] + hull_n[i, p, 1] * tri[j, a, 1]
                            + hull_n[i, p, 2] * tri[j, a, 2] - hull_o[i, p]) < -tol:
                        apart = False
                        break
            if not apart and (plane[j, 0] != 0.0 or plane[j, 1] != 0.0 or plane[j, 2] != 0.0):
                above = False
                below = False
                for v in range(hull_v.shape[1]):
                    d = (plane[j, 0] * hull_v[i, v, 0] + plane[j, 1] * hull_v[i, v, 1]
                         + plane[j, 2] * hull_v[i, v, 2] - plane[j, 3])
                    above = above or d > tol
                    below = below or d < -tol
                apart = not (above and below)
            if not apart:
                if c < cap:
                    out[i, c] = j
                c += 1
                if c > cap:
                    break
        count[i] = c
    return count
