"""The detector-model registry: one entry per ``DetectorConfig.model``, registered by the module that implements it.

Each entry says how the model turns per-bin avalanche rates into an exposure's histogram and what the rest of
datagen may rely on (docs/physics.md §6, docs/architecture.md "Adding a detector model"):

- ``expected(rates, config)`` and ``sample(rates, config, rng)``: (P, T) float64 rates (expected avalanches per
  cycle per bin, P pixels) → (P, T) expected counts (float64) / one exposure's counts (int64) over
  ``config.cycles`` cycles, before the Gaussian jitter (:mod:`.histogram` applies it after pile-up);
- ``dead_time``: "none" (counts are Poisson: no pile-up to decide), "synchronous" (re-armed every laser cycle) or
  "free_running" (dead time across cycles); the planner's pile-up decision (:mod:`.pileup`) reads it;
- ``torch_noise``: :class:`~datagen.spad.torch_noise.SPADNoise` draws it on the training device;
- ``fittable``: ``datagen fit-detector`` fits it (:mod:`.fit`);
- ``paralyzable``, ``afterpulsing``, ``crosstalk``: the detector effects it simulates beyond its dead time
  (``DetectorConfig`` refuses a config that asks a model for one it does not).

:mod:`.synchronous` registers ``poisson``, ``pile_up`` and ``multi_stop``; :mod:`.free_running_batched` registers
``free_running`` (where both its samplers are in reach); :mod:`.histogram` imports both, and ``datagen.spad`` imports :mod:`.histogram`, so the registry
is full once ``datagen.spad`` (or any of its modules) is imported. The names a config may give are
the :data:`ModelName` literal (``DetectorConfig.model``); a test holds the two equal.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal, get_args

import numpy as np

from ..errors import ConfigError

ModelName = Literal["poisson", "pile_up", "multi_stop", "free_running"]
"""The model names a config may give (``DetectorConfig.model``), in the order listings use."""

__all__ = ["DetectorModel", "register_model", "detector_model", "model_names"]


@dataclass(frozen=True)
class DetectorModel:
    """One detector model (module docstring): its name, the two histogram functions and what it supports."""

    name: str
    expected: Callable[[np.ndarray, object], np.ndarray]
    sample: Callable[[np.ndarray, object, np.random.Generator], np.ndarray]
    dead_time: Literal["none", "synchronous", "free_running"]
    torch_noise: bool = False
    fittable: bool = False
    paralyzable: bool = False
    afterpulsing: bool = False
    crosstalk: bool = False
    description: str = ""


_MODELS: dict[str, DetectorModel] = {}


def register_model(model: DetectorModel) -> DetectorModel:
    """Add ``model`` to the registry (its module calls this once, at import); returns it.

    Raises:
        ValueError: a model of that name is registered already.
    """
    if model.name in _MODELS:
        raise ValueError(f"detector model {model.name!r} is registered twice")
    _MODELS[model.name] = model
    return model


def detector_model(name: str) -> DetectorModel:
    """The registry entry of ``name``.

    Raises:
        ConfigError: no model of that name (the message lists the registered ones).
    """
    if name not in _MODELS:
        raise ConfigError(f"detector model {name!r} is not registered (registered: {', '.join(model_names())})")
    return _MODELS[name]


def model_names(**supports: bool) -> tuple[str, ...]:
    """Registered model names, in the order of :data:`ModelName` (then any other, by name);
    keyword filters keep those with the given support, e.g. ``model_names(fittable=True)``."""
    order = {name: i for i, name in enumerate(get_args(ModelName))}
    names = sorted(_MODELS, key=lambda n: (order.get(n, len(order)), n))
    return tuple(n for n in names if all(getattr(_MODELS[n], k) == v for k, v in supports.items()))
