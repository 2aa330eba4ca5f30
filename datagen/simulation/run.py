"""The main job: scene → sampling → transport → envelope L(t) → SPAD histogram.

``simulate(scene, config)`` returns a :class:`Result` holding the binned envelope (expected detected photons
per laser pulse per time bin), its components (room, each object, secondary) and a finite-exposure SPAD
histogram drawn from it. The estimator is chosen by name from the transport registry
(:func:`datagen.transport.estimator`); the effect planner decides first which effects to simulate. Random
streams: :func:`datagen.simulation.config.stream_rng` (docs/physics.md §7).
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ..threads import one_blas_thread
from ..planner import Plan, plan_effects
from ..scene import RayCaster, Scene, resolve_capture
from ..scene.capture import Capture
from ..errors import SceneError
from ..timing import EnvelopeAccumulator
from ..timing.binned_sink import BinnedSink
from ..transport import estimator, estimator_names
from ..transport.base import Estimator, run_replicas
from ..transport.multibounce import COMPONENT, AllOrders
from ..transport.multibounce.orders import beside, tracer_nominal_seconds, tracer_settings
from ..transport.multibounce.tracer import tracer_rng
from ..transport.multibounce.smoothing import RICHARDSON, RICHARDSON_KINK
from .budget import check_simulation_memory
from .config import STREAM_SAMPLING, SimulationConfig, resolve_config, stream_rng
from .detection import Result, Transported, make_result
from .replicas import (FIRST_TRACER_REPLICAS, ReplicaSums, combined_error, neyman_split, relative_cross,
                       relative_difference, replica_root, replica_rng, tracer_replicas_wanted, whole_split)


class Planned(NamedTuple):
    """What :func:`prepare_transport` builds before the estimator, estimator-neutral: the scene the estimator sees,
    its ray caster, the resolved capture and the effect plan. A run that changes only the estimator's settings (the
    quadrature's levels of :func:`datagen.simulation.tolerance.simulate_to_tolerance`) passes it on."""

    scene: Scene
    caster: RayCaster
    capture: Capture
    plan: Plan


def prepare_transport(scene: Scene, config: SimulationConfig, planned: Planned | None = None,
                      memory_checked: bool = False) -> tuple[Estimator, Plan]:
    """Plan the effects and build the configured estimator (scene → planner → transport), ready to run.

    Without ``config.split_components`` the estimator sees the scene with one primary component
    (:meth:`~datagen.scene.Scene.with_summed_primary`). The flow reads in one direction and is estimator-neutral
    up to the last step: the capture is resolved (:func:`datagen.scene.resolve_capture`); the effect planner
    decides on it (:func:`datagen.planner.plan_effects`) and sets its decisions on the physics of ``config``
    (:meth:`SimulationConfig.physics_settings`, :meth:`~datagen.planner.Plan.apply`: the switches the estimator's
    registry entry follows, ``follows_plan``); the estimator registered under ``config.estimator`` builds its
    own settings from that physics and the secondary mode the plan keeps (its entry's ``from_config``). No
    estimator object or settings exist before that step; the pile-up decision is the detector stage's
    (:func:`make_result`).

    ``memory_checked``: the caller checked a run of the scene at least as large (a sequence's change: its
    reference's).

    Returns:
        (the estimator, the :class:`~datagen.planner.Plan`).
    Raises:
        ResourceError: the estimated memory exceeds what is available (:mod:`datagen.simulation.budget`).
        SceneError: the capture or planner errors (:func:`datagen.scene.resolve_capture`,
            :func:`datagen.planner.plan_effects`) and the estimator's settings errors.
    """
    if not memory_checked:
        check_simulation_memory(scene, config)     # refuse what cannot fit before allocating anything
    scene, caster, capture, plan = planned if planned is not None else plan_transport(scene, config)
    entry = estimator(config.estimator.kind)
    secondary = plan.secondary_mode(config.secondary)
    if capture.pixel_size is not None and (not entry.wide_pixels or secondary != "none"):
        where = f"{scene.source}: " if scene.source else ""
        raise SceneError(f"{where}capture.detector_fov {[float(x) for x in capture.pixel_size]} m (a field of view "
                         f"per scan point other than the scan's cell) is integrated by the "
                         f"{' / '.join(e for e in estimator_names() if estimator(e).wide_pixels)} estimator only, with "
                         f"secondary: none (got estimator {entry.name!r}, secondary {secondary!r})")
    physics = plan.apply(config.physics_settings(), entry.follows_plan)
    transport: Estimator = entry.from_config(scene, config, physics, caster, capture, secondary)
    orders = plan.decisions.get("multibounce")
    if orders is not None and orders.on:     # the tracer beside the estimator: orders ≥ 3, or ≥ 2 without secondary
        settings = tracer_settings(orders.choice, config.multibounce, config.tracer_paths(capture.n_lasers),
                                   config.time.bin_width, config.effect_threshold, capture.kind == "confocal",
                                   config.error.common_random_numbers)
        transport = beside(transport, settings, (config.time.t_start, config.time.t_stop), config.irf.support[0])
    return transport, plan


