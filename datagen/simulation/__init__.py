"""Simulation: the main job, scene → sampling → transport → timing → detector (the layer above the planner).

- :mod:`.config`: :class:`SimulationConfig` (sampling, estimator, time axis, IRF, detector, effects; pydantic),
  :func:`resolve_config` (a scene file's ``simulation`` block merged with overrides) and the random streams
  (:func:`stream_rng`, ``STREAM_SAMPLING`` / ``STREAM_NOISE``).
- :mod:`.run`: :func:`simulate` → :class:`Result` (``time_edges`` (T+1,) s, ``envelope`` (…, T) detected
  photons per pulse per bin, ``components``, ``counts`` (…, T) int64, ``attrs``); :func:`run_transport` (plan,
  estimate, bin) → :class:`Transported`; :class:`Replicas` (independent replicas of one estimator and their
  mean); :func:`make_result` (detector draw and metadata).
- :mod:`.replicas`: the error estimate every result carries (``attrs["error"]``: the replicas' standard error
  in the relative L2 measure of :func:`datagen.analysis.relative_l2`), replica streams.
- :mod:`.tolerance`: :func:`simulate_to_tolerance` (replicas added, or the quadrature edge refined, until the
  estimate meets a target; ``simulate --tolerance``, dataset builds).
- :mod:`.budget`: the memory a simulation needs, estimated before allocating (:func:`simulation_memory`), and
  the refusal (:class:`ResourceError`) when it exceeds the memory available.
"""
from .budget import ResourceError, available_memory, check_memory, check_simulation_memory, simulation_memory
from .config import (STREAM_NOISE, STREAM_SAMPLING, TIME_AXIS_FIELDS, LegacyKeysWarning, SimulationConfig,
                     detector_error, legacy_note, merge_overrides, parse_grid, resolve_config, stream_rng,
                     translate_legacy)
from .replicas import PEAK_FLOOR, ReplicaSums, relative_standard_error, replica_rng, replica_root
from .tolerance import (MIN_TOLERANCE, TIME_CAP_S, ToleranceOutOfReach, check_tolerance, projected_seconds,
                        simulate_to_tolerance)
from .run import (Replicas, Result, Transported, library_versions, make_result, prepare_transport, run_transport,
                  simulate)

__all__ = ["STREAM_NOISE", "STREAM_SAMPLING", "TIME_AXIS_FIELDS", "detector_error", "LegacyKeysWarning",
           "SimulationConfig", "legacy_note", "merge_overrides", "parse_grid", "resolve_config", "stream_rng",
           "translate_legacy",
           "PEAK_FLOOR", "ReplicaSums", "relative_standard_error", "replica_rng", "replica_root", "Replicas",
           "Result", "Transported", "library_versions", "make_result", "prepare_transport", "run_transport",
           "simulate", "simulate_to_tolerance", "TIME_CAP_S", "MIN_TOLERANCE", "ToleranceOutOfReach",
           "check_tolerance", "projected_seconds",
           "ResourceError", "available_memory", "check_memory", "check_simulation_memory", "simulation_memory"]
