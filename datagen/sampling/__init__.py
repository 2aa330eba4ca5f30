"""Sampling: where estimators put their points and rays (after the scene, before transport).

- :mod:`.directions`: stratified grids on [0, 1]² and their maps to the hemisphere (cosine or uniform pdf).
- :mod:`.lookins`: the paper's lookins (√N×√N rays from the laser spot, :func:`sample_lookins` →
  :class:`Lookins`, arrays (N, 3) / (N,)) and hemispherical cameras (:func:`observe` →
  :class:`ObservedPoints`, arrays (B, l·p, 3) / (B, l·p); every pixel 2π/(l·p) sr).
- :mod:`.surfaces`: points on triangles, one implementation for every estimator: :func:`subdivide_triangles`,
  :func:`subdivide_with_vertices`, :func:`sample_surfaces` → :class:`SurfaceSamples` (points (M, 3), areas (M,)).
"""
from .directions import HemispherePdf, concentric_disk, square_to_hemisphere, stratified_grid, to_world
from .lookins import Lookins, ObservedPoints, camera_solid_angle, observe, sample_lookins
from .surfaces import (AreaSampling, SurfaceSamples, padding, sample_surfaces, stratified_edge, subdivide_triangles,
                       subdivide_with_vertices, subdivisions, unit_square_points, unit_triangle, coarse_cells)

__all__ = ["HemispherePdf", "concentric_disk", "square_to_hemisphere", "stratified_grid", "to_world", "Lookins",
           "ObservedPoints", "camera_solid_angle", "observe", "sample_lookins", "AreaSampling", "SurfaceSamples",
           "padding", "coarse_cells", "sample_surfaces", "stratified_edge", "subdivide_triangles", "subdivide_with_vertices",
           "subdivisions", "unit_square_points", "unit_triangle"]
