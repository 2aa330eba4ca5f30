"""Which laser legs of each sub-triangle a candidate occluder may block: a conservative map on the laser points' plane.

The compiled pair loop (:mod:`.kernel`) tests a pair's laser leg, the segment from sub-triangle m's
centroid x to laser point s, exactly against the triangles that may block its hidden face's legs
(:func:`~datagen.transport.quadrature.kernel._blocked` through the public kernels; margin δ). Where every laser
point lies on one plane P (a scanned relay wall), :func:`shadow_flags` first marks, per sub-triangle, the laser
points whose segment some candidate could block at all, by central projection from x onto P; the pair loop runs
the exact test only for marked pairs and takes "not blocked" for the others. The mark is conservative, so the
envelope is the same bit for bit:

- the exact test reports a block, or a near miss for a shadow ray, only where the segment crosses the
  triangle's plane at a point p inside the triangle grown by δ (both ends more than δ off that plane). The map
  grows each triangle by 2δ (T⁺) and, with a(q) = D(q)/D(x) the signed distance of q from P over that of x,
  keeps the part of T⁺ with 0 ≤ a ≤ 1 − ε: p = x + t·(s − x) has a(p) = 1 − t, t ∈ (0, 1), and
  t ≥ |p − x| / |s − x| ≥ dist(x, T⁺) / R > ε = dist(x, T⁺) / (2R), R bounding |s − x| (a lower bound of
  dist(x, T⁺) from x's distance to the plane and to the grown edges' lines);
- that clipped polygon projects from x onto P (s = x + (q − x)/(1 − a(q)), finite because a ≤ 1 − ε) to a
  convex polygon that holds every s the triangle could block; laser points within 1e-9 m of it are marked
  (the projection's round-off is ~1e-15 m; a polygon seen edge-on marks its whole bounding box).

Triangles the exact test skips the same way (x within δ of the triangle's plane, computed by the same expression)
mark nothing; a sub-triangle within 1e-9 m of P, or a triangle whose distance from x has no positive lower bound,
marks every laser point.
"""
from __future__ import annotations

import math

import numpy as np

from ...vectors import matmul, norm
from numba import njit, prange

__all__ = ["FLAG_MAX_BYTES", "grown_triangles", "row_span", "shadow_flags", "spot_buckets", "spot_plane"]

FLAG_MAX_BYTES = 1 << 28
"""The map holds one byte per (laser point used, sub-triangle); a larger one is not built (the exact test runs for
every pair)."""

PLANE_TOL = 1e-9
"""Laser points farther than this (m) from their common plane: no map."""

INSIDE_TOL = 1e-9
"""Laser points within this (m) of a projected polygon are marked."""