def plan_transport(scene: Scene, config: SimulationConfig) -> Planned:
    """The estimator-neutral first steps of :func:`prepare_transport`: the scene with one primary component unless
    ``config.split_components``, its ray caster, the resolved capture and the effect plan. Raises as
    :func:`prepare_transport`."""
    if not config.split_components:
        scene = scene.with_summed_primary()
    caster = RayCaster(scene)
    capture = resolve_capture(scene, caster)
    return Planned(scene, caster, capture, plan_effects(scene, config, capture, caster))


def run_transport(scene: Scene, config: SimulationConfig, rng: np.random.Generator,
                  progress: bool = False) -> Transported:
    """One run of the configured estimator at the config's setting, binned (scene → transport → envelope;
    no replicas, no error estimate: :class:`Replicas` does that)."""
    t0 = time.perf_counter()
    transport, plan = prepare_transport(scene, config)
    t_setup = time.perf_counter() - t0
    names = transport.component_names
    n_ch = transport.capture.n_channels
    acc = EnvelopeAccumulator(config.time, config.irf, len(names) * n_ch)
    bar = _progress_bar(transport, 1) if progress else None
    t1 = time.perf_counter()
    transport.run(acc, rng, progress=(bar.update if bar is not None else None))
    if bar is not None:
        bar.close()
    t_transport = time.perf_counter() - t1
    t2 = time.perf_counter()
    binned = acc.binned().reshape(len(names), n_ch, -1)
    outside = acc.outside().reshape(len(names), n_ch)
    seconds = {"setup": t_setup, "transport": t_transport, "binning": time.perf_counter() - t2}
    return Transported(names, binned, outside, transport, plan, seconds)


def _progress_bar(transport: Estimator, replicas: int):
    from tqdm.auto import tqdm
    total, unit = transport.progress_total()
    return tqdm(total=total * replicas, unit=unit, desc="transport", leave=False)


NARROW_SHARE = 0.7
"""The tracer's smoothing bias may take this share of the tolerance before its lowest band is narrowed: the share
beyond which the tolerance loops could not plan the replicas around it (``tolerance.FIXED_LIMIT``)."""

NARROW_RUNS = 4
"""…judged once the tracer has this many runs (two in each half of the bias estimate; at one each its noise alone
narrowed the demo room's)."""

MAX_NARROW = 1
"""The lowest smoothing band is narrowed at most this many times (to a quarter of its spacing)."""

REPLICA_SINK_BYTES = 1 << 26
"""Replica accumulators alive at once are bounded to this many bytes of fine histograms (64 MiB; at least one):
long time axes (a 1.67 M-bin corridor) run their replicas one by one."""


