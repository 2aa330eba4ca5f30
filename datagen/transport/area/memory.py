"""The area sampler's memory estimate: bytes per hidden sample (:attr:`EstimatorEntry.memory
<datagen.transport.EstimatorEntry>`; the quadrature's Monte Carlo secondary uses it too)."""
from __future__ import annotations

from ...scene import Scene


AREA_SAMPLE_BYTES = 500
"""Bytes per hidden sample of the area sampler (point, normal, ids, both connections, weights)."""


def area_memory(scene: Scene, config, lasers: int, sensors: int) -> list[tuple[str, str, float]]:
    """(field, value, bytes) of the area sampler's hidden samples (``config.estimator.samples``; the quadrature's
    Monte Carlo secondary passes its ``secondary_samples``) (:attr:`EstimatorEntry.memory
    <datagen.transport.EstimatorEntry>`)."""
    return samples_memory(config.estimator.samples, "estimator.samples")


def samples_memory(samples: int, field: str) -> list[tuple[str, str, float]]:
    """(field, value, bytes) of ``samples`` hidden samples of the area sampler."""
    return [(field, str(samples), float(AREA_SAMPLE_BYTES) * samples)]
