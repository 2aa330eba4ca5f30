"""Simulate to a tolerance (the loop lives in :mod:`datagen.simulation.tolerance`, below the dataset layer that
needs it). This module keeps the analysis-layer names: :func:`simulate_to_tolerance`,
:func:`replica_error` (the error estimate of K replicas' mean) and :func:`describe_setting`.
"""
from __future__ import annotations

import numpy as np

from ..simulation import simulate_to_tolerance
from ..simulation.replicas import ReplicaSums
from ..simulation.tolerance import TIME_CAP_S
from ..simulation.config import translate_legacy
from ..transport import estimator
from ..transport.base import estimator_options

__all__ = ["TIME_CAP_S", "describe_setting", "replica_error", "simulate_to_tolerance"]


def describe_setting(config: dict) -> str:
    """The sampling setting of the JSON config of a result (``result.attrs["config"]``, also one written in the old
    flat form) in words, from the estimator's registry entry, e.g. "65536 hidden samples per laser point"."""
    block = translate_legacy(config)[0].get("estimator", "lookin")       # older results: flat keys
    options = estimator_options(block)
    entry = estimator(options.kind)
    return entry.describe(options) if entry.describe is not None else options.kind


def replica_error(parts: list[np.ndarray]) -> float:
    """ε̂ = sqrt(Σ_b s_b² / K) / ‖M‖ over bins above 1 % of M's peak: the relative standard error of the mean M of
    K independent replicas X_k (s_b² their sample variance in bin b; :mod:`datagen.simulation.replicas`)."""
    first = np.asarray(parts[0], dtype=np.float64)
    sums = ReplicaSums.zeros(1, first.size)
    for x in parts:
        sums.add(np.asarray(x, dtype=np.float64).reshape(1, -1))
    return sums.error()
