"""Simulate to a tolerance: add sampling until the result's own error estimate meets a target (docs/accuracy.md).

Monte Carlo estimators (area, lookin): the config's sampling is split into R = ``config.error.replicas`` independent
replicas (:class:`~datagen.simulation.run.Replicas`); their spread gives the relative L2 error estimate ε̂ of
their mean (:mod:`datagen.simulation.replicas`). While ε̂ > tolerance, more replicas of the same size are
added: ε̂ falls as R^(-1/2), so the next round brings the total to R·(ε̂/tol)²·``SAFETY`` (at most ×``MAX_GROWTH``
per round), within ``max_replicas``. Replica r is always drawn from the same stream, so the result depends only
on the scene, the config and the tolerance: never on timing, worker count or machine load. The earlier rounds
are not wasted: every replica is part of the mean.

The quadrature (deterministic, error ∝ h²): its edge is refined instead, h → h·sqrt(tol/ε̂)·``SAFETY_EDGE``. Each
level's error is its own estimate ‖P(h) − P(2h)‖/3 when the run makes its rule at 2h from the same evaluations
(the quadrature's coarse rule: point-radiance captures, and aperture captures whose FoV cells are the same at
2h, e.g. the scan configs); the edge then shrinks by at most ``MAX_SHRINK`` (cost ∝ h⁻²: a level at 0.73 h
costs 1.9× where h/2 costs 4×), or halves after a level whose estimate barely fell (``STALLED``). Otherwise a
level's error is estimated from the previous one as ‖P(h') − P(h)‖/((h/h')² − 1) (the first level from a run at
2h) and the edge at least halves. Either is added in quadrature to the replica spread of its Monte Carlo
secondary. A graded quadrature with ``estimator.refine_grading`` scales its grading ratio with the edge at each
level (:meth:`datagen.transport.quadrature.options.QuadratureOptions.at_edge`): its error sits near the scan,
which the edge alone barely refines.

A wall-clock cap (``max_seconds``) is available for interactive use; it makes the result depend on the
machine's speed, so dataset builds cap the work in nominal seconds instead (``max_cost``: the estimator's
``nominal_seconds()``, counted work at fixed rates fitted to one machine, so the cap is deterministic; the lookin and
area samplers, the quadrature and the order ≥ 3 tracer beside any of them each count theirs), or the replica count
(``max_replicas``). Every cap bounds every estimator: the Monte Carlo loop plans no round beyond it, the quadrature
starts no level predicted (cost ∝ h^-``LEVEL_COST_POWER``) to end beyond it, and the tracer's replicas beside the
quadrature stop at it too; the first round (level) always runs. A result that missed its tolerance says which cap
stopped it (``capped``) and what meeting the tolerance projects in nominal seconds, or that the parts of the error
no sampling reduces (orders left out, smoothing bias) exceed it (``unreachable``). With a wall-clock
cap the first round's estimate is projected to the tolerance (:func:`projected_seconds`: the same predictions
the loop makes for its next round, :func:`replicas_needed` and :func:`edge_factor`, taken all the way to the
tolerance). A projection beyond ``HOPELESS`` × the cap is refused (:class:`ToleranceOutOfReach`, naming the
projection and the tolerance reachable within the cap); one beyond the cap runs on to it after a one-line
warning. Tolerances below :data:`MIN_TOLERANCE` are refused before any work (docs/reliability.md).
"""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from ..errors import ConfigError
from ..threads import one_blas_thread
from ..scene import Scene
from .config import STREAM_SAMPLING, SimulationConfig, stream_rng
from .replicas import FIRST_TRACER_REPLICAS, relative_difference, tracer_replicas_wanted
from ..transport.multibounce.orders import tracer_nominal_seconds
from .replicas import MIN_TOLERANCE  # noqa: F401 (its old home)
from .detection import Result, make_result
from .run import NARROW_SHARE, Replicas

TIME_CAP_S = 600.0
"""Default wall-time cap of ``simulate --tolerance`` (``max_seconds``): no round starts that is predicted to end
after it; the result then carries the best estimate reached, with ``met`` False (docs/reliability.md)."""

SAFETY = 1.1
"""Factor on the predicted replica count, so that the next round lands below the tolerance rather than on it."""

MAX_GROWTH = 8.0
"""Largest growth of the replica count per round (guards a noisy first estimate)."""

