"""The quadrature's primary through the compiled kernel (:mod:`.kernel`), and its shadow-ray culling.

:func:`run_compiled` runs :meth:`datagen.transport.quadrature.Quadrature._primary` for the cases the kernel covers
(:meth:`~datagen.transport.quadrature.Quadrature.compiled_case`): per block of connections, one compiled pass
over the (sub-triangle, connection) pairs deposits every contributing pair whose laser leg no triangle can block,
Embree shadow rays decide the listed others, and a second compiled pass deposits the visible ones. Which
triangles can block a face's laser legs comes from the separating-plane test per hidden face
(:func:`leg_occluders`): the kernel tests those exactly and asks for a ray only when a pair's segment passes within
a margin of one of their edges (:mod:`.kernel` on how this differs from Embree's float32 rays;
``Quadrature.segment_tests`` = False: a ray for every lit pair, the numpy path's visibility).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ...scene import RayCaster
from ...scene.separation import hull_planes, may_meet, outward_planes
from ...scene.brdf_kernel import lambertian_value, on_arrays
from ...threads import threads_for
from ...units import SPEED_OF_LIGHT
from .kernel import OCC, candidates, channel_groups, deposit_pairs, face_candidates, occluder_planes
from .shadow import FLAG_MAX_BYTES, grown_triangles, shadow_flags, spot_buckets, spot_plane
from ...vectors import matmul, norm

__all__ = ["PAIR_TEST_MAX_PAIRS", "PAIR_BLOCK", "RUN_CHUNK", "RUN_CHUNKED", "SHADOW_MAP", "FOV_MAP_PAIRS", "dark_faces",
           "front_only", "leg_occluders", "morton_codes", "run_chunks", "run_compiled", "run_spheres"]

PAIR_TEST_MAX_PAIRS = 1 << 22
"""The occluder test costs hidden triangles × scene triangles; above this many pairs it is not attempted and the
shadow rays are kept."""

MAX_CANDIDATES = 128
"""A hidden face of a big mesh (no numpy occluder test) with more triangles that may block its laser legs casts a
shadow ray for every lit pair instead of the kernel's segment tests (the torus of docs/scans.md: at most 128 with a
2 m × 2 m scan, 70 % of the faces none)."""

PARALLEL_MIN_PAIRS = 1 << 26
"""Runs over fewer (sub-triangle, target) pairs (confocal.yaml samples: 27–33 M, wall.yaml: 6–11 M) use one thread:
a dataset build already keeps every core busy with one worker process each, and numba's OpenMP threads cost ≈ 5 %
more CPU time there (measured on confocal.yaml samples); longer runs (the 128 × 128 torus of docs/scans.md: 164 M)
use all of numba's. Either way the kernels are numba's parallel ones: a process that ran one has GNU OpenMP
started, and a child it forks must not run them (numba stops such a child); the build's workers come from a fork
server, which runs none."""

RUN_CHUNK = 8
"""Candidate triangles per bounding sphere inside a run of the segment test (:func:`run_chunks`): a face of a
curved mesh may have hundreds of candidates from its own object, and a segment from the face passes through that
object's sphere."""

RUN_CHUNKED = 16
"""Runs of at most this many candidates (a box's twelve triangles) stay one chunk, in their order."""

PAIR_BLOCK = 1 << 22
"""(sub-triangle, connection) pairs per compiled block: bounds the list of pairs waiting for shadow rays."""

SHADOW_MAP = True
"""Mark per sub-triangle the laser points a candidate occluder may shadow before the pair loop
(:mod:`.shadow`); False runs the exact segment test for every lit pair (the same envelope, slower)."""

FOV_MAP_PAIRS = 1 << 20
"""(sub-triangle, target) pairs per block of the FoV leg's visibility map (the target leg's (pairs, 3) float64
temporaries: ≈ 25 MB each)."""

MARGIN_OFFSETS = 8.0
"""The kernel's segment test counts a triangle as possibly blocking within this many ray offsets
(:attr:`datagen.scene.RayCaster.offset`, ~100 float32 ULPs of the scene) of the segment: Embree's rays start
pushed off the surfaces by one offset and run in float32."""


