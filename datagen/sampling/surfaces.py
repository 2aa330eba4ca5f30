"""Points on triangles: subdivision into congruent sub-triangles and surface sampling, in one place.

Every estimator that integrates over hidden surfaces draws its points here: the area sampler
(:mod:`datagen.transport.area`: stratified, Sobol or random points with their densities), the quadrature
(:mod:`datagen.transport.quadrature`: sub-triangles with shared vertices), the effect planner's coarse
quadrature and the converged reference. A triangle of longest edge e is split into k² congruent
sub-triangles, k = ceil(e / h) (:func:`subdivisions`), in the same order everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import ConfigError
from ..scene import RayCaster
from .directions import stratified_grid
from .sobol import scrambled_sobol

AreaSampling = Literal["stratified", "sobol", "random"]
"""How :func:`sample_surfaces` draws points: jittered sub-triangles, scrambled Sobol points, or independent."""


@dataclass(frozen=True)
class SurfaceSamples:
    """Points on triangles.

    Attributes:
        points: (M, 3) float64 metres.
        normals: (M, 3) float64 unit face normals (unoriented: the estimator orients them per leg).
        face: (M,) int64 face index; object_id: (M,) int64.
        area: (M,) float64 m², the area each point stands for under its own sampling (1/density).
        pad: (M, 2) float64 in [0, 1)², the shift of each point's FoV grid (the padding dimensions of the
            sampling pattern; see :func:`padding`).
    """

    points: np.ndarray
    normals: np.ndarray
    face: np.ndarray
    object_id: np.ndarray
    area: np.ndarray
    pad: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def take(self, sel) -> SurfaceSamples:
        return SurfaceSamples(self.points[sel], self.normals[sel], self.face[sel], self.object_id[sel],
                              self.area[sel], self.pad[sel])

    @staticmethod
    def concat(parts: list[SurfaceSamples]) -> SurfaceSamples:
        return SurfaceSamples(*(np.concatenate([getattr(p, f) for p in parts])
                                for f in ("points", "normals", "face", "object_id", "area", "pad")))


def unit_triangle(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square-root map of [0,1]² onto the triangle (0,0), (1,0), (0,1), uniform in area (Turk 1990).

    Returns the barycentric weights (b1, b2) of vertices 1 and 2.
    """
    su = np.sqrt(u)
    return su * (1.0 - v), su * v


def subdivisions(tri: np.ndarray, h: float) -> np.ndarray:
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1).max(axis=1)
    return np.maximum(1, np.ceil(edges / h).astype(np.int64))


