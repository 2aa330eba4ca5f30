"""Sampling: where estimators put their points and rays (after the scene, before transport).

- :mod:`.directions`: stratified grids on [0, 1]² and their maps to the hemisphere (cosine or uniform pdf).
- :mod:`.lookins`: the paper's lookins (√N×√N rays from the laser spot, :func:`sample_lookins` →
  :class:`Lookins`, arrays (N, 3) / (N,)) and hemispherical cameras (:func:`observe` →
  :class:`ObservedPoints`, arrays (B, l·p, 3) / (B, l·p); every pixel 2π/(l·p) sr).
- :mod:`.sobol`: scrambled Sobol sets (:func:`~.sobol.scrambled_sobol`, (2^m, d) float64), each scrambled once and
  remembered while its generator's seed sequence repeats it (a capture sequence's changes).
- :mod:`.surfaces`: points on triangles, one implementation for every estimator: :func:`subdivide_triangles`,
  :func:`subdivide_with_vertices`, :func:`sample_surfaces` → :class:`SurfaceSamples` (points (M, 3), areas (M,)).

Exported here: :func:`square_to_hemisphere`, :func:`sample_lookins`, :func:`observe` and
:func:`sample_surfaces`; the estimators import the rest from its module.
"""
from .directions import square_to_hemisphere
from .lookins import observe, sample_lookins
from .surfaces import sample_surfaces

__all__ = ["square_to_hemisphere", "sample_lookins", "observe", "sample_surfaces"]
