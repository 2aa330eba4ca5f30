"""Exact convex geometry of oriented boxes (rotated about z), segments and pyramids.

Hidden objects are oriented boxes (OBBs): dicts with ``center`` [x, y, z] m, ``size`` [dx, dy, dz] m and
``yaw_deg`` (degrees about +z, counter-clockwise seen from above). The room sampler
(:mod:`datagen.dataset.sampler`) tests them, inflated by the minimum gap, against each other, the laser beam
(a segment) and the sensor's view of its FoV (a pyramid); the labels (:mod:`datagen.dataset.labels`) test
points against them. Separating-axis theorem for convex polytopes: Gottschalk, Lin & Manocha, "OBBTree",
SIGGRAPH 1996 (axes: face normals of both, cross products of their edge directions).
"""
from __future__ import annotations

import math

import numpy as np

from ..vectors import matmul

_EPS = 1e-12
"""Axes shorter than this (cross products of parallel edges) carry no separation information."""


def yaw_matrix(yaw_deg: float) -> np.ndarray:
    """(3, 3) rotation about +z by ``yaw_deg`` degrees (same as :func:`datagen.scene.builders.box_mesh`)."""
    a = math.radians(yaw_deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def obb_vertices(center, size, yaw_deg: float) -> np.ndarray:
    """(8, 3) float64 corners of the box ``size`` centred at ``center`` rotated by ``yaw_deg`` about z."""
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    return matmul(corners * np.asarray(size, float), yaw_matrix(yaw_deg).T) + np.asarray(center, float)


def convex_overlap(verts_a: np.ndarray, dirs_a: np.ndarray, normals_a: np.ndarray,
                   verts_b: np.ndarray, dirs_b: np.ndarray, normals_b: np.ndarray) -> bool:
    """Separating-axis test of two convex polytopes (Gottschalk et al. 1996).

    Args:
        verts_*: (n, 3) vertices; dirs_*: (e, 3) edge directions; normals_*: (f, 3) face normals
            (a segment has one edge direction and no face normals).
    Returns:
        True when no axis separates them (they overlap or touch); False when they are disjoint.
    """
    cross = np.cross(dirs_a[:, None, :], dirs_b[None, :, :]).reshape(-1, 3)
    axes = np.concatenate([normals_a.reshape(-1, 3), normals_b.reshape(-1, 3), cross])
    norm = np.linalg.norm(axes, axis=1)
    axes = axes[norm > _EPS] / norm[norm > _EPS, None]
    pa, pb = matmul(verts_a, axes.T), matmul(verts_b, axes.T)
    separated = (pa.max(0) < pb.min(0)) | (pb.max(0) < pa.min(0))
    return not bool(separated.any())


def _box_parts(center, size, yaw_deg):
    rot = yaw_matrix(yaw_deg)
    return obb_vertices(center, size, yaw_deg), rot.T, rot.T   # edge dirs = face normals = box axes


def boxes_overlap(a: dict, b: dict, gap: float = 0.0) -> bool:
    """True when boxes ``a`` and ``b`` (dicts with center, size, yaw_deg), each inflated by ``gap``/2 per
    side, overlap. Rotations about z only: z-interval test plus 2D separating axes of the footprints."""
    (ca, sa), (cb, sb) = (np.asarray(a["center"]), np.asarray(a["size"]) + gap), \
                         (np.asarray(b["center"]), np.asarray(b["size"]) + gap)
    if abs(ca[2] - cb[2]) >= (sa[2] + sb[2]) / 2:
        return False
    return convex_overlap(obb_vertices(ca, sa, a["yaw_deg"]), yaw_matrix(a["yaw_deg"]).T[:2],
                          yaw_matrix(a["yaw_deg"]).T[:2], obb_vertices(cb, sb, b["yaw_deg"]),
                          yaw_matrix(b["yaw_deg"]).T[:2], yaw_matrix(b["yaw_deg"]).T[:2])


def box_hits_segment(obj: dict, p: np.ndarray, q: np.ndarray, gap: float = 0.0) -> bool:
    """True when the segment p→q ((3,) m each) touches the box ``obj`` inflated by ``gap``/2 per side."""
    v, e, n = _box_parts(obj["center"], np.asarray(obj["size"]) + gap, obj["yaw_deg"])
    seg = np.stack([p, q]).astype(float)
    return convex_overlap(v, e, n, seg, (q - p)[None].astype(float), np.zeros((0, 3)))


def box_hits_pyramid(obj: dict, apex: np.ndarray, base: np.ndarray, gap: float = 0.0) -> bool:
    """True when the pyramid (apex (3,), base (4, 3) corners of a planar quad in order) touches ``obj``.

    The pyramid is the set of sight lines from a sensor at ``apex`` to every point of its FoV ``base``.
    """
    v, e, n = _box_parts(obj["center"], np.asarray(obj["size"]) + gap, obj["yaw_deg"])
    apex = np.asarray(apex, float)
    base = np.asarray(base, float)
    nxt = np.roll(base, -1, axis=0)
    lateral = base - apex
    base_edges = nxt - base
    side_normals = np.cross(lateral, nxt - apex)
    base_normal = np.cross(base_edges[0], base_edges[1])[None]
    verts = np.concatenate([apex[None], base])
    return convex_overlap(v, e, n, verts, np.concatenate([lateral, base_edges]),
                          np.concatenate([side_normals, base_normal]))


def points_in_box(points: np.ndarray, obj: dict) -> np.ndarray:
    """(n,) bool: which of ``points`` (n, 3) lie inside (or on) the oriented box ``obj``."""
    local = matmul(np.asarray(points, float) - np.asarray(obj["center"], float), yaw_matrix(obj["yaw_deg"]))
    return np.all(np.abs(local) <= np.asarray(obj["size"], float) / 2, axis=-1)
