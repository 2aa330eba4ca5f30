"""The lookin estimator: the paper's sampler of the transient path integral (docs/physics.md §3).

Scholes & Leach 2024 (Sensors 24(20):6522) sample the hidden scene from the laser spot: N rays ("lookins")
from the spot on a √N×√N stratified grid over the hemisphere give N hidden points x_j, each with a 180°
camera of l×p equal-area pixels whose hits are the *observed points*. Observed points in the sensor's FoV
close the primary path spot → x_j → y → sensor; pairs of observed points make the secondary
(:mod:`datagen.transport.lookin.secondary`). With ``sensor_sampling="connect"`` the lookins connect to the FoV by
next-event estimation instead (forced for point-radiance captures).

Weights come from :mod:`datagen.transport.physics`. The paper's factors map to them per leg:

- **A1** (spot → lookin, Γ₁ α₁ B₁ / R_j²): lookins are sampled by *direction* ω_j with pdf p(ω_j), and a
  point reached through dω has dA = R² dω / cosθ, so the 1/R_j² cancels: a lookin carries
  W_j = Φ·f_l(ω_e, ω_j)·cosθ_l / (N·p(ω_j)) photons (:meth:`LegPhysics.spot_emission`; α₁ → 1/(N·p)).
- **A2** (lookin → observed point, Γ_j α_j B_j / (R_k^o)²): the pixel of solid angle Ω = 2π/(l·p) carries
  W_j·f_j(ω_in, ω_k)·cosθ_k·Ω photons to the observed point; again the 1/R² cancels and α_j → Ω.
- **A3/A4** (FoV point → sensor, Γ β B / (R^s)² and the aperture term π f²/f_no²):
  :meth:`LegPhysics.sensor_collection`, with A_ap = π r_ap² (r_ap = f/(2 f_no)); β is unity.
- C_atm = e^{−μ·path} (:meth:`LegPhysics.attenuation`); q is the PDE.

Primary and full / exact secondary are consistent: they converge to the path integral as N and l×p grow
(tests compare against the independent oracle of :mod:`datagen.analysis.oracle`). Work is split into fixed
batches of lookins with their own random streams, so results are bit-identical for any number of workers.
"""
from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, fields, replace
from typing import Any, Callable, ClassVar, Literal

import multiprocessing as mp
import numpy as np
from pydantic import Field, field_validator

from ...sampling import observe, sample_lookins
from ...sampling.lookins import Lookins, ObservedPoints
from ...scene import RayCaster, Scene, resolve_capture
from ...scene.capture import Capture, FOV_PLANE_TOL
from ...scene.materials import MaterialTable
from ...processes import set_parent_death_signal
from ...units import SPEED_OF_LIGHT, parse_grid
from ...vectors import dot
from ..base import Connections, Counters, EstimatorOptions, Sink, register, sink_far_time
from ..physics import LegPhysics, PhysicsSettings
from .secondary import ConvGrid, LookinSecondary

SecondaryMode = Literal["none", "optimized", "full", "exact"]


@dataclass(frozen=True)
class LookinSettings(PhysicsSettings):
    """Settings of the lookin estimator (the user side is :class:`datagen.simulation.SimulationConfig`).

    The physics switches (attenuation, pde, leg switches, shadow rays, first bounce, BRDF angles, blockers)
    are those of :class:`~datagen.transport.physics.PhysicsSettings`, which this class extends.

    Attributes:
        lookins: (n_u, n_v) lookin grid; pixels: (l, p) camera resolution.
        lookin_pdf: "cosine" or "uniform" hemisphere sampling at the spot.
        jitter: stratified jitter (True) or cell centres (False).
        secondary: "none" | "optimized" | "full" | "exact"; top_k: kept k' per (lookin, FoV point) when
            optimized.
        sensor_sampling: "camera" (the paper: FoV points are the lookin cameras' observed points) or
            "connect" (next-event connection from each lookin to ``connect_samples`` stratified points per
            sensor pixel region, or to each sensor point for point radiance).
        connect_samples: (n_u, n_v) stratified points per pixel region for ``connect``.
        dark_middle: add the secondary paths whose middle vertex the laser does not light (next-event
            connections from the lookins' observed points in laser shadow; :meth:`LookinSecondary.dark_middle`)
            to the full and exact secondaries. Off reproduces the paper's estimator, which misses them; the
            optimized (top-K) secondary, an approximation by design, never adds them.
        conv_refine: the exact secondary bins its time profiles this many times finer than the envelope's
            fine grid before convolving (its only approximation; error ~ (step/feature width)²).
        batch: lookins per random stream and unit of work of ``workers`` (each is processed in slices of
            ``CACHE_RAYS`` camera rays).
        workers: processes sharing the lookin batches (results do not depend on it).
    """

    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    secondary: SecondaryMode = "full"
    top_k: int = 1
    sensor_sampling: Literal["camera", "connect"] = "camera"
    connect_samples: tuple[int, int] = (4, 4)
    dark_middle: bool = True
    conv_refine: int = 1
    batch: int = 32
    workers: int = 1

    @classmethod
    def from_transport(cls, settings: PhysicsSettings, **kwargs) -> "LookinSettings":
        """``settings`` (lookin settings) with the fields ``kwargs`` replaced; the same call as the other
        estimators' settings classes (:attr:`datagen.transport.base.EstimatorEntry.settings_class`)."""
        return replace(settings, **kwargs)


