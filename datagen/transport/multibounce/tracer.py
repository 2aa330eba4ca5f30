"""Light of order ≥ 3: a transient light tracer from the laser spot with next-event connections to the FoV.

A path's *order* is its number of hidden vertices (docs/physics.md §2, "Orders"): the laser spot and the FoV
point are not counted, a relay-wall vertex between hidden vertices is. Orders 1 and 2 are the estimators' primary
and secondary; this module adds every order from ``min_order`` (3) up, as the component ``multibounce``.

The estimator (docs/physics.md §2, "Light of every order"; docs/accuracy.md for its cost):

- **Light paths.** Each path starts at laser point x_l with a cosine-weighted direction (density cosθ_l/π), so
  its flux is Φ f_l(ω_e, ω) π / N per path of N (:func:`~datagen.transport.physics.launched_flux` of
  :meth:`LegPhysics.spot_emission <datagen.transport.physics.LegPhysics.spot_emission>` over the density). At every hidden vertex x_k the next
  direction is cosine-weighted about the normal on the side the light arrives from, the flux is multiplied by
  f(ω_in, ω_out) π (the BRDF over the cosine density, :meth:`LegPhysics.brdf`) and divided by the survival
  probability q = min(1, ρ) of Russian roulette (ρ the material's albedo: a Lambertian path keeps its flux and
  survives with probability ρ). Roulette is unbiased. Every surface takes part, the relay wall included.
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
from ..physics import LegPhysics, launched_flux

MULTIBOUNCE_STREAM = 57
"""The spawn-key entry of the tracer's random stream, appended to the run's :class:`numpy.random.SeedSequence`
(so that orders 1–2 draw exactly what they draw without it, whatever order the two run in)."""

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

    Raises:
        ConfigError: a field out of range (the message names it and the value).
    """

    paths: int = 8192
    min_order: int = 3
    max_order: int = 0
    batch: int = 32768

    def __post_init__(self):
        for name, low in (("paths", 1), ("min_order", 1), ("max_order", 0), ("batch", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ConfigError(f"multibounce tracer: {name} must be an integer >= {low}, got {v!r}")
        if self.max_order and self.max_order < self.min_order:
            raise ConfigError(f"multibounce tracer: max_order {self.max_order} is below min_order {self.min_order}")


@dataclass
class MultibounceStats(Counters):
    """Counters of tracer runs (``add`` merges replicas): paths started, vertices reached, next-event connections,
    direction hits on the FoV, and paths ended by roulette, by escaping, by the window's end."""

    paths: int = 0
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
    """

    def __init__(self, capture: Capture, caster: RayCaster, physics: LegPhysics, settings: MultibounceSettings,
                 component: int, window: tuple[float, float]):
        self.capture, self.caster, self.physics, self.settings = capture, caster, physics, settings
        self.component = int(component)
        self.t_start, self.t_stop = float(window[0]), float(window[1])
        self.order_energy = np.zeros(ORDER_TALLY)
        albedo = physics.materials.albedo
        self.survival = np.minimum(1.0, albedo)                   # q per object: Russian roulette
        self.stats = MultibounceStats()

    def progress_total(self) -> tuple[int, str]:
        """Light paths over all laser points."""
        return self.settings.paths * self.capture.n_lasers, "path"

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from every laser point and send the impulses of order ≥ ``min_order`` to
        ``sink``. ``rng`` is used as given (callers pass :func:`tracer_rng` of their stream)."""
        for laser in range(self.capture.n_lasers):
            self.run_laser(sink, rng, laser, progress)

    def run_laser(self, sink: Sink, rng: np.random.Generator, laser: int,
                  progress: Callable[[int], None] | None = None) -> None:
        """Trace ``paths`` light paths from laser point ``laser`` only (the planner's pilot)."""
        s = self.settings
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
        limit = SPEED_OF_LIGHT * self.t_stop                      # metres of counted path: the window's end
        while len(flux) and order < MAX_VERTICES:
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
            local, _ = square_to_hemisphere(rng.random(m), rng.random(m), "cosine")
            w_out = to_world(local, n_x)
            f = ph.brdf(obj, n_x, w_in, w_out)
            q = self.survival[obj]
            live = rng.random(m) < q
            self.stats.roulette += int((~live).sum())
            flux = np.divide(flux * f * np.pi, q, out=np.zeros(m), where=q > 0)
            sel = np.flatnonzero(live & (flux > 0))
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
        conn = ph.connect(x, n_x, laser, rng, (1, 1), jitter=rng.random((len(x), 2)))
        if not len(conn.b):
            return
        b, wk = conn.b, conn.direction
        cos_x = dot(n_x[b], wk)
        f = ph.brdf(obj[b], n_x[b], w_in[b], wk)
        weight = flux[b] * f * cos_x * conn.weight
        if c.convention == "aperture":                            # balance heuristic with the direction hits
            cos_y = -dot(wk, c.fov_normal)
            r = dot(x[b] - c.fov_center, c.fov_normal) / cos_y            # y on the FoV plane; cos_y > 0
            p_a = c.n_pixels / (c.fov_size[0] * c.fov_size[1])
            p_d = self.survival[obj[b]] * cos_x * cos_y / (np.pi * r * r)
            weight = weight * (p_a / (p_a + p_d))
        weight = weight * ph.attenuation(physical[b] + conn.phys)
        self.stats.connections += len(b)
        self._deposit(sink, (counted[b] / SPEED_OF_LIGHT) + conn.time, weight, conn.channel, order)

    def _fov_hits(self, hits, origin: np.ndarray, direction: np.ndarray, flux: np.ndarray, counted: np.ndarray,
                  physical: np.ndarray, q: np.ndarray, n_x: np.ndarray, laser: int, sink: Sink, order: int) -> None:
        """Continuation rays (flux already × f π / q) that land on a FoV pixel region: the direction strategy of
        the FoV connection, weighted by the balance heuristic against :meth:`_connect`'s area strategy."""
        c, ph = self.capture, self.physics
        if c.convention != "aperture":
            return
        pts = np.nan_to_num(hits.points)
        chan = np.where(hits.hit, c.channel(laser, c.fov_pixel(pts, ph.tol)), -1)
        idx = np.flatnonzero(chan >= 0)
        if not len(idx):
            return
        y, wk, r = pts[idx], direction[idx], hits.distance[idx]
        n_y = hits.normals[idx]
        collect, d_ys = ph.sensor_collection(y, n_y, np.full(len(idx), ph.wall_object), -wk)
        cos_x = dot(n_x[idx], wk)
        cos_y = -dot(wk, c.fov_normal)
        p_a = c.n_pixels / (c.fov_size[0] * c.fov_size[1])
        p_d = q[idx] * cos_x * cos_y / (np.pi * r * r)
        weight = flux[idx] * collect * (p_d / (p_a + p_d))
        weight = weight * ph.attenuation(physical[idx] + r + d_ys)
        self.stats.fov_hits += len(idx)
        self._deposit(sink, (counted[idx] + r + ph.sensor_leg(d_ys)) / SPEED_OF_LIGHT, weight, chan[idx], order)

    def _deposit(self, sink: Sink, t: np.ndarray, weight: np.ndarray, channel: np.ndarray, order: int) -> None:
        """Send impulses of paths of order ``order`` to ``sink`` and tally their in-window weight."""
        inside = (t >= self.t_start) & (t < self.t_stop)
        self.order_energy[min(order, ORDER_TALLY) - 1] += float(weight[inside].sum())
        sink.add(t, weight, self.component * self.capture.n_channels + channel)