def subdivide_triangles(tri: np.ndarray, h: float, rng: np.random.Generator | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split triangles (F, 3, 3) into k² congruent sub-triangles each, k = ceil(longest edge / h).

    Args:
        tri: (F, 3, 3) float64 vertices, metres.
        h: target sub-triangle edge, metres (> 0).
        rng: None puts one point at each sub-triangle's centroid (midpoint rule); a generator puts one
            uniform random point in each (stratified sampling).
    Returns:
        points (M, 3), areas (M,) m², parent face index (M,) int64.
    Raises:
        ConfigError: h not finite or ≤ 0.
    """
    if not np.isfinite(h) or h <= 0:
        raise ConfigError(f"subdivide_triangles: h must be finite and > 0, got {h!r}")
    ks = subdivisions(tri, h)
    pts, areas, parents = [], [], []
    for k in np.unique(ks):
        faces = np.flatnonzero(ks == k)
        i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        up = (i + j) < k                                  # upward sub-triangles (i, j), (i+1, j), (i, j+1)
        down = (i + j) < k - 1                            # downward ones (i+1, j), (i, j+1), (i+1, j+1)
        corner = np.concatenate([np.stack([i[up], j[up]], -1), np.stack([i[down] + 1, j[down] + 1], -1)])
        sign = np.concatenate([np.ones(int(up.sum())), -np.ones(int(down.sum()))])[:, None]
        shape = (len(faces), len(corner))
        if rng is None:
            a = b = np.full(shape, 1.0 / 3.0)
        else:
            a, b = unit_triangle(rng.random(shape), rng.random(shape))
        bary = (corner[None] + sign[None] * np.stack([a, b], -1)) / k      # (faces, sub, 2)
        t = tri[faces]
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        p = t[:, None, 0] + bary[..., :1] * e1[:, None] + bary[..., 1:] * e2[:, None]
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1) / k ** 2
        pts.append(p.reshape(-1, 3))
        areas.append(np.repeat(area, shape[1]))
        parents.append(np.repeat(faces, shape[1]))
    return np.concatenate(pts), np.concatenate(areas), np.concatenate(parents).astype(np.int64)


def stratified_edge(tri: np.ndarray, samples: int) -> float:
    """Largest sub-triangle edge h whose subdivision of ``tri`` (F, 3, 3) gives at most ``samples`` points
    (but at least one per triangle), by bisection on log h."""
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1).max(axis=1)
    lo, hi = edges.max() * 1e-6, edges.max() * 1.0001
    for _ in range(60):
        mid = np.sqrt(lo * hi)
        if int((subdivisions(tri, mid) ** 2).sum()) > samples:
            lo = mid
        else:
            hi = mid
    return float(hi)


def padding(n: int, method: AreaSampling, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) points of [0,1)² for the padding dimensions of a stratified or random pattern: the first n of a
    randomly permuted jittered k×k grid, k = ceil(√n) ("stratified": padded stratified sampling, each point
    uniform on its own, jointly spread), or independent uniform points."""
    if method == "stratified" and n > 0:
        k = int(np.ceil(np.sqrt(n)))
        return rng.permutation(stratified_grid(k, k, rng)[0])[:n]
    return rng.random((n, 2))


def unit_square_points(samples: int, method: AreaSampling, rng: np.random.Generator) -> np.ndarray:
    """Points on [0,1]⁴: dims 0-1 a jittered k×k grid with k = round(√samples) ("stratified"), scrambled Sobol
    points rounded up to a power of two ("sobol") or independent uniform points ("random"); dims 2-3 the
    padding (:func:`padding`; Sobol dims 2-3 for "sobol"). (n, 4) float64."""
    if method == "stratified":
        k = max(1, int(round(np.sqrt(samples))))
        u = stratified_grid(k, k, rng)[0]
        return np.concatenate([u, padding(len(u), method, rng)], axis=1)
    if method == "sobol":
        return scrambled_sobol(4, samples, rng)
    return rng.random((samples, 4))


def sample_surfaces(caster: RayCaster, faces: np.ndarray, samples: int, method: AreaSampling,
                    rng: np.random.Generator) -> tuple[SurfaceSamples, np.ndarray]:
    """Sample points by area over the triangles ``faces`` (indices into the caster's faces).

    Args:
        samples: requested count (see :class:`datagen.transport.AreaSettings` for how each method rounds it).
        method: "stratified", "sobol" or "random".
    Returns:
        The samples, and the sample density per face (n_faces_total,) in 1/m² (0 off ``faces``): k_f²/A_f for
        "stratified", M/A for the others. The samples' areas are its inverse.
    Raises:
        ConfigError: unknown method.
    """
    tri = caster.vertices[caster.faces[faces]]
    density = np.zeros(len(caster.faces))
    if method == "stratified":
        h = stratified_edge(tri, samples)
        pts, area, parent = subdivide_triangles(tri, h, rng)
        face = faces[parent]
        density[faces] = subdivisions(tri, h) ** 2 / caster.face_area[faces]
        pad = padding(len(pts), method, rng)
    elif method in ("sobol", "random"):
        areas = caster.face_area[faces]
        total = float(areas.sum())
        if method == "sobol":
            u = scrambled_sobol(5, samples, rng)
        else:
            u = rng.random((samples, 5))
        pad = u[:, 3:]
        cdf = np.cumsum(areas) / total
        pick = np.minimum(np.searchsorted(cdf, u[:, 0], side="right"), len(faces) - 1)
        b1, b2 = unit_triangle(u[:, 1], u[:, 2])
        t = tri[pick]
        pts = t[:, 0] + b1[:, None] * (t[:, 1] - t[:, 0]) + b2[:, None] * (t[:, 2] - t[:, 0])
        face = faces[pick]
        density[faces] = len(pts) / total
        area = np.full(len(pts), total / len(pts))
    else:
        raise ConfigError(f"area sampler: sampling must be 'stratified', 'sobol' or 'random', got {method!r}")
    return SurfaceSamples(pts, caster.face_normals[face], face, caster.face_object[face], area, pad), density



def subdivide_with_vertices(tri: np.ndarray, h: float, even: bool = False
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split triangles (F, 3, 3) into k² congruent sub-triangles each, k = ceil(longest edge / h), keeping their
    vertices: the same split and order as :func:`subdivide_triangles`.

    Args:
        even: round every k up to an even number, so that the sub-triangles group 4 by 4 into the split at
            k/2 (:func:`coarse_cells`).
    Returns:
        vertices (V, 3) float64, the lattice points (shared by neighbouring sub-triangles of one face);
        cells (M, 3) int64 indices into ``vertices``; areas (M,) m²; parent face index (M,) int64.
    Raises:
        ConfigError: h not finite or ≤ 0.
    """
    out = _lattice_split(tri, h, even)
    return out[0], out[1], out[2], out[3]


def coarse_cells(tri: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The split at k/2 of :func:`subdivide_with_vertices` (``even=True``), in terms of the fine one: each coarse
    sub-triangle is the union of 4 fine ones and its centroid is that of the middle (inverted) one.

    Returns:
        coarse cells (Mc, 3) int64 indices into the fine ``vertices`` (the coarse corners are fine lattice points);
        central (Mc,) int64, the index of the fine cell whose centroid is the coarse centroid (its area is a
        quarter of the coarse one).
    """
    out = _lattice_split(tri, h, True)
    return out[4], out[5]


def _lattice_split(tri: np.ndarray, h: float, even: bool):
    if not np.isfinite(h) or h <= 0:
        raise ConfigError(f"subdivide_with_vertices: h must be finite and > 0, got {h!r}")
    ks = subdivisions(tri, h)
    if even:
        ks = ks + ks % 2
    verts, cells, areas, parents, coarse, central = [], [], [], [], [], []
    offset = cell_offset = 0
    for k in np.unique(ks):
        faces = np.flatnonzero(ks == k)
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        lattice = (i + j) <= k
        index = np.full((k + 1, k + 1), -1, dtype=np.int64)
        index[lattice] = np.arange(int(lattice.sum()))
        n_lat = int(lattice.sum())
        up = (i[:k, :k] + j[:k, :k]) < k
        down = (i[:k, :k] + j[:k, :k]) < k - 1
        iu, ju, idn, jdn = i[:k, :k][up], j[:k, :k][up], i[:k, :k][down], j[:k, :k][down]
        local = np.concatenate([np.stack([index[iu, ju], index[iu + 1, ju], index[iu, ju + 1]], 1),
                                np.stack([index[idn + 1, jdn], index[idn, jdn + 1], index[idn + 1, jdn + 1]], 1)])
        t = tri[faces]
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        a, b = i[lattice] / k, j[lattice] / k
        p = t[:, None, 0] + a[None, :, None] * e1[:, None] + b[None, :, None] * e2[:, None]     # (f, n_lat, 3)
        vert_base = offset + n_lat * np.arange(len(faces))[:, None, None]
        verts.append(p.reshape(-1, 3))
        cells.append((local[None] + vert_base).reshape(-1, 3))
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1) / k ** 2
        areas.append(np.repeat(area, len(local)))
        parents.append(np.repeat(faces, len(local)))
        if even:
            # coarse up (I, J): corners (2I, 2J), (2I+2, 2J), (2I, 2J+2), middle child the fine down cell (2I, 2J);
            # coarse down (I, J): corners (2I+2, 2J), (2I, 2J+2), (2I+2, 2J+2), middle child the fine up (2I+1, 2J+1)
            cell_of = np.full((2, k, k), -1, dtype=np.int64)
            cell_of[0][up] = np.arange(len(iu))
            cell_of[1][down] = len(iu) + np.arange(len(idn))
            kc = k // 2
            ic, jc = np.meshgrid(np.arange(kc), np.arange(kc), indexing="ij")
            cu = (ic + jc) < kc
            cd = (ic + jc) < kc - 1
            I, J, Id, Jd = 2 * ic[cu], 2 * jc[cu], 2 * ic[cd], 2 * jc[cd]
            c_local = np.concatenate([np.stack([index[I, J], index[I + 2, J], index[I, J + 2]], 1),
                                      np.stack([index[Id + 2, Jd], index[Id, Jd + 2], index[Id + 2, Jd + 2]], 1)])
            mid = np.concatenate([cell_of[1][I, J], cell_of[0][Id + 1, Jd + 1]])
            coarse.append((c_local[None] + vert_base).reshape(-1, 3))
            central.append((mid[None] + cell_offset + len(local) * np.arange(len(faces))[:, None]).reshape(-1))
        offset += n_lat * len(faces)
        cell_offset += len(local) * len(faces)
    as_int = lambda parts: np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, dtype=np.int64)
    return (np.concatenate(verts), np.concatenate(cells).astype(np.int64), np.concatenate(areas), as_int(parents),
            np.concatenate(coarse).astype(np.int64) if coarse else np.zeros((0, 3), dtype=np.int64), as_int(central))
