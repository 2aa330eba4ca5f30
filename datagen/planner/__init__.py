"""The effect planner: before transport, decide which effects a scene calls for (docs/planner.md).

In: the scene, its capture, the ray caster and the simulation config (tolerance, forced effects, time axis,
detector). Out: a :class:`Plan` of one :class:`Decision` per effect of :data:`EFFECTS` (on/off, the reason with
its numbers, forced or not), which ``Plan.apply`` sets on an estimator-neutral
:class:`~datagen.transport.PhysicsSettings` (the chosen estimator builds its own settings from it). The pile-up
rule is the detector's (:mod:`datagen.spad.pileup`); the planner previews it before transport.

Exported here: :func:`plan_effects`, :class:`Plan`, :class:`Decision`, :data:`EFFECTS`; the rest is imported
from its module.

- :mod:`.decisions`: the rules and :func:`plan_effects`.
- :mod:`.geometry`: :class:`PlanGeometry`, triangles and the capture frame, and which side of each closed
  mesh the laser light can reach (:func:`reachable_side`).
- :mod:`.coarse`: the coarse area quadrature of the primary and secondary energy behind the secondary and
  pile-up decisions.
- :mod:`.orders`: how many orders of light a scene calls for (``orders: auto``: a pilot of the order ≥ 3 tracer).
- :mod:`.coarse_kernel`: the compiled (numba) passes of the coarse quadrature.
"""
from .decisions import EFFECTS, Decision, Plan, plan_effects

__all__ = ["EFFECTS", "Decision", "Plan", "plan_effects"]