class Replicas:
    """The configured estimator built once and run replica by replica (docs/accuracy.md; :mod:`.replicas`).

    A Monte Carlo estimator (one whose registry entry gives ``replica``) runs at the *replica setting*, the
    config's sampling split R = ``config.error.replicas`` ways (e.g. ``samples`` / R hidden samples); replica r
    draws from :func:`~datagen.simulation.replicas.replica_rng` (root, r), so the result of R replicas does not
    depend on how they were run (in one call or in rounds, on any number of workers). A deterministic estimator
    (the quadrature without a Monte Carlo secondary) runs once.

    Args:
        scene, config: as for :func:`simulate`. rng: the sampling stream (the replicas' root is drawn from it).
        planned: the :class:`Planned` steps of an earlier run of the same scene and config but the estimator's
            settings (None: plan here). memory_checked: as for :func:`prepare_transport`.
    Attributes:
        entry: the estimator's :class:`~datagen.transport.EstimatorEntry`; replica_config: the config of one
        replica; transport: the estimator; sums: :class:`~datagen.simulation.replicas.ReplicaSums`;
        monte_carlo: whether the run has noise (replicas); seconds: setup / transport / binning wall times.
    """

    def __init__(self, scene: Scene, config: SimulationConfig, rng: np.random.Generator,
                 planned: Planned | None = None, memory_checked: bool = False):
        t0 = time.perf_counter()
        self.scene, self.config = scene, config
        self.entry = estimator(config.estimator.kind)
        if not memory_checked:
            check_simulation_memory(scene, config)   # the grids as the user gave them (a replica's are smaller)
        update = self.entry.replica(config.estimator, config.error.replicas) if self.entry.replica is not None else {}
        self.replica_config = config.with_estimator(**update)
        self.planned = planned if planned is not None else plan_transport(scene, self.replica_config)
        if self.entry.replica is not None:             # the order ≥ 3 tracer's paths split as the sampling is
            paths = max(1, -(-config.tracer_paths(self.planned.capture.n_lasers) // config.error.replicas))
            self.replica_config = self.replica_config.model_copy(
                update={"multibounce": self.replica_config.multibounce.model_copy(update={"paths": paths})})
        self.transport, self.plan = prepare_transport(scene, self.replica_config, self.planned, memory_checked)
        # the tracer's replicas are counted apart from the base's, so that each gets the share of the work that
        # the error of their sum asks for (replicas.tracer_replicas_wanted); beside a deterministic base (the
        # quadrature) the base runs once and only the tracer has replicas
        self.tracer = getattr(self.transport, "tracer", None)
        base = self.transport.base if self.tracer is not None else self.transport
        self.base_monte_carlo = self.entry.replica is not None and getattr(base, "monte_carlo", True)
        self.monte_carlo = self.base_monte_carlo or self.tracer is not None
        if self.tracer is not None and not self.base_monte_carlo:    # the tracer's paths in FIRST_TRACER_REPLICAS
            paths = max(1, -(-config.tracer_paths(self.planned.capture.n_lasers) // FIRST_TRACER_REPLICAS))
            self.tracer.settings = replace(self.tracer.settings, paths=paths)
        self.names = self.transport.component_names
        self.n_channels = self.transport.capture.n_channels
        self.total = EnvelopeAccumulator(config.time, config.irf, len(self.names) * self.n_channels)
        # the tracer's replicas deposit their smoothed orders binned (BinnedSink): summed here beside the total
        rows = self.total.n_components if self.tracer is not None else 0
        self.tracer_binned, self.tracer_outside = np.zeros((rows, config.time.n_bins)), np.zeros(rows)
        self.sums = ReplicaSums.zeros(self.n_channels, config.time.n_bins)
        self.sums.exact = not self.base_monte_carlo
        self.tracer_sums = ReplicaSums.zeros(self.n_channels if self.tracer is not None else 0, config.time.n_bins)
        self.root = replica_root(rng)
        self.seconds = {"setup": time.perf_counter() - t0, "transport": 0.0, "binning": 0.0}
        self._smoothing_key, self._smoothing_value = None, 0.0     # _mean_smoothing_error's cache

    @property
    def count(self) -> int:
        """Replicas run so far."""
        return self.sums.count

    def adopt_tracer(self, earlier: "Replicas") -> None:
        """Continue the tracer's replicas of ``earlier``, a run of the same scene and plan with other estimator
        settings (a quadrature level before this one), before this run has any: the tracer does not depend on those
        settings, so its replicas, their sums, its smoothing totals and its components of the total carry over."""
        if self.tracer is None or earlier.tracer is None or self.tracer_sums.count or self.base_monte_carlo:
            return
        self.transport = AllOrders(self.transport.base, earlier.tracer)
        self.tracer, self.tracer_sums = earlier.tracer, earlier.tracer_sums
        rows = self._tracer_rows(self.tracer)
        fine, total = earlier.total.fine_histogram()[rows], earlier.total.total_weight()[rows]
        self.total.add_fine(fine, rows, 0, total, total - fine.sum(axis=1))
        self.tracer_binned[rows] = earlier.tracer_binned[rows]
        self.tracer_outside[rows] = earlier.tracer_outside[rows]

    def _tracer_rows(self, tracer) -> np.ndarray:
        """The rows of :attr:`total` that ``tracer``'s components fill (component × n_channels + channel)."""
        return np.concatenate([c * self.n_channels + np.arange(self.n_channels) for c in tracer.components])

    def narrow_smoothing(self, tolerance: float) -> bool:
        """Restart the tracer with its lowest smoothing band's node spacing halved when the smoothing's estimated bias
        (relative to the replicas' mean envelope) exceeds :data:`NARROW_SHARE` × ``tolerance`` and it has been
        narrowed fewer than :data:`MAX_NARROW` times: its replicas, their sums and its part of the total are dropped
        (the base's stay). A sharp feature of the lowest order (order 2's jump where a corner of a confocal room
        returns light at one delay) can hold a bias that more replicas never bring down. Returns whether it
        restarted."""
        t = self.tracer
        if (t is None or t.smoothing is None or t.settings.smooth_narrow >= MAX_NARROW
                or self.tracer_sums.count < NARROW_RUNS
                or self._mean_smoothing_error() <= NARROW_SHARE * tolerance):
            return False
        self.tracer = t.narrowed()
        self.transport = AllOrders(self.transport.base, self.tracer)
        rows = self._tracer_rows(t)
        self.total.clear(rows)
        self.tracer_binned[rows], self.tracer_outside[rows] = 0.0, 0.0
        self.tracer_sums = ReplicaSums.zeros(self.n_channels, self.config.time.n_bins)
        return True

    def settle_smoothing(self, tolerance: float) -> bool:
        """Run the tracer's replicas up to :data:`NARROW_RUNS` when the fixed parts of the error
        (:meth:`fixed_error`) exceed :data:`NARROW_SHARE` × ``tolerance`` and the smoothing could still be narrowed: a
        bias estimate of fewer runs is too noisy to narrow on (:meth:`narrow_smoothing`), yet too large to plan the
        replicas around (docs/accuracy.md, "The error budget", gives the spread measured). Both tolerance
        loops ask before they plan replicas. Returns whether it ran any."""
        t = self.tracer
        if (t is None or t.smoothing is None or t.settings.smooth_narrow >= MAX_NARROW
                or self.fixed_error() <= NARROW_SHARE * tolerance):
            return False
        more = NARROW_RUNS - self.tracer_sums.count
        if more > 0:
            self._run_group(t, self.tracer_sums, more, self._tracer_stream, None)
        return more > 0

    def run(self, n: int, progress: bool = False, tracer_target: int | None = None, min_tracer: int = 2) -> None:
        """Run the next ``n`` replicas (one, at most, for a deterministic estimator); beside orders 1–2 that run
        replicas, the tracer runs to ``tracer_target`` replicas when given (:meth:`whole_top_up`), else to its
        Neyman share of them (:func:`~datagen.simulation.replicas.tracer_replicas_wanted`), and to ``min_tracer`` at
        least (two: the spread that share is read from; a capture sequence's change runs its halves one by one)."""
        if not self.monte_carlo:
            n = 1 - self.count
        if n <= 0:
            return
        bar = _progress_bar(self.transport, n) if progress else None
        if not self.monte_carlo:                 # one deterministic run, straight into the total: no spread
            t1 = time.perf_counter()
            run_replicas(self.transport, [self.total], [replica_rng(self.root, 0)], bar.update if bar else None)
            self.sums.count = 1
            self.seconds["transport"] += time.perf_counter() - t1
            if bar is not None:
                bar.close()
            return
        if self.tracer is None:
            self._run_group(self.transport, self.sums, n, lambda r: replica_rng(self.root, r), bar)
        elif not self.base_monte_carlo:          # the deterministic base once, then the tracer's replicas
            first = self.sums.count == 0
            if first:
                self._run_group(self.transport.base, self.sums, 1, lambda r: replica_rng(self.root, r), bar)
            more = max(FIRST_TRACER_REPLICAS - self.tracer_sums.count, 0) if first else n
            self._run_group(self.tracer, self.tracer_sums, more, self._tracer_stream, None)
        else:                                    # orders 1–2, then the tracer's replicas that go with them
            self._run_group(self.transport.base, self.sums, n, lambda r: replica_rng(self.root, r), bar)
            if self.tracer_sums.count < min_tracer:
                self._run_group(self.tracer, self.tracer_sums, min_tracer - self.tracer_sums.count,
                                self._tracer_stream, None)
            wanted = (tracer_target if tracer_target is not None
                      else tracer_replicas_wanted(self.sums, self.tracer_sums, *self.replica_costs()))
            self._run_group(self.tracer, self.tracer_sums, wanted - self.tracer_sums.count, self._tracer_stream,
                            None)
        if bar is not None:
            bar.close()

    def _tracer_stream(self, r: int) -> np.random.Generator:
        """The tracer's stream of replica r (its own, beside the base's ``replica_rng(root, r)``)."""
        return tracer_rng(replica_rng(self.root, r))

    def tracer_paths_run(self) -> int:
        """Light paths per laser point the order ≥ 3 tracer has traced over all its replicas so far (0 without it)."""
        return 0 if self.tracer is None else int(self.tracer.settings.paths) * self.tracer_sums.count

    def replica_costs(self) -> tuple[float, float]:
        """Nominal seconds of one replica of orders 1–2 and of one of the tracer (0 when unknown)."""
        base_cost = getattr(self.transport.base, "nominal_seconds", None)
        return (base_cost() / max(self.count, 1) if base_cost is not None else 0.0,
                tracer_nominal_seconds(self.tracer.stats) / max(self.tracer_sums.count, 1))

    def whole_top_up(self, budget: float) -> tuple[int, int] | None:
        """The replica counts (orders 1–2, tracer) that bring the Monte Carlo error to ``budget`` at least cost,
        rounded as a whole (:func:`~datagen.simulation.replicas.whole_split`); None without a tracer beside replicas
        of orders 1–2 or before the split is known."""
        if self.tracer is None or not self.base_monte_carlo:
            return None
        costs = self.replica_costs()
        split = neyman_split(self.sums, self.tracer_sums, *costs)
        if split is None:
            return None
        rms = budget / self.confidence_factor()          # the split's variances are the standard error's
        return whole_split(split[0], split[1], *costs, self.sums.count, self.tracer_sums.count, rms * rms)

    def _mc_parts(self) -> list[ReplicaSums]:
        """The independent Monte Carlo parts: the replicas of orders 1–2, and the tracer's beside them."""
        return [self.sums] if self.tracer is None else [self.sums, self.tracer_sums]

    def confidence_factor(self) -> float:
        """:meth:`error` over the plain standard error (≥ 1: the factor that makes it a bound at
        ``config.error.confidence``; 1 without one, or while either is not finite and positive)."""
        if self.config.error.confidence is None:
            return 1.0
        bound, rms = self.error(), combined_error(self._mc_parts())
        return bound / rms if 0 < rms < float("inf") and bound < float("inf") else 1.0

    def _run_group(self, transport, sums: ReplicaSums, n: int, streams, bar) -> None:
        """Run replicas ``sums.count`` … ``sums.count + n − 1`` of ``transport`` (stream r: ``streams(r)``) into
        the total and ``sums``, a group of replica sinks at a time (memory); a single replica into an empty total
        goes straight into it (the quadrature beside the tracer: no 127 MB sink of a 32 × 32 scan to merge)."""
        group = max(1, REPLICA_SINK_BYTES // (8 * self.total.n_components * self.total.n_fine))
        start, stop = sums.count, sums.count + max(n, 0)
        binned = transport is self.tracer              # its smoothed orders come binned (BinnedSink)
        direct = n == 1 and not binned and not self.total.total_weight().any()
        for first in range(start, stop, group):
            sinks = ([self.total] if direct else
                     [BinnedSink(self.total.spawn()) if binned else self.total.spawn()
                      for _ in range(min(group, stop - first))])
            rngs = [streams(first + k) for k in range(len(sinks))]
            t1 = time.perf_counter()
            run_replicas(transport, sinks, rngs, bar.update if bar is not None else None)
            t2 = time.perf_counter()
            for sink in sinks:
                if binned:
                    if sink.holds_fine():
                        self.total.merge(sink.fine)
                    self.tracer_binned += sink.binned_rows
                    self.tracer_outside += sink.outside
                elif not direct:
                    self.total.merge(sink)
                sums.add(sink.binned_total(self.n_channels))
            del sinks
            self.seconds["transport"] += t2 - t1
            self.seconds["binning"] += time.perf_counter() - t2

    def error(self) -> float:
        """The Monte Carlo part of the error estimate of the mean (0 for a deterministic run)."""
        if not self.monte_carlo:
            return 0.0
        return combined_error(self._mc_parts(), self.config.error.confidence)

    def transported(self) -> Transported:
        """The mean of the replicas run so far, binned."""
        t0 = time.perf_counter()
        r = max(self.count, 1)
        binned, outside = self.total.binned(copy=False), self.total.outside()
        if len(self.tracer_binned):                # the tracer's binned deposits
            binned, outside = binned + self.tracer_binned, outside + self.tracer_outside
        binned = binned.reshape(len(self.names), self.n_channels, -1)
        outside = outside.reshape(len(self.names), self.n_channels)
        if self.tracer is not None:                # the tracer's component over its own replica count
            runs = np.full(len(self.names), float(r))
            runs[self.tracer.components] = max(self.tracer_sums.count, 1)
            binned, outside = binned / runs[:, None, None], outside / runs[:, None]
        elif r > 1:                                # one replica (every deterministic run): no full-size copy
            binned, outside = binned / r, outside / r
        self.seconds["binning"] += time.perf_counter() - t0
        return Transported(self.names, binned, outside, self.transport, self.plan, dict(self.seconds))

    def refinement_error(self, tr: Transported, rng: np.random.Generator) -> float | None:
        """A deterministic estimator's error from its coarser setting (registry ``refine``): ‖P(h) − P(2h)‖ /
        (2^order − 1) relative to the envelope, P the primary (no Monte Carlo secondary, whose noise the replicas
        measure, nor the direct first bounce). The estimator's own coarse sums (``transport.coarse``: the
        quadrature's rule at 2h from the same evaluations, or its rule at h/2 on a sub-scan when
        ``transport.coarse_ratio`` is 0.5: then ‖P(h) − P(h/2)‖ / (1 − 2^−order)) are used when it has them, else a
        coarse run. None for Monte Carlo estimators."""
        if self.entry.refine is None:
            return None
        t0 = time.perf_counter()
        keep = [i for i, n in enumerate(tr.names) if n not in ("secondary", "first_bounce", COMPONENT)]
        coarse_acc = getattr(self.transport, "coarse", None)
        channels = slice(None)
        ratio = 2.0                                # the compared rule's edge over the result's (h/2: 0.5)
        if coarse_acc is not None:                 # holds the coarse primary only, per channel (some channels)
            ratio = getattr(self.transport, "coarse_ratio", 2.0)
            channels = getattr(self.transport, "coarse_channels", slice(None))
            coarse_p = coarse_acc.binned_total(self.n_channels, channels)
        else:
            no_secondary = {"secondary": "none", "effects": {**self.replica_config.effects, "secondary": False},
                            "orders": None}          # the primary only (no pilot: the plan's residual is counted)
            coarse_cfg = self.replica_config.with_estimator(**self.entry.refine(self.replica_config.estimator))
            coarse_cfg = coarse_cfg.model_copy(update=no_secondary)
            coarse = run_transport(self.scene, coarse_cfg, rng)
            coarse_p = coarse.binned[[i for i, n in enumerate(coarse.names)
                                      if n not in ("secondary", "first_bounce")]].sum(axis=0)
        self.seconds["refinement"] = time.perf_counter() - t0
        fine_p = tr.binned[keep][:, channels].sum(axis=0)         # the compared channels only (same sums)
        scale = tr.binned[:, channels].sum(axis=0)
        return relative_difference(fine_p, coarse_p, scale) / abs(ratio ** self.entry.order - 1.0)

    @property
    def smoothing(self):
        """The tracer's time smoothing (:class:`~datagen.transport.multibounce.smoothing.SmoothingBands`), or None
        when no orders are smoothed."""
        return self.tracer.smoothing if self.tracer is not None else None

    def smoothing_error(self, envelope: np.ndarray) -> float:
        """The smoothing's bias over the tracer's runs relative to ``envelope`` (n_channels, n_bins), the mean of
        every component, on the error measure's bins (only when :attr:`smoothing` is not None)."""
        factor = RICHARDSON if self.config.error.confidence is None else RICHARDSON_KINK   # an estimate / a bound
        halves = self.smoothing.bias_halves(self.config.time.edges, factor)
        if halves is not None:                  # two independent halves: the bias's norm without their noise
            return relative_cross(*halves, envelope)
        bias = self.smoothing.bias(self.config.time.edges, max(self.tracer_sums.count, 1), factor)
        return relative_difference(bias, np.zeros_like(bias), envelope)

    def omitted_error(self) -> float:
        """The share of the in-window energy that the orders left out carry (the planner's pilot), or 0."""
        orders = self.plan.decisions.get("multibounce")
        return orders.choice.residual if orders is not None else 0.0

    def fixed_error(self) -> float:
        """The parts of the error estimate that more replicas do not bring down, in quadrature: the orders left out
        and the deep orders' smoothing bias (relative to the replicas' mean envelope)."""
        smoothing = self._mean_smoothing_error() if self.smoothing is not None else 0.0
        return float(np.hypot(self.omitted_error(), smoothing))

    def _mean_smoothing_error(self) -> float:
        """:meth:`smoothing_error` relative to the replicas' mean envelope, computed once per state of the runs (the
        tolerance loops ask for it twice a round, :meth:`narrow_smoothing` and :meth:`fixed_error`; on a 32 × 32
        scan it takes 80 ms)."""
        key = (id(self.tracer), self.tracer_sums.count, self.sums.count)
        if self._smoothing_key != key:
            self._smoothing_key = key
            self._smoothing_value = self.smoothing_error(self.sums.mean() + self.tracer_sums.mean())
        return self._smoothing_value

    def error_attrs(self, tr: Transported, rng: np.random.Generator) -> dict:
        """``attrs["error"]`` of the result: the estimate (relative L2 of the envelope over bins above 1 % of its
        peak), its parts and how it was made."""
        mc = self.error()
        refined = self.refinement_error(tr, rng)
        omitted = self.omitted_error()
        smoothing = self.smoothing_error(tr.binned.sum(axis=0)) if self.smoothing is not None else None
        # in quadrature; hypot(x, 0) is x to the bit, so results without the new terms keep their old estimate
        total = float(np.hypot(np.hypot(mc, refined or 0.0), np.hypot(omitted, smoothing or 0.0)))
        q = self.config.error.confidence
        describe = self.entry.describe or (lambda opts: opts.kind)
        setting = describe(self.replica_config.estimator)
        parts = []
        tracer = (f"{self.tracer_sums.count} of the order ≥ {self.tracer.settings.min_order} tracer "
                  f"({self.tracer.settings.paths} light paths per laser point each)") if self.tracer is not None else ""
        if self.monte_carlo:
            base = f"{self.count} independent replicas ({setting} each)" if self.base_monte_carlo else ""
            parts.append("standard error of the mean of " + " and of ".join(p for p in (base, tracer) if p))
            if q is not None:
                parts[-1] += (f", times √F_{q:g}(d, ν) = {self.confidence_factor():.3g}: a {q:.0%} upper bound "
                              "(docs/accuracy.md)")
        if refined is not None:
            half = (getattr(self.transport, "coarse", None) is not None
                    and getattr(self.transport, "coarse_ratio", 2.0) < 1)
            parts.append(f"edge refinement ‖E(h) − E(h/2)‖/(1 − 2^−{self.entry.order}) on a sub-scan" if half else
                         f"edge refinement ‖E(h) − E(2h)‖/{2 ** self.entry.order - 1}")
            parts[-1] += f" of the primary ({setting})"
        if smoothing is not None:
            factor = "4/3" if q is None else "2"
            parts.append(f"the estimated bias of the deep orders' time smoothing (L(Δ) − L(Δ/2))·{factor} (the even "
                         "runs' against the odd runs': without their noise)")
        if omitted:
            parts.append(f"the share {omitted:.3g} of the in-window energy that the orders left out carry (the "
                         "planner's pilot, docs/planner.md)")
        return {"rel_l2": total, "monte_carlo": mc, "refinement": refined, "omitted_orders": omitted,
                "smoothing": smoothing, "confidence": q if self.monte_carlo else None,
                "replicas": self.count, "replica_setting": setting,
                **({"tracer_replicas": self.tracer_sums.count} if self.tracer is not None else {}),
                "method": " and ".join(parts) + "; relative L2 over bins above 1 % of the peak"}


@one_blas_thread()
def simulate(scene: Scene, config: SimulationConfig | None = None, progress: bool = False,
             sampling_rng: np.random.Generator | None = None,
             noise_rng: np.random.Generator | None = None) -> Result:
    """Simulate the envelope and a SPAD histogram for ``scene``, with an estimate of the envelope's error.

    A Monte Carlo estimator runs as ``config.error.replicas`` independent replicas that share its sampling (their
    mean is the envelope; :class:`Replicas`); the quadrature runs once and estimates its error from a coarser
    edge. ``attrs["error"]["rel_l2"]`` is the estimated relative L2 error of the envelope over bins above 1 %
    of its peak (:mod:`datagen.simulation.replicas`).

    Args:
        scene: the scene (see :func:`datagen.load_scene`).
        config: sampling, time axis, IRF and detector; default: the scene's ``simulation`` block.
        progress: show a tqdm bar over the estimator's work.
        sampling_rng, noise_rng: the scene-sampling and detector-noise streams; default
            ``stream_rng(config.seed, STREAM_SAMPLING)`` and ``stream_rng(config.seed, STREAM_NOISE)``. Dataset
            builds pass streams keyed by (dataset seed, split, index, stream) (docs/physics.md §7).
    Returns:
        :class:`Result`.
    Raises:
        SceneError: invalid scene (laser spot off every surface, FoV sees no surface, …); ConfigError: invalid
            config (a detector setting the noise model cannot draw, …).
    """
    return simulate_runs(scene, config, progress, sampling_rng, noise_rng)[0]


def simulate_runs(scene: Scene, config: SimulationConfig | None = None, progress: bool = False,
                  sampling_rng: np.random.Generator | None = None,
                  noise_rng: np.random.Generator | None = None) -> tuple[Result, Replicas]:
    """:func:`simulate`, also returning its :class:`Replicas` (their effect plan and the tracer's light paths, which a
    capture sequence's changes follow: :mod:`datagen.simulation.sequence`)."""
    config = config or resolve_config(scene)
    t0 = time.perf_counter()
    rng = sampling_rng if sampling_rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    runs = Replicas(scene, config, rng)
    runs.run(config.error.replicas, progress)
    tr = runs.transported()
    return make_result(scene, config, tr, noise_rng, t0, {"error": runs.error_attrs(tr, rng)}), runs
