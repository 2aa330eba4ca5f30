"""The converged reference every estimator is measured against.

:func:`converged_reference` is the reference every estimator is measured against (``datagen bench
accuracy``). It runs the hidden-surface area sampler (:mod:`datagen.transport.area`: area + laser-direction hidden
points, stratified FoV connections, MIS partners for the secondary) as independent *replicas*, replica i seeded
by ``SeedSequence(REFERENCE_SEED, spawn_key=(i,))``, and averages them. Its error estimate is the standard
error of that mean, put into the error measure of :func:`datagen.analysis.accuracy.envelope_error`:

    rel_l2 ≈ sqrt(Σ_b var(mean_b)) / ||mean||   over bins where the mean exceeds 1 % of its peak,
    total  ≈ sd(replica totals) / √R / |mean total|,    peak_time ≈ sd(replica peak times) / √R  (seconds).

Replicas are added until the rel_l2 estimate is below ``rel_tol`` (at least ``min_replicas``) or
``max_seconds`` is spent. The estimate covers the Monte Carlo error only: every replica is unbiased (tests
check it against closed forms), and binning is that of :class:`datagen.timing.EnvelopeAccumulator` at its default
oversample, as for the estimators (its splatting error on the demo room is 2e-5 relative L2). Nothing here uses
the lookin sampler. The running sums are cached on disk (``cache_dir``) under a hash of the scene and of every
config field that changes the envelope, so a later call with the same or a looser tolerance returns at once and
a tighter one resumes where the last stopped.

A config whose estimator is a deterministic rule refined by its edge (the quadrature of the scan configs) gets another
reference, since the area sampler
runs once per laser point and a scan's replica would outlast any budget: the quadrature at a quarter of the
config's edge, run once, its own error (its rule at 2h) added in quadrature to the replicas' spread, and the
light tracer, unsmoothed, for every order the config asks for beyond the quadrature's, its replicas on every core
(:func:`_quadrature_parts`; docs/accuracy.md, "The converged reference").

The brute-force oracle of the tests is :func:`datagen.analysis.oracle.primary_area_quadrature`.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..simulation.replicas import PEAK_FLOOR, relative_standard_error
from ..processes import ForkedCall
from ..transport import AreaSampler, AreaSettings, estimator
from ..transport.multibounce import MultibounceSettings
from ..transport.multibounce.orders import beside
from ..timing import EnvelopeAccumulator
from ..scene import RayCaster
from ..errors import ConfigError
from ..units import format_duration
from ..scene import Scene

__all__ = [
    "PEAK_FLOOR",
    "REFERENCE_SAMPLER",
    "REFERENCE_SAMPLES",
    "REFERENCE_SEED",
    "REFERENCE_POINT_SECONDS",
    "Reference",
    "check_reference_size",
    "converged_reference",
]

REFERENCE_VERSION = 2
"""Bumped whenever the reference estimator changes, so stale cache files are not reused."""

REFERENCE_SEED = 20240611
"""Default root seed of the reference replicas (replica i: SeedSequence(seed, spawn_key=(i,)))."""

REFERENCE_SAMPLER = {"spot_fraction": 0.5, "fov_fraction": 0.0, "fov_samples": (4, 4), "fov_directions": 2}
"""The reference's sampling strategies: hidden points by area and from the spot only (no FoV paths), 4×4 FoV
points and 2 cosine directions per point, i.e. the area sampler in the form validated against the closed forms
(tests/test_area.py). Estimators with the default :class:`~datagen.transport.AreaSettings` (FoV paths, 3×3 points) thus
share no importance-sampling choice with their reference beyond the per-leg physics."""

REFERENCE_SAMPLES = 1 << 17
"""Hidden samples per replica (per laser point): ~4 s on the demo room on one core, relative L2 ≈ 0.8 %."""

REFERENCE_POINT_SECONDS = 4.0
"""Rough compute of one reference replica per laser point at :data:`REFERENCE_SAMPLES` hidden samples, seconds
(2–5 s measured on the smoke, multizone and confocal rooms on the 2-core machine of docs/benchmarks.md). The area
sampler runs once per laser point and a replica cannot stop half-way, so a scan's replica outlasts any budget:
≈ 17 min for 16 × 16 points."""


def check_reference_size(scene: Scene, where: str, samples: int, budget: float) -> None:
    """Refuse a capture whose single reference replica is projected to outlast the whole ``budget``
    (``datagen bench accuracy``): laser points × :data:`REFERENCE_POINT_SECONDS` × samples / REFERENCE_SAMPLES.

    Args:
        scene: the scene to benchmark. where: what to name in the message (a file, or a dataset config's room).
        samples: hidden samples per replica and laser point. budget: the command's wall time, seconds.
    Raises:
        ConfigError: the projection exceeds ``budget``; the message names ``where``, the laser points, the
            projection and what to change (a larger budget, fewer samples, or for a scan
            ``--quadrature-reference``: :mod:`datagen.analysis.scan_accuracy`).
    """
    from ..scene import resolve_capture

    n = resolve_capture(scene, RayCaster(scene)).n_lasers
    replica = n * REFERENCE_POINT_SECONDS * samples / REFERENCE_SAMPLES
    if replica > budget:
        fits = int(REFERENCE_SAMPLES * budget / (n * REFERENCE_POINT_SECONDS))
        points = "laser point" if n == 1 else f"{n} laser points (the area sampler runs once per laser point)"
        scan = ("; or, for a scanned capture, --quadrature-reference (the quadrature against a quarter of its "
                "edge)") if n > 1 else ""
        raise ConfigError(
            f"{where}: one reference replica of its {points} takes ≈ {format_duration(replica)} and cannot stop "
            f"half-way, more than --budget {format_duration(budget)}: give --budget {format_duration(2 * replica)} "
            f"or more, or --reference-samples {fits} or fewer{scan}")



@dataclass(frozen=True)
class Reference:
    """A converged reference envelope and its own error estimate.

    Attributes:
        envelope: channel_shape + (n_bins,) float64, expected detected photons per pulse per bin (the shape of
            :attr:`datagen.simulation.Result.envelope`: (n_bins,) for the paper's single pixel).
        components: name → array like ``envelope`` (primary components, "secondary"[, "first_bounce"]).
        time_edges: (n_bins+1,) float64 seconds.
        error_estimate: {"rel_l2", "total" (relative), "peak_time" (s)}: standard errors of the mean.
        settings: the area sampler settings, replicas, rel_tol, cache key and file.
        seconds: compute time of all replicas (those loaded from the cache included).
        replicas: R; converged: the rel_l2 estimate met ``rel_tol``.
    """

    envelope: np.ndarray
    components: dict[str, np.ndarray]
    time_edges: np.ndarray
    error_estimate: dict[str, float]
    settings: dict
    seconds: float
    replicas: int
    converged: bool

    @property
    def time_centers(self) -> np.ndarray:
        return 0.5 * (self.time_edges[1:] + self.time_edges[:-1])


def peak_time(envelope: np.ndarray, time_edges: np.ndarray) -> float:
    """Time (s) of the maximum of the channel-summed ``envelope`` (..., n_bins), refined by the vertex of the
    parabola through the maximal bin and its neighbours (sub-bin resolution; bin centre at the window edges)."""
    y = np.asarray(envelope, dtype=np.float64).reshape(-1, np.shape(envelope)[-1]).sum(0)
    centers = 0.5 * (time_edges[1:] + time_edges[:-1])
    i = int(np.argmax(y))
    if 0 < i < len(y) - 1:
        a, b, c = y[i - 1], y[i], y[i + 1]
        den = a - 2 * b + c
        if den < 0:
            return float(centers[i] + 0.5 * (a - c) / den * (time_edges[1] - time_edges[0]))
    return float(centers[i])


def _scene_fingerprint(scene: Scene) -> dict:
    geo = hashlib.sha256()
    for arr in (scene.vertices, scene.faces, scene.face_object):
        geo.update(np.ascontiguousarray(arr).tobytes())
    capture = getattr(scene, "capture", None)
    return {"geometry": geo.hexdigest(),
            "materials": [o.material.model_dump(mode="json") for o in scene.objects],
            "labels": [[o.name, o.label] for o in scene.objects],
            "laser": scene.laser.model_dump(mode="json"), "sensor": scene.sensor.model_dump(mode="json"),
            "capture": capture.model_dump(mode="json") if capture is not None else None}


def reference_key(scene: Scene, config, settings: AreaSettings, seed: int = REFERENCE_SEED) -> str:
    """sha256 over the scene (geometry, materials, laser, sensor, capture), the config fields that change the
    envelope (time axis, IRF) and the sampler settings (which carry secondary on/off, μ, q, legs, shadows)."""
    data = {"version": REFERENCE_VERSION, "scene": _scene_fingerprint(scene),
            "time": config.time.model_dump(mode="json"), "irf": config.irf.model_dump(mode="json"),
            "settings": asdict(settings), "seed": seed}
    orders = config.orders_setting()
    if orders == "auto" or orders > 2:          # every order: another reference (orders 1–2 keys unchanged)
        data["orders"] = {"orders": "all" if orders == "auto" else orders,
                          "paths_per_sample": REFERENCE_PATHS_PER_SAMPLE}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


@dataclass
class _Sums:
    """Running sums over replicas (what the cache stores)."""

    comp: np.ndarray            # (n_components·n_channels, n_bins) Σ replica component envelopes
    env_sq: np.ndarray          # (n_channels, n_bins) Σ replica envelope²
    totals: list = field(default_factory=list)
    peaks: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def replicas(self) -> int:
        return len(self.totals)


def _load(path: Path, shape_comp, shape_env) -> _Sums | None:
    try:
        with np.load(path) as z:
            sums = _Sums(z["comp"], z["env_sq"], list(z["totals"]), list(z["peaks"]), float(z["seconds"]))
    except (OSError, KeyError, ValueError):
        return None
    if sums.comp.shape != shape_comp or sums.env_sq.shape != shape_env:
        return None
    return sums


def _save(path: Path, sums: _Sums, meta: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp.npz")
    np.savez(tmp, comp=sums.comp, env_sq=sums.env_sq, totals=np.asarray(sums.totals, dtype=np.float64),
             peaks=np.asarray(sums.peaks, dtype=np.float64), seconds=sums.seconds, meta=json.dumps(meta))
    os.replace(tmp, path)


REFERENCE_PATHS_PER_SAMPLE = 4
"""Light paths of the order ≥ 3 tracer per hidden sample of a reference replica."""


def all_orders(sampler: AreaSampler, config, samples: int):
    """``sampler``, or the sampler with the order ≥ 3 tracer beside it (unsmoothed) when ``config.orders`` asks for
    more than two orders ("auto": every order)."""
    orders = config.orders_setting()
    if orders != "auto" and orders <= 2:
        return sampler
    settings = MultibounceSettings(paths=REFERENCE_PATHS_PER_SAMPLE * samples,
                                   max_order=0 if orders == "auto" else int(orders))
    return beside(sampler, settings, (config.time.t_start, config.time.t_stop), config.irf.support[0])


QUADRATURE_REFERENCE_EDGE = 4
"""A quadrature config's reference runs the quadrature at 1/this of the config's edge (its grading with it)."""

REFERENCE_SCAN_PATHS = 1024
"""Light paths per laser point of one replica of a quadrature config's reference tracer (unsmoothed)."""


@dataclass
class _Fixed:
    """The deterministic part of a quadrature config's reference: its accumulator (added to every replica) and the
    component names of the runs."""

    sink: EnvelopeAccumulator
    names: list


def _quadrature_parts(scene: Scene, config, rel_tol: float):
    """The reference of a quadrature config (the scan configs): the quadrature at 1/:data:`QUADRATURE_REFERENCE_EDGE`
    of the config's edge, run once, with its own error (its rule at 2h: ‖P(h) − P(2h)‖/3, relative to its
    envelope; a run at 2h when the rule has no coarse sums of its own), and the light tracer, unsmoothed, for
    every order the config asks for beyond the quadrature's (``orders: auto`` decided at ``rel_tol``: orders
    carrying more than a quarter of it are traced).

    Returns:
        (the tracer (or an estimator that adds nothing), :class:`_Fixed`, the refinement error, the settings that
        identify the reference)."""
    from ..simulation.replicas import relative_difference
    from ..simulation.run import prepare_transport

    est = config.estimator
    cfg = config.with_estimator(**est.at_edge(est.edge / QUADRATURE_REFERENCE_EDGE))
    cfg = cfg.model_copy(update={"effect_threshold": rel_tol, "multibounce": cfg.multibounce.model_copy(
        update={"smoothing": False, "paths": REFERENCE_SCAN_PATHS})})
    transport, _ = prepare_transport(scene, cfg)
    tracer = getattr(transport, "tracer", None)
    base = transport.base if tracer is not None else transport
    n_ch = transport.capture.n_channels
    sink = EnvelopeAccumulator(cfg.time, cfg.irf, len(transport.component_names) * n_ch)
    base.run(sink, np.random.default_rng(0))           # deterministic: the quadrature without its secondary
    coarse = getattr(base, "coarse", None)           # its rule at 2h from the same evaluations, else a run at 2h
    if coarse is None:
        wide, _ = prepare_transport(scene, cfg.with_estimator(**cfg.estimator.at_edge(cfg.estimator.edge * 2)))
        coarse = EnvelopeAccumulator(cfg.time, cfg.irf, len(wide.component_names) * n_ch)
        (wide.base if getattr(wide, "tracer", None) is not None else wide).run(coarse, np.random.default_rng(0))
    fine = sink.binned_total(n_ch)
    refinement = relative_difference(fine, coarse.binned_total(n_ch), fine) / 3.0
    settings = {"sampler": "quadrature" + (" + tracer" if tracer is not None else ""),
                "estimator": cfg.estimator.model_dump(mode="json"),
                "tracer_paths": REFERENCE_SCAN_PATHS if tracer is not None else 0,
                "min_order": tracer.settings.min_order if tracer is not None else None}
    return (tracer if tracer is not None else _Nothing(transport)), _Fixed(sink, list(transport.component_names)), \
        refinement, settings


class _Nothing:
    """An estimator that adds nothing (a quadrature reference without orders beyond the quadrature's)."""

    def __init__(self, transport):
        self.capture, self.caster = transport.capture, transport.caster

    def run(self, sink, rng) -> None:
        pass


def _replicas_child(estimator, sinks: list, rngs: list) -> list:
    for sink, rng in zip(sinks, rngs):
        estimator.run(sink, rng)
    return sinks


def replicas_in_processes(estimator, sinks: list, rngs: list, workers: int) -> None:
    """Run ``estimator`` once per (sink, generator) pair, sink k in process k mod ``workers`` (this one and forked
    children, :class:`~datagen.processes.ForkedCall`, which query the BVH built before the fork); each sink ends
    filled exactly as by ``estimator.run(sink, rng)`` here."""
    if workers <= 1 or len(sinks) <= 1:
        for sink, rng in zip(sinks, rngs):
            estimator.run(sink, rng)
        return
    estimator.caster.commit()
    calls = {}
    try:
        for k in range(1, min(workers, len(sinks))):
            share = list(range(k, len(sinks), workers))
            calls[k] = (share, ForkedCall(_replicas_child, estimator, [sinks[r] for r in share], [rngs[r] for r in share]))
        for r in range(0, len(sinks), workers):
            estimator.run(sinks[r], rngs[r])
        for share, call in calls.values():
            for r, filled in zip(share, call.result()):
                sinks[r].merge(filled)
    finally:
        for _, call in calls.values():
            call.cancel()


def _estimate(sums: _Sums, n_components: int, n_channels: int, refinement: float | None = None
              ) -> tuple[np.ndarray, dict]:
    """The mean per component and the error estimate of the mean; ``refinement`` (a deterministic part's own
    error, relative) is added to rel_l2 in quadrature."""
    r = sums.replicas
    mean_comp = sums.comp / max(r, 1)
    mean = mean_comp.reshape(n_components, n_channels, -1).sum(0)
    if r < 2:
        return mean_comp, {"rel_l2": float("inf"), "total": float("inf"), "peak_time": float("inf")}
    var_mean = np.maximum(sums.env_sq / r - mean ** 2, 0.0) / (r - 1)
    totals = np.asarray(sums.totals)
    est = {"rel_l2": relative_standard_error(mean, var_mean) if mean.max() > 0 else float("inf"),
           "total": float(totals.std(ddof=1) / np.sqrt(r) / abs(totals.mean())) if totals.mean() else float("inf"),
           "peak_time": float(np.std(sums.peaks, ddof=1) / np.sqrt(r))}
    if refinement is not None:
        est["monte_carlo"], est["refinement"] = est["rel_l2"], refinement
        est["rel_l2"] = float(np.hypot(est["rel_l2"], refinement))
    return mean_comp, est


def converged_reference(scene: Scene, config=None, rel_tol: float = 1e-3, cache_dir: str | Path | None = None,
                        samples: int = REFERENCE_SAMPLES, max_seconds: float | None = None,
                        min_replicas: int = 8, max_replicas: int = 100_000,
                        progress: Callable[[int, dict], None] | None = None,
                        caster: RayCaster | None = None, seed: int = REFERENCE_SEED, workers: int | None = None,
                        **sampler) -> Reference:
    """Converged reference envelope of ``scene`` under ``config`` (see the module docstring).

    Args:
        scene: the scene. config: a :class:`datagen.simulation.SimulationConfig` (default: the scene's); its
            time axis, IRF, secondary on/off (any mode but "none" means the full secondary), attenuation, PDE,
            time-of-flight legs and forced effects are used; sampling settings (lookins, pixels) are not.
        rel_tol: target of the rel_l2 error estimate (0.1 % by default).
        cache_dir: directory of the cache files (None: no cache).
        samples: hidden samples per replica; ``sampler``: further :class:`datagen.transport.AreaSettings` fields.
        max_seconds: stop adding replicas after this much compute (the result then has converged=False and
            says what it reached); min_replicas / max_replicas: bounds on R.
        progress: called after each replica with (R, error estimate).
        seed: root seed of the replicas (independent references need different seeds).
        workers: processes running replicas at once (default: every core); the result does not depend on it.
    With ``config.orders`` "auto" or ≥ 3 the reference holds every order (or every order up to N): the light tracer
    of :mod:`datagen.transport.multibounce` beside the area sampler, :data:`REFERENCE_PATHS_PER_SAMPLE` paths per
    hidden sample, every order deposited as impulses (no time smoothing: unbiased), component ``multibounce``.
    A quadrature config: the quadrature at a quarter of its edge once, and the tracer's replicas
    (:data:`REFERENCE_SCAN_PATHS` paths per laser point each) beside it (module docstring); ``samples`` and
    ``sampler`` are not used, ``error_estimate`` adds ``monte_carlo`` and ``refinement``.
    Returns:
        :class:`Reference`.
    Raises:
        ConfigError: invalid scene, config or tolerances (rel_tol ≤ 0, min_replicas < 2).
    """
    from ..simulation import resolve_config

    if not (np.isfinite(rel_tol) and rel_tol > 0):
        raise ConfigError(f"converged_reference: rel_tol must be > 0, got {rel_tol!r}")
    if min_replicas < 2 or max_replicas < min_replicas:
        raise ConfigError(f"converged_reference: need 2 <= min_replicas <= max_replicas, got {min_replicas!r}, "
                         f"{max_replicas!r}")
    config = config or resolve_config(scene)
    fixed, refinement = None, None
    if estimator(config.estimator.kind).refine is not None:   # a deterministic rule (the scans' quadrature): once,
                                                              # and the tracer's replicas
        sampler_, fixed, refinement, settings = _quadrature_parts(scene, config, rel_tol)
        key = hashlib.sha256(json.dumps({"version": REFERENCE_VERSION, "scene": _scene_fingerprint(scene),
                                         "config": config.model_dump(mode="json", exclude={"replicas", "seed"}),
                                         "seed": seed, "parts": settings},
                                        sort_keys=True, default=str).encode()).hexdigest()
    else:
        settings = AreaSettings.from_transport(config.transport_settings(), samples=samples,
                                               **{**REFERENCE_SAMPLER, **sampler})
        caster = caster or RayCaster(scene)
        sampler_ = all_orders(AreaSampler(scene, settings, caster), config, samples)
        key = reference_key(scene, config, settings, seed)
        settings = {"sampler": "area", **asdict(settings)}
    names = sampler_.component_names if fixed is None else fixed.names
    cap = sampler_.capture
    n_comp, n_ch = len(names), cap.n_channels
    axis = config.time
    workers = max(1, min(int(workers if workers is not None else (os.cpu_count() or 1)), max_replicas))
    path = Path(cache_dir) / f"reference_{key[:24]}.npz" if cache_dir is not None else None
    shape_comp, shape_env = (n_comp * n_ch, axis.n_bins), (n_ch, axis.n_bins)
    sums = (_load(path, shape_comp, shape_env) if path is not None and path.is_file() else None) or \
        _Sums(np.zeros(shape_comp), np.zeros(shape_env))
    meta = {"key": key, "scene": scene.name, "settings": settings}
    start_seconds = sums.seconds
    t_start = time.perf_counter()
    mean_comp, est = _estimate(sums, n_comp, n_ch, refinement)
    while sums.replicas < max_replicas and (sums.replicas < min_replicas or est["rel_l2"] > rel_tol):
        if max_seconds is not None and time.perf_counter() - t_start >= max_seconds and sums.replicas >= 2:
            break
        t0 = time.perf_counter()
        batch = range(sums.replicas, min(sums.replicas + workers, max_replicas))   # one replica per core at once
        rngs = [np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(r,))) for r in batch]
        accs = [EnvelopeAccumulator(axis, config.irf, n_comp * n_ch) for _ in batch]
        replicas_in_processes(sampler_, accs, rngs, workers)
        for acc in accs:                                    # in replica order: the sums do not depend on workers
            if fixed is not None:
                acc.merge(fixed.sink)                       # the quadrature's deterministic part, in every replica
            binned = acc.binned()
            env = binned.reshape(n_comp, n_ch, -1).sum(0)
            sums.comp += binned
            sums.env_sq += env ** 2
            sums.totals.append(float(env.sum()))
            sums.peaks.append(peak_time(env, axis.edges))
        sums.seconds += (time.perf_counter() - t0) * min(workers, len(accs))    # CPU-seconds: wall × processes
        if path is not None:
            _save(path, sums, meta)
        mean_comp, est = _estimate(sums, n_comp, n_ch, refinement)
        if progress is not None:
            progress(sums.replicas, est)
    shape = cap.channel_shape() + (axis.n_bins,)
    per = mean_comp.reshape(n_comp, n_ch, -1)
    components = {name: per[i].reshape(shape) for i, name in enumerate(names)}
    envelope = per.sum(0).reshape(shape)
    converged = bool(est["rel_l2"] <= rel_tol)
    info = {**settings, "replicas": sums.replicas, "rel_tol": rel_tol, "seed": seed,
            "key": key, "cache_file": str(path) if path is not None else None,
            "seconds_this_call": time.perf_counter() - t_start, "seconds_cached": start_seconds}
    return Reference(envelope, components, axis.edges, est, info, sums.seconds, sums.replicas, converged)
