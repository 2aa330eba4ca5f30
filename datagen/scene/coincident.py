"""Coincident faces: z-fighting between objects (rejected) and duplicate faces (removed).

Two faces of different objects that lie in the same plane (within ``COPLANAR_TOL_REL`` of the scene size),
overlap with positive area and can be seen from a common side have no defined reflectance there: Embree picks
one per ray by BVH order. :func:`resolve_coincident_faces` (called by :class:`datagen.scene.Scene` on
construction) rejects them when the materials differ or the overlap is partial, removes exact same-material
duplicates (area-based estimators would count them twice) and accepts touching solids, whose faces are back
to back (the side light can reach each face from decides, not the winding).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from .parts import ROOM_LABELS, Laser, SceneError, SceneObject, Sensor
from .static_faces import StaticFaces, viewpoint_key
from ..vectors import matmul

COPLANAR_TOL_REL = 1e-5
"""Faces closer than this fraction of the scene size (the largest extent of :meth:`Scene.bounds`) count as
coincident. It equals ``datagen.scene.raycast.RAY_OFFSET_REL``, the surface offset of ray origins (the scene
model is upstream of the ray caster, so the value is repeated here; a test keeps the two equal): a ray leaving
one of two such faces starts beyond the other, and Embree orders first hits between them by float32 round-off."""

NORMAL_CELL = 1e-3
"""Cell of the rounded unit normals faces are grouped by before the exact pairwise test. Faces of one plane have
normals equal to round-off, so they share a cell unless a cell boundary falls between them (probability ~1e-12
per pair). Faces tilted against each other by ≳ 1e-3 rad are never compared: they stay within the tolerance of
each other over at most tol / 1e-3 = 1 % of the scene size."""

CANONICAL_DIRECTION = np.array([0.7548776662, 0.5698402910, 0.3247179572])
"""Grouping flips each normal to a positive component along this fixed generic direction, so both windings of a
plane share a key. No plane with an integer normal of components up to ±10 is within 3e-4 of perpendicular to
it (checked), so float noise (~1e-16) never flips the sign of a real mesh's face."""

WINDING_INSIDE = 0.75
"""|winding number| above this: a point is inside a closed mesh; below 1 − this: outside; between: on it."""

SPOT_ON_SURFACE_REL = 1e-3
"""The laser spot counts as on a surface (and so inside the scene, usable to tell a room surface's inner side)
within this fraction of the scene size of some face."""

PAIR_CHUNK = 1 << 20
"""Candidate face pairs tested per vectorised batch (bounds temporary memory to ~100 MB)."""

COMPONENTS_KEPT, COMPONENTS_FACES = 16, 1 << 16
"""Meshes (of at most this many faces) whose closed components are kept by their faces' merged vertices (a moving
object's are the same in every pose; :func:`_closed_components`)."""
_COMPONENTS: dict[bytes, np.ndarray] = {}

FRONT, BACK = 1, 2
"""Side bits of a face: FRONT the side its canonical normal points to, BACK the other."""


