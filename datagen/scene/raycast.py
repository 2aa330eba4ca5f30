"""First-hit ray casting and shadow (visibility) rays over a scene, on Embree (embreex).

Embree works in float32. To keep that from limiting large scenes, the mesh is translated so its bounding box
is centred on the origin before it is handed to Embree, and every hit point is placed in float64 along the
float64 ray where it crosses the hit triangle's plane in float64 (so it lies on its surface to float64
precision, and so does the distance). Rays leave a
surface from a point pushed off it along the normal by a *scale-aware* offset (a fixed fraction of the scene
size), so a 6 m room and a 600 m tunnel both work.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from numba import njit

from .model import Scene

RAY_OFFSET_REL = 1e-5
"""Surface offset for ray origins, as a fraction of the scene size: ~100 float32 ULPs of the centred
coordinates, enough to step past the surface a ray leaves, small against any feature we model."""

GRAZING_COS = 1e-3
"""|cos| between a ray and the hit face's normal below which the float64 ray-plane intersection is
ill-conditioned and Embree's own distance is kept."""

CHUNK = 1 << 21
"""Rays per Embree call: bounds the temporary float32 buffers (~50 MB) for huge ray batches."""


@dataclass(frozen=True)
class Hits:
    """First hits of a batch of rays (all arrays have the batch's leading shape).

    Attributes:
        hit: bool, the ray hit something.
        distance: float64 metres from the ray origin (inf where no hit).
        points: (..., 3) float64 hit positions (nan where no hit).
        normals: (..., 3) float64 unit geometric normals facing the ray origin (zero where no hit).
        face: int64 face index (−1 where no hit).
        object_id: int64 object index (−1 where no hit).
    """

    hit: np.ndarray
    distance: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    face: np.ndarray
    object_id: np.ndarray

    def hit_points(self) -> np.ndarray:
        """(..., 3) float64 :attr:`points` with 0 where no hit (``numpy.nan_to_num`` of them, without its
        per-call checks: a hit's point is finite)."""
        return np.where(self.hit[..., None], self.points, 0.0)