FIXED_LIMIT = NARROW_SHARE
"""The replicas meet the tolerance less the parts of the error they cannot reduce (orders left out, the deep
orders' smoothing bias) while those take at most this fraction of it; beyond, the tolerance cannot be met. The share
at which the smoothing is narrowed (:data:`~datagen.simulation.run.NARROW_SHARE`): a smoothing bias is narrowed
before it can put the tolerance out of reach."""

MAX_ROUNDS = 8

MIN_STEP = 1 / 8
"""Under a cost cap, a round adds at least this fraction of the replicas run so far (their error falls by 6 %) or
the loop stops at the cap: rounds of a replica or two, each re-planned as the cost per replica drifts, cost their
error estimate and gain nothing."""

SAFETY_EDGE = 0.9
"""Factor on the quadrature's predicted edge."""

MAX_SHRINK = 0.85
"""Largest edge factor of a quadrature level whose error estimate comes from its own run (the coarse rule at 2h):
each level shrinks the edge at least this much. Without its own estimate a level is compared with the previous
one, which needs the edge at least halved (a small step makes ‖P(h') − P(h)‖/((h/h')² − 1) a ratio of small,
noisy differences)."""

LEVEL_COST_POWER = 4
"""A quadrature level's cost grows as h^-LEVEL_COST_POWER when the edge shrinks (h^-2 for point sensors to h^-4
with an aperture): predictions use the steeper law."""


HOPELESS = 10.0
"""A first round whose projection (:func:`projected_seconds`) exceeds this multiple of ``max_seconds`` is refused
(:class:`ToleranceOutOfReach`) rather than run to the cap: the projection from 8 replicas is uncertain by tens of
percent, not by a factor 10."""

EDGE_SHARE = 0.8
"""Beside the tracer (a quadrature with orders it leaves to the tracer), the edge is refined until its part of the
estimate is at most this fraction of the tolerance; the tracer's replicas take the rest (:func:`top_up_tracer`)."""

EDGE_BESIDE_TRACER = 0.7
"""When the planner runs the tracer beside a quadrature, the first level's edge is this fraction of the config's (and
its grading with it, :meth:`~datagen.transport.quadrature.options.QuadratureOptions.at_edge`): the quadrature's part
of the error then leaves room for the tracer's, whose replicas cost more per unit of error. On ``confocal.yaml``
train 0–5 at 2 %: 22 s against 30 s at the config's edge (the quadrature 1.6× dearer, its part halved, the tracer
at 2–6 replicas instead of 2–8); 0.5 cost 24 s."""

STALLED = 0.9
"""A level whose estimate stayed above this fraction of the previous level's is followed by a halved edge: a small
step can leave the split of the triangles that carry the error unchanged (every triangle is cut into an even number
of parts per side, :func:`datagen.sampling.surfaces.subdivide_with_vertices`)."""


class ToleranceOutOfReach(ConfigError):
    """The first round's error estimate projects far more time than ``max_seconds`` to meet the tolerance.

    Attributes:
        tolerance: the target (relative L2). projected: the projected total wall time, s. max_seconds: the cap, s.
        reachable: the tolerance the projection says the cap affords (time ∝ tolerance⁻², both laws).
        detail: the message without the leading "tolerance X: " (a CLI names its own option instead).
    """

    def __init__(self, tolerance: float, detail: str, projected: float, max_seconds: float, reachable: float):
        super().__init__(f"tolerance {tolerance:.3g}: {detail}")
        self.tolerance, self.detail, self.projected = tolerance, detail, projected
        self.max_seconds, self.reachable = max_seconds, reachable


def check_tolerance(tolerance: float) -> float:
    """``tolerance`` as a float if it is a number in [:data:`MIN_TOLERANCE`, 1).

    Raises:
        ConfigError: not a number, not finite, or outside [MIN_TOLERANCE, 1) (the message gives the value).
    """
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not 0 < tolerance < 1:
        raise ConfigError(f"tolerance must be in (0, 1), got {tolerance!r}")
    if tolerance < MIN_TOLERANCE:
        raise ConfigError(f"tolerance {tolerance:.3g} is below {MIN_TOLERANCE:g}: relative errors that small are "
                         "float64 round-off, not measurable")
    return float(tolerance)


