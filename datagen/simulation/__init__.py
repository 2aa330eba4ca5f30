"""Simulation: the main job, scene → sampling → transport → timing → detector (the layer above the planner).

- :mod:`.config`: :class:`SimulationConfig` (sampling, estimator, time axis, IRF, detector, effects; pydantic),
  :func:`resolve_config` (a scene file's ``simulation`` block merged with overrides) and the random streams
  (:func:`stream_rng`, ``STREAM_SAMPLING`` / ``STREAM_NOISE``).
- :mod:`.run`: :func:`simulate` → :class:`Result` (``time_edges`` (T+1,) s, ``envelope`` (…, T) detected
  photons per pulse per bin, ``components``, ``counts`` (…, T) int64, ``attrs``); :func:`run_transport` (plan,
  estimate, bin) → :class:`Transported`; :func:`make_result` (detector draw and metadata).
- :mod:`.budget`: the memory a simulation needs, estimated before allocating (:func:`simulation_memory`), and
  the refusal (:class:`ResourceError`) when it exceeds the memory available.
"""
from .budget import ResourceError, available_memory, check_memory, check_simulation_memory, simulation_memory
from .config import STREAM_NOISE, STREAM_SAMPLING, SimulationConfig, parse_grid, resolve_config, stream_rng
from .run import Result, Transported, library_versions, make_result, run_transport, simulate

__all__ = ["STREAM_NOISE", "STREAM_SAMPLING", "SimulationConfig", "parse_grid", "resolve_config", "stream_rng",
           "Result", "Transported", "library_versions", "make_result", "run_transport", "simulate",
           "ResourceError", "available_memory", "check_memory", "check_simulation_memory", "simulation_memory"]