class RayCaster:
    """Embree BVH over all objects of a :class:`~datagen.scene.Scene`.

    Attributes:
        offset: float metres, the surface offset for ray origins (``RAY_OFFSET_REL`` × scene size).
    """

    def __init__(self, scene: Scene):
        import embreex.mesh_construction as mesh_construction
        import embreex.rtcore_scene as rtcore_scene

        self.vertices = scene.vertices
        self.faces = scene.faces
        self.face_object = scene.face_object
        bounds = scene.bounds()
        self.center = 0.5 * (bounds[0] + bounds[1])
        self.size = float(np.max(bounds[1] - bounds[0]))
        self.offset = RAY_OFFSET_REL * max(self.size, 1e-3)
        tri = self.vertices[self.faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(cross, axis=1)
        self.face_area = 0.5 * norm
        self.face_normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
        self._tri0 = tri[:, 0]
        self._plane_offset = np.einsum("ij,ij->i", self.face_normals, self._tri0)     # n·p₀ per face, metres
        self._e1 = tri[:, 1] - tri[:, 0]
        self._e2 = tri[:, 2] - tri[:, 0]
        self._embree = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._embree, (tri - self.center).astype(np.float32))

    def commit(self) -> None:
        """Build the BVH now (Embree builds it at the first query, with its TBB thread pool). Call before forking
        worker processes: they then only query the inherited BVH, since TBB is not fork-safe (a child that
        builds a BVH can wait forever on a TBB lock that was held in the parent at the fork)."""
        if not self._embree.is_committed:
            self._embree.run(np.zeros((1, 3), np.float32), np.array([[0.0, 0.0, 1.0]], np.float32))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """First hit along each ray.

        Args:
            origins: (..., 3) float64 metres (already offset off any surface they start on); broadcast against
                ``directions`` (e.g. (B, 1, 3) origins for (B, P, 3) directions: one origin per camera).
            directions: (..., 3) float64 unit vectors.
        Returns:
            :class:`Hits` with the broadcast batch shape.

        Embree finds the face in float32; the distance is then the float64 intersection of the float64 ray with
        that face's plane, t = (n·p₀ − n·o) / (n·d), so hit points lie on the surface to float64 precision
        (falling back to Embree's float32 distance, ~6e-8 relative, for rays within 1e-3 of grazing).
        """
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.asarray(directions, dtype=np.float64)
        shape = _batch_shape(origins, directions)
        n = math.prod(shape)
        o, d = _rows(origins, shape), _rows(directions, shape)
        o32, d32 = _float32_rays(o, d, self.center, n)
        face = np.empty(n, dtype=np.int64)
        tfar = np.empty(n, dtype=np.float64)
        for start in range(0, n, CHUNK):
            sl = slice(start, start + CHUNK)
            res = self._embree.run(o32[sl], d32[sl], output=1)
            face[sl], tfar[sl] = res["primID"], res["tfar"]
        hit, distance, points, normals, face, obj = _first_hits(o, d, face, tfar, self.face_normals,
                                                                self._plane_offset, self.face_object, GRAZING_COS)
        return Hits(hit.reshape(shape), distance.reshape(shape), points.reshape(shape + (3,)),
                    normals.reshape(shape + (3,)), face.reshape(shape), obj.reshape(shape))

    def visible(self, p: np.ndarray, n_p: np.ndarray | None, q: np.ndarray, n_q: np.ndarray | None) -> np.ndarray:
        """Mutual visibility of point pairs by shadow rays (Embree occlusion queries).

        Args:
            p, q: (..., 3) float64 end points (broadcast against each other).
            n_p, n_q: (..., 3) unit normals of the surfaces p and q lie on, facing the segment, or None for
                a point in free space (a sensor, an emitter). Ends are pushed off their surface by
                :attr:`offset` along them so the surfaces themselves do not occlude.
        Returns:
            (...,) bool, True where nothing blocks the segment.
        """
        p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
        shape = _batch_shape(p, q)
        n = math.prod(shape)
        rows = [_rows(v, shape) for v in (p, n_p if n_p is not None else p, q, n_q if n_q is not None else q)]
        # ends pushed off their surfaces, centred, in float32 (Embree's precision; the offset is ~100 ULPs)
        a, d, tmax, ok = _segments(*rows, n_p is not None, n_q is not None, self.center, self.offset, n)
        res = np.empty(len(a), dtype=np.int32)
        for start in range(0, len(a), CHUNK):
            sl = slice(start, start + CHUNK)
            res[sl] = self._embree.run(np.ascontiguousarray(a[sl]), d[sl], dists=tmax[sl], query="OCCLUDED")
        out = np.ones(len(ok), dtype=bool)
        out[ok] = res == -1
        return out.reshape(shape)


def _batch_shape(a: np.ndarray, b: np.ndarray) -> tuple:
    """The batch shape of two (..., 3) arrays broadcast against each other (their common shape when equal: the
    usual case, without numpy's broadcasting machinery, which costs more than a small batch's rays)."""
    return a.shape[:-1] if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape)[:-1]


def _rows(v: np.ndarray, shape: tuple) -> np.ndarray:
    """(n, 3) float64 rows of v for a batch of ``shape``, or (1, 3) when v is one point (broadcast)."""
    v = np.asarray(v, dtype=np.float64)
    if v.size == 3:
        return v.reshape(1, 3)
    if v.shape == shape + (3,) and v.flags.c_contiguous:        # already one row per ray: a view, as below
        return v.reshape(-1, 3)
    return np.ascontiguousarray(np.broadcast_to(v, shape + (3,))).reshape(-1, 3)