def replicas_needed(count: int, estimate: float, tolerance: float) -> float:
    """R·(ε̂/tol)²·``SAFETY``: the replicas in all that the R^(-1/2) law predicts meet ``tolerance``, from an
    estimate ε̂ of ``count`` replicas (the loop grows toward it by at most ``MAX_GROWTH`` per round). inf, never
    an OverflowError, for an enormous ratio."""
    ratio = estimate / tolerance
    return count * (ratio * ratio) * SAFETY


def edge_factor(estimate: float, tolerance: float) -> float:
    """sqrt(tol/ε̂)·``SAFETY_EDGE``: the factor on the quadrature edge that the h² law predicts meets
    ``tolerance`` from a level's estimate ε̂ (> 0)."""
    return math.sqrt(tolerance / estimate) * SAFETY_EDGE


def projected_seconds(first_seconds: float, estimate: float, tolerance: float, count: int | None = None) -> float:
    """Wall time, s, the first round projects for a run that meets ``tolerance``.

    Args:
        first_seconds: the first round's wall time, s (with its setup).
        estimate: its error estimate ε̂ (relative L2), > ``tolerance``.
        count: its replicas (Monte Carlo: the time per replica times :func:`replicas_needed`); None for the
            quadrature (the level at ``edge_factor`` × h costs ``first_seconds`` / factor^LEVEL_COST_POWER).
    Either law makes the time grow as tolerance⁻²; inf for an enormous ratio.
    """
    if count is not None:
        return first_seconds / count * replicas_needed(count, estimate, tolerance)
    try:
        return first_seconds / edge_factor(estimate, tolerance) ** LEVEL_COST_POWER
    except (OverflowError, ZeroDivisionError):
        return math.inf


def _check_projection(first_seconds: float, estimate: float, tolerance: float, count: int | None,
                      max_seconds: float, what: str, warn: Callable[[str], None] | None,
                      fixed_seconds: float = 0.0) -> None:
    """Refuse (:class:`ToleranceOutOfReach`) a first round projecting beyond ``HOPELESS`` × ``max_seconds``;
    ``warn`` one line when it projects beyond ``max_seconds``. ``fixed_seconds``: work done once (not scaled)."""
    projected = fixed_seconds + projected_seconds(first_seconds, estimate, tolerance, count)
    first_seconds += fixed_seconds
    if not projected > max_seconds:
        return
    reachable = tolerance * math.sqrt(projected / max_seconds) if math.isfinite(projected) else math.inf
    detail = (f"the first round ({what}, {first_seconds:.3g} s) estimates the error at {estimate:.3g}, which "
              f"projects {projected:.3g} s to reach {tolerance:.3g}, beyond the time cap of {max_seconds:g} s "
              f"(within it about {reachable:.3g} is reachable)")
    if projected > HOPELESS * max_seconds:
        raise ToleranceOutOfReach(tolerance, detail, projected, max_seconds, reachable)
    if warn is not None:
        warn(detail)


