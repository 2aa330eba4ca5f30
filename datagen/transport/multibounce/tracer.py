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
  Roulette is unbiased. Every surface takes part, the relay wall included. This step runs in one compiled pass
  (:func:`~datagen.transport.multibounce.kernels.continue_paths`).
- **Termination** is exact and bounded: a path whose counted length already exceeds the window's end c·t_stop can
  add nothing inside the window (every further leg only adds time), so it stops there; a path also stops when
  its ray leaves the scene or roulette ends it. In a closed room of albedo 1 every path ends at the window's end:
  the work is bounded by N × (window length × c / mean free path) vertices.
- **Next-event connections** at every vertex of order k ≥ ``min_order``: one point y per sensor pixel region,
  uniform in it (density p_a = 1/A_pixel), with a shadow ray x→y, weighted by the FoV leg
  cosθ_y / r² · collection(y) (:func:`~datagen.transport.physics.fov_connection_weight`,
  :meth:`LegPhysics.sensor_collection`) times the vertex's radiant intensity flux · f(ω_in, ω_y) cosθ_x.
- **Direction hits** (aperture captures): the continuation ray of a vertex of order k ≥ ``min_order`` that lands
  on a FoV pixel region is a second strategy for the same path (density q cosθ_x cosθ_y/(π r²) in area
  measure). Both are combined by the balance heuristic (Veach & Guibas 1995), as the area sampler's FoV
  connections are: the weight stays bounded next to the FoV, where the area strategy alone has G ~ 1/r².
  Point-radiance captures connect to the sensor points only (points cannot be hit).
- **Time smoothing** of the deep orders (:class:`SmoothingBands`): their impulses are linearly binned on nodes Δ
  apart and deposited as tents, Δ growing with the order (the tail of deeper orders is smoother) and with the
  tolerance (Δ ∝ √tolerance keeps the bias a fixed fraction of it); the bias is estimated from the same impulses
  on nodes 2Δ apart (Richardson) and counted in the stated error.
- **Time and attenuation**: each impulse arrives at (switched laser leg + hidden legs + r + switched sensor
  leg)/c (:meth:`LegPhysics.laser_leg`, :meth:`LegPhysics.sensor_leg`) and weighs e^{−μ·physical path}
  (:meth:`LegPhysics.attenuation`), as every other estimator's paths.

Every leg weight comes from :mod:`datagen.transport.physics`; what differs from the area sampler is only how the
vertices are sampled (by following the light instead of by area).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
from ..area.kernels import fov_targets, material_arrays, sensor_collection
from ..physics import LegPhysics, fov_connection_weight, launched_flux
from .kernels import brdf_many, continue_paths

MULTIBOUNCE_STREAM = 57
"""The spawn-key entry of the tracer's random stream, appended to the run's :class:`numpy.random.SeedSequence`
(so that orders 1–2 draw exactly what they draw without it, whatever order the two run in)."""

SMOOTH_ORDER = 3
"""Orders from this one up are deposited smoothed in time (:class:`DeepSmoothing`) by default."""

SMOOTH_WIDTH = 2e-9
"""Δ, the node spacing of the lowest smoothed orders, s, at a tolerance of :data:`SMOOTH_TOLERANCE`: the bias of a
kernel estimate grows as Δ² and its noise falls as 1/Δ, so Δ scales as √tolerance (the bias stays the same
fraction of the tolerance: about a third of it in the shipped rooms at 2 ns and 1 %), and never above this."""

SMOOTH_TOLERANCE = 0.01

SMOOTH_MIN_WIDTH = 0.5e-9
"""The narrowest Δ, s (tolerances below 0.06 %)."""

SMOOTH_BANDS = 2
"""Bands of orders with their own Δ: orders s..2s−2 at Δ, deeper orders at 2Δ (:class:`SmoothingBands`)."""

SMOOTH_MIN_BINS = 4
"""No smoothing when the output bins are not at least this many times finer than Δ (nothing to gain)."""