def leg_occluders(caster: RayCaster, faces: np.ndarray, apexes: np.ndarray, tol: float,
                  first_only: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """(occluders (k,) face ids, (k, F) bool): whether occluder i may meet a segment from a point of triangle
    ``faces[j]`` to a point of the convex hull of ``apexes`` (A, 3) (separating planes,
    :func:`datagen.scene.separation.may_meet`; exact when False; a face never blocks itself). None: more than
    PAIR_TEST_MAX_PAIRS pairs to test. ``first_only``: rows after the first chunk holding a meeting pair are left
    False (enough to know whether any pair meets)."""
    occluders = np.flatnonzero(caster.face_area > 0)
    if len(faces) * len(occluders) > PAIR_TEST_MAX_PAIRS:
        return None
    tri = caster.vertices[caster.faces]
    n, o, valid, hull_v = _leg_hulls(tri[faces], apexes)
    normals = caster.face_normals[occluders]
    offsets = np.einsum("ij,ij->i", normals, tri[occluders, 0])
    return occluders, may_meet(tri[occluders], normals, offsets, np.ones(len(occluders), dtype=bool), n, o, valid,
                               hull_v, tol, exclude=(occluders, faces), first_only=first_only)


def _leg_hulls(t: np.ndarray, apexes: np.ndarray) -> tuple:
    """Per triangle of ``t`` (F, 3, 3) the convex hull of it and the points ``apexes`` (A, 3) (duplicates within
    1e-12 m merged): (normals, offsets, valid) of its planes and its vertices (F, A + 3, 3), as
    :func:`datagen.scene.separation.may_meet` takes them (one apex: the tetrahedron's four faces)."""
    apexes = np.unique(np.round(apexes, 12), axis=0)
    if len(apexes) == 1:
        s = np.broadcast_to(apexes[0], (len(t), 3))
        quads = np.stack([t, np.stack([s, t[:, 0], t[:, 1]], 1), np.stack([s, t[:, 1], t[:, 2]], 1),
                          np.stack([s, t[:, 2], t[:, 0]], 1)], axis=1)
        opposite = np.stack([s, t[:, 2], t[:, 0], t[:, 1]], axis=1)
        n, o, valid = outward_planes(quads, opposite)
        return n, o, valid, np.concatenate([s[:, None], t], axis=1)
    hull_v = np.concatenate([np.broadcast_to(apexes, (len(t),) + apexes.shape), t], axis=1)
    return (*hull_planes(hull_v), hull_v)


def _occluder_lists(q, front: np.ndarray) -> tuple:
    """The kernel's :data:`~datagen.transport.quadrature.kernel.OCC` group for quadrature ``q``: per hidden face the
    triangles that may block its laser legs, in runs of one object each (CSR ``run_ptr`` over runs; run r holds
    ``idx[run_lo[r]:run_hi[r]]`` inside the bounding sphere ``spheres[r]``, in the chunks of :func:`run_chunks`),
    their planes and edge planes, the margin, and per hidden face whether every lit pair casts a ray instead. The
    triangles come from :func:`leg_occluders`, or, when that has too many pairs to test (a big mesh), from the
    compiled :func:`~datagen.transport.quadrature.kernel.face_candidates`, which also separates by a face's own plane
    where only its front is lit (``front`` (F,) bool per hidden face: :func:`closed_outward`); a face with more than
    ``MAX_CANDIDATES`` of them casts rays."""
    caster, faces = q.caster, q.area.hidden_faces
    shadow = bool(q.settings.shadow_spot)
    found = q.spot_occluders if shadow else None        # the same test, done when q was built (or None)
    if shadow and found is None:
        found = leg_occluders(caster, faces, q.laser_hull, q.area.tol)
    face_ray = np.full(len(faces), shadow and not q.segment_tests, dtype=np.uint8)
    if found is not None:
        occluders, meet = found
        face_of, occ_of = np.nonzero(meet.T)                          # face-major
    elif shadow and q.segment_tests:        # too many pairs for numpy: the compiled test per face
        occluders, face_of, occ_of, many = _face_candidates(q, front)
        face_ray[many] = 1
    else:                                   # no test: every lit pair of every face casts a ray
        occluders, face_of, occ_of = (np.zeros(0, dtype=np.int64),) * 3
        face_ray[:] = shadow
    obj = caster.face_object[occluders[occ_of]]
    order = np.lexsort((occ_of, obj, face_of))                        # by face, then object
    face_of, occ_of, obj = face_of[order], occ_of[order], obj[order]
    new_run = np.ones(len(face_of), dtype=bool)
    new_run[1:] = (face_of[1:] != face_of[:-1]) | (obj[1:] != obj[:-1])
    run_lo = np.flatnonzero(new_run)
    run_hi = np.append(run_lo[1:], len(face_of))
    run_ptr = np.searchsorted(face_of[run_lo], np.arange(len(faces) + 1)).astype(np.int64)
    tri = caster.vertices[caster.faces[occluders]]
    spheres = run_spheres(tri[occ_of].reshape(-1, 3), 3 * run_lo)
    plane, edges = occluder_planes(tri) if len(tri) else (np.zeros((1, 4)), np.zeros((1, 3, 4)))
    margin = MARGIN_OFFSETS * caster.offset
    grown = grown_triangles(tri, 2.0 * margin) if len(tri) else np.zeros((1, 3, 3))
    occ_of, run_chunk, chunk_ptr, chunk_spheres = run_chunks(tri, grown, occ_of, run_lo, run_hi)
    return (shadow, run_ptr, run_lo.astype(np.int64), run_hi.astype(np.int64), spheres, run_chunk, chunk_ptr,
            chunk_spheres, occ_of.astype(np.int64), plane, edges, float(margin), face_ray), grown


def run_chunks(tri: np.ndarray, grown: np.ndarray, occ_of: np.ndarray, run_lo: np.ndarray,
               run_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The runs' triangles in chunks of at most ``RUN_CHUNK``, each inside a sphere that the kernel's segment test
    checks before its triangles (:func:`datagen.transport.quadrature.kernel.candidates`); a run of at most
    ``RUN_CHUNKED`` stays one chunk, in its order.

    Args:
        tri: (k, 3, 3) the candidate triangles, metres; grown: (k, 3, 3) the same grown by 2δ (:func:`grown_triangles`:
            NaN where degenerate); occ_of: (n,) int64 the runs' entries (indices into ``tri``); run_lo, run_hi: (R,)
            run r holds entries [run_lo[r], run_hi[r]), contiguous and ascending.
    Returns:
        occ_of: (n,) the same entries, each chunked run's in the Morton order of their centroids (a run's entries
        stay in it: the segment test's verdict does not depend on their order); run_chunk: (R + 1,) int64, run r's
        chunks [run_chunk[r], run_chunk[r + 1]); chunk_ptr: (C + 1,) int64, chunk c's entries [chunk_ptr[c],
        chunk_ptr[c + 1]); chunk_spheres: (C, 4) centre and radius (m) holding the grown triangles of each chunk.
        A triangle can only block a segment or send it to a shadow ray where the segment passes within δ of the
        triangle grown by δ (its edge test), so a segment missing a chunk's sphere by more than δ needs none of its
        triangles tested: the verdict is the same as without chunks.
    """
    n_runs = len(run_lo)
    if n_runs == 0:
        return occ_of, np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros((0, 4))
    length = run_hi - run_lo
    split = length > RUN_CHUNKED
    run = np.repeat(np.arange(n_runs), length)
    key = np.where(split[run], morton_codes(tri.mean(axis=1))[occ_of], np.arange(len(occ_of)))
    occ_of = occ_of[np.lexsort((key, run))]
    per_run = np.where(split, -(-length // RUN_CHUNK), 1)
    run_chunk = np.append(0, np.cumsum(per_run)).astype(np.int64)
    first = np.repeat(run_lo, per_run)
    chunk_lo = first + RUN_CHUNK * (np.arange(run_chunk[-1]) - np.repeat(run_chunk[:-1], per_run))
    chunk_ptr = np.append(chunk_lo, len(occ_of)).astype(np.int64)
    bound = np.where(np.isnan(grown), tri, grown)            # a degenerate triangle is never crossed
    return occ_of, run_chunk, chunk_ptr, run_spheres(bound[occ_of].reshape(-1, 3), 3 * chunk_lo)


def morton_codes(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """(n,) int64 Morton (Z-order) codes of ``points`` (n, 3), each axis quantised to ``bits`` bits over their
    bounding box: sorting by them keeps nearby points close."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, span = points.min(axis=0), np.ptp(points, axis=0)
    q = np.floor((points - lo) / np.where(span > 0, span, 1.0) * ((1 << bits) - 1)).astype(np.int64)
    code = np.zeros(len(points), dtype=np.int64)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> b) & 1) << (3 * b + axis)
    return code


