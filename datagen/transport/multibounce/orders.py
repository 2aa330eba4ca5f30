"""Any estimator plus the light of order ≥ 3: :class:`AllOrders` runs an estimator's orders 1–2 and the
:class:`~datagen.transport.multibounce.tracer.MultibounceTracer` into the same sink, as one estimator; :func:`beside`
is the front door that puts the tracer beside an estimator (:func:`tracer_settings`: its settings for a run).

The tracer draws from its own stream (:func:`~datagen.transport.multibounce.tracer.tracer_rng`), so the orders
1–2 of a run with ``orders: 3`` or more are bit-identical to the same run with ``orders: 2``, and the components
add one, ``multibounce``. A replica of the pair is a replica of each: the error estimate of every result (the
spread of the replicas) counts the tracer's noise with the estimator's.
"""
from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace

import numpy as np

from ...errors import ConfigError
from ..base import Estimator, Sink, run_replicas
from .options import MultibounceOptions, OrdersChoice
from .smoothing import default_smoothing
from .tracer import MultibounceSettings, MultibounceTracer, build_tracer, tracer_rng

COMPONENT = "multibounce"
"""The component name of light with three or more hidden vertices (docs/physics.md §2, "Orders")."""


def tracer_settings(choice: OrdersChoice, options: MultibounceOptions, paths: int, bin_width: float,
                    tolerance: float, confocal: bool = False, aligned: bool = False) -> MultibounceSettings:
    """The tracer's settings for a run: the orders ``choice`` asks for, ``paths`` light paths per laser point, and
    unless ``options.smoothing`` is False the time smoothing of :func:`~.smoothing.default_smoothing` for output bins
    of ``bin_width`` seconds at ``tolerance`` (across the points of a ``confocal`` scan too); ``aligned``: the
    paths' draws in slots of their own (:attr:`~.tracer.MultibounceSettings.aligned`)."""
    smoothing = (default_smoothing(bin_width, tolerance, choice.min_order, confocal) if options.smoothing else {})
    return MultibounceSettings(paths=paths, min_order=choice.min_order, max_order=choice.max_order,
                               aligned=aligned, **smoothing)


def beside(base: Estimator, settings: MultibounceSettings, window: tuple[float, float],
           irf_reach: float = 0.0) -> "AllOrders":
    """The front door: ``base`` (a built estimator) with the light tracer of ``settings`` beside it, on the same
    capture, caster and leg physics, depositing into the component ``multibounce`` after the base's components (and
    order 2 into its ``secondary`` when ``settings.min_order`` is 2).

    Args:
        base: the estimator of orders 1–2; settings: :class:`~.tracer.MultibounceSettings`; window: (t_start,
            t_stop) of the time axis, s; irf_reach: how much earlier than an impulse the IRF spreads light, s.
    Raises:
        ConfigError: ``min_order`` 2 beside an estimator without a ``secondary`` component."""
    names = list(base.component_names)
    if settings.min_order == 2 and "secondary" not in names:
        raise ConfigError(f"the tracer carries order 2 into the component 'secondary', which the {type(base).__name__} "
                          f"has not (components {names})")
    secondary = names.index("secondary") if settings.min_order == 2 else None
    only_two = settings.max_order == 2                # order 2 alone: no component of its own (none would be lit)
    tracer = build_tracer(base.capture, base.caster, base.physics, settings, window=window,
                          component=secondary if only_two else len(names), secondary_component=secondary,
                          irf_reach=irf_reach)
    return AllOrders(base, tracer)


class AllOrders:
    """An estimator of orders 1–2 (``base``) and the order ≥ 3 tracer, behind the estimator interface
    (:class:`datagen.transport.base.Estimator`): ``component_names`` are the base's plus ``"multibounce"`` (none added
    when the tracer carries order 2 alone, into the base's ``secondary``); every other attribute is the base's
    (capture, settings, physics, …).

    Args:
        base: a built estimator (area, lookin); tracer: the :class:`MultibounceTracer` of the same capture,
            caster and leg physics, whose ``component`` is ``len(base.component_names)``.
    """

    def __init__(self, base: Estimator, tracer: MultibounceTracer):
        self.base, self.tracer = base, tracer
        own = tracer.component >= len(base.component_names)      # (order 2 alone goes into the base's secondary)
        self.component_names = list(base.component_names) + ([COMPONENT] if own else [])

    def __getattr__(self, name: str):
        if name in ("base", "tracer"):        # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.base, name)

    @property
    def stats(self):
        """The base's counters and the tracer's, the latter prefixed ``multibounce_``."""
        both = dict(vars(self.base.stats))
        both.update({f"{COMPONENT}_{k}": v for k, v in vars(self.tracer.stats).items()})
        return SimpleNamespace(**both)

    def progress_total(self) -> tuple[int, str]:
        total, unit = self.base.progress_total()
        return total, unit

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """The base's run, then the tracer's from its own stream of ``rng``."""
        own = tracer_rng(rng)
        self.base.run(sink, rng, progress)
        self.tracer.run(sink, own)

    def run_replicas(self, sinks: list[Sink], rngs: list[np.random.Generator],
                     progress: Callable[[int], None] | None = None) -> None:
        """The base's replicas (its own worker pool, if any), then the tracer's into the same sinks, each from
        its replica's own stream (taken before the base draws, so the worker count changes nothing)."""
        own = [tracer_rng(rng) for rng in rngs]
        run_replicas(self.base, sinks, rngs, progress)
        for sink, rng in zip(sinks, own):
            self.tracer.run(sink, rng)

    def nominal_seconds(self) -> float:
        """The base's nominal seconds plus the tracer's (:func:`tracer_nominal_seconds`)."""
        base = getattr(self.base, "nominal_seconds", None)
        return (base() if base is not None else 0.0) + tracer_nominal_seconds(self.tracer.stats)


NOMINAL_TRACER_SECONDS = {"vertex": 3.6e-7, "step": 2.4e-4, "connection": 1.6e-6}
"""Seconds of one core per traced vertex (its continuation ray, the sampling and the weights), per step (one
order of one batch: the fixed cost of the array passes, which dominates batches whose paths are short) and per
next-event connection (target point, shadow ray, sensor collection): a non-negative least-squares fit to 14 runs
(default.yaml samples, the demo and office rooms, 4096–65536 paths; within 40 %). Dataset builds cap work with it
and the tolerance loop splits replicas by it, deterministically (:meth:`AllOrders.nominal_seconds`)."""


def tracer_nominal_seconds(stats) -> float:
    """Nominal seconds of the work counted in :class:`~datagen.transport.multibounce.tracer.MultibounceStats`."""
    n = NOMINAL_TRACER_SECONDS
    # an eye ray (:mod:`.eye`) is a traced ray with its sensor collection: a vertex's and a connection's work
    eye = stats.eye_rays * (n["vertex"] + n["connection"])
    return n["vertex"] * stats.vertices + n["step"] * stats.steps + n["connection"] * stats.connections + eye