@one_blas_thread()
def simulate_to_tolerance(scene: Scene, config: SimulationConfig, tolerance: float,
                          max_replicas: int | None = None, max_cost: float | None = None,
                          max_seconds: float | None = None,
                          progress: bool = False, sampling_rng: np.random.Generator | None = None,
                          noise_rng: np.random.Generator | None = None,
                          warn: Callable[[str], None] | None = None) -> Result:
    """Simulate with the least sampling whose error estimate meets ``tolerance`` (module docstring).

    Args:
        scene, config: as for :func:`datagen.simulate` (``config.error.replicas`` replicas of the config's sampling
            are the first round; the quadrature starts from ``config.estimator.edge``).
        tolerance: target relative L2 error of the envelope (bins above 1 % of its peak), in (0, 1).
        max_replicas: most replicas in all (Monte Carlo estimators; deterministic cap).
        max_cost: most work in all, in the estimator's nominal seconds (``nominal_seconds()``: counted work
            times fixed rates, so the cap is deterministic; an estimator without it is capped by ``max_replicas``
            only). The first round (the quadrature's first level) always runs; no later round or level is planned
            beyond the cap.
        max_seconds: stop once the next round is predicted to end after this much wall time (not deterministic);
            a first round projecting more than ``HOPELESS`` × it to meet the tolerance is refused, one projecting
            more than it is reported to ``warn`` (:func:`projected_seconds`).
        progress: print one line per round.
        sampling_rng, noise_rng: as for :func:`datagen.simulate`.
        warn: called with one line (the first round, its estimate, the projection, the cap and the reachable
            tolerance; the caller names its options) when the first round projects beyond ``max_seconds`` but
            within ``HOPELESS`` × it; the run then goes on to the cap.
    Returns:
        :class:`~datagen.simulation.detection.Result` with ``attrs["error"]`` (as every result) and
        ``attrs["tolerance"]``: target, estimate, met, ``nominal_seconds`` (Monte Carlo loop), and every round
        (replicas or edge, estimate, seconds, nominal seconds so far). A result that could not meet the target
        within the caps says so (``met`` False, ``capped``, ``unreachable``, ``projected_nominal_seconds``:
        :func:`_capped_info`), never silently.
    Raises:
        ConfigError: tolerance outside [:data:`MIN_TOLERANCE`, 1) (before any work), or an envelope with no energy
            in the window.
        ToleranceOutOfReach: (a ConfigError) the first round's projection exceeds ``HOPELESS`` × ``max_seconds``.
    """
    tolerance = check_tolerance(tolerance)
    t0 = time.perf_counter()
    rng = sampling_rng if sampling_rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    cfg = config.model_copy(update={"effect_threshold": tolerance})
    runs = Replicas(scene, cfg, rng)
    if runs.tracer is not None and not runs.base_monte_carlo and hasattr(cfg.estimator, "at_edge"):
        cfg = cfg.with_estimator(**cfg.estimator.at_edge(EDGE_BESIDE_TRACER * float(cfg.estimator.edge)))
        runs = Replicas(scene, cfg, rng, planned=runs.planned)       # the same plan, a finer first level
    if not runs.base_monte_carlo or runs.entry.replica is None:
        return _refine_to_tolerance(scene, cfg, runs, tolerance, max_seconds, progress, rng, noise_rng, t0, warn,
                                    max_cost)
    cap = max(int(max_replicas), cfg.error.replicas) if max_replicas is not None else None

    def nominal() -> float | None:               # (narrow_smoothing replaces the transport: asked each time)
        cost = getattr(runs.transport, "nominal_seconds", None)
        return cost() if cost is not None else None

    rounds = []
    target, tracer_target, capped = cfg.error.replicas, None, None
    for _ in range(MAX_ROUNDS):
        t_round = time.perf_counter()
        runs.run(target - runs.count, tracer_target=tracer_target)
        tracer_target = None
        spent = max_cost is not None and nominal() is not None and nominal() >= max_cost   # no more work at all
        if not spent and runs.narrow_smoothing(tolerance):   # a smoothing bias replicas cannot bring down: finer
            target = runs.count + 1
            continue
        mc, fixed = runs.error(), runs.fixed_error()
        if not spent and runs.settle_smoothing(tolerance):
            continue                                # judged (and narrowed) on more of the tracer's runs
        estimate = float(np.hypot(mc, fixed))
        # what the replicas may add: the tolerance less what they cannot bring down (orders left out, smoothing
        # bias) while that is at most FIXED_LIMIT of it; beyond, the tolerance cannot be met, the replicas aim at
        # the tolerance alone and the result says it missed (met: false), rather than spend without end
        budget = (math.sqrt(tolerance * tolerance - fixed * fixed) if 0 < fixed <= FIXED_LIMIT * tolerance
                  else tolerance)
        seconds = time.perf_counter() - t_round
        rounds.append({"replicas": runs.count, "estimate": estimate, "seconds": seconds,
                       "nominal_seconds": nominal()})
        if progress:
            print(f"{runs.count} replicas ({runs.entry.describe(runs.replica_config.estimator)} each): "
                  f"estimated error {estimate:.3%} ({seconds:.2f} s)")
        if mc <= budget:
            break
        if cap is not None and runs.count >= cap:
            capped = "replicas"
            break
        if not math.isfinite(estimate) and runs.sums.mean().max() <= 0:
            break
        if max_seconds is not None and len(rounds) == 1:   # the setup before the round is done once
            _check_projection(seconds, mc, budget, runs.count, max_seconds, f"{runs.count} replicas", warn,
                              fixed_seconds=max(0.0, time.perf_counter() - t0 - seconds))
        whole = runs.whole_top_up(budget / math.sqrt(SAFETY))   # orders ≥ 3: both counts, rounded as a whole
        needed = replicas_needed(runs.count, mc, budget) if whole is None else whole[0]
        wanted = math.ceil(min(runs.count * MAX_GROWTH, needed))
        target = max(runs.count + 1, wanted if cap is None else min(wanted, cap))
        scaled = None
        if max_cost is not None and nominal() is not None:
            plan = _within_cost(runs, target, whole[1] if whole is not None and target == whole[0] else None,
                                max_cost, nominal())
            if plan is None:
                capped = "cost"
                break
            target, scaled = plan
        if max_seconds is not None:
            per_replica = (time.perf_counter() - t0) / runs.count
            affordable = int((max_seconds - (time.perf_counter() - t0)) / per_replica)
            if affordable < 1:
                capped = "time"
                break
            target = min(target, runs.count + affordable)
        if scaled is not None:
            tracer_target = scaled                  # the cost cap scaled both counts down
        elif whole is not None and target == whole[0]:
            tracer_target = whole[1]                # (a capped base count takes the tracer's Neyman share)
    tr = runs.transported()
    _check_energy(scene, tr)
    error = runs.error_attrs(tr, rng)
    met = bool(error["rel_l2"] <= tolerance)
    info = {"target": tolerance, "estimate": error["rel_l2"], "met": met,
            "method": error["method"], "rounds": rounds,
            "nominal_seconds": nominal(),
            **_capped_info(met, capped, error, tolerance,
                           lambda budget: (nominal() / runs.count * replicas_needed(runs.count, error["monte_carlo"],
                                                                                    budget)
                                           if nominal() is not None and error["monte_carlo"] > budget else None))}
    return make_result(scene, cfg, tr, noise_rng, t0, {"error": error, "tolerance": info})


