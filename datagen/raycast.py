"""First-hit ray casting and shadow (visibility) rays over a scene, on Embree (embreex).

Embree works in float32. To keep that from limiting large scenes, the mesh is translated so its bounding box
is centred on the origin before it is handed to Embree, every hit point is rebuilt in float64 from the hit
triangle's barycentric coordinates, and distances are recomputed in float64 from those points. Rays leave a
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
        u = np.empty(len(o), dtype=np.float64)
        v = np.empty(len(o), dtype=np.float64)
        for start in range(0, len(o), CHUNK):
            sl = slice(start, start + CHUNK)
            res = self._embree.run((o[sl] - self.center).astype(np.float32), d[sl].astype(np.float32), output=1)
            face[sl], u[sl], v[sl] = res["primID"], res["u"], res["v"]
        hit = face >= 0
        f = np.where(hit, face, 0)
        points = self._tri0[f] + u[:, None] * self._e1[f] + v[:, None] * self._e2[f]
        distance = np.linalg.norm(points - o, axis=1)
        normals = self.face_normals[f]
        flip = np.einsum("ij,ij->i", normals, d) > 0
        normals = np.where(flip[:, None], -normals, normals)
        points[~hit] = np.nan
        distance[~hit] = np.inf
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
        a = p + (0.0 if n_p is None else self.offset * np.asarray(n_p))
        b = q + (0.0 if n_q is None else self.offset * np.asarray(n_q))
        a = np.broadcast_to(a, p.shape).reshape(-1, 3)
        b = np.broadcast_to(b, p.shape).reshape(-1, 3)
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        out = np.ones(len(a), dtype=bool)
        ok = length > self.offset
        d = seg[ok] / length[ok, None]
        tmax = length[ok] - self.offset
        res = np.empty(int(ok.sum()), dtype=np.int32)
        oa = a[ok]
        for start in range(0, len(oa), CHUNK):
            sl = slice(start, start + CHUNK)
            res[sl] = self._embree.run((oa[sl] - self.center).astype(np.float32), d[sl].astype(np.float32),
                                       dists=tmax[sl].astype(np.float32), query="OCCLUDED")
        out[ok] = res == -1
        return out.reshape(shape)