def default_smoothing(bin_width: float, tolerance: float) -> dict:
    """The smoothing fields of :class:`MultibounceSettings` (``smooth_order``, ``smooth_width``,
    ``smooth_max_width``) for output bins of ``bin_width`` seconds and a target relative error ``tolerance``:
    Δ = :data:`SMOOTH_WIDTH` · √(tolerance / :data:`SMOOTH_TOLERANCE`) within [:data:`SMOOTH_MIN_WIDTH`,
    :data:`SMOOTH_WIDTH`], the deeper band at 2Δ; no smoothing when the bins are not :data:`SMOOTH_MIN_BINS`
    times finer than Δ."""
    width = float(np.clip(SMOOTH_WIDTH * np.sqrt(tolerance / SMOOTH_TOLERANCE), SMOOTH_MIN_WIDTH, SMOOTH_WIDTH))
    order = SMOOTH_ORDER if SMOOTH_MIN_BINS * bin_width <= width else 0
    return {"smooth_order": order, "smooth_width": width, "smooth_max_width": width * 2 ** (SMOOTH_BANDS - 1)}


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
            :class:`SmoothingBands`); smooth_width: Δ, the node spacing of the lowest smoothed orders, seconds;
            smooth_max_width: the widest node spacing of the deeper orders, seconds (= smooth_width: one Δ for all).

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

    def __post_init__(self):
        for name in ("smooth_width", "smooth_max_width"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"multibounce tracer: {name} must be > 0 seconds, got {v!r}")
        if self.smooth_max_width < self.smooth_width:
            raise ConfigError(f"multibounce tracer: smooth_max_width {self.smooth_max_width!r} s is below smooth_width "
                              f"{self.smooth_width!r} s")
        for name, low in (("paths", 1), ("min_order", 1), ("max_order", 0), ("batch", 1), ("smooth_order", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ConfigError(f"multibounce tracer: {name} must be an integer >= {low}, got {v!r}")
        if self.max_order and self.max_order < self.min_order:
            raise ConfigError(f"multibounce tracer: max_order {self.max_order} is below min_order {self.min_order}")


@dataclass
class MultibounceStats(Counters):
    """Counters of tracer runs (``add`` merges replicas): paths started, vertices reached, steps (one per order and
    batch: a ray cast for every path still alive), next-event connections, direction hits on the FoV, and paths
    ended by roulette, by escaping, by the window's end."""

    paths: int = 0
    steps: int = 0
    vertices: int = 0
    connections: int = 0
    fov_hits: int = 0
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
        window: (t_start, t_stop) of the time axis, s (paths stop once their counted length exceeds c·t_stop).
    Attributes:
        stats: :class:`MultibounceStats`.
        order_energy: (:data:`ORDER_TALLY`,) float64, the weight deposited inside the window by order (index k−1
            for order k; the last entry holds every higher order), summed over runs: photons per pulse over all
            runs (divide by the runs for their mean).
        order_time: (:data:`ORDER_TALLY`,) float64, the same impulses' Σ weight × arrival time (photon-seconds):
            ``order_time / order_energy`` is each order's mean arrival time in the window.
    """

    def __init__(self, capture: Capture, caster: RayCaster, physics: LegPhysics, settings: MultibounceSettings,
                 component: int, window: tuple[float, float]):
        self.capture, self.caster, self.physics, self.settings = capture, caster, physics, settings
        self.component = int(component)
        self.t_start, self.t_stop = float(window[0]), float(window[1])
        self.order_energy = np.zeros(ORDER_TALLY)
        self.order_time = np.zeros(ORDER_TALLY)
        self.smoothing = (SmoothingBands(settings.smooth_order, settings.smooth_width, settings.smooth_max_width,
                                         self.t_start, self.t_stop, capture.n_channels)
                          if settings.smooth_order else None)
        # paths are followed past the window's end by the smoothing's reach, so that the kernel near the end
        # receives the mass from beyond it that it spreads into the window
        self.t_follow = self.t_stop + (self.smoothing.margin if self.smoothing is not None else 0.0)
        albedo = physics.materials.albedo
        self.survival = np.minimum(1.0, albedo)                   # q per object: Russian roulette
        self._mat = material_arrays(physics)
        # the FoV's pixel regions (aperture captures): one uniform target in each recorded one per vertex
        self._pixel_area = capture.fov_size[0] * capture.fov_size[1] / capture.n_pixels if capture.n_pixels else 0.0
        self._p_a = 1.0 / self._pixel_area if self._pixel_area > 0 else 0.0
        self._fov = (capture.fov_center, capture.fov_u, capture.fov_v, capture.fov_normal,
                     np.asarray(capture.fov_size, dtype=np.float64), np.asarray(capture.fov_pixels, dtype=np.float64))
        self.stats = MultibounceStats()

    def progress_total(self) -> tuple[int, str]:
        """Light paths over all laser points."""
        return self.settings.paths * self.capture.n_lasers, "path"

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from every laser point and send the impulses of order ≥ ``min_order`` to
        ``sink``. ``rng`` is used as given (callers pass :func:`tracer_rng` of their stream)."""
        for laser in range(self.capture.n_lasers):
            self.run_laser(sink, rng, laser, progress)
        if self.smoothing is not None:
            self.smoothing.flush(sink, self.component)

    def run_laser(self, sink: Sink, rng: np.random.Generator, laser: int,
                  progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from laser point ``laser`` only (the planner's pilot)."""
        s, c = self.settings, self.capture
        pix = np.arange(c.n_pixels)
        ch = c.channel(laser, pix)
        pix, ch = pix[ch >= 0], ch[ch >= 0]                    # the pixel regions this laser point records
        iy, ix = np.divmod(pix, c.fov_pixels[0])
        self._pix_x, self._pix_y, self._pix_ch = ix.astype(np.int64), iy.astype(np.int64), ch.astype(np.int64)
        self._corner = np.zeros((len(pix), 2))
        for start in range(0, s.paths, s.batch):
            n = min(s.batch, s.paths - start)
            self._trace(n, laser, sink, rng)
            if progress is not None:
                progress(n)

    # -- one batch of paths ------------------------------------------------------------------------------------

    def _trace(self, n: int, laser: int, sink: Sink, rng: np.random.Generator) -> None:
        c, cst, ph, s = self.capture, self.caster, self.physics, self.settings
        self.stats.paths += n
        normal = np.broadcast_to(c.spot_normals[laser], (n, 3))
        local, _ = square_to_hemisphere(rng.random(n), rng.random(n), "cosine")
        w = to_world(local, normal)
        pdf = local[:, 2] / np.pi                                  # cosine-weighted directions, 1/sr
        flux = np.zeros(n)
        ok = pdf > 0
        # Φ/N per path: N paths per laser point over all batches
        flux[ok] = on_arrays(launched_flux)(c.photons / s.paths, ph.spot_emission(w[ok], laser), pdf[ok])
        origin = np.broadcast_to(c.spots[laser] + cst.offset * c.spot_normals[laser], (n, 3))
        counted = np.full(n, float(ph.laser_leg(laser)))         # metres of the path that count in the time
        physical = np.full(n, float(c.emitter_legs[laser]))      # metres of physical path (attenuation)
        ray_origin, ray_dir, src_normal = origin, w, normal
        q_prev = np.ones(n)                                      # survival probability of the ray just cast
        order = 0
        limit = SPEED_OF_LIGHT * self.t_follow                    # metres of counted path: the window's end
        while len(flux) and order < MAX_VERTICES:
            self.stats.steps += 1
            hits = cst.intersect(ray_origin, ray_dir)
            if order >= s.min_order:                            # the ray left a vertex of order ≥ min_order
                self._fov_hits(hits, ray_origin, ray_dir, flux, counted, physical, q_prev, src_normal, laser, sink,
                               order)
            alive = hits.hit
            self.stats.escaped += int((~alive).sum())
            order += 1
            dist = hits.distance
            counted = counted + np.where(alive, dist, 0.0)
            physical = physical + np.where(alive, dist, 0.0)
            in_window = counted < limit
            self.stats.window += int((alive & ~in_window).sum())
            keep = np.flatnonzero(alive & in_window)
            if s.max_order and order > s.max_order:
                break
            x, n_x = hits.points[keep], hits.normals[keep]      # n_x faces the incoming ray
            obj = hits.object_id[keep]
            w_in = -ray_dir[keep]
            flux, counted, physical = flux[keep], counted[keep], physical[keep]
            self.stats.vertices += len(keep)
            if order >= s.min_order and len(keep):
                self._connect(x, n_x, obj, w_in, flux, counted, physical, laser, sink, rng, order)
            # continue: cosine direction about n_x, flux × f π / q, roulette with q = min(1, ρ)
            m = len(keep)
            u, v, r = rng.random(m), rng.random(m), rng.random(m)
            w_out, flux, live = continue_paths(np.ascontiguousarray(n_x), obj, np.ascontiguousarray(w_in), u, v, r,
                                               flux, self.survival, self._mat)
            q = self.survival[obj]
            self.stats.roulette += int((r >= q).sum())
            sel = np.flatnonzero(live)
            flux, counted, physical = flux[sel], counted[sel], physical[sel]
            src_normal, q_prev = n_x[sel], q[sel]
            ray_origin = x[sel] + cst.offset * src_normal
            ray_dir = w_out[sel]

    def _connect(self, x: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_in: np.ndarray, flux: np.ndarray,
                 counted: np.ndarray, physical: np.ndarray, laser: int, sink: Sink, rng: np.random.Generator,
                 order: int) -> None:
        """Next-event connections of vertices x (m, 3) (normals n_x facing the incoming light) to one uniform point
        per sensor pixel region (aperture) or to the sensor points (point radiance), with their MIS weights."""
        c, ph = self.capture, self.physics
        if c.convention != "aperture":                            # sensor points: the shared connection
            conn = ph.connect(x, n_x, laser, rng, (1, 1))
            if not len(conn.b):
                return
            b, wk = conn.b, conn.direction
            weight = flux[b] * ph.brdf(obj[b], n_x[b], w_in[b], wk) * dot(n_x[b], wk) * conn.weight
            self.stats.connections += len(b)
            self._deposit(sink, (counted[b] / SPEED_OF_LIGHT) + conn.time,
                          weight * ph.attenuation(physical[b] + conn.phys), conn.channel, order)
            return
        # one uniform point per recorded pixel region and vertex (density p_a = 1/A_pixel): the area sampler's
        # compiled target geometry and sensor collection, a shadow ray x → y
        b, s_idx, y, wk, r, cos_y = fov_targets(np.ascontiguousarray(x), np.ascontiguousarray(n_x), self._pix_x,
                                                self._pix_y, self._corner, rng.random((len(x), len(self._pix_x), 2)),
                                                (1.0, 1.0), self._fov)
        vis = self.caster.visible(x[b], n_x[b], y, c.fov_normal)
        ph.stats.shadow_rays += len(b)
        b, s_idx, y, wk, r, cos_y = b[vis], s_idx[vis], y[vis], wk[vis], r[vis], cos_y[vis]
        if not len(b):
            return
        collect, d_ys = sensor_collection(ph, y, np.broadcast_to(c.fov_normal, y.shape),
                                          np.full(len(b), ph.wall_object), -wk)
        cos_x = dot(n_x[b], wk)
        # radiant intensity flux f cosθ_x toward y, times the FoV leg cosθ_y dA_y / r² · collection (A2, A3)
        f = brdf_many(self._mat, obj[b], np.ascontiguousarray(n_x[b]), np.ascontiguousarray(w_in[b]),
                      np.ascontiguousarray(wk))
        weight = flux[b] * f * cos_x * fov_connection_weight(
            cos_y * self._pixel_area, r, collect)
        p_d = self.survival[obj[b]] * cos_x * cos_y / (np.pi * r * r)     # balance heuristic with the direction hits
        weight = weight * (self._p_a / (self._p_a + p_d)) * ph.attenuation(physical[b] + r + d_ys)
        self.stats.connections += len(b)
        self._deposit(sink, (counted[b] + r + ph.sensor_leg(d_ys)) / SPEED_OF_LIGHT, weight, self._pix_ch[s_idx],
                      order)

    def _fov_hits(self, hits, origin: np.ndarray, direction: np.ndarray, flux: np.ndarray, counted: np.ndarray,
                  physical: np.ndarray, q: np.ndarray, n_x: np.ndarray, laser: int, sink: Sink, order: int) -> None:
        """Continuation rays (flux already × f π / q) that land on a FoV pixel region: the direction strategy of
        the FoV connection, weighted by the balance heuristic against :meth:`_connect`'s area strategy."""
        c, ph = self.capture, self.physics
        if c.convention != "aperture":
            return
        on_wall = np.flatnonzero(hits.hit & np.isin(hits.object_id, ph.fov_objects))   # only these can be in the FoV
        chan = c.channel(laser, c.fov_pixel(hits.points[on_wall], ph.tol))
        idx = on_wall[chan >= 0]
        chan = chan[chan >= 0]
        if not len(idx):
            return
        y, wk, r = hits.points[idx], direction[idx], hits.distance[idx]
        n_y = hits.normals[idx]
        collect, d_ys = sensor_collection(ph, y, n_y, np.full(len(idx), ph.wall_object), -wk)
        cos_x = dot(n_x[idx], wk)
        cos_y = -dot(wk, c.fov_normal)
        p_a = c.n_pixels / (c.fov_size[0] * c.fov_size[1])
        p_d = q[idx] * cos_x * cos_y / (np.pi * r * r)
        weight = flux[idx] * collect * (p_d / (p_a + p_d))
        weight = weight * ph.attenuation(physical[idx] + r + d_ys)
        self.stats.fov_hits += len(idx)
        self._deposit(sink, (counted[idx] + r + ph.sensor_leg(d_ys)) / SPEED_OF_LIGHT, weight, chan, order)

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
        sink.add(t, weight, self.component * self.capture.n_channels + channel)


class SmoothingBands:
    """The time smoothing of the deep orders, one :class:`DeepSmoothing` per band of orders whose node spacing
    doubles each time the order doubles: order k ≥ s = ``first_order`` in band ⌊log2((k − 1)/(s − 1))⌋ (orders 3–4, 5–8,
    9–16, … for s = 3), the last band taking every deeper order, up to ``max_width``.

    Order k's part of the transient is k chord lengths convolved: it spreads in time and its curvature L_k''
    falls as k grows, so the bias Δ² L_k'' of a kernel of width Δ stays small for a wider kernel on deeper orders,
    while the noise of a kernel estimate falls as 1/Δ. Each band estimates its own bias (Richardson,
    :meth:`DeepSmoothing.bias`); their sum is the bias of the smoothed orders.

    Args:
        first_order: the lowest smoothed order (≥ 2); width: Δ of the band that starts there, s; max_width: the
            widest Δ, s; t_start, t_stop: the window, s; n_channels: output channels.
    Attributes:
        margin: how far past the window's end paths are followed, s (the widest band's reach).
    """

    def __init__(self, first_order: int, width: float, max_width: float, t_start: float, t_stop: float,
                 n_channels: int):
        self.first_order = int(first_order)
        self.widths: list[float] = []
        w = float(width)
        while True:
            self.widths.append(min(w, max_width))
            if w >= max_width:
                break
            w *= 2.0
        self.bands = [DeepSmoothing(w, t_start, t_stop, n_channels) for w in self.widths]
        self.margin = max(b.margin for b in self.bands)

    def band(self, order: int) -> DeepSmoothing | None:
        """The band that smooths order ``order``, or None below :attr:`first_order`."""
        if order < self.first_order:
            return None
        j = int(np.floor(np.log2((order - 1) / max(self.first_order - 1, 1)) + 1e-12))
        return self.bands[min(j, len(self.bands) - 1)]

    def flush(self, sink: Sink, component: int) -> None:
        """:meth:`DeepSmoothing.flush` of every band."""
        for b in self.bands:
            b.flush(sink, component)

    def bias(self, edges: np.ndarray, runs: int) -> np.ndarray:
        """The sum of the bands' :meth:`DeepSmoothing.bias`, (n_channels, n_bins) photons per pulse."""
        return sum(b.bias(edges, runs) for b in self.bands)


class DeepSmoothing:
    """Orders that are smooth in time, deposited smoothed: a kernel estimate with its bias estimated and counted.

    Impulses inside the window are linearly binned onto nodes Δ apart (t_start + jΔ: the mass splits between the
    two nearest nodes, which keeps it and its mean time); :meth:`flush` deposits each node's mass as a tent of
    half-width Δ centred on it (:meth:`~datagen.timing.EnvelopeAccumulator.add_tents`), i.e. the piecewise-linear
    density through the node masses. The deep orders of a closed room are a long tail that changes over many
    nanoseconds, so the smoothing removes the noise of single paths at a bias of order Δ² L''. The same impulses are
    also binned at 2Δ: the bias of a kernel estimate grows as its width squared, so ‖L_2Δ − L_Δ‖ / 3 estimates the
    bias of L_Δ (Richardson), and :meth:`bias` returns it for the result's stated error (noise in that difference
    only makes the estimate larger).

    The nodes reach :attr:`margin` (4Δ) beyond both ends of the window, and the tracer follows paths that far past
    its end, so that the kernels near the ends receive from outside the mass they spread out of the window.

    Args:
        width: Δ, s; t_start, t_stop: the window, s; n_channels: output channels.
    """

    def __init__(self, width: float, t_start: float, t_stop: float, n_channels: int):
        self.width, self.n_channels = float(width), int(n_channels)
        self.margin = 4 * self.width                  # the 2Δ kernel's reach: the nodes cover the window and this
        self.t_start = float(t_start) - self.margin   # node 0
        self.t_end = float(t_stop) + self.margin
        self.nodes = int(np.ceil((self.t_end - self.t_start) / self.width)) + 2
        self.pending = np.zeros((self.n_channels, self.nodes))      # this run's node masses, photons
        self.total = np.zeros((self.n_channels, self.nodes))        # every run's, for the bias
        self.coarse = np.zeros((self.n_channels, self.nodes // 2 + 2))   # every run's at 2Δ

    def covers(self, t: np.ndarray) -> np.ndarray:
        """(n,) bool: the times t (n,) s that the nodes cover (the window widened by the margin on both sides)."""
        return (t >= self.t_start) & (t < self.t_end)

    def add(self, t: np.ndarray, weight: np.ndarray, channel: np.ndarray) -> None:
        """Linearly bin impulses at times t (n,) s, weights (n,) photons, channels (n,) int."""
        for out, width in ((self.pending, self.width), (self.coarse, 2 * self.width)):
            f = (t - self.t_start) / width
            j = np.minimum(f.astype(np.int64), out.shape[1] - 2)
            frac = f - j
            flat = out.reshape(-1)
            base = channel * out.shape[1] + j
            flat += np.bincount(base, weight * (1.0 - frac), minlength=flat.size)
            flat += np.bincount(base + 1, weight * frac, minlength=flat.size)

    def flush(self, sink: Sink, component: int) -> None:
        """Deposit this run's node masses into ``sink`` as tents (component ``component * n_channels +
        channel``) and start the next run."""
        ch, j = np.nonzero(self.pending)
        if len(ch):
            t = self.t_start + j * self.width
            sink.add_tents(np.stack([t - self.width, t, t + self.width], axis=1), self.pending[ch, j],
                           component * self.n_channels + ch)
        self.total += self.pending
        self.pending[:] = 0.0

    def bias(self, edges: np.ndarray, runs: int) -> np.ndarray:
        """‖L_2Δ − L_Δ‖ / 3 per output bin: (n_channels, n_bins) photons per pulse, the estimated bias of the
        smoothed orders' mean over ``runs`` runs on the bins ``edges`` (n_bins + 1,) s."""
        centres = 0.5 * (edges[1:] + edges[:-1])
        widths = np.diff(edges)
        out = np.zeros((self.n_channels, len(centres)))
        for c in range(self.n_channels):
            fine = np.interp(centres, self.t_start + self.width * np.arange(self.nodes), self.total[c] / self.width)
            cells = self.coarse.shape[1]
            wide = np.interp(centres, self.t_start + 2 * self.width * np.arange(cells), self.coarse[c] / (2 * self.width))
            out[c] = (wide - fine) * widths / 3.0
        return out / max(runs, 1)
