"""What every estimator shares: the sink it sends path impulses to, its interface and the registry by name.

An estimator of the transient path integral (docs/physics.md §2–3) is built from a scene, its settings and a
ray caster, and ``run(sink, rng, progress)`` sends *impulses* — arrival times (s), weights (detected photons per
pulse, or radiance per unit power for point-radiance captures) and component ids
(``component * n_channels + channel``) — to a :class:`Sink` (the time stage's
:class:`~datagen.timing.EnvelopeAccumulator`). Estimators register under a name (:func:`register`), so that
``simulate``, the accuracy ladder, ``--tolerance`` and the command line choose them in one place
(:func:`estimator`, :func:`estimator_names`); a new estimator is one new module with one ``@register``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict


PLANNED_SWITCHES = ("shadow_spot", "shadow_sensor", "first_bounce", "brdf_angles", "attenuation")
"""The physics switches (fields of :class:`~datagen.transport.physics.PhysicsSettings`) the effect planner decides
(:meth:`datagen.planner.Plan.apply`); an estimator follows all of them unless its entry's ``follows_plan`` says
otherwise. The planner's other decisions: ``secondary`` (the mode passed to ``from_config``) and ``pile_up`` (the
detector's)."""

TARGET_BYTES = 100
"""Bytes per capture grid point and per quadrature target (FoV cell or sensor point), for the memory estimates
(:attr:`EstimatorEntry.memory`, :func:`datagen.simulation.simulation_memory`)."""