def _within_cost(runs: Replicas, target: int, tracer_target: int | None, max_cost: float, spent: float
                 ) -> tuple[int, int | None] | None:
    """The next round's replica counts within ``max_cost`` nominal seconds (``spent`` so far): (base count, None)
    when the planned round fits (the tracer then takes its share as planned), else both counts' increments scaled
    down to fit, the tracer's given explicitly; None when the cap leaves room for fewer than ``MIN_STEP`` × the
    replicas of orders 1–2 run so far (and at least one).

    Without the tracer every replica costs the same (the mean so far). Beside it, a replica of orders 1–2 and one of
    the tracer each cost what they have cost so far on average, and the tracer's count is ``tracer_target`` or its
    Neyman share of ``target`` (as :func:`~datagen.simulation.replicas.tracer_replicas_wanted` gives it): the mean
    cost per replica of orders 1–2 would count the tracer's replicas again in every one, and the rounds would creep
    toward the cap (a smoke sample at 0.5 %: 5 → 35 → 48 → 50 → 51 replicas; so, 5 → 40 → 52)."""
    count = runs.count
    least = count + max(1, math.ceil(MIN_STEP * count))
    if runs.tracer is None:
        affordable = int(max_cost / (spent / count))
        return None if affordable < min(target, least) else (min(target, affordable), None)
    have = runs.tracer_sums.count
    c_base, c_tracer = runs.replica_costs()
    if tracer_target is None:
        tracer_target = tracer_replicas_wanted(runs.sums, runs.tracer_sums, c_base, c_tracer, target)
    more_base, more_tracer = max(target - count, 0), max(tracer_target - have, 0)
    planned = c_base * more_base + c_tracer * more_tracer
    if spent + planned <= max_cost or planned <= 0:        # (no cost counted for what the round adds)
        return (target, None) if spent < max_cost or planned > 0 else None
    tracer = have + int(max(max_cost - spent, 0.0) / planned * more_tracer)      # both scaled alike; what the
    left = max_cost - spent - c_tracer * (tracer - have)                          # tracer's rounding leaves goes
    base = min(target, count + int(left / c_base)) if c_base > 0 else count       # to orders 1–2
    return None if base < min(target, least) else (base, tracer)


