"""The hidden-surface quadrature's split of the hidden faces, and the rule its error estimate compares with.

:class:`datagen.transport.quadrature.Quadrature` splits every hidden face into k² congruent sub-triangles of edge
≤ h (:func:`datagen.sampling.surfaces.subdivide_with_vertices`) in one of two ways, each with its own error
estimate (the quadrature's error falls as h², docs/physics.md §2 and the module doc of :mod:`.quadrature`):

- **even** (k rounded up to an even number): every 2 × 2 group of sub-triangles is a sub-triangle of the split at
  2h (:func:`datagen.sampling.surfaces.coarse_cells`), so the same evaluations give the rule at 2h as well, and the
  estimate is ‖P(h) − P(2h)‖ / (2² − 1) (``coarse_ratio`` 2). Free, but where a face is already shorter than h (a fine mesh:
  k = 1) it costs 4× the pairs of the plain split.
- **plain** (k = ceil(longest edge / h); a mesh whose triangles are shorter than h is used as it is): the estimate
  is ‖P(h) − P(h/2)‖ / |(1/2)² − 1| = (4/3)·‖P(h) − P(h/2)‖, P(h/2) the even split at h/2 (every sub-triangle of
  the plain split cut into exactly 2 × 2) run on a sub-scan only: every ``REFINE_STRIDE``-th laser point in each
  grid axis (``coarse_ratio`` 1/2; 4 / ``REFINE_STRIDE``² = 6 % more pairs). The estimate is over those channels.

The plain split is chosen for confocal laser grids with at least ``MIN_REFINE_LASERS`` points in that sub-scan (64 × 64
scans and larger) whose even split would hold more than ``EVEN_EXTRA`` times the sub-triangles of the plain one;
every other capture keeps the even split.
"""
from __future__ import annotations

import copy

import numpy as np

from ...sampling.surfaces import coarse_cells, subdivide_with_vertices, subdivisions
from ...vectors import distinct_rows

__all__ = ["EVEN_EXTRA", "MIN_REFINE_LASERS", "REFINE_STRIDE", "apply_split", "choose_split", "refine_lasers",
           "refined"]

REFINE_STRIDE = 8
"""The plain split's error estimate runs the rule at h/2 on every ``REFINE_STRIDE``-th laser point of each grid axis."""

MIN_REFINE_LASERS = 64
"""The plain split needs at least this many laser points in that sub-scan (a 64 × 64 grid gives 8 × 8)."""

EVEN_EXTRA = 1.1
"""The plain split is chosen when the even one would hold more than this many times its sub-triangles."""


def refine_lasers(capture, minimum: int = MIN_REFINE_LASERS) -> np.ndarray | None:
    """Laser indices (n,) int64 of the sub-scan of the plain split's estimate: for a confocal grid every
    ``REFINE_STRIDE``-th point of each grid axis, starting at ``REFINE_STRIDE // 2`` (at least one per axis), else
    every laser point; None when there are fewer than ``minimum``."""
    if capture.kind != "confocal":
        lasers = np.arange(capture.n_lasers, dtype=np.int64)
    else:
        lx, ly = capture.laser_shape
        ix = np.arange(min(REFINE_STRIDE // 2, lx // 2), lx, REFINE_STRIDE)
        iy = np.arange(min(REFINE_STRIDE // 2, ly // 2), ly, REFINE_STRIDE)
        lasers = (iy[:, None] * lx + ix[None, :]).reshape(-1).astype(np.int64)      # laser p = iy · lx + ix
    return lasers if len(lasers) >= minimum else None


def choose_split(tri: np.ndarray, edge: float, capture, split: str = "auto") -> np.ndarray | None:
    """The split of faces ``tri`` (F, 3, 3) at ``edge`` (m) for ``capture``: None for the even split, else the
    laser indices of the plain split's sub-scan (:func:`refine_lasers`). ``split`` "even" / "plain" forces one
    (a forced plain split takes its sub-scan from any capture); "auto" chooses as the module doc says."""
    if split != "auto":
        return None if split == "even" else refine_lasers(capture, 1)
    lasers = refine_lasers(capture) if capture.kind == "confocal" else None
    if lasers is None or len(tri) == 0:
        return None
    k = subdivisions(tri, edge)
    return lasers if float(((k + k % 2) ** 2).sum()) > EVEN_EXTRA * float((k ** 2).sum()) else None


def apply_split(q, tri: np.ndarray, edge: float, even: bool, piece_of: np.ndarray | None = None) -> None:
    """Set the sub-triangles of quadrature ``q`` from the hidden faces ``tri`` (F, 3, 3) (``q.area.hidden_faces``,
    or pieces of them: ``piece_of`` (F,) the hidden face of each piece, from the grading of
    :func:`datagen.transport.quadrature.grading.graded_triangles`) split at ``edge``: ``vertices`` (V, 3), ``cells``
    (M, 3), ``cell_area`` (M,) m², ``cell_hidden`` (M,) index into the hidden faces, ``cell_face``,
    ``centroids``, ``cell_normal``, ``cell_object``, ``n_cells``, and the coarse rule's ``coarse_cells`` (Mc, 3) /
    ``coarse_of`` (M,) (−1: not the middle of a coarse cell; all −1 when not ``even``). ``vertices`` holds each
    distinct lattice point once (sorted; points of neighbouring faces that came out bit-equal are one vertex)."""
    vertices, cells, q.cell_area, parent = subdivide_with_vertices(tri, edge, even=even)
    q.coarse_of = np.full(len(cells), -1, dtype=np.int64)         # fine cell → coarse cell it is the middle of
    coarse = np.zeros((0, 3), dtype=np.int64)
    if even:
        coarse, central = coarse_cells(tri, edge)
        q.coarse_of[central] = np.arange(len(central))
    # a lattice point of several faces (a mesh's shared vertex) once, where the faces computed it to the same bits:
    # the path lengths per connection are computed per vertex (6× fewer on a mesh split one cell per face)
    q.vertices, index = distinct_rows(vertices)
    q.cells, q.coarse_cells = index[cells], index[coarse]
    q.cell_hidden = parent if piece_of is None else piece_of[parent]   # index into area.hidden_faces
    q.cell_face = q.area.hidden_faces[q.cell_hidden]
    q.centroids = q.vertices[q.cells].mean(axis=1)
    q.cell_normal = q.caster.face_normals[q.cell_face]
    q.cell_object = q.caster.face_object[q.cell_face]
    q.n_cells = len(q.cells)


def refined(q, stats):
    """A shallow copy of quadrature ``q`` (plain split) that runs the rule at h/2 on the sub-scan ``q.refine_lasers``:
    the even split at ``q.settings.edge`` / 2 without its own coarse rule, only the connections of those laser
    points, every object in component 0 (its primary goes to the channel rows of the estimate's accumulator), and
    counters ``stats``."""
    sub = copy.copy(q)
    tri, piece_of = q.split_faces                                 # graded pieces, if the run grades them
    apply_split(sub, tri, 0.5 * q.settings.edge, even=True, piece_of=piece_of)
    sub.coarse_of = np.full(sub.n_cells, -1, dtype=np.int64)
    keep = np.isin(q.conn_laser, q.refine_lasers)
    sub.conn_laser, sub.conn_target, sub.conn_channel = q.conn_laser[keep], q.conn_target[keep], q.conn_channel[keep]
    sub.object_component = np.zeros_like(q.object_component)
    sub.coarse, sub.refine_lasers, sub.stats = None, None, stats
    sub.total_rows = sub.n_cells * len(sub.conn_laser)
    return sub
