"""Separating-plane tests between triangles and convex hulls (scene geometry shared by the effect planner and the
quadrature's occluder test).

A triangle and a convex hull cannot meet when a plane separates them; testing the hull's face planes and the
triangle's own plane is conservative (missing the edge×edge axes only reports "may meet" too often). The
planner uses it to prove that shadow rays cannot be blocked (docs/planner.md); the quadrature
(:mod:`datagen.transport.quadrature`) to decide which legs need shadow rays.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..vectors import matmul

CHUNK_ELEMENTS = 1 << 22
"""Floats per temporary in the vectorised pair tests (32 MiB)."""


def outward_planes(faces: np.ndarray, opposite: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planes through (..., 3, 3) vertex triples with unit normals pointing away from ``opposite`` (..., 3).

    Returns normals (..., 3), offsets (...,) with n·x = offset on the plane, and validity (...,) (False for a
    degenerate triple or when ``opposite`` lies on the plane).
    """
    n = np.cross(faces[..., 1, :] - faces[..., 0, :], faces[..., 2, :] - faces[..., 0, :])
    length = np.linalg.norm(n, axis=-1)
    n = np.divide(n, length[..., None], out=np.zeros_like(n), where=length[..., None] > 0)
    side = np.einsum("...k,...k->...", n, opposite - faces[..., 0, :])
    n = np.where((side > 0)[..., None], -n, n)
    valid = (length > 0) & (side != 0)
    return n, np.einsum("...k,...k->...", n, faces[..., 0, :]), valid


HULL_EPS = 1e-12
"""Points within this fraction of a point set's extent of a plane count as on it (:func:`hull_planes`)."""