def spot_plane(spots: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(unit normal (3,), offset n·p) of the plane holding every laser point ``spots`` (L, 3) m (the plane through
    their mean with their mean normal ``normals`` (L, 3)), or None when one lies farther than ``PLANE_TOL`` from
    it or the normals cancel."""
    n = normals.mean(axis=0)
    length = norm(n)
    if not length > 0:
        return None
    n = n / length
    o = float(matmul(n, spots.mean(axis=0)))
    return (n, o) if float(np.abs(matmul(spots, n) - o).max()) <= PLANE_TOL else None


def grown_triangles(tri: np.ndarray, grow: float) -> np.ndarray:
    """(k, 3, 3) the vertices of triangles ``tri`` (k, 3, 3) with every edge moved out by ``grow`` (m) in their
    plane: the triangle scaled about its incentre by (r + grow)/r, r its inradius (moving a triangle's three edges
    out by d is that homothety). Degenerate triangles (r = 0) get NaN."""
    side = np.linalg.norm(np.roll(tri, -1, axis=1) - np.roll(tri, 1, axis=1), axis=2)     # side opposite corner i
    perimeter = side.sum(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ok = (area > 0) & (perimeter > 0)
    r = np.where(ok, 2.0 * area / np.where(ok, perimeter, 1.0), 1.0)
    centre = np.einsum("ki,kij->kj", side, tri) / np.where(ok, perimeter, 1.0)[:, None]
    out = centre[:, None, :] + (tri - centre[:, None, :]) * ((r + grow) / r)[:, None, None]
    out[~ok] = np.nan
    return out


@njit(cache=True, inline="always")
def _clip(px, py, pz, pa, n, out_x, out_y, out_z, out_a, bound, keep_below) -> int:
    """Sutherland–Hodgman: the polygon (px, py, pz) with values pa of an affine function, cut to pa ≤ bound
    (``keep_below``) or pa ≥ bound; writes it to the out arrays, returns its vertex count."""
    c = 0
    for i in range(n):
        j = (i + 1) % n
        inside_i = pa[i] <= bound if keep_below else pa[i] >= bound
        inside_j = pa[j] <= bound if keep_below else pa[j] >= bound
        if inside_i:
            out_x[c], out_y[c], out_z[c], out_a[c] = px[i], py[i], pz[i], pa[i]
            c += 1
        if inside_i != inside_j:
            w = (bound - pa[i]) / (pa[j] - pa[i])
            out_x[c] = px[i] + w * (px[j] - px[i])
            out_y[c] = py[i] + w * (py[j] - py[i])
            out_z[c] = pz[i] + w * (pz[j] - pz[i])
            out_a[c] = bound
            c += 1
    return c


ROW_SLACK = 1e-6
"""A bucket row's strip is widened by this fraction of a bucket height, and the polygon's span on it by this fraction
of a bucket width, before the span picks the row's buckets: the points' buckets come from a rounded division."""


@njit(cache=True, inline="always")
def row_span(pu, pv, c, v_lo, v_hi, slack) -> tuple[float, float]:
    """(lowest, highest) u (m) of the convex polygon whose first ``c`` vertices are ``pu``, ``pv`` (float64 arrays,
    metres on the laser plane's axes) within the strip v_lo ≤ v ≤ v_hi widened by ``slack`` + 2 ``INSIDE_TOL``, the
    span widened by ``INSIDE_TOL``: every point within ``INSIDE_TOL`` of the polygon whose v lies in the strip
    (within ``slack``) has u in that span ((inf, −inf): the polygon misses the strip). Used by :func:`shadow_flags`
    per bucket row."""
    a, b = v_lo - slack - 2.0 * INSIDE_TOL, v_hi + slack + 2.0 * INSIDE_TOL
    lo, hi = np.inf, -np.inf
    for j in range(c):
        j1 = (j + 1) % c
        va, vb, ua, ub = pv[j], pv[j1], pu[j], pu[j1]
        if (va < a and vb < a) or (va > b and vb > b):
            continue                                  # the edge misses the strip
        if va == vb:
            lo, hi = min(lo, ua, ub), max(hi, ua, ub)
            continue
        for v in (min(max(va, a), b), min(max(vb, a), b)):      # the edge's part inside the strip: its two ends
            u = ua + (ub - ua) * ((v - va) / (vb - va))
            lo, hi = min(lo, u), max(hi, u)
    return lo - INSIDE_TOL, hi + INSIDE_TOL


@njit(cache=True, inline="always")
def _bucket(position, count) -> int:
    """The bucket (0 … count − 1) of a coordinate in bucket widths, clamped (before the cast: no overflow)."""
    return int(min(max(math.floor(position), 0.0), count - 1.0))


@njit(cache=True, parallel=True)
def shadow_flags(cells, occ, grown, laser_plane, out):
    """out[c, m] = 1 where occluder candidates of sub-triangle m's hidden face may block the segment from
    ``centroid[m]`` to laser point c (module doc), else left 0; where ``closed[m]`` (the pair loop skips laser
    points behind sub-triangle m's plane, ``normal[m]``) only the part in front of that plane counts, and the
    marks behind it are not needed (some are left 0). The groups of arguments:

    - ``cells`` (centroid (M, 3), normal (M, 3), closed (M,) uint8, cell_face (M,) int64 hidden face of each);
    - ``occ``: the kernel's :data:`datagen.transport.quadrature.kernel.OCC` group (per hidden face the runs
      ``run_ptr`` / ``run_lo`` / ``run_hi`` over ``idx`` of candidate triangles, their ``plane`` (k, 4), ``edges``
      (k, 3, 4), ``margin`` δ, ``face_ray``), and ``grown`` (k, 3, 3): :func:`grown_triangles` by 2δ;
    - ``laser_plane`` (surface (4,): unit normal and offset of the laser points' plane P; axes (3, 3): an origin
      on P and two orthonormal in-plane axes; spot_uv (n, 2): the laser points' coordinates on them, m; centre
      (3,), radius: a ball holding every laser point; buckets (6,): u0, v0, bucket width and height, columns, rows
      of a uniform grid of buckets over the points; bucket_ptr / bucket_col: the points of each bucket, CSR).

    out (n, M) uint8 (laser point-major: the pair loop reads one laser point's row), zeroed by the caller."""
    centroid, normal, closed, cell_face = cells
    shadow, run_ptr, run_lo, run_hi, spheres, run_chunk, chunk_ptr, chunk_spheres, idx, plane, edges, margin, \
        face_ray = occ
    surface, axes, spot_uv, centre, radius, buckets, bucket_ptr, bucket_col = laser_plane
    M = centroid.shape[0]
    n_spots = out.shape[0]
    u0, v0, bw, bh = buckets[0], buckets[1], buckets[2], buckets[3]
    nbu, nbv = int(buckets[4]), int(buckets[5])
    for m in prange(M):
        f = cell_face[m]
        if face_ray[f] or run_ptr[f] == run_ptr[f + 1]:
            continue
        x0, x1, x2 = centroid[m, 0], centroid[m, 1], centroid[m, 2]
        dx = surface[0] * x0 + surface[1] * x1 + surface[2] * x2 - surface[3]
        r0, r1, r2 = x0 - centre[0], x1 - centre[1], x2 - centre[2]
        reach = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) + radius
        everything = abs(dx) <= PLANE_TOL
        px = np.empty(6)
        py = np.empty(6)
        pz = np.empty(6)
        pa = np.empty(6)
        qx = np.empty(6)
        qy = np.empty(6)
        qz = np.empty(6)
        qa = np.empty(6)
        sx = np.empty(6)
        sy = np.empty(6)
        sz = np.empty(6)
        sa = np.empty(6)
        pu = np.empty(6)
        pv = np.empty(6)
        for r in range(run_ptr[f], run_ptr[f + 1]):
            if everything:
                break
            for i in range(run_lo[r], run_hi[r]):
                k = idx[i]
                n0, n1, n2, o = plane[k, 0], plane[k, 1], plane[k, 2], plane[k, 3]
                d0 = n0 * x0 + n1 * x1 + n2 * x2 - o            # the exact test's expression
                if abs(d0) <= margin:
                    continue                                     # skipped by the exact test too
                if math.isnan(grown[k, 0, 0]) or math.isnan(grown[k, 1, 0]) or math.isnan(grown[k, 2, 0]):
                    everything = True
                    break
                below = True
                above = True
                for j in range(3):
                    px[j], py[j], pz[j] = grown[k, j, 0], grown[k, j, 1], grown[k, j, 2]
                    pa[j] = (surface[0] * px[j] + surface[1] * py[j] + surface[2] * pz[j] - surface[3]) / dx
                    below = below and pa[j] <= 0.0
                    above = above and pa[j] >= 1.0
                if below or above:
                    continue                                     # wholly beyond P or behind x
                viol = 0.0
                for j in range(3):
                    viol = max(viol, -(edges[k, j, 0] * x0 + edges[k, j, 1] * x1 + edges[k, j, 2] * x2
                                       - edges[k, j, 3]) - 2.0 * margin)
                eps = math.sqrt(d0 * d0 + viol * viol) / (2.0 * reach)
                if not eps > 0.0:
                    everything = True
                    break
                c = 3
                if closed[m]:          # the part in front of m's plane (front distance in pa, then a again)
                    for j in range(3):
                        pa[j] = (normal[m, 0] * (px[j] - x0) + normal[m, 1] * (py[j] - x1)
                                 + normal[m, 2] * (pz[j] - x2))
                    c = _clip(px, py, pz, pa, 3, qx, qy, qz, qa, 0.0, False)
                    if c == 0:
                        continue
                    for j in range(c):
                        px[j], py[j], pz[j] = qx[j], qy[j], qz[j]
                        pa[j] = (surface[0] * px[j] + surface[1] * py[j] + surface[2] * pz[j] - surface[3]) / dx
                c = _clip(px, py, pz, pa, c, qx, qy, qz, qa, 1.0 - eps, True)
                if c == 0:
                    continue
                c = _clip(qx, qy, qz, qa, c, sx, sy, sz, sa, 0.0, False)
                if c == 0:
                    continue
                lo_u, hi_u, lo_v, hi_v = np.inf, -np.inf, np.inf, -np.inf
                for j in range(c):                               # project from x onto P, to (u, v)
                    w = 1.0 / (1.0 - sa[j])
                    g0 = x0 + (sx[j] - x0) * w - axes[0, 0]
                    g1 = x1 + (sy[j] - x1) * w - axes[0, 1]
                    g2 = x2 + (sz[j] - x2) * w - axes[0, 2]
                    pu[j] = g0 * axes[1, 0] + g1 * axes[1, 1] + g2 * axes[1, 2]
                    pv[j] = g0 * axes[2, 0] + g1 * axes[2, 1] + g2 * axes[2, 2]
                    lo_u, hi_u = min(lo_u, pu[j]), max(hi_u, pu[j])
                    lo_v, hi_v = min(lo_v, pv[j]), max(hi_v, pv[j])
                area = 0.0
                for j in range(c):
                    j1 = (j + 1) % c
                    area += pu[j] * pv[j1] - pu[j1] * pv[j]
                sign = 1.0 if area > 0.0 else -1.0
                flat = not abs(area) > 1e-18
                b_u0 = _bucket((lo_u - INSIDE_TOL - u0) / bw, nbu)
                b_u1 = _bucket((hi_u + INSIDE_TOL - u0) / bw, nbu)
                b_v0 = _bucket((lo_v - INSIDE_TOL - v0) / bh, nbv)
                b_v1 = _bucket((hi_v + INSIDE_TOL - v0) / bh, nbv)
                for bv in range(b_v0, b_v1 + 1):
                    if flat:
                        r_u0, r_u1 = b_u0, b_u1
                    else:                    # the buckets of this row that the polygon (grown by the tolerance) meets
                        lo_r, hi_r = row_span(pu, pv, c, v0 + bv * bh, v0 + (bv + 1) * bh, ROW_SLACK * bh)
                        if lo_r > hi_r:
                            continue
                        r_u0 = max(b_u0, _bucket((lo_r - ROW_SLACK * bw - u0) / bw, nbu))
                        r_u1 = min(b_u1, _bucket((hi_r + ROW_SLACK * bw - u0) / bw, nbu))
                    for bu in range(r_u0, r_u1 + 1):
                        b = bv * nbu + bu
                        for e in range(bucket_ptr[b], bucket_ptr[b + 1]):
                            col = bucket_col[e]        # out[col, m] is written, never read (a strided byte)
                            u, v = spot_uv[col, 0], spot_uv[col, 1]
                            if (u < lo_u - INSIDE_TOL or u > hi_u + INSIDE_TOL or v < lo_v - INSIDE_TOL
                                    or v > hi_v + INSIDE_TOL):
                                continue
                            inside = True
                            if not flat:
                                for j in range(c):
                                    j1 = (j + 1) % c
                                    eu, ev = pu[j1] - pu[j], pv[j1] - pv[j]
                                    cross = sign * (eu * (v - pv[j]) - ev * (u - pu[j]))
                                    if cross < -INSIDE_TOL * math.sqrt(eu * eu + ev * ev):
                                        inside = False
                                        break
                            if inside:
                                out[col, m] = 1
            if everything:
                break
        if everything:
            for col in range(n_spots):
                out[col, m] = 1


def spot_buckets(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A uniform grid of about len(uv) buckets over points ``uv`` (n, 2): (buckets (6,) float64 as
    :func:`shadow_flags` takes them, bucket_ptr (B + 1,) int64, bucket_col (n,) int64)."""
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    side = max(1, int(math.sqrt(len(uv))))
    nb = np.array([side, side])
    width = span / nb * (1 + 1e-12)
    cell = np.minimum(((uv - lo) / width).astype(np.int64), nb - 1)
    b = cell[:, 1] * nb[0] + cell[:, 0]
    order = np.argsort(b, kind="stable")
    ptr = np.searchsorted(b[order], np.arange(nb[0] * nb[1] + 1)).astype(np.int64)
    return np.array([lo[0], lo[1], width[0], width[1], nb[0], nb[1]], dtype=np.float64), ptr, order.astype(np.int64)
