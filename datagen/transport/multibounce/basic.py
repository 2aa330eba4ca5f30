"""The light tracer of orders ≥ 3 in its plainest form: read it first, and use it to check the fast one.

:class:`~datagen.transport.multibounce.tracer.MultibounceTracer` estimates the same light (docs/physics.md §2,
"Orders" and "Light of every order") with compiled passes, three strategies under the balance heuristic (next-event
connections, direction hits on the FoV, eye vertices), shared batches across a scan's points and time smoothing.
:func:`trace_basic` keeps only what makes the estimator unbiased, in numpy, top to bottom, as Mitsuba keeps
``prb_basic`` beside ``prb``:

1. N paths leave laser point x_l in cosine-weighted directions ω (density cosθ_l/π), each with flux
   Φ f_l(ω_e, ω) cosθ_l / (N p(ω)) (:func:`~datagen.transport.physics.launched_flux`).
2. A path's k-th hit is its vertex of order k. Once its counted metres plus its distance to the FoV rectangle plus
   the shortest FoV → sensor leg that counts exceed c·t_stop, no impulse of it or of a later vertex can land in the
   window, and the path stops there (exact, unbiased).
3. At every vertex of order k ≥ ``min_order``: one uniform point y per recorded pixel region (density 1/A_pixel),
   a shadow ray, and the impulse flux · f(ω_in, ω_y) cosθ_x (:func:`~datagen.transport.physics.emission_term`) ×
   the FoV leg and sensor collection of :meth:`LegPhysics.connect <datagen.transport.physics.LegPhysics.connect>`
   × e^{−μ·path}, at (counted path + r + sensor leg)/c. Next-event weight 1: no MIS. The pixel regions are sampled
   by area, so this strategy alone covers every path that ends on the FoV (point-radiance captures: the sensor
   points, as the fast tracer connects them).
4. The path goes on in a cosine-weighted direction about the normal on the lit side, flux × f cosθ / (q p(ω))
   (the same :func:`~datagen.transport.physics.launched_flux`), kept by Russian roulette with probability
   q = min(1, ρ).

No eye vertex, no direction hit, no smoothing, no shared batches: it is deliberately slow (one laser point at a
time, numpy passes, one ray cast per order) and meant for tests and for reading. Its variance is that of next-event
connections alone, which is large next to the relay wall (the 1/r² of the FoV leg is weighed, not sampled).
Every leg weight is a call to :mod:`datagen.transport.physics` (BRDFs through ``LegPhysics.brdf``, i.e.
:mod:`datagen.scene.materials`); only how the vertices are sampled is written here.
"""
from __future__ import annotations

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
from ..physics import LegPhysics, emission_term, launched_flux
from .tracer import ORDER_TALLY


@dataclass(frozen=True)
class BasicTrace:
    """What :func:`trace_basic` returns (photons per pulse, summed over the laser points).

    Attributes:
        order_energy: (:data:`~datagen.transport.multibounce.tracer.ORDER_TALLY`,) float64, the weight that landed
            inside the window by order (index k − 1 for order k, the last entry holds every higher order), as
            :attr:`MultibounceTracer.order_energy <datagen.transport.multibounce.tracer.MultibounceTracer>` of one run.
        envelope: (n_channels, n_bins) float64, the same impulses binned on ``edges`` (channel order of
            :meth:`~datagen.scene.capture.Capture.channel`); no IRF.
    """

    order_energy: np.ndarray
    envelope: np.ndarray


