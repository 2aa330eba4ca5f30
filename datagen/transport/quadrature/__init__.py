"""The hidden-surface quadrature (``estimator: {kind: quadrature}``): a deterministic area rule with exact time binning.

Converges to: the primary L_p, deterministically, as O(h²) in the sub-triangle edge h away from kernel singularities
(≈ O(h) where a surface meets the FoV); a planned secondary comes from the area sampler (docs/physics.md §3.4). No
noise: the error estimate is the difference between edges h and 2h; a finer level costs ∝ h⁻² to h⁻⁴, counted in
nominal seconds for a dataset's ``cost_cap`` (:meth:`Quadrature.nominal_seconds`). Pick it for small smooth hidden
objects seen by point sensors or scanned walls (tal's captures, confocal and exhaustive scans, docs/scans.md,
docs/tal.md).

- :mod:`.estimator`: :class:`Quadrature` (registered as ``"quadrature"``) and :class:`QuadratureSettings`.
- :mod:`.options`: the options block (:class:`~.options.QuadratureOptions`, the edge ladder of the tolerance loop).
- :mod:`.split`: the sub-triangles of each hidden face (even, plain, auto) and the error estimate's rule.
- :mod:`.grading`: hidden triangles graded finer near the scanned points.
- :mod:`.primary`: the primary through the compiled pair kernel, and its shadow-ray culling.
- :mod:`.kernel`: the compiled pair loop (weights, tents, shadow tests).
- :mod:`.shadow`: the conservative projection that decides which laser legs need a shadow ray.
- :mod:`.numpy_kernel`: the same primary in numpy, the kernel's reference in ``tests/test_quadrature_kernel.py``.
"""
from .estimator import Quadrature, QuadratureSettings

__all__ = ["Quadrature", "QuadratureSettings"]