@dataclass(frozen=True)
class Coincidence:
    """Overlapping coplanar faces of two different objects, one row per face pair (P pairs).

    Attributes:
        objects: (P, 2) int64 object indices, objects[:, 0] < objects[:, 1].
        faces: (P, 2) int64 face indices within each object (``objects[i].faces`` rows).
        normal: (P, 3) float64 unit normal of the shared plane (canonical sign); offset: (P,) metres, the plane
            is normal·x = offset.
        area: (P,) float64 m², area of the overlap; point: (P, 3) float64, centroid of its polygon's vertices.
        duplicate: (P,) bool, the two triangles have the same three vertices (within the tolerance).
        sides: (P,) int8, bit mask of the sides light can reach *both* faces from (FRONT along ``normal``,
            BACK against it); 0 means back to back (touching solids), nothing can see both.
    """

    objects: np.ndarray
    faces: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    area: np.ndarray
    point: np.ndarray
    duplicate: np.ndarray
    sides: np.ndarray

    @classmethod
    def empty(cls) -> Coincidence:
        z = np.zeros(0)
        return cls(np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros((0, 3)), z, z,
                   np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0, np.int8))

    def take(self, keep: np.ndarray) -> Coincidence:
        return Coincidence(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


def _triangle_planes(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, 3, 3) triangles → winding normals (F, 3) (unit, zero for degenerate ones), twice the areas (F,),
    widths (F,) m: 2·area / longest edge, the height over the longest edge (0 for degenerate triangles)."""
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    longest = np.max(np.linalg.norm(tri - tri[:, [1, 2, 0]], axis=2), axis=1)
    normal = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    width = np.divide(norm, longest, out=np.zeros_like(norm), where=longest > 0)
    return normal, norm, width


def _on_a_face(point: np.ndarray, tri: np.ndarray, tol: float) -> bool:
    """True when ``point`` (3,) lies within ``tol`` metres of a triangle of (F, 3, 3) (its projection on the
    triangle's plane inside the triangle, barycentric slack 1e-9)."""
    e1, e2, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], point - tri[:, 0]
    n = np.cross(e1, e2)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 0
    e1, e2, w, n, nn = e1[ok], e2[ok], w[ok], n[ok], nn[ok]
    height = np.einsum("ij,ij->i", w, n) / np.sqrt(nn)
    b1 = np.einsum("ij,ij->i", np.cross(w, e2), n) / nn
    b2 = np.einsum("ij,ij->i", np.cross(e1, w), n) / nn
    inside = (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1 + 1e-9)
    return bool(np.any(inside & (np.abs(height) < tol)))


def duplicate_faces(vertices: np.ndarray, faces: np.ndarray, tol: float) -> np.ndarray:
    """(F,) bool: faces whose three vertices (in any order or winding) repeat an earlier face's, within ``tol``
    metres (vertices rounded to a grid of ``tol``; exact copies always match).

    Args:
        vertices: (V, 3) float64 metres; faces: (F, 3) int64; tol: metres > 0.
    """
    if len(faces) < 2:
        return np.zeros(len(faces), dtype=bool)
    keys = np.round((vertices - vertices.min(axis=0)) / tol).astype(np.int64)[faces]      # (F, 3, 3)
    for axis in (2, 1, 0):          # sort the three vertices of each face lexicographically (stable passes)
        order = np.argsort(keys[:, :, axis], axis=1, kind="stable")
        keys = np.take_along_axis(keys, order[:, :, None], axis=1)
    order, new, _ = _row_groups(keys.reshape(len(faces), 9))
    dup = np.empty(len(faces), dtype=bool)
    dup[order] = ~new                                   # all but the first (lowest index) of each group
    return dup


def _clip_triangles(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersections of 2-D triangles a and b (P, 3, 2), Sutherland–Hodgman (a clipped by b's three edges).

    Returns area (P,), perimeter (P,) and vertex centroid (P, 2) of each intersection polygon (zeros if empty).
    """
    p = len(a)
    rows = np.arange(p)
    flip = ((b[:, 1, 0] - b[:, 0, 0]) * (b[:, 2, 1] - b[:, 0, 1])
            - (b[:, 1, 1] - b[:, 0, 1]) * (b[:, 2, 0] - b[:, 0, 0])) < 0
    b = np.where(flip[:, None, None], b[:, ::-1], b)                    # counter-clockwise clip edges
    poly = np.zeros((p, 8, 2))
    poly[:, :3] = a
    count = np.full(p, 3)
    for k in range(3):
        e0, e1 = b[:, k], b[:, (k + 1) % 3]
        edge = e1 - e0
        side = edge[:, None, 0] * (poly[..., 1] - e0[:, None, 1]) - edge[:, None, 1] * (poly[..., 0] - e0[:, None, 0])
        out = np.zeros_like(poly)
        n_out = np.zeros(p, dtype=np.int64)
        safe = np.maximum(count, 1)
        for m in range(int(count.max(initial=0))):
            valid = m < count
            prev = (m - 1) % safe
            cur_p, prev_p = poly[:, m], poly[rows, prev]
            s_cur, s_prev = side[:, m], side[rows, prev]
            inside_cur, inside_prev = s_cur >= 0, s_prev >= 0
            crossing = valid & (inside_cur != inside_prev)
            t = np.divide(s_prev, s_prev - s_cur, out=np.zeros(p), where=crossing)
            w = np.flatnonzero(crossing)
            out[w, n_out[w]] = prev_p[w] + t[w, None] * (cur_p[w] - prev_p[w])
            n_out[w] += 1
            w = np.flatnonzero(valid & inside_cur)
            out[w, n_out[w]] = cur_p[w]
            n_out[w] += 1
        poly, count = out, n_out
    safe = np.maximum(count, 1)
    area2 = np.zeros(p)
    perimeter = np.zeros(p)
    for m in range(int(count.max(initial=0))):
        valid = m < count
        nxt = poly[rows, (m + 1) % safe]
        area2 += np.where(valid, poly[:, m, 0] * nxt[:, 1] - poly[:, m, 1] * nxt[:, 0], 0.0)
        perimeter += np.where(valid, np.linalg.norm(nxt - poly[:, m], axis=1), 0.0)
    mask = np.arange(8)[None, :] < count[:, None]
    centroid = (poly * mask[..., None]).sum(axis=1) / safe[:, None]
    empty = count < 3
    return np.where(empty, 0.0, 0.5 * np.abs(area2)), np.where(empty, 0.0, perimeter), centroid


def _row_groups(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group identical rows of an (N, k) array by a stable lexsort (numpy 2's np.unique with axis=0 is several
    times slower). Returns (order (N,), new (N,) bool: row order[i] starts a group, inverse (N,) group id of
    each row, ids in sorted order); within a group rows keep their original order."""
    order = np.lexsort(rows.T[::-1])
    s = rows[order]
    new = np.ones(len(rows), dtype=bool)
    new[1:] = np.any(s[1:] != s[:-1], axis=1)
    inverse = np.empty(len(rows), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return order, new, inverse


def _sorted_unique(x: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an int64 array (by sorting: numpy 2's hash-based np.unique is ~10× slower on
    millions of int64 keys)."""
    x = np.sort(x)
    return x[np.concatenate([[True], x[1:] != x[:-1]])] if len(x) else x


def _candidate_pairs(cluster: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Broad phase: every pair of boxes of one cluster whose 2-D boxes [lo, hi] (m, 2) overlap, each pair once,
    in chunks of ≤ PAIR_CHUNK pairs: yields (i, j) int64 index arrays, i < j.

    Hierarchical grid (cell sizes s0·2^ℓ): a box lives at the level whose cell is at least its size, so it
    covers ≤ 2×2 cells there, and visits the ≤ 2×2 cells it covers at every coarser level in use. Pairs are
    the residents of a cell with each other and its visitors with its residents: two overlapping boxes share
    a cell at the coarser of their levels. Cost ~ boxes × levels, whatever the sizes and layout of the boxes.
    """
    m = len(lo)
    size = np.max(hi - lo, axis=1)
    s0 = max(float(np.min(size[size > 0], initial=1.0)), 1e-12)
    level = np.maximum(np.ceil(np.log2(np.maximum(size, s0) / s0)), 0).astype(np.int64)
    level += s0 * 2.0 ** level < size                          # guard against log2 round-off
    parts = []
    for lev in np.unique(level):
        member = np.flatnonzero(level <= lev)
        cell = s0 * 2.0 ** lev
        c_lo = np.floor(lo[member] / cell).astype(np.int64)
        c_hi = np.floor(hi[member] / cell).astype(np.int64)
        for dx in (0, 1):
            for dy in (0, 1):
                cx, cy = c_lo[:, 0] + dx, c_lo[:, 1] + dy
                ok = (cx <= c_hi[:, 0]) & (cy <= c_hi[:, 1])
                parts.append(np.stack([np.full(ok.sum(), lev), cluster[member[ok]], cx[ok], cy[ok],
                                       (level[member[ok]] != lev).astype(np.int64), member[ok]], axis=1))
    e = np.concatenate(parts)
    e = e[np.lexsort(e.T[::-1])]                  # by level, cluster, cell, then residents (0) before visitors
    new = np.ones(len(e), dtype=bool)
    new[1:] = np.any(e[1:, :4] != e[:-1, :4], axis=1)
    group = np.cumsum(new) - 1
    g_start = np.flatnonzero(new)
    residents = np.bincount(group, weights=e[:, 4] == 0, minlength=len(g_start)).astype(np.int64)
    pos = np.arange(len(e)) - g_start[group]
    visitor = e[:, 4] == 1
    # a resident pairs with the residents after it, a visitor with every resident of its cell
    first = np.where(visitor, g_start[group], np.arange(len(e)) + 1)
    count = np.where(visitor, residents[group], np.maximum(residents[group] - pos - 1, 0))
    cum = np.cumsum(count)
    keys = []
    done = 0
    while done < len(e):
        base = cum[done - 1] if done else 0
        last = max(int(np.searchsorted(cum, base + PAIR_CHUNK, side="right")), done + 1)
        c = count[done:last]
        k = np.repeat(np.arange(done, last), c)
        other = first[k] + (np.arange(len(k)) - np.repeat(np.cumsum(c) - c, c))
        i, j = e[k, 5], e[other, 5]
        keys.append(_sorted_unique(np.minimum(i, j) * m + np.maximum(i, j)))
        done = last
    keys = _sorted_unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)
    for s in range(0, len(keys), PAIR_CHUNK):
        yield keys[s:s + PAIR_CHUNK] // m, keys[s:s + PAIR_CHUNK] % m


def _closed_components(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) int64 label of the closed, consistently wound connected component of each face, −1 for faces of
    open or inconsistently wound components. Identical vertices are merged first; a component is closed and
    consistently wound when each directed edge occurs once and so does its reverse (as in datagen.planner)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = _row_groups(vertices)[2][faces]
    n = int(f.max()) + 1
    first = np.full(n, f.size)          # merged vertices numbered by first use: the same in any pose
    np.minimum.at(first, f.reshape(-1), np.arange(f.size))
    key = hashlib.sha1(np.argsort(np.argsort(first))[f].tobytes()).digest() if len(f) <= COMPONENTS_FACES else None
    if key in _COMPONENTS:
        return _COMPONENTS[key].copy()
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    _, vertex_label = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    label = vertex_label[f[:, 0]]
    fwd = a * n + b
    keys = np.sort(fwd)
    counts = np.searchsorted(keys, fwd, side="right") - np.searchsorted(keys, fwd, side="left")
    rev = b * n + a
    pos = np.minimum(np.searchsorted(keys, rev), len(keys) - 1)
    edge_ok = (a != b) & (counts == 1) & (keys[pos] == rev)
    bad = np.unique(label[~edge_ok.reshape(-1, 3).all(axis=1)])
    label = np.where(np.isin(label, bad), -1, label)
    if key is not None:
        if len(_COMPONENTS) >= COMPONENTS_KEPT:
            _COMPONENTS.pop(next(iter(_COMPONENTS)))
        _COMPONENTS[key] = label.copy()
    return label


def _winding_number(tri: np.ndarray, point: np.ndarray) -> float:
    """Generalised winding number of ``point`` w.r.t. triangles (F, 3, 3): Σ solid angles / 4π (Van Oosterom &
    Strackee, IEEE TBME 30(2), 1983); ±1 inside a closed consistently wound surface, 0 outside, ±½ on it."""
    a, b, c = (tri[:, i] - point for i in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
           + np.einsum("ij,ij->i", b, c) * la)
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * np.pi))


class _Reach:
    """Which side(s) of a face light from the laser can reach, per object (computed on first use).

    - A face of a closed, consistently wound component: the side where the laser spot is (outside the solid
      when the spot is outside it; the sensor, then the emitter, decide when the spot lies on it).
    - An open face of a room surface (label in ROOM_LABELS: the scene's enclosure): the side of its plane the
      laser spot is on (the sensor, then the emitter, when the spot lies in the plane, as on the relay wall).
    - Any other open face (or an inconsistently wound closed mesh, whose inside is unknown): both sides.
    """

    def __init__(self, objects: list[SceneObject], viewpoints: list[np.ndarray], tol: float,
                 static: StaticFaces | None = None):
        self.objects, self.viewpoints, self.tol = objects, viewpoints, tol
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._static, self._key = static, viewpoint_key(viewpoints) if static is not None else None

    def _closed(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(F,) closed-component label of each face of object i (−1 open) and, indexed by label + 1, +1 where
        light reaches the side the winding normals point to, −1 the other side, 0 both (open or undecided); those
        of an object that does not move are kept in ``static`` for the same object and viewpoints."""
        obj = self.objects[i]
        kept = None if self._static is None or obj.name in self._static.moving else self._static.reach.get(obj.name)
        if kept is not None and kept[0] is obj and kept[1] == self._key:
            self._cache[i] = kept[2]
        if i not in self._cache:
            label = _closed_components(obj.vertices, obj.faces)
            tri = obj.vertices[obj.faces]
            seen = np.zeros(int(label.max(initial=-1)) + 2, dtype=np.int64)
            for comp in _sorted_unique(label[label >= 0]):
                t = tri[label == comp]
                volume = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum()
                where = 0
                for p in self.viewpoints:
                    w = abs(_winding_number(t, p))
                    if w <= 1 - WINDING_INSIDE or w >= WINDING_INSIDE:
                        where = 1 if w <= 1 - WINDING_INSIDE else -1
                        break
                seen[comp + 1] = int(np.sign(volume)) * where       # outward winding: +1 if volume > 0
            self._cache[i] = label, seen
            if self._static is not None and obj.name not in self._static.moving:
                self._static.reach[obj.name] = (obj, self._key, (label, seen))
        return self._cache[i]

    def sides(self, obj: np.ndarray, face: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """(P,) int8 side masks of faces ``face`` of objects ``obj`` relative to the canonical ``normal`` (P, 3)
        of their plane normal·x = ``offset`` (P,)."""
        out = np.full(len(obj), FRONT | BACK, dtype=np.int8)
        for i in np.unique(obj):
            rows = np.flatnonzero(obj == i)
            o = self.objects[i]
            label, seen = self._closed(int(i))
            comp = label[face[rows]]
            tri = o.vertices[o.faces[face[rows]]]
            winding = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), normal[rows])
            # closed: +1 when light reaches the side the winding normal points to (outward and spot outside, …)
            towards = seen[comp + 1] * np.sign(winding)
            mask = np.where(towards > 0, FRONT, np.where(towards < 0, BACK, FRONT | BACK))
            if o.label in ROOM_LABELS:
                open_ = comp < 0
                side = np.zeros(len(rows))
                for p in self.viewpoints:
                    h = matmul(normal[rows], p) - offset[rows]
                    pick = (side == 0) & (np.abs(h) > self.tol)
                    side[pick] = np.sign(h[pick])
                room = np.where(side > 0, FRONT, np.where(side < 0, BACK, FRONT | BACK))
                mask = np.where(open_, room, mask)
            out[rows] = mask
        return out


def find_coincident_faces(objects: list[SceneObject], viewpoints: Any, tol: float,
                          moving: np.ndarray | None = None, static: StaticFaces | None = None) -> Coincidence:
    """Overlapping coplanar faces of different objects and the sides light reaches both from.

    Two faces coincide when each one's vertices lie within ``tol`` of the other's plane and their overlap (the
    intersection polygon in that plane) is wider than ``tol``: 2·area / perimeter > tol, so faces that only
    share an edge, or overlap in a sliver thinner than the ray offset, do not count. Degenerate faces (zero
    area, or thinner than ``tol``) are skipped: they are invisible. Cost O(F log F): faces are grouped by
    rounded normal (NORMAL_CELL) and chained by plane offset (gaps ≤ 2·tol); only groups holding two objects
    go on to a hierarchical-grid broad phase on their in-plane bounding boxes (:func:`_candidate_pairs`) and
    the exact triangle clipping (:func:`_clip_triangles`).

    Args:
        objects: the scene's objects.
        viewpoints: points deciding which side of closed meshes and room surfaces light reaches, (3,) metres
            each: the laser spot first, then fallbacks used where it lies on the surface in question (the
            sensor, the emitter). See :class:`_Reach`. May be a callable returning them, called only when
            some faces coincide (deciding them can cost O(F)).
        tol: metres, the coplanarity tolerance (COPLANAR_TOL_REL × scene size).
        moving: (n_objects,) bool, or None for every object: only pairs with at least one such object are tested.
        static: where the sides of the objects that do not move are kept across calls (:class:`StaticFaces`).
    Returns:
        :class:`Coincidence` (face pairs sorted by object pair, then face indices).
    """
    if len(objects) < 2:
        return Coincidence.empty()
    origin = np.mean([o.vertices.mean(axis=0) for o in objects], axis=0)       # work near the scene
    tri = np.concatenate([o.vertices[o.faces] for o in objects]) - origin
    obj = np.concatenate([np.full(len(o.faces), i, dtype=np.int64) for i, o in enumerate(objects)])
    local = np.concatenate([np.arange(len(o.faces), dtype=np.int64) for o in objects])
    normal, _, width = _triangle_planes(tri)
    idx = np.flatnonzero(width > tol)
    n = normal[idx] * np.where(matmul(normal[idx], CANONICAL_DIRECTION) < 0, -1.0, 1.0)[:, None]
    d = np.einsum("ij,ij->i", n, tri[idx, 0])
    group = _row_groups(np.floor(n / NORMAL_CELL).astype(np.int64))[2]
    order = np.lexsort((d, group))
    new = np.ones(len(order), dtype=bool)
    new[1:] = (group[order][1:] != group[order][:-1]) | (np.diff(d[order]) > 2 * tol)
    cluster = np.empty(len(order), dtype=np.int64)
    cluster[order] = np.cumsum(new) - 1
    # keep clusters holding faces of at least two objects
    pairs = _sorted_unique(cluster * len(objects) + obj[idx])
    multi = np.bincount(pairs // len(objects), minlength=int(cluster.max(initial=-1)) + 1) >= 2
    if moving is not None:                                  # and a face of a moving object
        multi &= np.bincount(cluster, weights=moving[obj[idx]], minlength=len(multi)) > 0
    sel = np.flatnonzero(multi[cluster])
    if len(sel) == 0:
        return Coincidence.empty()
    idx, n, d, cluster = idx[sel], n[sel], d[sel], cluster[sel]
    # in-plane coordinates from each cluster's first normal
    order, new, cl = _row_groups(cluster[:, None])
    ref = n[order[new]][cl]                                          # each cluster's first normal
    helper = np.eye(3)[np.argmin(np.abs(ref), axis=1)]
    u = np.cross(ref, helper)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(ref, u)
    t = tri[idx]
    uv = np.stack([np.einsum("fkj,fj->fk", t, u), np.einsum("fkj,fj->fk", t, v)], axis=-1)   # (m, 3, 2)
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    found = []
    for a, b in _candidate_pairs(cl, lo + tol / 2, hi - tol / 2):       # pairs overlapping by > tol
        keep = obj[idx[a]] != obj[idx[b]]
        if moving is not None:
            keep &= moving[obj[idx[a]]] | moving[obj[idx[b]]]
        keep &= (np.minimum(hi[a, 0], hi[b, 0]) - np.maximum(lo[a, 0], lo[b, 0])) > tol
        keep &= (np.minimum(hi[a, 1], hi[b, 1]) - np.maximum(lo[a, 1], lo[b, 1])) > tol
        a, b = a[keep], b[keep]
        dist_ab = np.abs(np.einsum("pkj,pj->pk", t[b], n[a]) - d[a, None]).max(axis=1)
        dist_ba = np.abs(np.einsum("pkj,pj->pk", t[a], n[b]) - d[b, None]).max(axis=1)
        keep = (dist_ab < tol) & (dist_ba < tol)
        a, b = a[keep], b[keep]
        if len(a) == 0:
            continue
        area, perimeter, centroid = _clip_triangles(uv[a], uv[b])
        keep = 2.0 * area > tol * perimeter
        a, b, area, centroid = a[keep], b[keep], area[keep], centroid[keep]
        gap = np.linalg.norm(t[a][:, :, None] - t[b][:, None, :], axis=-1)                # (P, 3, 3)
        duplicate = (gap.min(axis=2).max(axis=1) < tol) & (gap.min(axis=1).max(axis=1) < tol)
        point = origin + centroid[:, :1] * u[a] + centroid[:, 1:] * v[a] + d[a, None] * n[a]
        found.append((a, b, area, point, duplicate))
    if not found:
        return Coincidence.empty()
    a, b, area, point, duplicate = (np.concatenate(x) for x in zip(*found))
    swap = obj[idx[a]] > obj[idx[b]]
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    fa, fb = idx[a], idx[b]
    offset = d[a] + matmul(n[a], origin)                                    # world coordinates
    viewpoints = [np.asarray(p, dtype=np.float64) for p in (viewpoints() if callable(viewpoints) else viewpoints)]
    reach = _Reach(objects, viewpoints, tol, static)
    sides = reach.sides(obj[fa], local[fa], n[a], offset) & reach.sides(obj[fb], local[fb], n[a], offset)
    c = Coincidence(np.stack([obj[fa], obj[fb]], 1), np.stack([local[fa], local[fb]], 1), n[a], offset, area,
                    point, duplicate, sides.astype(np.int8))
    return c.take(np.lexsort((c.faces[:, 1], c.faces[:, 0], c.objects[:, 1], c.objects[:, 0])))


def _side_words(mask: int) -> str:
    return {FRONT: "from the side the normal points to", BACK: "from the side opposite the normal",
            FRONT | BACK: "from both sides"}[mask]


def resolve_coincident_faces(objects: list[SceneObject], laser: Laser, sensor: Sensor, where: str = "",
                             static: StaticFaces | None = None) -> tuple[list[SceneObject], list[str]]:
    """Apply the coincident-face policy; returns the objects to keep and notes on what was removed.

    Policy (docs/hard_cases.md, case 7). Faces are coincident when coplanar within COPLANAR_TOL_REL × the
    scene size and overlapping with positive area (:func:`find_coincident_faces`). For faces of two objects:

    - seen by light from no common side (:class:`_Reach`): touching solids (a box on the floor or against a
      wall, a pillar under the ceiling, stacked boxes) are legal whatever their materials and left alone;
    - seen from a common side with different materials: the reflectance there is undefined (the ray caster
      picks one face per ray by BVH order): **SceneError** naming both objects, the plane, the overlap area
      and a point of it;
    - the same, same material, the two triangles identical (an exact duplicate): the later object's face is
      **removed** (a note says so; an object left with no face is dropped), so that every estimator counts the
      surface once (area samplers and the reference quadrature would otherwise count it twice);
    - the same, same material, a partial overlap: **SceneError** (area-based estimators would count the
      overlap twice; it cannot be removed without re-meshing).

    Exact duplicates within one object are removed too (:func:`duplicate_faces`). The tolerance is tied to the
    ray offset, so coincident faces are exactly those the ray caster cannot order by depth.

    ``static`` (a sequence's frames): the verdict on the objects that do not move, read when it holds (then only
    the pairs with a moving object are tested, and the static objects' own duplicates not again) and kept when
    they come out clean (:class:`StaticFaces`).

    Raises:
        SceneError: as above; ``where`` ("file: ") prefixes the message.
    """
    bounds = np.concatenate([np.concatenate([o.vertices for o in objects]),
                             [laser.emitter, laser.spot, sensor.position]])
    tol = COPLANAR_TOL_REL * max(float(np.max(bounds.max(axis=0) - bounds.min(axis=0))), 1e-3)
    notes: list[str] = []
    kept = []
    moves = np.array([static is not None and o.name in static.moving for o in objects])
    statics = tuple(o for o, m in zip(objects, moves) if not m)
    spot = np.asarray(laser.spot, float)

    def spot_on(objs: list[SceneObject]) -> bool:
        return bool(objs) and _on_a_face(spot, np.concatenate([o.vertices[o.faces] for o in objs]),
                                         SPOT_ON_SURFACE_REL * tol / COPLANAR_TOL_REL)

    # the laser spot decides which side of room surfaces and closed meshes light reaches, unless it is off
    # every surface (an invalid scene, reported by transport.resolve_capture): then the sensor, the emitter
    def viewpoints():                                  # (the static objects' part kept once known)
        moved = [o for o, m in zip(objects, moves) if m]
        spot_ok = static.spot_on or spot_on(moved) if known else spot_on(kept)
        return ([laser.spot] if spot_ok else []) + [sensor.position, laser.emitter]

    known = static is not None and static.holds(statics, tol)
    if known and static.view is not None:              # their verdict read the viewpoints: the same ones?
        known = static.view == viewpoint_key(viewpoints())
    clean = True                                        # nothing removed from or refused among the static objects
    for o, m in zip(objects, moves):
        if known and not m:
            kept.append(o)                              # checked clean at this tolerance
            continue
        dup = duplicate_faces(o.vertices, o.faces, tol)
        clean &= bool(m or not dup.any())
        if dup.any():
            notes.append(f"object {o.name!r}: removed {int(dup.sum())} duplicate face(s) (same vertices as an "
                         f"earlier face of the object)")
            o = SceneObject(o.name, o.label, o.material, o.vertices, o.faces[~dup])
        kept.append(o)
    c = find_coincident_faces(kept, viewpoints, tol, moves if known else None, static)
    if static is not None and not known:               # keep the verdict on the static objects when clean
        both = ~moves[c.objects].any(axis=1)
        clean &= not (c.sides[both] != 0).any()
        if clean:
            static.objects, static.tol, static.spot_on = statics, tol, spot_on(list(statics))
            # some of their faces coincide: their sides read the viewpoints
            static.view = viewpoint_key(viewpoints()) if both.any() else None
    c = c.take(c.sides != 0)
    if len(c.sides) == 0:
        return kept, notes
    same = np.array([kept[i].material == kept[j].material for i, j in c.objects])
    bad = ~(same & c.duplicate)
    if bad.any():
        i, j = c.objects[np.flatnonzero(bad)[0]]
        rows = np.flatnonzero((c.objects[:, 0] == i) & (c.objects[:, 1] == j))
        r = rows[0]
        plane = (f"on the plane n·x = {c.offset[r]:.6g} m with n = ({', '.join(f'{x + 0.0:.4g}' for x in c.normal[r])}), "
                 f"{len(rows)} face pair(s) overlapping over {c.area[rows].sum():.4g} m² around "
                 f"({', '.join(f'{x + 0.0:.4g}' for x in c.point[r])}), seen {_side_words(int(c.sides[r]))}")
        a, b = kept[i].name, kept[j].name
        if not same[r]:
            raise SceneError(
                f"{where}objects {a!r} and {b!r} have coincident faces with different materials {plane}: the "
                f"reflectance there is undefined (ray casting picks one face per ray). Move one by more than "
                f"{tol:.3g} m, cut the overlap out of one, or give both the same material")
        raise SceneError(
            f"{where}objects {a!r} and {b!r} have coplanar faces with the same material that overlap without "
            f"being exact duplicates {plane}: area-based estimators would count the overlap twice. Merge them "
            f"into one surface, cut the overlap out of one, or move one by more than {tol:.3g} m")
    drop: dict[int, set[int]] = {}
    for j, f in zip(c.objects[:, 1], c.faces[:, 1]):
        drop.setdefault(int(j), set()).add(int(f))
    out = []
    for i, o in enumerate(kept):
        if i not in drop:
            out.append(o)
            continue
        keep = np.ones(len(o.faces), dtype=bool)
        keep[sorted(drop[i])] = False
        others = sorted({kept[k].name for k, f in zip(c.objects[:, 0], c.objects[:, 1]) if f == i})
        if keep.any():
            notes.append(f"object {o.name!r}: removed {int((~keep).sum())} face(s) duplicating faces of "
                         f"{', '.join(map(repr, others))} with the same material")
            out.append(SceneObject(o.name, o.label, o.material, o.vertices, o.faces[keep]))
        else:
            notes.append(f"object {o.name!r} dropped: every face duplicates a face of "
                         f"{', '.join(map(repr, others))} with the same material")
    return out, notes