def trace_basic(capture: Capture, caster: RayCaster, physics: LegPhysics, paths: int, rng: np.random.Generator,
                edges: np.ndarray, min_order: int = 3, max_order: int = 0) -> BasicTrace:
    """Light of orders ``min_order``..``max_order`` by plain light tracing with next-event connections (module doc).

    Args:
        capture, caster, physics: the resolved capture, the scene's ray caster and the leg weights, as the fast tracer
            takes them (a built estimator's ``capture``, ``caster`` and ``physics``).
        paths: N, light paths per laser point (int ≥ 1).
        rng: the only source of randomness.
        edges: (n_bins + 1,) float64 bin edges in seconds, strictly increasing; the window is [edges[0], edges[−1]).
        min_order: the lowest order deposited (≥ 1); max_order: the highest, or 0 for every order.
    Returns:
        :class:`BasicTrace`.
    Raises:
        ConfigError: ``paths``, ``min_order`` or ``max_order`` out of range, or ``edges`` not a strictly increasing
            finite 1-D array of at least two entries (the message names the argument and the value).
    """
    for name, value, low in (("paths", paths, 1), ("min_order", min_order, 1), ("max_order", max_order, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ConfigError(f"basic tracer: {name} must be an integer >= {low}, got {value!r}")
    if max_order and max_order < min_order:
        raise ConfigError(f"basic tracer: max_order {max_order} is below min_order {min_order}")
    edges = np.asarray(edges, dtype=np.float64)
    if edges.ndim != 1 or len(edges) < 2 or not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0):
        raise ConfigError(f"basic tracer: edges must be >= 2 strictly increasing finite seconds, got {edges!r}")
    energy = np.zeros(ORDER_TALLY)
    envelope = np.zeros((capture.n_channels, len(edges) - 1))
    for laser in range(capture.n_lasers):
        _trace_laser(capture, caster, physics, laser, paths, rng, edges, (min_order, max_order), (energy, envelope))
    return BasicTrace(energy, envelope)


def _cosine_directions(normals: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine-weighted unit directions about unit normals (m, 3): (directions (m, 3), cosθ (m,), density (m,) 1/sr)."""
    local, pdf = square_to_hemisphere(rng.random(len(normals)), rng.random(len(normals)), "cosine")
    return to_world(local, normals), local[:, 2], pdf


def _trace_laser(c: Capture, caster: RayCaster, ph: LegPhysics, laser: int, paths: int, rng: np.random.Generator,
                 edges: np.ndarray, orders: tuple[int, int], out: tuple[np.ndarray, np.ndarray]) -> None:
    """The N paths of laser point ``laser``, their impulses added to ``out`` = (order energy, envelope)."""
    min_order, max_order = orders
    normal = np.broadcast_to(c.spot_normals[laser], (paths, 3))
    w, cos, pdf = _cosine_directions(normal, rng)
    ok = pdf > 0
    w, cos, pdf = w[ok], cos[ok], pdf[ok]
    flux = on_arrays(launched_flux)(c.photons / paths, ph.spot_emission(w, laser), pdf)        # 1. the laser spot
    origin = np.broadcast_to(c.spots[laser] + caster.offset * c.spot_normals[laser], w.shape)
    counted = np.full(len(w), float(ph.laser_leg(laser)))         # metres that count in the time of flight
    physical = np.full(len(w), float(c.emitter_legs[laser]))      # metres of physical path (attenuation)
    reach = SPEED_OF_LIGHT * edges[-1] - ph.sensor_leg(c.fov_sensor_distance())
    albedo = ph.materials.albedo
    order = 0
    while len(flux):
        hits = caster.intersect(origin, w)
        order += 1
        h = np.flatnonzero(hits.hit)                                # 2. the vertices of this order
        x, n_x, obj, w_in = hits.points[h], hits.normals[h], hits.object_id[h], -w[h]
        counted, physical, flux = counted[h] + hits.distance[h], physical[h] + hits.distance[h], flux[h]
        alive = counted + c.fov_distance(x) < reach
        x, n_x, obj, w_in, counted, physical, flux = (a[alive] for a in (x, n_x, obj, w_in, counted, physical, flux))
        if order >= min_order and len(x):                           # 3. next event
            _connect(ph, x, n_x, obj, w_in, (flux, counted, physical), laser, rng, edges, order, out)
        if max_order and order >= max_order:
            break
        q = np.minimum(1.0, albedo[obj])                            # 4. continue, Russian roulette
        w, cos, pdf = _cosine_directions(n_x, rng)
        live = (rng.random(len(x)) < q) & (pdf > 0)
        x, n_x, obj, w_in, counted, physical, flux, q, w, cos, pdf = (
            a[live] for a in (x, n_x, obj, w_in, counted, physical, flux, q, w, cos, pdf))
        f = ph.brdf(obj, n_x, w_in, w)
        flux = on_arrays(launched_flux)(flux / q, on_arrays(emission_term)(f, cos), pdf)
        origin = x + caster.offset * n_x


def _connect(ph: LegPhysics, x: np.ndarray, n_x: np.ndarray, obj: np.ndarray, w_in: np.ndarray, state: tuple,
             laser: int, rng: np.random.Generator, edges: np.ndarray, order: int,
             out: tuple[np.ndarray, np.ndarray]) -> None:
    """Next-event connections of vertices x (m, 3) (normals n_x on the lit side, ω_in w_in (m, 3) toward where the
    light came from; state = (flux, counted m, physical m) per vertex) to one uniform point of every pixel region
    that laser point ``laser`` records (the same place in each, uniform per vertex: ``LegPhysics.connect``'s
    jitter), deposited in ``out``."""
    flux, counted, physical = state
    conn = ph.connect(x, n_x, laser, rng, (1, 1), jitter=rng.random((len(x), 2)))
    b, wk = conn.b, conn.direction
    intensity = flux[b] * on_arrays(emission_term)(ph.brdf(obj[b], n_x[b], w_in[b], wk), dot(n_x[b], wk))
    weight = intensity * conn.weight * ph.attenuation(physical[b] + conn.phys)
    t = counted[b] / SPEED_OF_LIGHT + conn.time
    inside = (t >= edges[0]) & (t < edges[-1])
    energy, envelope = out
    energy[min(order, ORDER_TALLY) - 1] += float(weight[inside].sum())
    np.add.at(envelope, (conn.channel[inside], np.searchsorted(edges, t[inside], side="right") - 1), weight[inside])