class EstimatorOptions(BaseModel):
    """Base of an estimator's settings model, the ``estimator:`` block of a simulation config (``kind`` picks the
    registered estimator: :func:`estimator_options`). Each estimator module subclasses it with
    ``kind: Literal["<name>"]`` and its knobs, and registers it (``register(..., options=...)``).

    Attributes:
        LEGACY: the flat simulation keys this estimator read before its knobs moved here (old key → field), e.g.
            ``{"area_samples": "samples"}``; :func:`datagen.simulation.config.translate_legacy` moves them.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: str
    LEGACY: ClassVar[dict[str, str]] = {}


def estimator_options(value: Any) -> EstimatorOptions:
    """The options model of ``value``: an :class:`EstimatorOptions`, a name (``"area"``: the defaults) or a
    mapping with ``kind`` (validated by the registered estimator's model).

    Raises:
        ValueError: no ``kind`` or an unknown one (the message lists the known ones).
    """
    if isinstance(value, EstimatorOptions):
        return value
    if isinstance(value, str):
        value = {"kind": value}
    if not isinstance(value, dict):
        raise ValueError(f"give an estimator name or a mapping with kind (one of {', '.join(_REGISTRY)}), "
                         f"got {type(value).__name__}")
    kind = value.get("kind")
    if kind not in _REGISTRY:
        what = "give kind" if kind is None else f"unknown estimator kind {kind!r}"
        raise ValueError(f"{what}; known: {', '.join(_REGISTRY)}")
    return _REGISTRY[kind].options.model_validate(value)


class Sink(Protocol):
    """Where transport sends path impulses (e.g. :class:`datagen.timing.EnvelopeAccumulator`).

    ``add(times (n,) s, weights (n,), component (n,) int)``.
    """

    def add(self, times: np.ndarray, weights: np.ndarray, component: np.ndarray) -> None: ...


def sink_far_time(sink: Sink) -> float:
    """A time (s) beyond every window of ``sink`` (for mass that must be counted as outside)."""
    axis = getattr(sink, "axis", None)
    return float(axis.t_stop + 1.0) if axis is not None else 1e9


class Counters:
    """Mixin for dataclasses of int counters: ``add`` sums another run's counters into this one."""

    def add(self, other: "Counters") -> None:
        for k, v in vars(other).items():
            setattr(self, k, getattr(self, k) + v)


@dataclass
class Connections:
    """Sensor-side impulses of a batch of hidden vertices: one row per (vertex, FoV point or sensor target).

    Attributes:
        b: (n,) int64 vertex index in the batch.
        direction: (n, 3) unit ω_k from the vertex toward the FoV point.
        weight: (n,) detected photons per unit radiant intensity of the vertex toward ω_k (geometry, far-side
            BRDF and sensor collection; excludes the vertex's own BRDF and cos).
        time: (n,) seconds from the vertex to detection; phys: (n,) metres of physical path (for attenuation).
        channel: (n,) int64 output channel.
    """

    b: np.ndarray
    direction: np.ndarray
    weight: np.ndarray
    time: np.ndarray
    phys: np.ndarray
    channel: np.ndarray

    FIELDS = ("b", "direction", "weight", "time", "phys", "channel")

    def take(self, sel) -> Connections:
        """The rows ``sel`` (mask or indices)."""
        return Connections(*(getattr(self, f)[sel] for f in self.FIELDS))


class Estimator(Protocol):
    """The interface every estimator offers (lookin, area, quadrature; docs/physics.md §3).

    Attributes:
        capture: the resolved :class:`~datagen.scene.capture.Capture`.
        settings: the estimator's settings (a :class:`~datagen.transport.physics.PhysicsSettings` subclass).
        component_names: names of the sink components: primary components, "secondary"[, "first_bounce"].
        stats: a dataclass of int counters (recorded in the result attributes).
        sensor_sampling: how the estimator reaches the FoV, in words (result attribute ``effects.sensor_sampling``).
    """

    capture: Any
    settings: Any
    component_names: list[str]
    stats: Any
    sensor_sampling: str

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Send every impulse to ``sink``; ``progress`` gets the units of work done after each batch."""

    def progress_total(self) -> tuple[int, str]:
        """(units of work of a run, their name) for a progress bar."""


def run_replicas(transport: Estimator, sinks: list[Sink], rngs: list[np.random.Generator],
                 progress: Callable[[int], None] | None = None) -> None:
    """Run ``transport`` once per (sink, generator) pair: independent replicas of the same setting.

    An estimator with its own ``run_replicas(sinks, rngs, progress)`` (e.g. one process pool for every
    replica's batches) is asked to do it; otherwise ``run`` is called once per replica, in order.
    """
    own = getattr(transport, "run_replicas", None)
    if own is not None:
        own(sinks, rngs, progress)
        return
    for sink, rng in zip(sinks, rngs):
        transport.run(sink, rng, progress)


@dataclass(frozen=True)
class EstimatorEntry:
    """A registered estimator.

    Attributes:
        name: the name users select it by (``estimator:`` in a config, ``--estimator``).
        cls: the estimator class, ``cls(scene, settings, caster)``.
        settings_class: its settings class; ``settings_class.from_transport(physics_settings, **fields)`` gives
            settings with the physics switches of any estimator's settings and the given sampling fields.
        from_config: ``(scene, config, physics, caster, capture, secondary) → Estimator``: builds it from a
            simulation config (any object with the config's fields, e.g. :class:`datagen.simulation.SimulationConfig`;
            the estimator's knobs are ``config.estimator``), the planned physics (a
            :class:`~datagen.transport.physics.PhysicsSettings` the effect planner has set the ``follows_plan``
            switches of, estimator-neutral), the scene's ray caster, its resolved
            :class:`~datagen.scene.capture.Capture` and the secondary mode the plan keeps (``config.secondary`` or "none"). The estimator builds its own
            settings from those (``settings_class.from_transport(physics, …)``).
        summary: one line for help texts.
        options: its settings model (an :class:`EstimatorOptions` subclass with ``kind: Literal[name]``), the
            ``estimator:`` block of a simulation config; the hooks below take an instance of it.
        replica: ``(options, replicas) → options updates`` giving one of ``replicas`` independent runs whose mean
            spends the options' sampling (e.g. ``{"samples": M / R}``); None for a deterministic estimator,
            whose error comes from ``refine`` instead. An estimator object whose ``monte_carlo`` attribute is
            False (e.g. the quadrature without its Monte Carlo secondary) runs once.
        refine: ``options → options updates`` of the coarser setting (e.g. twice the quadrature edge) whose
            difference estimates a deterministic estimator's error, with its ``order`` (error ∝ h^order);
            None for Monte Carlo estimators.
        describe: ``options → str``, the sampling setting in words (e.g. "65536 hidden samples per laser
            point").
        order: convergence order of ``refine`` (2: the error falls as h²).
        memory: ``(scene, config, lasers, sensors) → [(field, value, bytes), …]`` (the options are
            ``config.estimator``; shared fields such as ``workers`` and ``secondary`` the config's), the
            estimator's own arrays at their peak for a capture of ``lasers`` laser points and ``sensors`` sensor
            points, estimated without allocating (:func:`datagen.simulation.simulation_memory` adds the shared
            ones); None: none worth counting.
        casts_lookins: the estimator samples the scene from the laser spot with lookins (pictures can show them).
        ladder: the settings the accuracy benchmark steps through (``datagen bench accuracy``,
            :func:`datagen.analysis.run_accuracy`), or None: the benchmark's own ladders only.
        wide_pixels: the estimator integrates pixel regions other than their grid cells (a confocal capture's
            ``detector_fov``, :attr:`datagen.scene.capture.Capture.pixel_size`) in its primary; the others refuse
            such a capture, and so does every estimator's Monte Carlo secondary.
        follows_plan: the planned physics switches (:data:`PLANNED_SWITCHES`) the estimator takes from the
            effect planner; for any other its ``from_config`` applies its own rule (the physics it gets holds the
            user's forced value or the default there), e.g. the area sampler's primary always needs the laser
            leg's shadow rays, which the planner's ``shadow_spot`` (a decision about the secondary) leaves out
            (``AreaSampler.follows_plan``, a class attribute :func:`register` takes).
    """

    name: str
    cls: type
    settings_class: type
    from_config: Callable[..., Estimator]
    summary: str
    options: type = EstimatorOptions
    replica: Callable[[Any, int], dict] | None = None
    refine: Callable[[Any], dict] | None = None
    describe: Callable[[Any], str] | None = None
    order: int = 2
    memory: Callable[..., list[tuple[str, str, float]]] | None = None
    casts_lookins: bool = False
    ladder: "AccuracyLadder | None" = None
    follows_plan: tuple[str, ...] = PLANNED_SWITCHES
    wide_pixels: bool = False


@dataclass(frozen=True)
class AccuracyLadder:
    """Settings an estimator is benchmarked at, cheapest first (``register(..., ladder=...)``).

    Attributes:
        label: legend text; steps: per step, fields of the estimator's ``settings_class`` to set (e.g.
        ``{"samples": 512}``); cost: a step's nominal cost (relative; predicts the next step's time from the
        measured ones); setting: a step in a few characters (the table's "setting" column).
    """

    label: str
    steps: tuple[dict, ...]
    cost: Callable[[dict], float]
    setting: Callable[[dict], str]


_REGISTRY: dict[str, EstimatorEntry] = {}


def register(name: str, settings_class: type, summary: str, *, options: type,
             replica: Callable[[Any, int], dict] | None = None,
             refine: Callable[[Any], dict] | None = None, describe: Callable[[Any], str] | None = None,
             order: int = 2, memory: Callable[..., list[tuple[str, str, float]]] | None = None,
             casts_lookins: bool = False, ladder: AccuracyLadder | None = None,
             follows_plan: tuple[str, ...] | None = None, wide_pixels: bool = False) -> Callable:
    """Class decorator: register an estimator class under ``name`` with its ``settings_class``; the class provides
    the classmethod ``from_config(scene, config, physics, caster, capture, secondary)`` (``config.estimator`` is an
    instance of ``options``, the estimator's settings model: :class:`EstimatorOptions`). A Monte Carlo estimator gives
    ``replica`` (how to split its sampling into independent replicas, whose spread is the error estimate of
    every result); a deterministic one gives ``refine`` and ``order``; one with both parts gives both (the
    quadrature: a deterministic primary and a Monte Carlo secondary). ``memory``, ``casts_lookins``, ``ladder``,
    ``follows_plan`` and ``wide_pixels``: see :class:`EstimatorEntry`; ``follows_plan`` None takes the class attribute
    ``follows_plan`` (so a subclass keeps its base estimator's rule), or all of :data:`PLANNED_SWITCHES`.

    Raises:
        ValueError: neither ``replica`` nor ``refine`` (no result could say how accurate it is); a name in
            ``follows_plan`` that is not a planned switch.
    """
    if replica is None and refine is None:
        raise ValueError(f"estimator {name!r}: give replica (Monte Carlo), refine (deterministic) or both")
    if options.model_fields["kind"].default != name:
        raise ValueError(f"estimator {name!r}: its options model needs kind: Literal[{name!r}] = {name!r}")

    def wrap(cls):
        follows = tuple(follows_plan if follows_plan is not None else getattr(cls, "follows_plan", PLANNED_SWITCHES))
        if set(follows) - set(PLANNED_SWITCHES):
            raise ValueError(f"estimator {name!r}: follows_plan {sorted(set(follows) - set(PLANNED_SWITCHES))} "
                             f"are not planned switches {list(PLANNED_SWITCHES)}")
        _REGISTRY[name] = EstimatorEntry(name, cls, settings_class, cls.from_config, summary, options, replica,
                                         refine, describe, order, memory, casts_lookins, ladder, follows,
                                         wide_pixels)
        return cls
    return wrap


def unregister(name: str) -> None:
    """Remove the estimator registered as ``name`` (a plugin's tests register a toy and remove it afterwards).

    Raises:
        KeyError: no estimator has that name.
    """
    estimator(name)
    del _REGISTRY[name]


def estimator(name: str) -> EstimatorEntry:
    """The registered estimator ``name``.

    Raises:
        KeyError: no estimator has that name (the message lists the known ones).
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown estimator {name!r}; known: {list(_REGISTRY)}") from None


def estimator_names() -> tuple[str, ...]:
    """Names of the registered estimators, in registration order (lookin, area, quadrature)."""
    return tuple(_REGISTRY)