def run_spheres(pts: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(R, 4) bounding spheres (centre, radius; metres) of the runs of points ``pts`` (n, 3) that begin at the
    ascending ``starts`` (R,): centred on each run's bounding box, radius its farthest point."""
    if len(starts) == 0:
        return np.zeros((0, 4))
    centre = 0.5 * (np.minimum.reduceat(pts, starts, axis=0) + np.maximum.reduceat(pts, starts, axis=0))
    run = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, len(pts))))
    radius = np.sqrt(np.maximum.reduceat(((pts - centre[run]) ** 2).sum(axis=1), starts))
    return np.concatenate([centre, radius[:, None]], axis=1)


def _shadow_map(q, occ: tuple, grown: np.ndarray, closed: np.ndarray) -> tuple:
    """The kernel's :data:`~datagen.transport.quadrature.kernel.SHADE` group for quadrature ``q``: per sub-triangle
    the laser points (of the connections) whose leg a candidate occluder may block
    (:func:`~datagen.transport.quadrature.shadow.shadow_flags`), or (False, …) when the laser points are not on one
    plane, nothing is tested, or the map would exceed ``FLAG_MAX_BYTES``."""
    shadow, occ_idx = occ[0], occ[OCC.index("occ_idx")]
    none = (False, np.zeros((1, 1), dtype=np.uint8), np.zeros(1, dtype=np.int64))
    lasers = np.unique(q.conn_laser)
    if not (SHADOW_MAP and shadow and len(occ_idx)) or q.n_cells * len(lasers) > FLAG_MAX_BYTES:
        return none
    c = q.capture
    spots = c.spots[lasers]
    found = spot_plane(spots, c.spot_normals[lasers])
    if found is None:
        return none
    n, o = found
    axes = np.concatenate([spots.mean(axis=0)[None], _plane_axes(n)])
    uv = matmul(spots - axes[0], axes[1:].T)
    buckets, bucket_ptr, bucket_col = spot_buckets(uv)
    centre = axes[0]                                      # the laser points' mean
    radius = float(np.sqrt(((spots - centre) ** 2).sum(axis=1).max()))
    flags = np.zeros((len(lasers), q.n_cells), dtype=np.uint8)       # laser point-major (the pair loop's order)
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
    shadow_flags((f64(q.centroids), f64(q.cell_normal), closed, q.cell_hidden.astype(np.int64)), occ, grown,
                 (np.append(n, o), axes, uv, centre, radius, buckets, bucket_ptr, bucket_col), flags)
    laser_col = np.full(c.n_lasers, -1, dtype=np.int64)
    laser_col[lasers] = np.arange(len(lasers))
    return True, flags, laser_col