def _capped_info(met: bool, capped: str | None, error: dict, tolerance: float,
                 projection: Callable[[float], float | None]) -> dict:
    """``attrs["tolerance"]`` keys of a run that missed ``tolerance`` (none when it met it): ``capped``, the cap that
    stopped it ("cost", "time", "replicas" or None: the rounds ran out), ``unreachable`` (True when the parts of the
    error that more sampling does not bring down, the orders left out and the smoothing bias, exceed ``FIXED_LIMIT``
    × the tolerance) and, when the sampling can meet it, ``projected_nominal_seconds``: what ``projection(budget)``
    predicts for the whole run to bring the reducible parts to ``budget`` (the tolerance less the fixed parts) by the
    laws the loop plans its rounds with (None without a nominal cost)."""
    if met:
        return {}
    fixed = float(np.hypot(error.get("omitted_orders") or 0.0, error.get("smoothing") or 0.0))
    if fixed > FIXED_LIMIT * tolerance:
        return {"capped": capped, "unreachable": True, "projected_nominal_seconds": None}
    projected = projection(math.sqrt(tolerance * tolerance - fixed * fixed))
    return {"capped": capped, "unreachable": False, "projected_nominal_seconds": projected}


def _check_energy(scene: Scene, tr) -> None:
    if tr.binned.max() <= 0:
        raise ConfigError(f"{scene.source or scene.name}: the envelope is zero in the time window; no error "
                         f"estimate is possible (check the time axis and the FoV)")


def _refine_to_tolerance(scene: Scene, config: SimulationConfig, runs: Replicas, tolerance: float,
                         max_seconds: float | None, progress: bool, rng: np.random.Generator,
                         noise_rng: np.random.Generator | None, t0: float,
                         warn: Callable[[str], None] | None = None, max_cost: float | None = None) -> Result:
    """The quadrature: the edge shrinks until the estimate of the latest level meets ``tolerance``, while the next
    level is predicted (cost ∝ h^-``LEVEL_COST_POWER``) to end within ``max_cost`` nominal seconds (the levels'
    quadratures and the tracer's replicas, :func:`_nominal`) and ``max_seconds``; the tracer's top-up replicas
    within a level are capped the same way (:func:`top_up_tracer`). The first level always runs."""
    h = float(config.estimator.edge)
    rounds, previous, capped, levels_cost = [], None, None, 0.0
    for level in range(MAX_ROUNDS + 2):
        t_level = time.perf_counter()
        if level:
            earlier = runs
            runs = Replicas(scene, config.with_estimator(**config.estimator.at_edge(h)), rng,
                            planned=runs.planned)   # same plan
            runs.adopt_tracer(earlier)              # the tracer's replicas go on (the edge does not change them)
        runs.run(config.error.replicas)
        tr = runs.transported()
        _check_energy(scene, tr)
        primary = _primary(tr)
        error = _level_error(runs, tr, rng, primary, h, previous)
        estimate = error["rel_l2"]
        edge_part = float(error["refinement"] or 0.0)     # (the smoothing bias's estimate falls with replicas)
        level_cost, tracer_cost = _nominal(runs)
        if runs.tracer is not None and estimate > tolerance and edge_part <= EDGE_SHARE * tolerance:
            # the edge is fine enough: the tracer's replicas bring the rest down, the quadrature is not re-run
            caps = _Caps(max_cost, levels_cost + level_cost, max_seconds, t0)
            tr, error = top_up_tracer(runs, tolerance, error["refinement"] or 0.0, rng, primary, h, previous, caps)
            estimate, capped = error["rel_l2"], caps.hit
            level_cost, tracer_cost = _nominal(runs)
        levels_cost += level_cost
        seconds = time.perf_counter() - t_level
        rounds.append({"quadrature_edge": h, "estimate": estimate, "seconds": seconds,
                       "nominal_seconds": levels_cost + tracer_cost,
                       **({"edge_part": edge_part} if runs.tracer is not None else {})})
        if progress:
            print(f"level {level}: quadrature edge {h:.4g} m: estimated error {estimate:.3%} ({seconds:.2f} s)")
        if estimate <= tolerance or level == MAX_ROUNDS + 1 or capped is not None:
            break
        if edge_part <= EDGE_SHARE * tolerance and runs.fixed_error() > FIXED_LIMIT * tolerance:
            break       # what is left (orders left out, smoothing bias) is what no finer edge brings down
        if max_seconds is not None and level == 0:       # the setup before the level is done once
            _check_projection(seconds, estimate, tolerance, None, max_seconds, f"quadrature edge {h:.4g} m", warn,
                              fixed_seconds=max(0.0, time.perf_counter() - t0 - seconds))
        part = "edge_part" if runs.tracer is not None else "estimate"      # (the tracer's part does not follow h)
        stalled = len(rounds) > 1 and rounds[-1][part] > STALLED * rounds[-2][part]
        own = getattr(runs.transport, "coarse", None) is not None
        shrink = min(MAX_SHRINK if own and not stalled else 0.5,
                     edge_factor(edge_part, EDGE_SHARE * tolerance) if runs.tracer is not None
                     else edge_factor(estimate, tolerance))
        # cost ∝ h^-2 (point sensors) to h^-4 (aperture): predict with the steeper law
        if max_seconds is not None and time.perf_counter() - t0 + seconds / shrink ** LEVEL_COST_POWER > max_seconds:
            capped = "time"
            break
        if max_cost is not None and levels_cost + tracer_cost + level_cost / shrink ** LEVEL_COST_POWER > max_cost:
            capped = "cost"
            break
        previous = (h, primary)
        h *= shrink
    met = bool(estimate <= tolerance)
    info = {"target": tolerance, "estimate": estimate, "met": met, "method": error["method"], "rounds": rounds,
            **_capped_info(met, capped, error, tolerance,
                           lambda budget: _projected_levels(levels_cost, level_cost, tracer_cost, error, budget, runs))}
    cfg = config.with_estimator(**config.estimator.at_edge(h))
    return make_result(scene, cfg, tr, noise_rng, t0, {"error": error, "tolerance": info})


