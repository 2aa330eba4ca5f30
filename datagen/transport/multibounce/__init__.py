"""Light of every order: paths with three or more hidden vertices (the component ``multibounce``), and order 2
(``secondary``) beside an estimator that runs without its own.

**What it converges to.** The transient path integral of docs/physics.md §2 summed over every order k ≥ 3 (k the
number of hidden vertices; a relay-wall vertex between hidden vertices counts), inside the time window: the light
that orders 1 (primary, the field's 3-bounce) and 2 (secondary, 5-bounce) leave out; from k ≥ 2 when the
estimator's secondary is off (the confocal configs' quadrature). In closed, bright rooms it is a large, late,
smooth tail (docs/physics.md §2, "Light of every order"). Unbiased: Russian roulette ends paths without bias, and a
path stops exactly when it can no longer reach the window; the smoothing's bias is estimated and counted.

**What it costs.** Per light path about (window length × c / mean free path) vertices, each one continuation ray,
one next-event connection per pixel region its laser point records with its shadow ray, and the leg weights:
linear in the paths, bounded even in a closed room of albedo 1 (every path ends at the window's end). A scan's
laser points share every batch. Its error falls as paths^(-1/2) and is measured with its own replicas.

**When to pick it.** Not directly: ``simulation.orders`` (``auto``, or an integer) asks the effect planner
(:mod:`datagen.planner.orders`), which runs a small pilot of this tracer and turns it on when the orders it would
carry exceed a stated fraction of the tolerance; the simulation then wraps the chosen estimator (any of them) in
:class:`AllOrders`.

- :mod:`.options`: the ``multibounce:`` block of a simulation config (:class:`MultibounceOptions`, the light paths
  it defaults to) and :class:`OrdersChoice`, the planner's typed decision on which orders the tracer carries.
- :mod:`.tracer`: :class:`MultibounceTracer` and its :class:`MultibounceSettings` (light paths from the laser
  spot, next-event connections and direction hits on the FoV under the balance heuristic, Russian roulette), and
  :func:`build_tracer`, its one constructor.
- :mod:`.basic`: a short numpy light tracer (continuation, roulette, next-event connections; no smoothing, no eye
  vertex, no second strategy), to read first and the tests' independent check of the fast one.
- :mod:`.eye`: the eye vertex, one hidden vertex per path sampled from the FoV's side and joined to every light
  vertex (a third strategy under the balance heuristic: it samples the FoV leg's 1/r² near the relay wall instead
  of weighing it), and the pixel table both strategies connect to.
- :mod:`.smoothing`: the smoothing of the smooth orders in time (nodes that widen with the order and the tolerance)
  and across a confocal scan's points, each with its bias estimated and counted in the stated error, its kernels kept
  after each channel's onset.
- :mod:`.scan_spread`: the spread across a confocal scan's points (a separable tent, point reflection at the edges)
  and its variance.
- :mod:`.onset`: the earliest time any light of the hidden scene can reach each channel, a bound from the geometry
  (causality of the smoothing).
- :mod:`.kernels`: the per-vertex arithmetic compiled (the continuation's direction, BRDF, flux and roulette;
  the next-event BRDFs).
- :mod:`.orders`: :class:`AllOrders`, an estimator of orders 1–2 plus the tracer as one estimator, :func:`beside`,
  the front door that puts the tracer beside a built estimator, and the tracer's nominal cost (:func:`~datagen.transport.multibounce.orders.tracer_nominal_seconds`).

A run counts the tracer's replicas apart from the estimator's and gives each the share of the work that the error
of their sum asks for (:func:`datagen.simulation.replicas.neyman_split`).
"""
from .options import MultibounceOptions, OrdersChoice
from .orders import COMPONENT, AllOrders, beside
from .tracer import MultibounceSettings, MultibounceStats, MultibounceTracer, build_tracer, tracer_rng

__all__ = ["AllOrders", "MultibounceTracer", "MultibounceSettings", "MultibounceOptions", "OrdersChoice", "beside",
           "build_tracer"]
