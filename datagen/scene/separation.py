"""Separating-plane tests between triangles and convex hulls (scene geometry shared by the effect planner and the
quadrature's occluder test).

A triangle and a convex hull cannot meet when a plane separates them; testing the hull's face planes and the
triangle's own plane is conservative (missing the edge×edge axes only reports "may meet" too often). The
planner uses it to prove that shadow rays cannot be blocked (docs/planner.md); the quadrature
(:mod:`datagen.transport.quadrature`) to decide which legs need shadow rays.
"""
from __future__ import annotations

import numpy as np

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


def hull_planes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outward face planes of the convex hulls of point sets (m, V, 3) → normals (m, P, 3), offsets (m, P),
    validity (m, P), by Qhull; a flat or degenerate set gets no valid plane (it is then never separated)."""
    from scipy.spatial import ConvexHull, QhullError

    planes = []
    for pts in points:
        try:
            eq = ConvexHull(pts).equations                             # n·x + d ≤ 0 inside, n unit
            planes.append((eq[:, :3], -eq[:, 3]))
        except (QhullError, ValueError):
            planes.append((np.zeros((1, 3)), np.zeros(1)))
    p = max(len(n) for n, _ in planes)
    normals = np.zeros((len(points), p, 3))
    offsets = np.zeros((len(points), p))
    valid = np.zeros((len(points), p), dtype=bool)
    for i, (n, o) in enumerate(planes):
        normals[i, :len(n)], offsets[i, :len(n)] = n, o
        valid[i, :len(n)] = np.linalg.norm(n, axis=1) > 0
    return normals, offsets, valid


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
        d_min = (t.reshape(a * 3, 3) @ planes).reshape(a, 3, m * p).min(axis=1)
        apart = ((d_min >= (hull_o.reshape(-1) - tol)[None]) & hull_valid.reshape(-1)[None]).reshape(a, m, p).any(-1)
        e = (tri_n[s:s + step] @ hull_v.reshape(m * v, 3).T).reshape(a, m, v)
        lo, hi = e.min(axis=-1), e.max(axis=-1)
        o = tri_o[s:s + step, None]
        apart |= tri_valid[s:s + step, None] & ((lo >= o - tol) | (hi <= o + tol))
        if exclude is not None:
            apart |= exclude[0][s:s + step, None] == exclude[1][None, :]
        out[s:s + step] = ~apart
        if first_only and out[s:s + step].any():
            break
    return out