def _nominal(runs: Replicas) -> tuple[float, float]:
    """(nominal seconds of this level's quadrature, of the tracer's replicas so far: they carry over from level to
    level); 0 where the estimator reports none."""
    base = runs.transport.base if runs.tracer is not None else runs.transport
    cost = getattr(base, "nominal_seconds", None)
    return (cost() if cost is not None else 0.0,
            tracer_nominal_seconds(runs.tracer.stats) if runs.tracer is not None else 0.0)


def _projected_levels(levels_cost: float, level_cost: float, tracer_cost: float, error: dict, budget: float,
                      runs: Replicas) -> float | None:
    """Nominal seconds the quadrature's loop projects to bring the edge's part of ``error`` and the tracer's spread to
    ``budget``: the nominal seconds spent, a level at the edge the h² law asks (``edge_factor``, cost ∝
    h^-``LEVEL_COST_POWER``; beside the tracer its part is ``EDGE_SHARE`` of the budget) and the tracer's replicas by
    the R^(-1/2) law for the rest; None without a cost."""
    if level_cost <= 0:
        return None
    edge, mc = error.get("refinement") or 0.0, error.get("monte_carlo") or 0.0
    edge_budget = EDGE_SHARE * budget if runs.tracer is not None else budget
    projected = levels_cost + tracer_cost
    if edge > edge_budget:
        projected += level_cost / edge_factor(edge, edge_budget) ** LEVEL_COST_POWER
    if runs.tracer is not None and tracer_cost > 0 and mc > 0:
        count = max(runs.tracer_sums.count, 1)
        room = math.sqrt(max(budget * budget - min(edge, edge_budget) ** 2, (budget / 3) ** 2))
        projected += tracer_cost / count * max(replicas_needed(count, mc, room) - count, 0.0)
    return projected


class _Caps:
    """The caps of a top-up within a quadrature level: ``max_cost`` nominal seconds of which ``spent`` went to the
    levels' quadratures, and ``max_seconds`` of wall time since ``t0``; ``hit`` names the cap that stopped it."""

    def __init__(self, max_cost: float | None, spent: float, max_seconds: float | None, t0: float):
        self.max_cost, self.spent, self.max_seconds, self.t0 = max_cost, spent, max_seconds, t0
        self.hit: str | None = None

    def affordable(self, runs: Replicas, wanted: int) -> int:
        """``wanted`` tracer replicas in all, fewer if a cap allows fewer (at the cost per replica so far)."""
        count = max(runs.tracer_sums.count, 1)
        if self.max_cost is not None:
            per = runs.replica_costs()[1]
            if per > 0 and int((self.max_cost - self.spent) / per) < wanted:
                wanted, self.hit = int((self.max_cost - self.spent) / per), "cost"
        if self.max_seconds is not None:          # as the Monte Carlo loop: the time so far over the replicas so far
            elapsed = time.perf_counter() - self.t0
            left = int((self.max_seconds - elapsed) / (elapsed / count))
            if count + left < wanted:
                wanted, self.hit = count + left, "time"
        return wanted


