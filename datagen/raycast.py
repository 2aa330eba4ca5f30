"""First-hit ray casting and shadow (visibility) rays over a scene, on Embree (embreex).

Embree works in float32. To keep that from limiting large scenes, the mesh is translated so its bounding box
is centred on the origin before it is handed to Embree, and every hit point is placed in float64 along the
float64 ray at Embree's hit distance, then projected onto the hit triangle's plane in float64 (so it lies on
its surface to float64 precision; along the surface it is within ~1e-7 of the distance). Rays leave a
surface from a point pushed off it along the normal by a *scale-aware* offset (a fixed fraction of the scene
size), so a 6 m room and a 600 m tunnel both work.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene

RAY_OFFSET_REL = 1e-5
"""Surface offset for ray origins, as a fraction of the scene size: ~100 float32 ULPs of the centred
coordinates, enough to step past the surface a ray leaves, small against any feature we model."""

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
        self._e1 = tri[:, 1] - tri[:, 0]
        self._e2 = tri[:, 2] - tri[:, 0]
        self._embree = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._embree, (tri - self.center).astype(np.float32))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """First hit along each ray.

        Args:
            origins: (..., 3) float64 metres (already offset off any surface they start on).
            directions: (..., 3) float64 unit vectors.
        Returns:
            :class:`Hits` with the batch's leading shape.
        """
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.asarray(directions, dtype=np.float64)
        shape = origins.shape[:-1]
        o = origins.reshape(-1, 3)
        d = np.broadcast_to(directions, origins.shape).reshape(-1, 3)
        face = np.empty(len(o), dtype=np.int64)
        tfar = np.empty(len(o), dtype=np.float64)
        center = self.center.astype(np.float32)
        for start in range(0, len(o), CHUNK):
            sl = slice(start, start + CHUNK)
            res = self._embree.run(o[sl].astype(np.float32) - center, d[sl].astype(np.float32), output=1)
            face[sl], tfar[sl] = res["primID"], res["tfar"]
        hit = face >= 0
        f = np.where(hit, face, 0)
        # Hit point in float64 along the float64 ray: |error| ≈ 6e-8 × distance (float32 tfar), far below the
        # surface offset (1e-5 × scene size) and below 1 fs of time of flight for a 1 km path.
        points = o + d * np.where(hit, tfar, np.nan)[:, None]
        normals = self.face_normals[f]
        # snap onto the hit triangle's plane in float64 (removes the float32 error across the surface)
        points -= np.einsum("ij,ij->i", points - self._tri0[f], normals)[:, None] * normals
        distance = np.where(hit, np.sqrt(np.einsum("ij,ij->i", points - o, points - o)), np.inf)
        flip = np.einsum("ij,ij->i", normals, d) > 0
        np.negative(normals, out=normals, where=flip[:, None])
        normals[~hit] = 0.0
        obj = np.where(hit, self.face_object[f], -1)
        return Hits(hit.reshape(shape), distance.reshape(shape), points.reshape(shape + (3,)),
                    normals.reshape(shape + (3,)), np.where(hit, face, -1).reshape(shape), obj.reshape(shape))

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
        p, q = np.broadcast_arrays(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64))
        shape = p.shape[:-1]
        a = p if n_p is None else p + self.offset * np.asarray(n_p)
        b = q if n_q is None else q + self.offset * np.asarray(n_q)
        a = np.broadcast_to(a, p.shape).reshape(-1, 3)
        b = np.broadcast_to(b, p.shape).reshape(-1, 3)
        seg = b - a
        length = np.sqrt(np.einsum("ij,ij->i", seg, seg))
        ok = length > self.offset
        if not ok.all():
            seg, a, length = seg[ok], a[ok], length[ok]
        d = (seg / length[:, None]).astype(np.float32)
        o = a.astype(np.float32) - self.center.astype(np.float32)
        tmax = (length - self.offset).astype(np.float32)
        res = np.empty(len(o), dtype=np.int32)
        for start in range(0, len(o), CHUNK):
            sl = slice(start, start + CHUNK)
            res[sl] = self._embree.run(o[sl], d[sl], dists=tmax[sl], query="OCCLUDED")
        out = np.ones(len(ok), dtype=bool)
        out[ok] = res == -1
        return out.reshape(shape)