@dataclass
class LookinStats(Counters):
    """Counters from a transport run (recorded in the result attributes).

    ``secondary_pairs`` counts the secondary pairs a run represents (the exact secondary sums them by convolution);
    the work :meth:`LookinSampler.nominal_seconds` weighs is ``sink_nodes`` (fine-grid nodes × components of each
    replica's sink: spawned, merged and binned), ``slices`` (array passes of at most ``CACHE_RAYS`` camera rays),
    ``camera_rays``, ``shadow_rays``, ``secondary_lookins`` (lookins whose lit observed points the secondary pairs
    with the FoV), ``pairs_summed`` (pairs weighed one by one: full, optimized before its top-k, dark middle, the
    exact secondary's lobes) and of those ``glossy_pairs`` (a non-Lambertian middle vertex) and ``ranked_pairs``
    (ranked for the optimized top-k)."""

    lookins_cast: int = 0
    lookins_hit: int = 0
    observed_points: int = 0
    fov_points: int = 0
    lit_points: int = 0
    shadow_rays: int = 0
    dark_points: int = 0
    secondary_pairs: int = 0
    sink_nodes: int = 0
    slices: int = 0
    camera_rays: int = 0
    secondary_lookins: int = 0
    pairs_summed: int = 0
    glossy_pairs: int = 0
    ranked_pairs: int = 0


CACHE_RAYS = 1 << 15
"""Camera rays processed together inside a batch: ~30k rays keep the slice's (rays, 3) float64 arrays within
a 2 MiB L2 cache (the choice and its measurement: docs/performance_history.md)."""

NOMINAL_SECONDS = {"sink_nodes": 1.8e-8, "slices": 1.0e-3, "camera_rays": 2.1e-7, "shadow_rays": 5.3e-7,
                   "secondary_lookins": 1.2e-4, "pairs_summed": 1.1e-8, "glossy_pairs": 1.4e-7, "ranked_pairs": 9.4e-9}
"""Seconds of one core per counted unit of :class:`LookinStats` (:meth:`LookinSampler.nominal_seconds`): a
non-negative least-squares fit (relative errors) of the CPU time of 72 runs of replicas (``python
benchmarks/fit_nominal.py lookin``: the demo, office and closed-corridor rooms and three smoke-dataset rooms with a
12 ns window; 1×1 to 8×8 lookins a replica, 16×16 to 60×60 pixels, secondary none, full, optimized and exact; 6 to
400 replicas, 0.12–6.1 s a run) on the shared 2-core machine: relative residual 14 % RMS, worst 50 % (the office
room's Phong pairs). The lookin counts and the exact secondary's convolutions took rate 0 and are left out."""

_WORKER: dict = {}


def _worker_init(transport: "LookinSampler") -> None:
    set_parent_death_signal()     # a fork worker dies with the process that forked it (no orphans after kill -9)
    _WORKER["transport"] = transport  # queries the BVH committed before the fork (RayCaster.commit)


def _worker_batch(args):
    return _WORKER["transport"]._run_batch(*args)