def _level_error(runs: Replicas, tr, rng: np.random.Generator, primary: np.ndarray, h: float,
                 previous: tuple[float, np.ndarray] | None) -> dict:
    """``attrs["error"]`` of a quadrature level: the run's own (its coarse rule at 2h, or a coarse run) on the first
    level and whenever the run has its own coarse sums, else the refinement between this level and the previous
    one, with the Monte Carlo parts' spread and the parts replicas cannot reduce (orders left out, smoothing)."""
    own = getattr(runs.transport, "coarse", None) is not None      # this run's rule at 2h: its own estimate
    if previous is None or own:
        return runs.error_attrs(tr, rng)
    entry = runs.entry
    ratio = previous[0] / h
    refined = relative_difference(primary, previous[1], tr.binned.sum(axis=0)) / (ratio ** entry.order - 1)
    mc = runs.error()
    estimate = float(np.hypot(np.hypot(mc, refined), runs.fixed_error()))
    return {"rel_l2": estimate, "monte_carlo": mc, "refinement": refined, "replicas": runs.count,
            "replica_setting": entry.describe(runs.replica_config.estimator),
            **({"tracer_replicas": runs.tracer_sums.count} if runs.tracer is not None else {}),
            "method": f"edge refinement ‖P(h') − P(h)‖/((h'/h)^{entry.order} − 1) of the primary between "
                      f"the last two levels, with the replica spread of the Monte Carlo parts; "
                      f"relative L2 over bins above 1 % of the peak"}


def top_up_tracer(runs: Replicas, tolerance: float, refined: float, rng: np.random.Generator,
                  primary: np.ndarray, h: float, previous, caps: _Caps | None = None) -> tuple:
    """Add replicas of the tracer beside a deterministic base (the quadrature at edge ``h``) until their spread meets
    what the tolerance leaves after the edge refinement and the fixed parts (at least a third of the tolerance), by
    the R^(−1/2) law.

    A smoothing bias read above ``FIXED_LIMIT`` × the tolerance from fewer runs than the narrowing is judged on is
    read again on that many first (``Replicas.settle_smoothing``, as the Monte Carlo loop does): two runs' reading is
    noisy, and replicas planned on it were planned for a bias that more runs did not confirm (a ``confocal.yaml``
    sample: 11 tracer runs planned from two, 7 after four).

    Args:
        runs: the level's :class:`~datagen.simulation.run.Replicas` (its tracer's replicas go on); tolerance: the
            target relative L2 error; refined: the level's edge-refinement part of the estimate (relative);
            rng: the sampling stream (for the level's error attrs); primary: (n_channels, n_bins) photons, the
            level's deterministic components; h: its edge, m; previous: (edge, primary) of the previous level, or None;
            caps: the cost and time caps (:class:`_Caps`: no replicas beyond them; ``caps.hit`` says which stopped
            the top-up), or None.
    Returns:
        (the transported mean, its ``attrs["error"]``).
    """
    for _ in range(MAX_ROUNDS):
        if runs.narrow_smoothing(tolerance):        # a smoothing bias replicas cannot bring down: a finer one
            runs.run(FIRST_TRACER_REPLICAS)
            continue
        if runs.settle_smoothing(tolerance):
            continue                                # judged (and narrowed) on more runs before replicas are planned
        mc = runs.error()
        room = tolerance * tolerance - refined * refined - runs.fixed_error() ** 2
        budget = math.sqrt(max(room, (tolerance / 3) ** 2))
        if mc <= budget or not math.isfinite(mc):
            break
        count = runs.tracer_sums.count
        wanted = math.ceil(min(count * MAX_GROWTH, replicas_needed(count, mc, budget)))
        if caps is not None:
            wanted = caps.affordable(runs, wanted)
            if wanted <= count:
                break
        runs.run(max(1, wanted - count))
    tr = runs.transported()
    return tr, _level_error(runs, tr, rng, primary, h, previous)


def _primary(tr) -> np.ndarray:
    """(n_channels, n_bins) sum of every component but the Monte Carlo ones (secondary, multibounce)."""
    keep = [i for i, name in enumerate(tr.names) if name not in ("secondary", "multibounce")]
    return tr.binned[keep].sum(axis=0)