def hull_planes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outward face planes of the convex hulls of point sets (m, V, 3) → normals (m, P, 3) (unit), offsets (m, P)
    (n·x = offset on the plane, n·x ≤ offset inside), validity (m, P); a flat or degenerate set gets no valid plane
    (it is then never separated). Every plane through three of the points with all points on one side (within
    ``HULL_EPS`` of the set's extent) is a face plane; coplanar triples give one plane (compiled:
    :func:`_supporting_planes`; the hulls here have a few points: a triangle and the corners of a scan)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    m, v = points.shape[:2]
    cap = max(1, v * (v - 1) * (v - 2) // 6)
    normals, offsets, count = _supporting_planes(points, HULL_EPS, cap)
    p = max(1, int(count.max()) if m else 1)
    valid = np.arange(p)[None, :] < count[:, None]
    return normals[:, :p].copy(), offsets[:, :p].copy(), valid


@njit(cache=True)
def _supporting_planes(points, eps, cap):
    """Per point set of ``points`` (m, V, 3): the planes through three of its points with every point on one side
    (within ``eps`` × the set's extent), oriented outward and without repeats: normals (m, cap, 3), offsets
    (m, cap), count (m,) int64 (0 for a flat set)."""
    m, v = points.shape[0], points.shape[1]
    normals = np.zeros((m, cap, 3))
    offsets = np.zeros((m, cap))
    count = np.zeros(m, dtype=np.int64)
    for s in range(m):
        extent = 0.0
        for a in range(v):
            for d in range(3):
                extent = max(extent, abs(points[s, a, d] - points[s, 0, d]))
        tol = eps * max(extent, 1e-300)
        c = 0
        flat = True
        for i in range(v):
            for j in range(i + 1, v):
                for k in range(j + 1, v):
                    a0 = points[s, j, 0] - points[s, i, 0]
                    a1 = points[s, j, 1] - points[s, i, 1]
                    a2 = points[s, j, 2] - points[s, i, 2]
                    b0 = points[s, k, 0] - points[s, i, 0]
                    b1 = points[s, k, 1] - points[s, i, 1]
                    b2 = points[s, k, 2] - points[s, i, 2]
                    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
                    length = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
                    if not length > tol * extent:
                        continue                                 # collinear triple
                    n0, n1, n2 = n0 / length, n1 / length, n2 / length
                    o = n0 * points[s, i, 0] + n1 * points[s, i, 1] + n2 * points[s, i, 2]
                    above = False
                    below = False
                    for q in range(v):
                        d = n0 * points[s, q, 0] + n1 * points[s, q, 1] + n2 * points[s, q, 2] - o
                        above = above or d > tol
                        below = below or d < -tol
                    if above and below:
                        continue                                 # cuts the set: not a face plane
                    if not (above or below):
                        continue                                 # every point on it so far
                    flat = False
                    if above:                                    # the points lie on its positive side: flip
                        n0, n1, n2, o = -n0, -n1, -n2, -o
                    seen = False
                    for e in range(c):
                        if (abs(normals[s, e, 0] - n0) <= 1e-9 and abs(normals[s, e, 1] - n1) <= 1e-9
                                and abs(normals[s, e, 2] - n2) <= 1e-9 and abs(offsets[s, e] - o) <= tol):
                            seen = True
                            break
                    if not seen and c < cap:
                        normals[s, c, 0], normals[s, c, 1], normals[s, c, 2] = n0, n1, n2
                        offsets[s, c] = o
                        c += 1
        count[s] = 0 if flat else c
    return normals, offsets, count


def may_meet(tri: np.ndarray, tri_n: np.ndarray, tri_o: np.ndarray, tri_valid: np.ndarray,
              hull_n: np.ndarray, hull_o: np.ndarray, hull_valid: np.ndarray, hull_v: np.ndarray,
              tol: float, exclude: np.ndarray | None = None, first_only: bool = False) -> np.ndarray:
    """Conservative triangle / convex-hull overlap test by separating planes.

    A triangle is apart from a convex hull when all its vertices lie outside (≥ −tol) one outward face plane
    of the hull, or all hull vertices lie on one side (within tol) of the triangle's plane. Touching within
    ``tol`` counts as apart: contact on the boundary blocks only a set of measure zero (docs/planner.md).
    Missing the edge×edge axes only makes the test report "may meet" too often, never too rarely.

    Args:
        tri: (k, 3, 3) triangles; tri_n, tri_o, tri_valid: their planes (k, 3), (k,), (k,) bool.
        hull_n, hull_o, hull_valid: (m, P, 3), (m, P), (m, P) outward face planes of m hulls.
        hull_v: (m, V, 3) hull vertices.
        exclude: optional (k, m) bool → (k,) and (m,) ids: pairs with equal ids never meet (pass as a pair of
            arrays (tri_ids, hull_ids)).
        first_only: stop after the first chunk of triangles that has a meeting pair (rows after it are False).
    Returns:
        (k, m) bool, True where the triangle may meet the hull.
    """
    k, m = len(tri), len(hull_n)
    out = np.zeros((k, m), dtype=bool)
    if k == 0 or m == 0:
        return out
    p, v = hull_n.shape[1], hull_v.shape[1]
    planes = hull_n.reshape(m * p, 3).T                                   # (3, m·P)
    step = max(1, CHUNK_ELEMENTS // max(1, 3 * m * p))
    if first_only:
        step = min(step, 128)
    for s in range(0, k, step):
        t = tri[s:s + step]
        a = len(t)
        d_min = (matmul(t.reshape(a * 3, 3), planes)).reshape(a, 3, m * p).min(axis=1)
        apart = ((d_min >= (hull_o.reshape(-1) - tol)[None]) & hull_valid.reshape(-1)[None]).reshape(a, m, p).any(-1)
        e = (matmul(tri_n[s:s + step], hull_v.reshape(m * v, 3).T)).reshape(a, m, v)
        lo, hi = e.min(axis=-1), e.max(axis=-1)
        o = tri_o[s:s + step, None]
        apart |= tri_valid[s:s + step, None] & ((lo >= o - tol) | (hi <= o + tol))
        if exclude is not None:
            apart |= exclude[0][s:s + step, None] == exclude[1][None, :]
        out[s:s + step] = ~apart
        if first_only and out[s:s + step].any():
            break
    return out