class LookinOptions(EstimatorOptions):
    """The lookin estimator's settings (``estimator: {kind: lookin, ...}`` in a simulation config).

    Attributes:
        lookins, pixels: lookin grid √N×√N and camera l×p ("10x10", "60x60" are the paper's).
        lookin_pdf: hemisphere sampling at the spot ("cosine" or "uniform").
        jitter: stratified jitter of lookin rays and camera pixels (False: the paper's regular grids).
        top_k: secondary "optimized" (paper §4): the strongest ``top_k`` per lookin and FoV point.
        sensor_sampling: "camera" (the paper: FoV points from the lookin cameras) or "connect" (next-event
            connections to ``connect_samples`` stratified points per sensor pixel; forced for point radiance).
        conv_refine: the exact secondary's profile grid is this many times finer than the envelope's grid.
        batch: lookins per batch (memory bound).
    """

    kind: Literal["lookin"] = "lookin"
    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    top_k: int = Field(1, ge=1)
    sensor_sampling: Literal["camera", "connect"] = "camera"
    connect_samples: tuple[int, int] = (4, 4)
    conv_refine: int = Field(1, ge=1, le=64)
    batch: int = Field(32, ge=1)

    LEGACY: ClassVar[dict[str, str]] = {k: k for k in ("lookins", "pixels", "lookin_pdf", "jitter", "top_k",
                                                       "sensor_sampling", "connect_samples", "conv_refine", "batch")}

    @field_validator("lookins", "pixels", "connect_samples", mode="before")
    @classmethod
    def _grid(cls, value: Any, info) -> tuple[int, int]:
        return parse_grid(value, info.field_name)

    def transport_fields(self) -> dict:
        """These options as :class:`LookinSettings` fields (every field but ``kind``)."""
        return self.model_dump(exclude={"kind"})

    def replica(self, replicas: int) -> dict:
        """One of ``replicas`` independent runs: each side of the lookin grid divided by √R (rounded, at least
        1), the camera unchanged."""
        side = np.sqrt(replicas)
        return {"lookins": tuple(max(1, int(round(n / side))) for n in self.lookins)}

    def describe(self) -> str:
        return f"lookins {'x'.join(map(str, self.lookins))}, pixels {'x'.join(map(str, self.pixels))}"


LOOKIN_BYTES = 400
"""Bytes per lookin ray: direction, hit point, normal, pdf, distance, object id and the ray caster's buffers
(about 20 float64 values with temporaries)."""

CAMERA_RAY_BYTES = 1000
"""Bytes per camera ray of one slice (observed point, normal, direction, distance, ids, FoV connection, laser
light, secondary partners; about 100 float64 values with temporaries)."""

SECONDARY_PAIR_BYTES = 8
"""Bytes per (pixels per lookin)² of the full and optimized secondaries, which form every (lit point, FoV point)
pair of a lookin at once: 2× the 3.9 bytes measured on the demo room (peak RSS above the same run without the
secondary: +66 MB at 60×60 pixels, +790 MB at 120×120, 3×3 lookins)."""


def _lookin_memory(scene: Scene, config, lasers: int, sensors: int) -> list[tuple[str, str, float]]:
    """(field, value, bytes) of the lookin grid of every laser point, the camera rays of one slice per worker
    and the full / optimized secondary's pairs
    (:attr:`EstimatorEntry.memory <datagen.transport.base.EstimatorEntry>`)."""
    workers, opts = max(1, config.workers), config.estimator
    n_lookins, n_pixels = math.prod(opts.lookins), math.prod(opts.pixels)
    pixels = "x".join(map(str, opts.pixels))
    terms = [("estimator.lookins", "x".join(map(str, opts.lookins)), float(LOOKIN_BYTES) * n_lookins * lasers),
             ("estimator.pixels", pixels, float(CAMERA_RAY_BYTES) * max(n_pixels, CACHE_RAYS) * workers)]
    if config.secondary in ("full", "optimized"):
        terms.append(("estimator.pixels", f"{pixels} (secondary {config.secondary}: pairs)",
                      float(SECONDARY_PAIR_BYTES) * n_pixels ** 2 * workers))
    return terms


@register("lookin", LookinSettings,
          "the paper's sampler: lookins from the laser spot and their hemispherical cameras",
          options=LookinOptions, replica=LookinOptions.replica, describe=LookinOptions.describe,
          memory=_lookin_memory, casts_lookins=True)
