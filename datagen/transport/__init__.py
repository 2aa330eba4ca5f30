"""Transport: estimators of the transient path integral, from the scene to path impulses (docs/physics.md §2–3).

In: a :class:`~datagen.scene.Scene`, its :class:`~datagen.scene.Capture` and a ray caster. Out: impulses
(times in s, weights in detected photons per pulse, component ids ``component * n_channels + channel``) sent
to a :class:`Sink`, usually the timing stage's :class:`~datagen.timing.EnvelopeAccumulator`.

- :mod:`.physics`: the weight of each leg, written once (:class:`LegPhysics`), and :class:`PhysicsSettings`,
  the physics switches every estimator's settings derive from.
- :mod:`.base`: the sink, the estimator interface and the registry by name (:func:`estimator`).
- one module per estimator: :mod:`.lookin` (the paper's lookins and hemispherical cameras, ``"lookin"``) with
  its secondaries in :mod:`.secondary`; :mod:`.area` (hidden-surface area sampling, ``"area"``);
  :mod:`.quadrature` (deterministic hidden-surface quadrature, ``"quadrature"``).
"""
from .base import (AccuracyLadder, Connections, Counters, Estimator, EstimatorEntry, EstimatorOptions, Sink,
                   estimator, estimator_names, estimator_options, register, run_replicas)
from .physics import PHYSICS_SWITCHES, LegPhysics, PhysicsSettings, fov_connection_weight, laser_irradiance
from .area_kernels import abs_sin_azimuth, brdf_value, material_arrays
from .lookin import LookinOptions, LookinSampler, SecondaryMode, Transport, TransportSettings, TransportStats
from .area import AreaOptions, AreaSampler, AreaSettings, AreaStats
from .quadrature import QUADRATURE_EDGE, Quadrature, QuadratureOptions, QuadratureSettings, QuadratureStats

__all__ = ["abs_sin_azimuth", "brdf_value", "material_arrays", "AccuracyLadder", "Connections", "Counters", "Estimator",
           "EstimatorEntry", "EstimatorOptions", "Sink", "estimator", "estimator_names", "estimator_options",
           "LookinOptions", "AreaOptions", "QuadratureOptions",
           "register", "run_replicas", "PHYSICS_SWITCHES", "LegPhysics", "PhysicsSettings", "fov_connection_weight",
           "laser_irradiance", "SecondaryMode", "LookinSampler", "TransportSettings", "TransportStats",
           "AreaSampler", "AreaSettings", "AreaStats", "QUADRATURE_EDGE", "Quadrature", "QuadratureSettings",
           "QuadratureStats"]
