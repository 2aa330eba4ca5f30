"""Light of order ≥ 3: a transient light tracer from the laser spot with next-event connections to the FoV.

A path's *order* is its number of hidden vertices (docs/physics.md §2, "Orders"): the laser spot and the FoV
point are not counted, a relay-wall vertex between hidden vertices is. Orders 1 and 2 are the estimators' primary
and secondary; this module adds every order from ``min_order`` (3) up, as the component ``multibounce``.

The estimator (docs/physics.md §2, "Light of every order"; docs/accuracy.md for its cost):

- **Light paths.** Each path starts at laser point x_l with a cosine-weighted direction (density cosθ_l/π), so
  its flux is Φ f_l(ω_e, ω) π / N per path of N (:func:`~datagen.transport.physics.launched_flux` of
  :meth:`LegPhysics.spot_emission <datagen.transport.physics.LegPhysics.spot_emission>` over the density). At every hidden vertex x_k the next
  direction is cosine-weighted about the normal on the side the light arrives from, the flux is multiplied by
  f(ω_in, ω_out) π (the BRDF over the cosine density) and divided by the survival probability q = min(1, ρ) of
  Russian roulette (ρ the material's albedo: a Lambertian path keeps its flux and survives with probability ρ).
  Roulette is unbiased. Every surface takes part, the relay wall included. A retroreflective vertex samples its
  BRDF instead: its lobe with probability k_s (:func:`~datagen.scene.brdf_kernel.retro_sample`), a cosine direction
  otherwise, the flux × f cosθ / (q p) over that mixture's density p, and every balance-heuristic density below
  that holds the continuation's cosθ/π holds p instead (the factor s = p π / cosθ,
  :func:`~datagen.scene.brdf_kernel.sampling_ratio`, exactly 1 for the other kinds). This step runs in one compiled
  pass (:func:`~datagen.transport.multibounce.kernels.continue_paths`).
- **Termination** is exact and bounded: every impulse of a vertex x, or of any later vertex of its path, arrives
  after the vertex's counted length plus at least x's distance to the FoV rectangle
  (:meth:`~datagen.scene.capture.Capture.fov_distance`: the legs that remain are at least that long) plus the
  shortest FoV → sensor leg d_min (:meth:`~datagen.scene.capture.Capture.fov_sensor_distance`, when that leg
  counts). A path whose vertex is later than c·t_follow by that sum can add nothing inside the window and stops
  there, t_follow being the window's end plus the reach of the smoothing's kernels and of the IRF; a path also
  stops when its ray leaves the scene or roulette ends it. In a closed room of albedo 1 every path ends at the window's end:
  the work is bounded by N × (window length × c / mean free path) vertices.
- **Next-event connections** at every vertex of order k ≥ ``min_order``: one point y per sensor pixel region,
  uniform in it (density p_a = 1/A_pixel), with a shadow ray x→y, weighted by the FoV leg
  cosθ_y / r² · collection(y) (:func:`~datagen.transport.physics.fov_connection_weight`,
  :meth:`LegPhysics.sensor_collection`) times the vertex's radiant intensity flux · f(ω_in, ω_y) cosθ_x.
- **Direction hits** (aperture captures): the continuation ray of a vertex of order k ≥ ``min_order`` that lands
  on a FoV pixel region is a second strategy for the same path (density q cosθ_x cosθ_y/(π r²) in area
  measure, × s at a retroreflective vertex). Both are combined by the balance heuristic (Veach & Guibas 1995), as the area sampler's FoV
  connections are: the weight stays bounded next to the FoV, where the area strategy alone has G ~ 1/r².
  Point-radiance captures connect to the sensor points only (points cannot be hit).
- **Eye vertices** (aperture captures, :mod:`.eye`): per path one hidden vertex z sampled from the FoV's side (a
  uniform point of a recorded pixel region, a cosine direction into the room; drawn when the path reaches the first
  vertex that uses it); every light vertex of order ≥ max(1, ``min_order`` − 1) is joined to z by a shadow ray, a
  path one order higher. It is the third strategy of the same paths under the same balance heuristic: it samples
  the FoV leg's 1/r² where next-event connections only weigh it (vertices near the relay wall); what it saves,
  measured: docs/accuracy.md.
- **Time smoothing** of the deep orders (:mod:`~datagen.transport.multibounce.smoothing`): their impulses are
  linearly binned on nodes Δ apart and deposited as tents, Δ growing with the order (the tail of deeper orders is
  smoother) and with the tolerance (Δ ∝ √tolerance keeps the bias a fixed fraction of it); across a confocal
  scan's points too. The bias is estimated from the same impulses at half the width (Richardson) and counted in
  the stated error; at tolerances of 1 % and below its smooth part is subtracted first.
- **Scans**: the paths of every laser point are traced in shared batches, each vertex connecting to the pixel
  regions its own laser point records (a confocal point: its own).
- **Time and attenuation**: each impulse arrives at (switched laser leg + hidden legs + r + switched sensor
  leg)/c (:meth:`LegPhysics.laser_leg`, :meth:`LegPhysics.sensor_leg`) and weighs e^{−μ·physical path}
  (:meth:`LegPhysics.attenuation`), as every other estimator's paths.

Every leg weight comes from :mod:`datagen.transport.physics`; what differs from the area sampler is only how the
vertices are sampled (by following the light instead of by area).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ...errors import ConfigError
from ...sampling import square_to_hemisphere
from ...sampling.directions import to_world
from ...scene import RayCaster
from ...scene.brdf_kernel import on_arrays
from ...scene.capture import Capture
from ...units import SPEED_OF_LIGHT
from ...vectors import dot
from ..base import Counters, Sink
from ..leg_kernels import material_arrays, sensor_collection
from ..physics import LegPhysics, geometry_weight, launched_flux
from .eye import EYE_MIN_ORDER, EyeVertices, PixelTable, eye_share, eye_vertices
from .kernels import arrive, continue_paths, eye_pairs, eye_weights, fov_targets_ranged, nee_weights, survivors
from .onset import earliest_arrival
from .smoothing import SmoothingBands

MULTIBOUNCE_STREAM = 57
"""The spawn-key entry of the tracer's random stream, appended to the run's :class:`numpy.random.SeedSequence`
(so that orders 1–2 draw exactly what they draw without it, whatever order the two run in)."""

EYE_UNIFORMS = 5
"""Uniforms one eye vertex takes (:func:`~.eye.eye_vertices`): its pixel region, the point in it (2), the direction
(2)."""

MAX_VERTICES = 10_000
"""Safety bound on the vertices of one path (a path in a closed albedo-1 room stops at the window's end first:
at ~1 m mean free path a 1 µs window holds ~300 vertices)."""


@dataclass(frozen=True)
class MultibounceSettings:
    """Settings of the order ≥ 3 light tracer (:class:`MultibounceTracer`).

    Attributes:
        paths: N, light paths per run and laser point (≥ 1).
        min_order: the lowest order deposited (3: orders 1 and 2 are the estimators' primary and secondary).
        max_order: the highest order deposited, or 0 for every order (paths then end by roulette, by leaving the
            scene or at the window's end).
        batch: paths traced together (memory: ~1 kB per path).
        smooth_order: orders from this one up are deposited smoothed in time (0: none; see
            :class:`~.smoothing.SmoothingBands`); smooth_width: Δ, the node spacing of the lowest smoothed orders, seconds;
            smooth_max_width: the widest node spacing of the deeper orders, seconds (= smooth_width: one Δ for all);
            smooth_scan: h, the half-width in scan pitches of the smoothing across a confocal scan's points (0 or 1:
            none; see :class:`~.smoothing.DeepSmoothing`); smooth_narrow: n, the lowest band's node spacing divided by
            2ⁿ (the tolerance loop narrows it when its bias is too large, ``Replicas.narrow_smoothing``);
            smooth_correct: subtract the smooth part of the estimated bias (:func:`~.smoothing.smoothed_correction`).
        eye: aperture captures: also join every light vertex to one vertex sampled from the FoV's side per path
            (:mod:`.eye`; False: next-event connections and direction hits only, as a check of the strategy).
        aligned: every path of a batch draws its random numbers from its own slot of fixed-size draws (each bounce
            draws for all the batch's paths, dead or alive), so that two scenes that differ in one object trace the
            paths that never meet it identically (common random numbers: capture sequences, docs/motion.md); False:
            draws for the live paths only (cheaper at deep orders). Aperture captures (a point-radiance capture's
            connections are drawn per laser point either way).

    Raises:
        ConfigError: a field out of range (the message names it and the value).
    """

    paths: int = 8192
    min_order: int = 3
    max_order: int = 0
    batch: int = 32768
    smooth_order: int = 0
    smooth_width: float = 1e-9
    smooth_max_width: float = 1e-9
    smooth_scan: int = 0
    smooth_narrow: int = 0
    smooth_correct: bool = False
    eye: bool = True
    aligned: bool = False

    def __post_init__(self):
        for name in ("smooth_width", "smooth_max_width"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"multibounce tracer: {name} must be > 0 seconds, got {v!r}")
        if self.smooth_max_width < self.smooth_width:
            raise ConfigError(f"multibounce tracer: smooth_max_width {self.smooth_max_width!r} s is below smooth_width "
                              f"{self.smooth_width!r} s")
        for name, low in (("paths", 1), ("min_order", 1), ("max_order", 0), ("batch", 1), ("smooth_order", 0),
                          ("smooth_scan", 0), ("smooth_narrow", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ConfigError(f"multibounce tracer: {name} must be an integer >= {low}, got {v!r}")
        for name in ("eye", "smooth_correct"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigError(f"multibounce tracer: {name} must be true or false, got {getattr(self, name)!r}")
        if self.max_order and self.max_order < self.min_order:
            raise ConfigError(f"multibounce tracer: max_order {self.max_order} is below min_order {self.min_order}")


@dataclass
class MultibounceStats(Counters):
    """Counters of tracer runs (``add`` merges replicas): paths started, vertices reached, steps (one per order and
    batch: a ray cast for every path still alive), next-event connections (to FoV points and to eye vertices), direction
    hits on the FoV, eye rays (one per path of an aperture capture, :mod:`.eye`), and paths ended by roulette, by
    escaping, by the window's end."""

    paths: int = 0
    steps: int = 0
    vertices: int = 0
    connections: int = 0
    fov_hits: int = 0
    eye_rays: int = 0
    roulette: int = 0
    escaped: int = 0
    window: int = 0


ORDER_TALLY = 16
"""Orders tallied one by one in :attr:`MultibounceTracer.order_energy` (the last entry holds every higher order)."""


def tracer_rng(rng: np.random.Generator) -> np.random.Generator:
    """The tracer's own stream, derived from ``rng``'s seed sequence without drawing from ``rng`` (spawn key +
    (:data:`MULTIBOUNCE_STREAM`,)); a generator without one gives a child seeded from it."""
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if isinstance(seq, np.random.SeedSequence):
        return np.random.default_rng(np.random.SeedSequence(seq.entropy,
                                                            spawn_key=tuple(seq.spawn_key) + (MULTIBOUNCE_STREAM,)))
    return np.random.default_rng(rng.integers(0, 2 ** 63))


class MultibounceTracer:
    """Light of order ≥ ``min_order`` by light tracing from the laser spot (module docstring).

    Args:
        capture: the resolved capture; caster: the scene's ray caster; physics: the leg weights
            (:class:`~datagen.transport.physics.LegPhysics`) of the estimator it runs beside (same switches).
        settings: :class:`MultibounceSettings`.
        component: the sink component id of ``multibounce`` (impulses go to ``component * n_channels + channel``).
        window: (t_start, t_stop) of the time axis, s (paths stop once no impulse of theirs can reach it: module
            docstring, "Termination").
        secondary_component: the sink component id of order 2 when ``min_order`` is 2 (the tracer then carries the
            secondary of an estimator that runs without one: docs/physics.md §2, "Light of every order").
        irf_reach: how much earlier than an impulse the IRF spreads its light, s (``Irf.support[0]``): impulses
            that late past the window's end still reach it (0: the in-window tallies only, as the planner's pilot).
    Attributes:
        stats: :class:`MultibounceStats`.
        order_energy: (:data:`ORDER_TALLY`,) float64, the weight deposited inside the window by order (index k−1
            for order k; the last entry holds every higher order), summed over runs: photons per pulse over all
            runs (divide by the runs for their mean).
        order_time: (:data:`ORDER_TALLY`,) float64, the same impulses' Σ weight × arrival time (photon-seconds):
            ``order_time / order_energy`` is each order's mean arrival time in the window.
    """

    def __init__(self, capture: Capture, caster: RayCaster, physics: LegPhysics, settings: MultibounceSettings,
                 component: int, window: tuple[float, float], secondary_component: int | None = None,
                 irf_reach: float = 0.0):
        self.capture, self.caster, self.physics, self.settings = capture, caster, physics, settings
        self.irf_reach = float(irf_reach)
        self.component = int(component)
        self.secondary_component = int(secondary_component) if secondary_component is not None else None
        self.t_start, self.t_stop = float(window[0]), float(window[1])
        self.order_energy = np.zeros(ORDER_TALLY)
        self.order_time = np.zeros(ORDER_TALLY)
        scan = ((capture.fov_pixels[1], capture.fov_pixels[0], settings.smooth_scan)
                if capture.kind == "confocal" and capture.n_channels == capture.n_pixels and settings.smooth_scan > 1
                else None)
        # the smoothing's kernels stay after the earliest time any light reaches each channel (causal, .onset;
        # computed once per capture)
        self.onset = earliest_arrival(capture, caster, physics) if settings.smooth_order else None
        self.smoothing = (SmoothingBands(settings.smooth_order, settings.smooth_width, settings.smooth_max_width,
                                         self.t_start, self.t_stop, capture.n_channels, scan, settings.smooth_narrow,
                                         settings.smooth_correct, self.onset)
                          if settings.smooth_order else None)
        # paths are followed as long as an impulse can still reach the window: past its end by the smoothing's reach
        # (the kernels near the end receive the mass from beyond it that they spread into the window) and the
        # IRF's; and every impulse arrives at least the shortest FoV → sensor leg after its vertex's counted length
        self.t_follow = self.t_stop + (self.smoothing.margin if self.smoothing is not None else 0.0) + self.irf_reach
        self.min_tail = float(physics.sensor_leg(capture.fov_sensor_distance()))
        # no surface point lies farther from the FoV than the farthest mesh vertex (the distance is convex)
        self._far_fov = float(capture.fov_distance(caster.vertices).max()) if len(caster.vertices) else 0.0
        albedo = physics.materials.albedo
        self.survival = np.minimum(1.0, albedo)                   # q per object: Russian roulette
        self._mat = material_arrays(physics)
        self._fov_object = np.zeros(len(albedo), dtype=bool)     # per object id: may hold FoV points
        self._fov_object[np.asarray(physics.fov_objects, dtype=np.int64)] = True
        # the FoV's pixel regions (aperture captures): one uniform target in each recorded one per vertex
        pixel_area = capture.pixel_area() if capture.n_pixels else 0.0
        self.pixels = PixelTable(*self._recorded_pixels(), pixel_area)
        self._p_a = 1.0 / self.pixels.area if self.pixels.area > 0 else 0.0
        self._fov = (capture.fov_center, capture.fov_u, capture.fov_v, capture.fov_normal,
                     np.asarray(capture.fov_size, dtype=np.float64), np.asarray(capture.fov_pixels, dtype=np.float64))
        self.stats = MultibounceStats()
        self._eye_on = bool(settings.eye) and capture.convention == "aperture" and self.pixels.max_count > 0

    def _eye_serves(self, order: int) -> bool:
        """Whether paths of order ``order`` have the eye-vertex strategy (:mod:`.eye`)."""
        s = self.settings
        return self._eye_on and order >= max(EYE_MIN_ORDER, s.min_order) and not (s.max_order and order > s.max_order)

    def narrowed(self) -> "MultibounceTracer":
        """A fresh tracer (no runs) with the same settings but the lowest smoothing band's node spacing halved."""
        settings = replace(self.settings, smooth_narrow=self.settings.smooth_narrow + 1)
        return build_tracer(self.capture, self.caster, self.physics, settings, window=(self.t_start, self.t_stop),
                            component=self.component, secondary_component=self.secondary_component,
                            irf_reach=self.irf_reach)

    @property
    def components(self) -> list[int]:
        """The sink component ids this tracer deposits into (``multibounce``, and order 2's when it carries it)."""
        both = [self.component] + ([self.secondary_component] if self.secondary_component is not None else [])
        return list(dict.fromkeys(both))              # (one when order 2 alone goes into the secondary)

    def progress_total(self) -> tuple[int, str]:
        """Light paths over all laser points."""
        return self.settings.paths * self.capture.n_lasers, "path"

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from every laser point and send the impulses of order ≥ ``min_order`` to
        ``sink``. ``rng`` is used as given (callers pass :func:`tracer_rng` of their stream)."""
        self.run_lasers(sink, rng, np.arange(self.capture.n_lasers), progress)
        if self.smoothing is not None:
            self.smoothing.flush(sink, self.component, self.secondary_component)

    def run_laser(self, sink: Sink, rng: np.random.Generator, laser: int,
                  progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from laser point ``laser`` only (the planner's pilot)."""
        self.run_lasers(sink, rng, np.array([laser]), progress)

    def run_lasers(self, sink: Sink, rng: np.random.Generator, lasers: np.ndarray,
                   progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from each laser point of ``lasers`` (k,) int, in batches of ``batch`` paths
        that mix laser points (a scan's thousands of points share every array pass and ray cast)."""
        s = self.settings
        lasers = np.asarray(lasers, dtype=np.int64)
        total = s.paths * len(lasers)
        for start in range(0, total, s.batch):
            n = min(s.batch, total - start)
            self._trace(lasers[np.arange(start, start + n) // s.paths], sink, rng)
            if progress is not None:
                progress(n)

    def _recorded_pixels(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The pixel regions each laser point records, as ranges of one table: (first (n_lasers,) int64, count
        (n_lasers,) int64, pixel column (T,) int64, pixel row (T,) int64, pixel index (T,) int64). A confocal
        capture records pixel l from laser point l; every other kind records the same pixels from every point."""
        c = self.capture
        pix = np.arange(c.n_pixels)
        if c.kind == "confocal":
            first = np.minimum(np.arange(c.n_lasers), c.n_pixels)
            count = (np.arange(c.n_lasers) < c.n_pixels).astype(np.int64)
        else:
            pix = pix[c.channel(0, pix) >= 0]
            first, count = np.zeros(c.n_lasers, np.int64), np.full(c.n_lasers, len(pix), np.int64)
        iy, ix = np.divmod(pix, c.fov_pixels[0])
        return (first.astype(np.int64), count, ix.astype(np.int64), iy.astype(np.int64), pix.astype(np.int64))

    # -- one batch of paths ------------------------------------------------------------------------------------

    def _trace(self, laser: np.ndarray, sink: Sink, rng: np.random.Generator) -> None:
        """One batch: light paths from laser points ``laser`` (n,) int (one entry per path)."""
        c, cst, ph, s = self.capture, self.caster, self.physics, self.settings
        n = len(laser)
        self.stats.paths += n
        ids = np.arange(n) if s.aligned else None        # each live path's slot in the batch's draws
        normal = c.spot_normals[laser]
        local, _ = square_to_hemisphere(rng.random(n), rng.random(n), "cosine")
        w = to_world(local, normal)
        pdf = local[:, 2] / np.pi                                  # cosine-weighted directions, 1/sr
        flux = np.zeros(n)
        ok = pdf > 0
        # Φ/N per path: N paths per laser point over all batches
        flux[ok] = on_arrays(launched_flux)(c.photons / s.paths, ph.spot_emission(w[ok], laser[ok]), pdf[ok])
        origin = c.spots[laser] + cst.offset * normal
        counted = np.zeros(n) + ph.laser_leg(laser)              # metres of the path that count in the time
        physical = c.emitter_legs[laser].astype(np.float64)     # metres of physical path (attenuation)
        ray_origin, ray_dir, src_normal = origin, w, normal
        q_prev = np.ones(n)                                      # survival probability of the ray just cast
        cos_src = local[:, 2]                                    # cosine of the ray just cast at its source
        eye, pid = None, None       # the eye vertices, drawn for the paths that reach their first use; each path's row
        p_in = np.ones(n)                                        # the light's area density of the current vertex
        order = 0
        # metres of counted path that can still reach it (a FoV hit may lie up to the tolerance outside the rectangle)
        limit = SPEED_OF_LIGHT * self.t_follow - self.min_tail + ph.tol
        fov = (np.asarray(c.fov_center, dtype=np.float64), np.asarray(c.fov_u, dtype=np.float64),
               np.asarray(c.fov_v, dtype=np.float64), 0.5 * c.fov_extent[0], 0.5 * c.fov_extent[1])
        no_pid = np.zeros(0, np.int64)
        while len(flux) and order < MAX_VERTICES:
            self.stats.steps += 1
            hits = cst.intersect(ray_origin, ray_dir)
            if order >= s.min_order:                            # the ray left a vertex of order ≥ min_order
                self._fov_hits(hits, ray_origin, ray_dir, flux, counted, physical, q_prev, src_normal, laser, sink,
                               order, p_in)
            order += 1
            # the vertices that an impulse of theirs, or of a later vertex, can still bring into the window: every
            # such impulse crosses at least the vertex's distance to the FoV (checked for the vertices within the
            # farthest surface point's distance of the end only)
            (keep, x, n_x, w_in, obj, laser, pid, flux, counted, physical, d, p_in, escaped, late) = arrive(
                hits.hit, hits.distance, hits.points, hits.normals, hits.object_id.astype(np.int64, copy=False),
                np.ascontiguousarray(ray_dir), counted, physical, flux, laser, pid if pid is not None else no_pid,
                q_prev, cos_src, limit, self._far_fov, fov)
            self.stats.escaped += escaped
            self.stats.window += late
            ids = ids[keep] if ids is not None else None
            if s.max_order and order > s.max_order:
                break
            pid = pid if eye is not None else None              # (no eye vertices yet: no rows)
            self.stats.vertices += len(keep)
            if order >= s.min_order and len(keep):
                self._connect(x, n_x, obj, w_in, flux, counted, physical, laser, sink, rng, order, p_in, (ids, n))
            if self._eye_serves(order + 1) and len(keep):
                if eye is None:
                    u = rng.random((n, EYE_UNIFORMS))[ids] if ids is not None else None
                    eye, pid = eye_vertices(c, cst, ph, self.pixels, laser, rng, u), np.arange(len(keep))
                    self.stats.eye_rays += len(keep)
                self._connect_eye(x, n_x, obj, w_in, flux, counted, physical, laser, eye, pid, sink, order + 1)
            # continue: the material's direction sampler (cosine about n_x but for retroreflective lobes), flux × f π /
            # (q s), roulette with q = min(1, ρ); q_prev carries q s, s the direction's density over the cosine density
            m = len(keep)
            if ids is None:
                u, v, r = rng.random(m), rng.random(m), rng.random(m)
            else:
                u, v, r = rng.random((3, n))[:, ids]
            w_out, flux, live, ratio = continue_paths(n_x, obj, w_in, u, v, r, flux, self.survival, self._mat)
            (flux, counted, physical, laser, pid_next, p_in, src_normal, q_prev, ray_origin, ray_dir, cos_src,
             roulette) = survivors(live, r, self.survival, obj, x, n_x, w_out, flux, counted, physical, laser,
                                   pid if pid is not None else no_pid, p_in, cst.offset, ratio)
            pid = pid_next if pid is not None else None
            ids = ids[live] if ids is not None else None
            self.stats.roulette += roulette

    def _connect(self, x: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_in: np.ndarray, flux: np.ndarray,
                 counted: np.ndarray, physical: np.ndarray, laser: np.ndarray, sink: Sink,
                 rng: np.random.Generator, order: int, p_in: np.ndarray,
                 slots: tuple[np.ndarray | None, int] = (None, 0)) -> None:
        """Next-event connections of vertices x (m, 3) (normals n_x facing the incoming light; paths from laser
        points ``laser`` (m,) int) to one uniform point per pixel region that their laser point records
        (aperture) or to the sensor points (point radiance), with their MIS weights. ``slots``: (each vertex's slot
        (m,) int64 in draws for n paths, n) when the draws are aligned (:attr:`MultibounceSettings.aligned`)."""
        c, ph = self.capture, self.physics
        if c.convention != "aperture":                            # sensor points: the shared connection
            for one in np.unique(laser):                          # one laser point per call
                rows = laser == one
                self._connect_points(x[rows], n_x[rows], obj[rows], w_in[rows], flux[rows], counted[rows],
                                     physical[rows], int(one), sink, rng, order)
            return
        # one uniform point per recorded pixel region and vertex (density p_a = 1/A_pixel): compiled target
        # geometry (the area sampler's, over each laser point's own pixel regions) and sensor collection, a shadow
        # ray x → y
        first, count = self.pixels.first[laser], self.pixels.count[laser]
        ids, n = slots
        points = c.region_offsets(rng.random((len(x), self.pixels.max_count, 2)) if ids is None
                                  else rng.random((n, self.pixels.max_count, 2))[ids])
        b, s_idx, y, wk, r, cos_y = fov_targets_ranged(np.ascontiguousarray(x), np.ascontiguousarray(n_x), first,
                                                       count, self.pixels.ix, self.pixels.iy, points, self._fov)
        vis = self.caster.visible(x[b], n_x[b], y, c.fov_normal)
        ph.stats.shadow_rays += len(b)
        b, s_idx, y, wk, r, cos_y = b[vis], s_idx[vis], y[vis], wk[vis], r[vis], cos_y[vis]
        if not len(b):
            return
        collect, d_ys = sensor_collection(ph, y, np.broadcast_to(c.fov_normal, y.shape),
                                          np.full(len(b), ph.wall_object), -wk)
        # radiant intensity flux f cosθ_x toward y, times the FoV leg cosθ_y dA_y / r² · collection (A2, A3), under
        # the balance heuristic with the direction hits (and the eye): one compiled pass
        weight, t, path = nee_weights((b, wk, r, cos_y, collect, d_ys), obj, n_x, w_in, flux, counted, physical,
                                      count, p_in, self.survival, self._mat,
                                      (self.pixels.area, self._p_a, self._eye_serves(order), ph.settings.count_sensor_leg))
        weight = weight * ph.attenuation(path)
        self.stats.connections += len(b)
        self._deposit(sink, t, weight, c.channel(laser[b], self.pixels.pix[s_idx]), order)

    def _connect_points(self, x: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_in: np.ndarray, flux: np.ndarray,
                        counted: np.ndarray, physical: np.ndarray, laser: int, sink: Sink, rng: np.random.Generator,
                        order: int) -> None:
        """Point-radiance captures: next-event connections of vertices of laser point ``laser`` to the sensor
        points (:meth:`LegPhysics.connect`)."""
        ph = self.physics
        conn = ph.connect(x, n_x, laser, rng, (1, 1))
        if not len(conn.b):
            return
        b, wk = conn.b, conn.direction
        weight = flux[b] * ph.brdf(obj[b], n_x[b], w_in[b], wk) * dot(n_x[b], wk) * conn.weight
        self.stats.connections += len(b)
        self._deposit(sink, (counted[b] / SPEED_OF_LIGHT) + conn.time,
                      weight * ph.attenuation(physical[b] + conn.phys), conn.channel, order)

    def _fov_hits(self, hits, origin: np.ndarray, direction: np.ndarray, flux: np.ndarray, counted: np.ndarray,
                  physical: np.ndarray, q: np.ndarray, n_x: np.ndarray, laser: np.ndarray, sink: Sink,
                  order: int, p_in: np.ndarray) -> None:
        """Continuation rays (flux already × f π / (q s)) that land on a FoV pixel region: the direction strategy of
        the FoV connection, weighted by the balance heuristic against :meth:`_connect`'s area strategy (``q``: the
        rays' q s, :func:`~datagen.transport.multibounce.kernels.survivors`)."""
        c, ph = self.capture, self.physics
        if c.convention != "aperture":
            return
        on_wall = np.flatnonzero(hits.hit & self._fov_object[hits.object_id])   # only these can be in the FoV
        chan = c.points_channel(laser[on_wall], hits.points[on_wall], ph.tol)
        idx = on_wall[chan >= 0]
        chan = chan[chan >= 0]
        if not len(idx):
            return
        y, wk, r = hits.points[idx], direction[idx], hits.distance[idx]
        n_y = hits.normals[idx]
        collect, d_ys = sensor_collection(ph, y, n_y, np.full(len(idx), ph.wall_object), -wk)
        cos_x = dot(n_x[idx], wk)
        cos_y = -dot(wk, c.fov_normal)
        p_a = c.pixel_density()
        g = geometry_weight(cos_x, cos_y, r) / np.pi
        p_d = q[idx] * g
        p_e = (on_arrays(eye_share)(p_a, g, self.pixels.count[laser[idx]], p_in[idx]) if self._eye_serves(order)
               else 0.0)
        weight = flux[idx] * collect * (p_d / (p_a + p_d + p_e))
        weight = weight * ph.attenuation(physical[idx] + r + d_ys)
        self.stats.fov_hits += len(idx)
        self._deposit(sink, (counted[idx] + r + ph.sensor_leg(d_ys)) / SPEED_OF_LIGHT, weight, chan, order)

    def _connect_eye(self, x: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_in: np.ndarray, flux: np.ndarray,
                     counted: np.ndarray, physical: np.ndarray, laser: np.ndarray, eye: EyeVertices, pid: np.ndarray,
                     sink: Sink, order: int) -> None:
        """Join light vertices x (m, 3) (order ``order`` − 1) to their paths' eye vertices (rows ``pid`` of ``eye``):
        paths of order ``order`` under the balance heuristic with the next-event and direction-hit strategies
        (:mod:`.eye`)."""
        ph = self.physics
        rows, w, d, cos_x, cos_z = eye_pairs(np.ascontiguousarray(x), np.ascontiguousarray(n_x), pid, eye.z,
                                             eye.n_z, eye.ok)
        if not len(rows):
            return
        e = pid[rows]
        vis = self.caster.visible(x[rows], n_x[rows], eye.z[e], eye.n_z[e])
        ph.stats.shadow_rays += len(rows)
        rows, e, w, d, cos_x, cos_z = rows[vis], e[vis], w[vis], d[vis], cos_x[vis], cos_z[vis]
        if not len(rows):
            return
        weight, t, path = eye_weights(rows, w, d, cos_x, cos_z, obj, n_x, w_in, flux, counted, physical, pid,
                                      (eye.obj, eye.n_z, eye.w_zy, eye.g, eye.n_rec, eye.fov, eye.r, eye.d_ys),
                                      self.survival, self._mat, (self._p_a, ph.settings.count_sensor_leg))
        weight = weight * ph.attenuation(path)
        self.stats.connections += len(rows)
        self._deposit(sink, t, weight, self.capture.channel(laser[rows], self.pixels.pix[eye.row[e]]), order)

    def _deposit(self, sink: Sink, t: np.ndarray, weight: np.ndarray, channel: np.ndarray, order: int) -> None:
        """Send impulses of paths of order ``order`` to ``sink`` and tally their in-window weight."""
        inside = (t >= self.t_start) & (t < self.t_stop)
        k = min(order, ORDER_TALLY) - 1
        self.order_energy[k] += float(weight[inside].sum())
        self.order_time[k] += float(np.dot(weight[inside], t[inside]))
        band = self.smoothing.band(order) if self.smoothing is not None else None
        if band is not None:
            near = band.covers(t)
            band.add(t[near], weight[near], channel[near])
            t, weight, channel = t[~near], weight[~near], channel[~near]
        component = self.secondary_component if order == 2 and self.secondary_component is not None \
            else self.component
        if len(t):
            sink.add(t, weight, component * self.capture.n_channels + channel)



def build_tracer(capture: Capture, caster: RayCaster, physics: LegPhysics, settings: MultibounceSettings, *,
                 window: tuple[float, float], component: int = 0, secondary_component: int | None = None,
                 irf_reach: float = 0.0) -> MultibounceTracer:
    """The one constructor of the light tracer: every site builds it here (the planner's pilot, a run beside its
    estimator through :func:`~datagen.transport.multibounce.orders.beside`, the converged reference, a narrowed
    smoothing); ``tests/test_architecture.py`` fails on a second. Arguments as :class:`MultibounceTracer`'s;
    ``component`` 0 and no IRF reach suit a tally that no sink keeps (the pilot)."""
    return MultibounceTracer(capture, caster, physics, settings, component, window, secondary_component, irf_reach)