class LookinSampler:
    """Runs the lookin estimator over a scene and sends impulses to a sink (module doc).

    Component ids sent to the sink: ``component * n_channels + channel`` where component indexes
    ``scene.component_names()`` for primary paths (by the object the lookin hit), then
    ``len(scene.component_names())`` for secondary paths and, when ``first_bounce`` is on, one more for the
    direct laser-spot return (:attr:`component_names`).

    Attributes:
        capture: the resolved capture; settings: :class:`LookinSettings`; physics: the
        :class:`~datagen.transport.physics.LegPhysics` that weighs every leg; stats: :class:`LookinStats`;
        secondary_paths: the :class:`~datagen.transport.lookin.secondary.LookinSecondary` computing the secondary.

    Raises:
        SceneError: the capture errors of :func:`datagen.scene.resolve_capture`.
    """

    def __init__(self, scene: Scene, settings: LookinSettings, caster: RayCaster | None = None,
                 capture: Capture | None = None):
        self.scene = scene
        self.settings = settings
        self.caster = caster or RayCaster(scene)
        self.capture = capture if capture is not None else resolve_capture(scene, self.caster)
        self.materials: MaterialTable = scene.materials
        self.object_component = scene.object_component()
        self.n_primary = len(scene.component_names())
        self.stats = LookinStats()
        self.physics = LegPhysics(scene, self.capture, self.caster, settings, self.stats)
        self.secondary_paths = LookinSecondary(self.capture, settings, self.physics, self.caster, self.materials,
                                               self.n_primary)
        self.configure(settings)

    @classmethod
    def from_config(cls, scene: Scene, config, physics: PhysicsSettings, caster: RayCaster,
                    capture: Capture | None, secondary: SecondaryMode) -> "LookinSampler":
        """The registry's constructor (:attr:`datagen.transport.base.EstimatorEntry.from_config`): lookin settings with
        every field of the planned ``physics`` (all planned switches and both blocker lists), the sampling of
        ``config.estimator`` (:class:`LookinOptions`), the ``secondary`` mode the plan keeps and
        ``config.workers``. The lookins are visible from the spot by construction, so its spot shadow rays are
        the secondary's alone, as the planner's ``shadow_spot`` decision assumes: it follows every decision."""
        planned = {f.name: getattr(physics, f.name) for f in fields(PhysicsSettings)}
        settings = LookinSettings(**planned, **config.estimator.transport_fields(), secondary=secondary,
                                     workers=config.workers)
        return cls(scene, settings, caster, capture)

    @property
    def sensor_sampling(self) -> str:
        """How the FoV is reached: "camera" (the paper's hemispherical cameras) or "connect" (next-event)."""
        return self.settings.sensor_sampling

    def nominal_seconds(self) -> float:
        """A deterministic measure of the work done so far (runs and replicas summed), in seconds of one core of
        the reference machine: the counters of :class:`LookinStats` at the rates ``NOMINAL_SECONDS``. Dataset
        builds cap the adaptive sampling with it (``cost_cap``), so that the cap, unlike a wall clock, never
        depends on the machine's load."""
        st = vars(self.stats)
        return float(sum(rate * st[key] for key, rate in NOMINAL_SECONDS.items()))

    def progress_total(self) -> tuple[int, str]:
        """Lookins cast over all laser points."""
        return self.settings.lookins[0] * self.settings.lookins[1] * self.capture.n_lasers, "lookin"

    def configure(self, settings: LookinSettings) -> None:
        """Replace the settings (e.g. after the effect planner); point radiance forces ``connect``."""
        if self.capture.convention == "point_radiance" and settings.sensor_sampling != "connect":
            settings = replace(settings, sensor_sampling="connect")
        self.settings = settings
        self.component_names = self.scene.component_names() + ["secondary"] + (
            ["first_bounce"] if settings.first_bounce else [])
        self.physics.configure(settings)
        self.secondary_paths.configure(settings)

    # -- estimator ---------------------------------------------------------------------------------------

    def lookins(self, rng: np.random.Generator | None, laser: int = 0) -> Lookins:
        s, c = self.settings, self.capture
        return sample_lookins(self.caster, c.spots[laser], c.spot_normals[laser], s.lookins, s.lookin_pdf, rng)

    def needs_camera(self) -> bool:
        return self.settings.sensor_sampling == "camera" or self.settings.secondary != "none"

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Sample lookins and observed points and send every primary (and secondary) impulse to ``sink``.

        Work is split into fixed batches of ``settings.batch`` lookins, each with its own random stream
        (from ``rng``) and its own partial sums, merged in batch order: the result is bit-identical whatever
        ``settings.workers``. With ``workers > 1`` and a sink that can ``spawn`` partial accumulators
        (:class:`~datagen.timing.EnvelopeAccumulator`), batches run in worker processes.
        """
        self.run_replicas([sink], [rng], progress)

    def run_replicas(self, sinks: list[Sink], rngs: list[np.random.Generator],
                     progress: Callable[[int], None] | None = None) -> None:
        """Independent runs into ``sinks``, one per generator of ``rngs`` (:func:`datagen.transport.base.run_replicas`),
        each as :meth:`run` does it; the batches of every replica share one pool of ``workers`` processes."""
        s, c = self.settings, self.capture
        convs = [self.secondary_paths.conv_grid(sink) if s.secondary == "exact" else None for sink in sinks]
        tasks = []
        for replica, rng in enumerate(rngs):
            root = np.random.SeedSequence(int(rng.integers(0, 2 ** 63)))
            self.stats.sink_nodes += getattr(sinks[replica], "n_fine", 0) * getattr(sinks[replica], "n_components", 0)
            for laser in range(c.n_lasers):
                look_rng = np.random.default_rng(root.spawn(1)[0]) if s.jitter else None
                look = self.lookins(look_rng, laser)
                self.stats.lookins_cast += look.n_rays
                idx = np.flatnonzero(look.hit)
                self.stats.lookins_hit += len(idx)
                for start in range(0, len(idx), s.batch):
                    sel = idx[start:start + s.batch]
                    tasks.append((replica, (laser, look.n_rays, look.directions[sel], look.pdf[sel], look.points[sel],
                                            look.normals[sel], look.object_id[sel], look.distance[sel],
                                            root.spawn(1)[0] if s.jitter else None)))
        spawns = [getattr(sink, "spawn", None) for sink in sinks]
        parallel = s.workers > 1 and all(sp is not None for sp in spawns) and len(tasks) > 1
        results = self._map(tasks, spawns, convs, parallel, sinks)
        for (replica, task), (partial, partial_conv, stats) in zip(tasks, results):
            if partial is not None:
                sinks[replica].merge(partial)
            if partial_conv is not None:
                convs[replica].merge(partial_conv)
            self.stats.add(stats)
            if progress is not None:
                progress(len(task[2]))
        for sink, conv in zip(sinks, convs):
            if s.first_bounce:
                self.physics.first_bounce(sink, self.n_primary + 1)
            if conv is not None:
                conv.flush(sink, self.n_primary * c.n_channels, sink_far_time(sink))
        if progress is not None and not tasks:
            progress(0)

    def _map(self, tasks, spawns, convs, parallel, sinks):
        """Yield (partial sink, partial conv grid, stats) per (replica, batch) task, in task order."""
        if not parallel:
            for replica, task in tasks:
                part = spawns[replica]() if spawns[replica] is not None else None
                stats = LookinStats()
                part_conv = convs[replica].empty_like() if convs[replica] is not None else None
                self._batch(task, part if part is not None else sinks[replica], part_conv, stats)
                yield part, part_conv, stats
            return
        ctx = mp.get_context("fork")
        self.caster.commit()
        with ProcessPoolExecutor(self.settings.workers, mp_context=ctx, initializer=_worker_init,
                                 initargs=(self,)) as pool:
            futures = [pool.submit(_worker_batch, (task, spawns[replica](),
                                                   convs[replica].empty_like() if convs[replica] else None))
                       for replica, task in tasks]
            for fut in futures:
                yield fut.result()

    def _run_batch(self, task, part, part_conv):
        stats = LookinStats()
        self._batch(task, part, part_conv, stats)
        return part, part_conv, stats

    def _batch(self, task, sink: Sink, conv: ConvGrid | None, stats: LookinStats) -> None:
        """One batch of lookins (one random stream), in cache-sized slices of ``CACHE_RAYS`` camera rays."""
        (laser, n_rays, directions, pdf, x, n_x, obj_x, r_lx, seed) = task
        saved, self.physics.stats = self.physics.stats, stats
        try:
            rng = np.random.default_rng(seed) if seed is not None else None
            # the dark-middle connections draw from their own stream, so switching them on or off (full vs
            # optimized secondary) leaves the cameras' jitter, hence the primary, unchanged
            dark_rng = np.random.default_rng(np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key + (1,))) \
                if seed is not None else None
            step = max(1, CACHE_RAYS // (self.settings.pixels[0] * self.settings.pixels[1]))
            for start in range(0, len(x), step):
                sl = slice(start, start + step)
                self._lookin_slice(laser, n_rays, directions[sl], pdf[sl], x[sl], n_x[sl], obj_x[sl], r_lx[sl],
                                   rng, dark_rng, sink, conv, stats)
        finally:
            self.physics.stats = saved

    def _lookin_slice(self, laser, n_rays, directions, pdf, x, n_x, obj_x, r_lx, rng, dark_rng, sink,
                      conv, stats: LookinStats) -> None:
        c, s = self.capture, self.settings
        spot = c.spots[laser]
        w_to_spot = (spot - x) / r_lx[:, None]
        cos_x_l = np.maximum(dot(n_x, w_to_spot), 0.0)
        flux = c.photons * self.physics.spot_emission(directions, laser) / (n_rays * pdf)   # W_j, photons
        obs = observe(self.caster, x, n_x, s.pixels, rng) if self.needs_camera() else None
        stats.slices += 1
        if obs is not None:
            stats.camera_rays += obs.hit.size
            stats.observed_points += int(obs.hit.sum())
        out = self._camera_out(obs, laser) if s.sensor_sampling == "camera" else \
            self.physics.connect(x, n_x, laser, rng, s.connect_samples)
        stats.fov_points += len(out.b)
        laser_t = self.physics.laser_leg(laser) / SPEED_OF_LIGHT
        if len(out.b):
            b = out.b
            f = self.physics.brdf(obj_x[b], n_x[b], w_to_spot[b], out.direction)
            cos_k = np.maximum(dot(n_x[b], out.direction), 0.0)
            weight = flux[b] * f * cos_k * out.weight * self.physics.attenuation(
                c.emitter_legs[laser] + r_lx[b] + out.phys)
            comp = self.object_component[obj_x[b]] * c.n_channels + out.channel
            sink.add(laser_t + r_lx[b] / SPEED_OF_LIGHT + out.time, weight, comp)
        if s.secondary != "none" and len(out.b):
            paths = self.secondary_paths
            light = paths.spot_light(obs, laser, stats)
            paths.lit_middle(laser, n_rays, pdf, x, n_x, obj_x, r_lx, cos_x_l, obs, light, out, sink, conv, stats)
            if s.dark_middle and s.secondary != "optimized":     # the paper's top-K approximation stays as is
                paths.dark_middle(laser, flux, x, n_x, obj_x, r_lx, w_to_spot, obs, light, sink, dark_rng, stats)

    # -- sensor side -------------------------------------------------------------------------------------

    def _camera_out(self, obs: ObservedPoints, laser: int) -> Connections:
        """FoV points among the observed points (the paper's final bounce through the camera pixels)."""
        c = self.capture
        tol = FOV_PLANE_TOL * self.caster.offset
        obj = obs.object_id.ravel()
        fov_ids = self.physics.fov_objects
        flat = np.flatnonzero(obj == fov_ids[0] if len(fov_ids) == 1 else np.isin(obj, fov_ids))   # pre-filter
        pts = np.take(obs.points.reshape(-1, 3), flat, axis=0)
        n_y = np.take(obs.normals.reshape(-1, 3), flat, axis=0)
        ch = c.channel(laser, c.fov_pixel(pts, tol))
        keep = np.flatnonzero((ch >= 0) & (dot(n_y, c.sensor - pts) > 0))
        flat, ch, y, n_y = flat[keep], ch[keep], pts[keep], n_y[keep]
        direction = np.take(obs.directions.reshape(-1, 3), flat, axis=0)
        collect, d_ys = self.physics.sensor_collection(y, n_y, obj[flat], direction, -1.0)
        r = obs.distance.ravel()[flat]
        time = (r + self.physics.sensor_leg(d_ys)) / SPEED_OF_LIGHT
        # per unit radiant intensity toward ω_k the pixel carries Ω photons to y (the caller applies f·cos)
        return Connections(flat // obs.hit.shape[1], direction, obs.solid_angle * collect, time, r + d_ys, ch)

