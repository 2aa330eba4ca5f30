"""Simulation: the main job, scene → sampling → transport → timing → detector (the layer above the planner).

Exported here, what users call: :class:`SimulationConfig`, :func:`resolve_config`, :func:`simulate` →
:class:`Result`, :func:`simulate_to_tolerance` (and its :class:`ToleranceOutOfReach`), :func:`simulation_memory`
and :class:`LegacyKeysWarning`; the rest (random streams, replicas, ``run_transport``, limits) is imported from
its module.

- :mod:`.config`: :class:`SimulationConfig` (sampling, estimator, time axis, IRF, detector, effects; pydantic),
  :func:`resolve_config` (a scene file's ``simulation`` block merged with overrides) and the random streams
  (:func:`stream_rng`, ``STREAM_SAMPLING`` / ``STREAM_NOISE``).
- :mod:`.run`: :func:`simulate` → :class:`~.detection.Result` (``time_edges`` (T+1,) s, ``envelope`` (…, T) detected
  photons per pulse per bin, ``components``, ``counts`` (…, T) int64, ``attrs``); :func:`run_transport` (plan,
  estimate, bin) → :class:`~.detection.Transported`; :class:`Replicas` (independent replicas of one estimator and their
  mean, the order ≥ 3 tracer's counted apart).
- :mod:`.detection`: the detector stage: :class:`Result`, :func:`~.detection.make_result` (pile-up decision from
  the envelope, the counts, the metadata), :func:`~.detection.detector_counts`.
- :mod:`.replicas`: the error estimate every result carries (``attrs["error"]``: the replicas' standard error
  in the relative L2 measure of :func:`datagen.analysis.relative_l2`), replica streams.
- :mod:`.confidence`: the stated error as a bound: the factor √F_q(d, ν) that raises the replicas' standard error
  to an upper confidence limit, d and ν read from the replicas' correlations (docs/accuracy.md).
- :mod:`.tolerance`: :func:`simulate_to_tolerance` (replicas added, or the quadrature edge refined, until the
  estimate meets a target; ``simulate --tolerance``, dataset builds).
- :mod:`.sequence`: :func:`~.sequence.simulate_sequence`, the frames of a scene whose objects move, at the cost of
  what changes (docs/motion.md).
- :mod:`.multizone`: :func:`~.multizone.simulate_multizone`, a flood-illuminated multi-zone capture (zone
  envelopes and histograms composed from the flood's nodes; docs/multizone.md).
- :mod:`.fov_sampling`: what a run sampled of the sensor grid: zones its fixed FoV points cannot resolve,
  refused or warned about before the work (:func:`~.fov_sampling.zone_sampling`), and the true reason of a zero
  envelope (:func:`~.fov_sampling.zero_reason`).
- :mod:`.provenance`: :func:`~.provenance.library_versions`, the versions every result and card records.
- :mod:`.budget`: the memory a simulation needs, estimated before allocating (:func:`simulation_memory`), and
  the refusal (:class:`ResourceError`) when it exceeds the memory available.
- :mod:`.bounds`: the upper bound of every numeric knob (light paths, samples, grids, bins, workers), checked
  before any work, and the projection of long work (:func:`~.bounds.projected_work`).
"""
from ..lazy import lazy_attributes

_LAZY = {"simulation_memory": "budget", "LegacyKeysWarning": "config", "SimulationConfig": "config",
         "resolve_config": "config", "Result": "detection", "simulate": "run", "ToleranceOutOfReach": "tolerance",
         "simulate_to_tolerance": "tolerance"}
"""The exported names, each imported from its module on first use (``import datagen.simulation`` stays light)."""

__getattr__ = lazy_attributes(__name__, _LAZY)

__all__ = ["SimulationConfig", "resolve_config", "simulate", "Result", "simulate_to_tolerance", "ToleranceOutOfReach",
           "simulation_memory", "LegacyKeysWarning"]
