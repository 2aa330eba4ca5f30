"""Transport: estimators of the transient path integral, from the scene to path impulses (docs/physics.md §2–3).

In: a :class:`~datagen.scene.Scene`, its :class:`~datagen.scene.capture.Capture` and a ray caster. Out: impulses
(times in s, weights in detected photons per pulse, component ids ``component * n_channels + channel``) sent
to a :class:`Sink`, usually the timing stage's :class:`~datagen.timing.EnvelopeAccumulator`.

Exported here, what users call: the registry (:func:`register`, :func:`estimator`, :func:`estimator_names`,
:class:`EstimatorOptions`, :class:`AccuracyLadder`), the physics an estimator builds on (:class:`PhysicsSettings`,
:class:`LegPhysics`) and the three estimators with their settings (:class:`LookinSampler` /
:class:`LookinSettings`, :class:`AreaSampler` / :class:`AreaSettings`, :class:`Quadrature` /
:class:`QuadratureSettings`). Options blocks, stats, kernels and constants are imported from their modules.

One folder per estimator; its ``__init__`` says what it converges to, what it costs and when to pick it:

- :mod:`.physics`: the weight of each leg, written once (:class:`LegPhysics`), and :class:`PhysicsSettings`,
  the physics switches every estimator's settings derive from.
- :mod:`.base`: the sink, the estimator interface and the registry by name (:func:`estimator`).
- :mod:`.leg_kernels`: compiled leg pieces the estimators share (the material table as kernels take it, a FoV
  target's geometry, the sensor collection in one pass).
- :mod:`.lookin`: the paper's lookins and hemispherical cameras (``"lookin"``).
- :mod:`.area`: hidden-surface area sampling with next-event connections (``"area"``).
- :mod:`.quadrature`: the deterministic hidden-surface quadrature (``"quadrature"``).
- :mod:`.multibounce`: light of order ≥ 3 (three or more hidden vertices, the component ``multibounce``): a light
  tracer from the laser spot that runs beside a Monte Carlo estimator when ``simulation.orders`` asks for it.
"""
from .base import AccuracyLadder, EstimatorOptions, estimator, estimator_names, register
from .physics import LegPhysics, PhysicsSettings
# importing the estimator modules registers them
from .lookin import LookinSampler, LookinSettings
from .area import AreaSampler, AreaSettings
from .quadrature import Quadrature, QuadratureSettings

__all__ = ["register", "estimator", "estimator_names", "EstimatorOptions", "AccuracyLadder", "PhysicsSettings",
           "LegPhysics", "LookinSampler", "LookinSettings", "AreaSampler", "AreaSettings", "Quadrature",
           "QuadratureSettings"]