def _plane_axes(n: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal axes in the plane of unit normal ``n`` (3,)."""
    u = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
    u /= norm(u)
    return np.stack([u, np.cross(n, u)])


def _fov_map(q) -> tuple[bool, np.ndarray]:
    """The FoV leg's part of the kernel's :data:`~datagen.transport.quadrature.kernel.SHADE` group: (True,
    ``fov_visible`` (targets, sub-triangles) uint8, 1 where the target's connection weight is positive with its
    shadow ray from the centroid: :meth:`~datagen.transport.quadrature.Quadrature.target_leg`) where ``shadow_fov``,
    else (False, a placeholder). Computed in blocks of at most FOV_MAP_PAIRS pairs."""
    if not q.settings.shadow_fov:
        return False, np.zeros((1, 1), dtype=np.uint8)
    n_t, M = len(q.targets), q.n_cells
    out = np.zeros((n_t, M), dtype=np.uint8)
    step = max(1, FOV_MAP_PAIRS // max(M, 1))
    for start in range(0, n_t, step):
        t = np.arange(start, min(n_t, start + step))
        out[t] = (q.target_leg(t, vertex_distances=False)["g"] > 0).T
    return True, out


def _face_candidates(q, front: np.ndarray) -> tuple:
    """(occluders (k,) face ids, face_of (n,), occ_of (n,) pairs of hidden face and index into occluders,
    face-major, and (F,) bool: hidden faces with more than ``MAX_CANDIDATES``) by
    :func:`~datagen.transport.quadrature.kernel.face_candidates` against the hull of each face and the laser points."""
    caster, faces = q.caster, q.area.hidden_faces
    occluders = np.flatnonzero(caster.face_area > 0)
    tri = caster.vertices[caster.faces[occluders]]
    t = caster.vertices[caster.faces[faces]]
    n, o, valid, hull_v = _leg_hulls(t, q.laser_hull)
    normal = caster.face_normals[faces]
    front_plane = np.concatenate([normal, np.einsum("ij,ij->i", normal, t[:, 0])[:, None]], axis=1)
    own = np.searchsorted(occluders, faces)                      # the face itself among the occluders (or none)
    own = np.where((own < len(occluders)) & (occluders[np.minimum(own, len(occluders) - 1)] == faces), own, -1)
    plane, _ = occluder_planes(tri)
    out = np.empty((len(faces), MAX_CANDIDATES), dtype=np.int64)
    count = face_candidates(tri, plane, own, front.astype(np.uint8), front_plane, n, o, valid, hull_v,
                            float(q.area.tol), MAX_CANDIDATES, out)
    many = count > MAX_CANDIDATES
    listed = np.where(many, 0, count)
    face_of = np.repeat(np.arange(len(faces)), listed)
    occ_of = out[np.arange(MAX_CANDIDATES)[None, :] < listed[:, None]]
    return occluders, face_of, occ_of, many


def closed_outward(caster: RayCaster, objects: np.ndarray, spots: np.ndarray) -> np.ndarray:
    """(len(objects),) bool: whether each object's triangles form a closed surface with outward normals (every
    directed edge once, its reverse once; positive signed volume) and every laser point (spots (L, 3)) lies outside
    its bounding box. A segment from a point outside such a surface to a point on its inner side crosses the
    surface, so the inner side of its faces is never lit."""
    out = np.zeros(len(objects), dtype=bool)
    for i, obj in enumerate(objects):
        f = caster.faces[caster.face_object == obj]
        box = caster.vertices[f].reshape(-1, 3)
        inside = ((spots >= box.min(axis=0) - caster.offset) & (spots <= box.max(axis=0) + caster.offset)).all(axis=1)
        if inside.any():
            continue
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).astype(np.int64)
        n = np.int64(len(caster.vertices))
        keys = np.sort(edges[:, 0] * n + edges[:, 1])                 # directed edge a → b as one integer
        if (keys[1:] == keys[:-1]).any():                             # a directed edge twice
            continue
        if not np.array_equal(keys, np.sort(edges[:, 1] * n + edges[:, 0])):   # every reverse present: a closed,
            continue                                                             # oriented surface
        tri = caster.vertices[f]
        out[i] = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() > 0
    return out


def front_only(caster: RayCaster, faces: np.ndarray, spots: np.ndarray) -> np.ndarray:
    """(F,) bool per face of ``faces``: its object is a closed outward surface with every laser point (``spots``
    (L, 3)) outside its box (:func:`closed_outward`), so only the side its normal points to can be lit."""
    face_object = caster.face_object[faces]
    objects = np.unique(face_object)
    return closed_outward(caster, objects, spots)[np.searchsorted(objects, face_object)]


def dark_faces(caster: RayCaster, faces: np.ndarray, front: np.ndarray, spots: np.ndarray, spot_normals: np.ndarray,
               tol: float) -> np.ndarray:
    """(F,) bool per face of ``faces``: lit on its front only (``front``, :func:`front_only`) and that front turned
    away from every laser point (n·(s − p₀) < −``tol`` for every s of ``spots`` (L, 3), n the face's unit normal,
    p₀ a vertex): the compiled primary never lights such a face (the kernel's ``dark_inside``; the numpy path's
    shadow rays find it blocked, Embree's float32 leaks aside), so its sub-triangles can be left out. The maximum
    over the laser points is taken over the vertices of their convex hull (within their plane,
    :func:`~datagen.transport.quadrature.shadow.spot_plane` with their normals ``spot_normals`` (L, 3), when they
    lie on one)."""
    if not front.any():
        return np.zeros(len(faces), dtype=bool)
    ext = spots[_extreme_points(spots, spot_normals)]
    n = caster.face_normals[faces]
    step = max(1, (1 << 22) // len(ext))                              # bounded memory for every laser point
    top = np.concatenate([(ext @ n[i:i + step].T).max(axis=0) for i in range(0, len(n), step)])
    reach = top - np.einsum("ij,ij->i", n, caster.vertices[caster.faces[faces, 0]])
    return front & (reach < -tol)


def _extreme_points(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Indices of points (n, 3) holding the maximum of every linear function over them: their convex hull's
    vertices (in their plane, when :func:`~datagen.transport.quadrature.shadow.spot_plane` finds one), or every point
    when Qhull cannot build it."""
    if len(points) <= 8:
        return np.arange(len(points))
    found = spot_plane(points, normals)
    try:
        if found is not None:
            return ConvexHull(matmul(points, _plane_axes(found[0]).T)).vertices
        return ConvexHull(points).vertices
    except (QhullError, ValueError):
        return np.arange(len(points))


def run_compiled(q, grid, coarse, progress: Callable[[int], None] | None) -> None:
    """The primary of :class:`~datagen.transport.quadrature.Quadrature` ``q`` into the fine grid ``grid`` (and the
    coarse rule of its error estimate into ``coarse``, or None), both :class:`datagen.timing.tent_kernel.TentGrid`
    from :meth:`datagen.timing.EnvelopeAccumulator.tent_grid` (module doc). Photons per pulse; updates ``q.stats``
    (tents, shadow rays, pair rows) and calls ``progress`` with the pairs of each block. Runs over at least
    ``PARALLEL_MIN_PAIRS`` (sub-triangle, target) pairs use numba's threads (so does the rule at h/2 of a plain
    split's estimate, :func:`datagen.transport.quadrature.split.refined`, with the same targets and 4× the sub-triangles),
    shorter ones one thread; the result is the same bit for bit."""
    with threads_for(q.n_cells * len(q.targets), PARALLEL_MIN_PAIRS):
        _run_compiled(q, grid, coarse, progress)


def _run_compiled(q, grid, coarse, progress: Callable[[int], None] | None) -> None:
    c, legs_ = q.capture, q.physics
    M = q.n_cells
    y = q.targets
    n_y = np.broadcast_to(c.fov_normal, y.shape)
    rays = legs_.stats.shadow_rays
    collect, d_y = legs_.sensor_collection(y, n_y, np.full(len(y), legs_.wall_object), n_y)
    q.stats.shadow_rays += legs_.stats.shadow_rays - rays
    lambert = on_arrays(lambertian_value)
    f_lamb = lambert(q.materials.albedo[q.cell_object])
    spot_f = lambert(q.materials.albedo[c.spot_objects])
    comp_base = (q.object_component[q.cell_object] * c.n_channels).astype(np.int64)
    laser_off = np.broadcast_to(np.asarray(legs_.laser_leg(np.arange(c.n_lasers)), dtype=np.float64),
                                (c.n_lasers,)).copy()
    sensor_off = np.broadcast_to(np.asarray(legs_.sensor_leg(d_y), dtype=np.float64), (len(y),)).copy()
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
    i64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)
    mat = q.materials
    cell_brdf = np.ascontiguousarray(np.stack([f_lamb, mat.kind[q.cell_object], mat.albedo[q.cell_object],   # CELL_BRDF
                                               mat.specular[q.cell_object], mat.exponent[q.cell_object],
                                               mat.width[q.cell_object]], axis=1),
                                     dtype=np.float64)
    geo = (f64(q.vertices), i64(q.cells), f64(q.cell_area), comp_base, i64(q.coarse_of),
           i64(q.coarse_cells.reshape(-1, 3)))
    front = q.front                                     # per hidden face (front_only)
    closed = front[q.cell_hidden].astype(np.uint8)
    pose = (f64(q.centroids), f64(q.cell_normal), i64(q.cell_hidden), closed, f64(c.spot_normals), f64(spot_f),
            float(c.photons), f64(c.fov_normal), f64(collect * q.target_area), float(q.area.tol), cell_brdf)
    same = (c.spots[q.conn_laser] == y[q.conn_target]).all(axis=1)         # the target is the laser point
    conn = (i64(q.conn_laser), i64(q.conn_target), i64(q.conn_channel), same.astype(np.uint8))
    legs = (f64(c.spots), f64(y), f64(c.emitter_legs), f64(laser_off), f64(d_y), f64(sensor_off),
            float(q.settings.attenuation), float(SPEED_OF_LIGHT), int(q.coarse_stride))
    cached = getattr(q, "occluder_cache", None)         # the same faces and laser points: kept for the estimate's
    if cached is None or cached[0] != q.segment_tests:     # sub-scan (split.refined) and later runs
        q.occluder_cache = cached = (q.segment_tests, *_occluder_lists(q, front))
    occ = cached[1]
    shade = (*_shadow_map(q, occ, cached[2], closed), *_fov_map(q))
    grid = tuple(grid)
    has_coarse = coarse is not None
    coarse = tuple(coarse) if has_coarse else grid
    n_conn = len(q.conn_laser)
    per_block = max(1, PAIR_BLOCK // max(M, 1))
    ray_cell = np.empty(max(1, M * min(per_block, n_conn)), dtype=np.int64)      # M slots per connection
    ray_count = np.zeros(min(per_block, n_conn), dtype=np.int64)
    for start in range(0, n_conn, per_block):
        block = (start, min(n_conn, start + per_block))
        groups = channel_groups(q.conn_channel, *block)
        tents = candidates(block, geo, pose, conn, legs, grid, coarse, has_coarse, occ, ray_cell, ray_count, groups,
                           shade)
        counts = ray_count[:block[1] - block[0]]
        n_rays = int(counts.sum())
        if n_rays:
            slot = np.flatnonzero(np.arange(M)[None, :] < counts[:, None])            # listed slots, in order
            mi, bi = ray_cell[slot], block[0] + slot // M
            li = q.conn_laser[bi]
            x, n = q.centroids[mi], q.cell_normal[mi]
            lit = np.where((np.einsum("ij,ij->i", n, c.spots[li] - x) < 0)[:, None], -n, n)
            visible = np.zeros(len(ray_cell), dtype=np.uint8)
            visible[slot] = q.caster.visible(x, lit, c.spots[li], c.spot_normals[li])
            tents += deposit_pairs(block, ray_cell, ray_count, visible, groups, geo, pose, conn, legs, grid, coarse,
                                   has_coarse, occ, shade)
            q.stats.shadow_rays += n_rays
        q.stats.tents += tents
        q.stats.pair_rows += M * (block[1] - block[0])
        if progress is not None:
            progress(M * (block[1] - block[0]))

