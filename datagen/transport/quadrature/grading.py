"""Graded hidden triangles for the quadrature: finer sub-triangles near the scanned points (docs/scans.md, Cost),
and the quadrature's memory estimate (:func:`quadrature_memory`, which counts them).

The quadrature's error is largest where a hidden surface passes close to the laser points and targets (the floor
under the lowest scan row of a confocal room: 1/r² of both legs changes fastest there), yet its lattice split
cuts every hidden triangle into sub-triangles of the same edge h. :func:`graded_triangles` first cuts a triangle
into four (at its edge midpoints), again and again, while its longest edge exceeds ``ratio`` × its distance to the
box holding the scanned points, down to ``min_edge``; the lattice split then cuts each piece (at least into 4, the
even split), so sub-triangles near the scan are about ``ratio`` × distance / 2 and far ones still h. The pieces
cover their triangle exactly, so the quadrature's O(h²) error and its rule at 2h (per piece) hold unchanged; the
occluder lists stay per original triangle (the pieces carry its index).
"""
from __future__ import annotations

import math

import numpy as np

from ..area.memory import samples_memory
from ..base import TARGET_BYTES
from .options import fov_cells_per_side

__all__ = ["GRADING_MIN_EDGE", "graded_triangles", "quadrature_memory"]

GRADING_MIN_EDGE = 0.4
"""Grading stops at pieces of this fraction of the quadrature edge h (``min_edge`` = 0.4 h): the lattice split then
cuts each into at least 4, so the finest sub-triangles are ≈ h/5."""


def _box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.maximum(0.0, np.maximum(lo - points, points - hi)), axis=-1)


def graded_triangles(tri: np.ndarray, near: np.ndarray, ratio: float, min_edge: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles into 4 while they are long for their distance to the scanned points (module doc).

    Args:
        tri: (F, 3, 3) float64 triangles, metres.
        near: (P, 3) the points whose neighbourhood gets finer triangles (laser points and targets); their
            axis-aligned box is the distance reference.
        ratio: a triangle is split while its longest edge > ratio × its distance to that box (the distance of its
            centroid less the largest centroid-to-vertex distance: never more than the true distance).
        min_edge: no piece is split once its longest edge is ≤ this (metres).
    Returns:
        pieces (F', 3, 3) float64 and origin (F',) int64, the index in ``tri`` each piece comes from (pieces of a
        triangle in a fixed order: the result depends only on the inputs).
    Raises:
        ValueError: ratio or min_edge not finite and > 0.
    """
    if not (np.isfinite(ratio) and ratio > 0 and np.isfinite(min_edge) and min_edge > 0):
        raise ValueError(f"graded_triangles: ratio and min_edge must be finite and > 0, got {ratio!r}, {min_edge!r}")
    lo, hi = near.min(axis=0), near.max(axis=0)
    done, origin_done = [], []
    todo, origin = np.asarray(tri, dtype=np.float64), np.arange(len(tri), dtype=np.int64)
    while len(todo):
        longest = np.linalg.norm(todo - np.roll(todo, 1, axis=1), axis=2).max(axis=1)
        centre = todo.mean(axis=1)
        reach = np.linalg.norm(todo - centre[:, None], axis=2).max(axis=1)
        dist = np.maximum(0.0, _box_distance(centre, lo, hi) - reach)
        split = (longest > ratio * dist) & (longest > min_edge)
        done.append(todo[~split])
        origin_done.append(origin[~split])
        t = todo[split]
        m01, m12, m20 = 0.5 * (t[:, 0] + t[:, 1]), 0.5 * (t[:, 1] + t[:, 2]), 0.5 * (t[:, 2] + t[:, 0])
        todo = np.stack([np.stack(q, axis=1) for q in ((t[:, 0], m01, m20), (m01, t[:, 1], m12),
                                                       (m20, m12, t[:, 2]), (m01, m12, m20))], axis=1).reshape(-1, 3, 3)
        origin = np.repeat(origin[split], 4)
    pieces, src = np.concatenate(done), np.concatenate(origin_done)
    order = np.argsort(src, kind="stable")                # pieces of one triangle together, in triangle order
    return pieces[order], src[order]


QUADRATURE_CELL_BYTES = 250
"""Bytes per quadrature sub-triangle (lattice vertices, cell indices, area, centroid, normal, ids, times)."""

def _hidden_triangles(scene) -> np.ndarray:
    """(F, 3, 3) triangles the quadrature may subdivide: every face not on the relay wall."""
    tris = [o.vertices[o.faces] for o in scene.objects if o.label != "relay_wall"]
    return np.concatenate(tris) if tris else np.zeros((0, 3, 3))


def _near_box(scene) -> np.ndarray:
    """(P, 3) points whose axis-aligned box holds every laser point and FoV point of ``scene``'s capture, for the
    grading estimate (:func:`graded_triangles` measures distances to that box): the laser spot, and each grid's and
    the FoV's centre ± half its diagonal along every axis (their plane is not resolved here, so the box is the same
    or larger and the estimate cuts as much as the run or more)."""
    points = [np.asarray(scene.laser.spot, dtype=np.float64)]
    rects = [scene.sensor.fov] if scene.sensor.fov is not None else []
    if scene.capture is not None:
        rects += [g for g in (scene.capture.laser_grid, scene.capture.sensor_grid) if g is not None]
    for rect in rects:
        centre, half = np.asarray(rect.center, dtype=np.float64), 0.5 * math.hypot(*rect.size)
        points += [centre - half, centre + half]
    return np.array(points)


def quadrature_memory(scene, config, lasers: int, sensors: int) -> list[tuple[str, str, float]]:
    """(field, value, bytes) of the quadrature's sub-triangles (graded when ``config.estimator.grading`` is set;
    k = ceil(longest edge / h) per side) and FoV cells per sensor point, from the scene's triangles without
    splitting them, and the area sampler's hidden samples of a planned Monte Carlo secondary
    (:attr:`EstimatorEntry.memory <datagen.transport.base.EstimatorEntry>`)."""
    opts = config.estimator
    terms = [] if config.secondary == "none" else samples_memory(opts.secondary_samples, "estimator.secondary_samples")
    tri = _hidden_triangles(scene)
    k_min = 1.0
    if opts.grading is not None and len(tri):      # graded pieces, each split at least in 2 × 2
        tri, _ = graded_triangles(tri, _near_box(scene), opts.grading, GRADING_MIN_EDGE * opts.edge)
        k_min = 2.0
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1).max(axis=1, initial=0.0)  # in float64:
    cells = float((np.maximum(k_min, np.ceil(longest / opts.edge)) ** 2).sum())   # no overflow
    fov = scene.sensor.fov     # FoV cells per pixel side: the quadrature caps them (at 64); not here
    side = max(fov.size) / min(fov.pixels) if fov is not None else 0.0
    k = fov_cells_per_side(opts.fov_cells, lasers > 1, side, opts.edge)
    return terms + [("estimator.edge", f"{opts.edge:g} m ({cells:.3g} sub-triangles)",
                     float(QUADRATURE_CELL_BYTES) * cells),
                    ("estimator.edge", f"{opts.edge:g} m ({k}x{k} FoV cells per pixel)",
                     float(TARGET_BYTES) * sensors * k * k)]