@njit(cache=True)
def _segments(p, n_p, q, n_q, use_np, use_nq, center, offset, n):
    """Shadow-ray segments of :meth:`RayCaster.visible` in one pass: the ends a = p − centre (+ offset·n_p) and
    b likewise in float32, d = (b − a)/|b − a| and t_max = |b − a| − offset in float32 arithmetic (the numpy
    expressions they replace, rounded the same way); rows shorter than the offset are dropped (ok False)."""
    a_out = np.empty((n, 3), np.float32)
    d_out = np.empty((n, 3), np.float32)
    tmax = np.empty(n, np.float32)
    ok = np.empty(n, np.bool_)
    off32 = np.float32(offset)
    a = np.empty(3, np.float32)
    seg = np.empty(3, np.float32)
    k = 0
    for i in range(n):
        ip, inp, iq, inq = (0 if p.shape[0] == 1 else i), (0 if n_p.shape[0] == 1 else i), \
            (0 if q.shape[0] == 1 else i), (0 if n_q.shape[0] == 1 else i)
        for c in range(3):
            av = p[ip, c] - center[c]
            if use_np:
                av = av + offset * n_p[inp, c]
            bv = q[iq, c] - center[c]
            if use_nq:
                bv = bv + offset * n_q[inq, c]
            a[c] = np.float32(av)
            seg[c] = np.float32(bv) - a[c]
        length = np.sqrt(seg[0] * seg[0] + seg[1] * seg[1] + seg[2] * seg[2])
        ok[i] = length > off32
        if ok[i]:
            for c in range(3):
                a_out[k, c] = a[c]
                d_out[k, c] = seg[c] / length
            tmax[k] = length - off32
            k += 1
    return a_out[:k], d_out[:k], tmax[:k], ok


@njit(cache=True)
def _float32_rays(o, d, center, n):
    """Ray origins (centred) and directions of :meth:`RayCaster.intersect` as contiguous (n, 3) float32."""
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    for i in range(n):
        io, jd = (0 if o.shape[0] == 1 else i), (0 if d.shape[0] == 1 else i)
        for c in range(3):
            o32[i, c] = np.float32(o[io, c] - center[c])
            d32[i, c] = np.float32(d[jd, c])
    return o32, d32


@njit(cache=True)
def _first_hits(o, d, face, tfar, face_normals, plane_offset, face_object, grazing):
    """:class:`Hits` fields of :meth:`RayCaster.intersect` from Embree's faces and float32 distances: the float64
    ray-plane distance t = (n·p₀ − n·o)/(n·d) unless |n·d| ≤ ``grazing`` (Embree's), points o + t·d (nan, no
    hit), normals facing the origin (0, no hit), face and object ids (−1, no hit); the numpy expressions they
    replace, in the same order."""
    n = face.shape[0]
    hit = face >= 0
    distance = np.empty(n)
    points = np.empty((n, 3))
    normals = np.empty((n, 3))
    face_out = np.empty(n, np.int64)
    obj = np.empty(n, np.int64)
    for i in range(n):
        io, jd = (0 if o.shape[0] == 1 else i), (0 if d.shape[0] == 1 else i)
        f = face[i] if hit[i] else 0
        n0, n1, n2 = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
        denom = d[jd, 0] * n0 + d[jd, 1] * n1 + d[jd, 2] * n2
        num = plane_offset[f] - (o[io, 0] * n0 + o[io, 1] * n1 + o[io, 2] * n2)
        t = num / denom if abs(denom) > grazing else tfar[i]
        distance[i] = t if hit[i] else np.inf
        tp = t if hit[i] else np.nan
        scale = (-1.0 if denom > 0 else 1.0) * (1.0 if hit[i] else 0.0)
        for c in range(3):
            points[i, c] = o[io, c] + d[jd, c] * tp
            normals[i, c] = face_normals[f, c] * scale
        face_out[i] = face[i] if hit[i] else -1
        obj[i] = face_object[f] if hit[i] else -1
    return hit, distance, points, normals, face_out, obj
