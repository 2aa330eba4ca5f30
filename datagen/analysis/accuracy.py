"""What accuracy costs: the error measure, ladders of settings per estimator, and the accuracy-vs-time benchmark.

Error measure (docs/accuracy.md), :func:`envelope_error`: for an estimated binned envelope e and the reference r (same
shape, (..., n_bins)),

- ``rel_l2`` = ||e − r|| / ||r|| over the bins (of every channel) where r exceeds ``PEAK_FLOOR`` = 1 % of its
  peak;
- ``total`` = |Σe − Σr| / Σr, the relative error of the expected detections per pulse in the window;
- ``peak_time`` = |t_peak(e) − t_peak(r)| in seconds, t_peak the maximum of the channel-summed envelope
  refined to sub-bin resolution by a parabola through the top three bins.

:func:`run_accuracy` runs each estimator over its ladder of settings (:data:`LADDERS`) until its wall-time budget
is spent, measures each run's wall time (transport + binning; the shared BVH build excluded) and its error
against a :class:`datagen.analysis.reference.Reference`, marks the Pareto front (no other run is both faster and more
accurate), and :func:`write_csv` / :func:`plot_accuracy` / :func:`format_table` report it
(``datagen bench accuracy``).

Estimators (selectable by name): ``lookin`` (the paper's sampler, primary + full secondary, at N and l×p),
``top1`` and ``top8`` (the optimized secondary keeping the K strongest pairs; biased low by design, so their
error levels off), ``exact`` (the factorised exact secondary, docs/physics.md §3), ``area`` (the hidden-surface
area sampler of :mod:`datagen.transport.area`) and ``quadrature`` (the deterministic hidden-surface quadrature of
:mod:`datagen.transport.quadrature`, its edge h halving; a planned secondary comes from the area sampler, whose hidden
samples grow with the ladder, so that part of its error is Monte Carlo noise).
"""
from __future__ import annotations

import csv
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

import numpy as np

from ..errors import ConfigError
from ..scene import RayCaster, Scene
from ..timing import EnvelopeAccumulator
from ..transport.lookin.estimator import SecondaryMode
from ..transport import estimator as transport_estimator
from ..transport import estimator_names as transport_estimator_names
from .reference import PEAK_FLOOR, Reference, peak_time

__all__ = [
    "ESTIMATORS",
    "LADDERS",
    "AccuracyRow",
    "Ladder",
    "envelope_error",
    "format_table",
    "pareto_front",
    "plot_accuracy",
    "run_accuracy",
    "write_csv",
]

OVERSHOOT = 1.25
"""A ladder step runs when the time already spent plus its predicted time is within this factor of its share."""

DEADLINE_SAFETY = 1.5
"""…and when this many times its predicted time still ends before the whole budget does (predictions from the
nominal cost ratios err by tens of per cent)."""


def _envelope_and_edges(obj: Any) -> tuple[np.ndarray, np.ndarray | None]:
    if hasattr(obj, "envelope"):
        return np.asarray(obj.envelope, dtype=np.float64), getattr(obj, "time_edges", None)
    return np.asarray(obj, dtype=np.float64), None


def relative_l2(estimate: np.ndarray, reference: np.ndarray) -> float:
    """‖e − r‖ / ‖r‖ over the bins (of every channel) where r exceeds ``PEAK_FLOOR`` of its peak; 0 for an
    all-zero reference. Arrays (..., n_bins) of the same shape."""
    peak = reference.max()
    if peak <= 0:
        return 0.0
    mask = reference > PEAK_FLOOR * peak
    return float(np.linalg.norm(estimate[mask] - reference[mask]) / np.linalg.norm(reference[mask]))


def envelope_error(estimate: Any, reference: Any, time_edges: np.ndarray | None = None) -> dict[str, float]:
    """Error of a binned envelope against a reference (module docstring).

    Args:
        estimate, reference: arrays (..., n_bins) of the same shape, or objects with ``.envelope`` (and
            ``.time_edges``), e.g. :class:`datagen.simulation.Result`, :class:`datagen.analysis.reference.Reference`.
        time_edges: (n_bins+1,) seconds; default: the reference's (or the estimate's) ``time_edges``.
    Returns:
        {"rel_l2": relative L2 over bins above 1 % of the reference peak, "total": relative error of the sum,
        "peak_time": absolute peak-time error in seconds}.
    Raises:
        ConfigError: shapes differ, the reference is zero everywhere or not finite, or no time edges are known.
    """
    e, e_edges = _envelope_and_edges(estimate)
    r, r_edges = _envelope_and_edges(reference)
    edges = time_edges if time_edges is not None else (r_edges if r_edges is not None else e_edges)
    if e.shape != r.shape:
        raise ConfigError(f"envelope_error: estimate shape {e.shape} differs from reference shape {r.shape}")
    if not np.isfinite(r).all() or not np.isfinite(e).all():
        raise ConfigError("envelope_error: estimate and reference must be finite")
    if edges is None or len(edges) != r.shape[-1] + 1:
        raise ConfigError(f"envelope_error: need time_edges of length n_bins+1 = {r.shape[-1] + 1}, got "
                         f"{None if edges is None else len(edges)}")
    peak = r.max()
    if peak <= 0:
        raise ConfigError("envelope_error: the reference envelope is zero everywhere (nothing reaches the sensor)")
    edges = np.asarray(edges, dtype=np.float64)
    return {"rel_l2": relative_l2(e, r),
            "total": float(abs(e.sum() - r.sum()) / r.sum()),
            "peak_time": float(abs(peak_time(e, edges) - peak_time(r, edges)))}


@dataclass(frozen=True)
class Ladder:
    """One estimator of the benchmark and its ladder of settings.

    Attributes:
        name: CLI name; label: legend text; kind: the registered transport estimator it runs
            (:func:`datagen.transport.estimator`: "lookin", "area" or "quadrature").
        ladder: per step, the settings to override (lookin: ``lookins``, ``pixels``, ``secondary``, ``top_k``;
            area: :class:`datagen.transport.AreaSettings` fields; quadrature:
            :class:`datagen.transport.QuadratureSettings` fields).
        cost: nominal cost of a step (used with measured times to predict the next step's time).
        describe: a step's setting in a few characters (the table's "setting" column).
        run: ``(scene, config, step, caster, seed) → (envelope, seconds)`` for a step that is not one run of
            ``kind`` (the ``tolerance`` ladder: the tolerance loop), or None.
    """

    name: str
    label: str
    kind: str
    ladder: tuple[dict, ...]
    cost: Callable[[dict], float]
    describe: Callable[[dict], str]
    run: Callable[..., tuple[np.ndarray, float]] | None = None


_LOOKIN_STEPS = ((3, 12), (4, 16), (6, 20), (8, 24), (10, 30), (12, 36), (16, 44), (20, 52), (24, 60), (32, 60),
                 (45, 60), (64, 60), (90, 60), (128, 60))
"""(√N, √(l·p)) of the lookin ladder: both grow, the paper's 10×10 / 45×45 × 60×60 among them."""


def _lookin_ladder(secondary: str, top_k: int = 1) -> tuple[dict, ...]:
    return tuple({"lookins": (n, n), "pixels": (p, p), "secondary": secondary, "top_k": top_k}
                 for n, p in _LOOKIN_STEPS)


def _lookin_setting(step: dict) -> str:
    (n, _), (l, p) = step["lookins"], step["pixels"]
    return f"{n}x{n}x{l}x{p}"


def _pair_cost(step: dict) -> float:
    n, p = step["lookins"][0] ** 2, step["pixels"][0] * step["pixels"][1]
    return n * p * (1.0 + p / 400.0)            # rays, plus the O((l·p)²) pairs per lookin


def _ray_cost(step: dict) -> float:
    return step["lookins"][0] ** 2 * step["pixels"][0] * step["pixels"][1]


def _run_tolerance(scene: Scene, config, step: dict, caster: RayCaster, seed: int) -> tuple[np.ndarray, float]:
    """One step of the ``tolerance`` ladder: ``simulate_to_tolerance`` with the area estimator (a first round of 2
    replicas of 8192 hidden samples) at ``step["tolerance"]`` and the config's ``orders`` (with ``orders: auto``,
    every order the planner asks for): what ``datagen simulate --tolerance`` costs. Returns the envelope and the wall
    seconds of the whole call (plan, pilot, replicas, tracer, error estimate)."""
    from ..simulation.config import STREAM_SAMPLING, stream_rng
    from ..simulation.tolerance import simulate_to_tolerance
    from ..transport.base import estimator_options

    # first round: 2 replicas of 8192 hidden samples, as the dataset configs' (benchmarks/multibounce.py)
    cfg = config.model_copy(update={"estimator": estimator_options({"kind": "area", "samples": 16384}),
                                    "replicas": 2})
    t0 = time.perf_counter()
    result = simulate_to_tolerance(scene, cfg, step["tolerance"], sampling_rng=stream_rng(seed, STREAM_SAMPLING))
    seconds = time.perf_counter() - t0
    return np.asarray(result.envelope, dtype=np.float64), seconds


LADDERS: dict[str, Ladder] = {
    "lookin": Ladder("lookin", "lookin, full secondary", "lookin", _lookin_ladder("full"), _pair_cost,
                        _lookin_setting),
    "top1": Ladder("top1", "lookin, optimized top-1", "lookin", _lookin_ladder("optimized", 1), _pair_cost,
                      _lookin_setting),
    "top8": Ladder("top8", "lookin, optimized top-8", "lookin", _lookin_ladder("optimized", 8), _pair_cost,
                      _lookin_setting),
    "exact": Ladder("exact", "lookin, exact secondary", "lookin", _lookin_ladder("exact"), _ray_cost,
                       _lookin_setting),
    "area": Ladder("area", "area sampler", "area",
                      tuple({"samples": 1 << k} for k in range(9, 24)), lambda s: float(s["samples"]),
                      lambda s: f"M={s['samples']}"),
    "quadrature": Ladder("quadrature", "hidden-surface quadrature", "quadrature",
                            tuple({"edge": 1.6 / 2 ** i, "secondary_samples": 1 << min(13 + 2 * i, 20)}
                                  for i in range(9)),
                            lambda s: s["edge"] ** -4 + s["secondary_samples"] / 16.0,
                            lambda s: f"h={s['edge']:g} m, M2={s['secondary_samples']}"),   # M2: planned secondary
    "tolerance": Ladder("tolerance", "area, tolerance loop (the config's orders)", "area",
                        tuple({"tolerance": 0.16 / 2 ** k} for k in range(8)), lambda s: s["tolerance"] ** -2.0,
                        lambda s: f"tol={s['tolerance']:.3g}", _run_tolerance),
}
"""Every estimator of the benchmark by name."""

ESTIMATORS = tuple(name for name in LADDERS if (name != "exact" or "exact" in get_args(SecondaryMode))
                   and name != "tolerance")
"""The estimators run by default in this build (``exact`` only when transport has it); ``tolerance`` (the tolerance
loop, every order with ``orders: auto``) runs when named or with ``datagen bench accuracy --orders``."""


def ladders() -> dict[str, Ladder]:
    """:data:`LADDERS` and the ladder of every registered estimator that gives one
    (:class:`datagen.transport.AccuracyLadder`; an estimator registered after import, e.g. a plugin, included)."""
    out = dict(LADDERS)
    for name in transport_estimator_names():
        lad = transport_estimator(name).ladder
        if lad is not None and name not in out:
            out[name] = Ladder(name, lad.label, name, lad.steps, lad.cost, lad.setting)
    return out


def available_estimators() -> tuple[str, ...]:
    """Names ``run_accuracy`` takes: :data:`ESTIMATORS`, ``tolerance`` and the registered estimators' own
    ladders."""
    return ESTIMATORS + ("tolerance",) + tuple(n for n in ladders() if n not in LADDERS)


@dataclass
class AccuracyRow:
    """One run of the benchmark: estimator, setting, wall time (s), errors (see :func:`envelope_error`)."""

    estimator: str
    setting: str
    cost: float
    seconds: float
    rel_l2: float
    total: float
    peak_time: float
    pareto: bool = False


def run_estimator(scene: Scene, config, estimator: Ladder, step: dict, caster: RayCaster,
                  seed: int = 0) -> tuple[np.ndarray, float]:
    """Run one ladder step; returns the envelope (channel_shape + (n_bins,)) and its wall time (s: transport
    and binning, not the shared BVH)."""
    if estimator.run is not None:
        return estimator.run(scene, config, step, caster, seed)
    base = config.transport_settings()
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))
    t0 = time.perf_counter()
    entry = transport_estimator(estimator.kind)
    if base.secondary == "none" and "secondary" in step:      # the config asks for no secondary at all
        step = {**step, "secondary": "none"}
    settings = entry.settings_class.from_transport(base, **step)
    runner = entry.cls(scene, settings, caster)
    names, cap = runner.component_names, runner.capture
    acc = EnvelopeAccumulator(config.time, config.irf, len(names) * cap.n_channels)
    runner.run(acc, rng)
    env = acc.binned().reshape(len(names), cap.n_channels, -1).sum(0)
    seconds = time.perf_counter() - t0
    return env.reshape(cap.channel_shape() + (config.time.n_bins,)), seconds


def pareto_front(rows: list[AccuracyRow]) -> list[AccuracyRow]:
    """Mark and return the rows no other row beats in both wall time and rel_l2 (sorted by time)."""
    front, best = [], np.inf
    for row in sorted(rows, key=lambda r: (r.seconds, r.rel_l2)):
        row.pareto = row.rel_l2 < best
        if row.pareto:
            front.append(row)
            best = row.rel_l2
    return front


def run_accuracy(scene: Scene, reference: Reference, config=None, budget: float = 60.0,
                 estimators: tuple[str, ...] | None = None, seed: int = 0,
                 echo: Callable[[str], None] | None = None, caster: RayCaster | None = None,
                 ladder_table: dict[str, Ladder] | None = None) -> list[AccuracyRow]:
    """Run every estimator over its ladder within ``budget`` seconds of wall time for all of them together.

    Each estimator gets the time left divided by the estimators left (time one does not use passes to the next).
    A step runs when the time spent on the estimator plus its predicted time (the last run's time scaled by the
    nominal cost ratio, with the exponent measured on the last two steps, clipped to [0.5, 1.5]) is within
    ``OVERSHOOT`` × its share and ends before the budget does; the first step of an estimator runs while any
    budget is left. The budget is thus exceeded by at most one step (the ladders start below 0.1 s).

    Args:
        reference: from :func:`datagen.analysis.reference.converged_reference` for the same scene and config.
        config: the simulation config (default: the scene's); its sampling fields are overridden per step.
        budget: wall seconds for every estimator's ladder together (the reference not included).
        estimators: names from :func:`available_estimators` (default :data:`ESTIMATORS`).
        echo: called with one line per finished run.
        ladder_table: ladders by name that replace or add to :func:`ladders` (e.g. a scan's quadrature ladder,
            :func:`datagen.analysis.scan_accuracy.scan_ladder`).
    Returns:
        Rows in run order, Pareto front marked.
    Raises:
        ConfigError: unknown estimator name or budget ≤ 0.
    """
    from ..simulation import resolve_config

    config = config or resolve_config(scene)
    table = {**ladders(), **(ladder_table or {})}
    known = tuple(dict.fromkeys(available_estimators() + tuple(table)))
    names = tuple(estimators or ESTIMATORS)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(f"unknown estimator(s) {unknown}; known: {list(known)}")
    if not budget > 0:
        raise ConfigError(f"budget must be > 0 seconds, got {budget!r}")
    end = time.perf_counter() + budget
    caster = caster or RayCaster(scene)
    rows: list[AccuracyRow] = []
    for k, name in enumerate(names):
        est = table[name]
        share = (end - time.perf_counter()) / (len(names) - k)
        spent, times, costs = 0.0, [], []
        for step in est.ladder:
            cost = est.cost(step)
            if time.perf_counter() >= end:
                break
            if times:
                alpha = 1.0
                if len(times) >= 2 and costs[-1] > costs[-2] and times[-2] > 0:
                    alpha = float(np.clip(np.log(times[-1] / times[-2]) / np.log(costs[-1] / costs[-2]), 0.5, 1.5))
                predicted = times[-1] * (cost / costs[-1]) ** alpha
                if spent + predicted > OVERSHOOT * share or time.perf_counter() + DEADLINE_SAFETY * predicted > end:
                    break
            env, seconds = run_estimator(scene, config, est, step, caster, seed)
            err = envelope_error(env, reference)
            rows.append(AccuracyRow(name, est.describe(step), cost, seconds, **err))
            spent += seconds
            times.append(seconds)
            costs.append(cost)
            if echo is not None:
                echo(f"{name:>7} {est.describe(step):>14}: {seconds:8.2f} s  rel L2 {err['rel_l2']:.2e}  "
                     f"total {err['total']:.2e}  peak {err['peak_time'] * 1e12:7.1f} ps")
    pareto_front(rows)
    return rows


_FIELDS = ("estimator", "setting", "cost", "seconds", "rel_l2", "total", "peak_time", "pareto")


def write_csv(rows: list[AccuracyRow], path: str | Path) -> Path:
    """Write the rows as CSV (columns: estimator, setting, cost, seconds, rel_l2, total, peak_time [s],
    pareto)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(_FIELDS)
        for r in rows:
            writer.writerow([r.estimator, r.setting, f"{r.cost:.6g}", f"{r.seconds:.6g}", f"{r.rel_l2:.6g}",
                             f"{r.total:.6g}", f"{r.peak_time:.6g}", int(r.pareto)])
    return path


def plot_accuracy(rows: list[AccuracyRow], path: str | Path, reference: Reference | None = None,
                  title: str = "") -> Path:
    """Log-log PNG of relative L2 error against wall time: one curve per estimator, the Pareto front as a
    black step line with circled points, and the reference's own error estimate as a dotted line."""
    fig, ax = loglog_axes()
    for name in dict.fromkeys(r.estimator for r in rows):
        sel = [r for r in rows if r.estimator == name]
        table = ladders()
        ax.plot([r.seconds for r in sel], [max(r.rel_l2, 1e-12) for r in sel], "o-", ms=4,
                label=table[name].label if name in table else name)
    front = sorted((r for r in rows if r.pareto), key=lambda r: r.seconds)
    if front:
        ax.step([r.seconds for r in front], [r.rel_l2 for r in front], where="post", color="k", lw=1.2, ls="--",
                label="Pareto front")
        ax.plot([r.seconds for r in front], [r.rel_l2 for r in front], "o", mfc="none", mec="k", ms=10)
    if reference is not None:
        ax.axhline(reference.error_estimate["rel_l2"], color="gray", ls=":",
                   label=f"reference error estimate ({reference.error_estimate['rel_l2']:.1e})")
    return save_loglog(fig, ax, path, "wall time (s)", "relative L2 error of L(t) (bins > 1 % of peak)",
                       title or "accuracy vs time")


def loglog_axes():
    """(figure, axes) of a 7.5 × 5 in matplotlib figure (Agg backend) for an error-against-time plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(7.5, 5.0))


def save_loglog(fig, ax, path: str | Path, xlabel: str, ylabel: str, title: str) -> Path:
    """Log-log axes with labels, title, grid and legend; the figure written to ``path`` (PNG, 120 dpi, parent
    directories made) and closed. Returns the path."""
    import matplotlib.pyplot as plt

    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def format_table(rows: list[AccuracyRow]) -> str:
    """Markdown table: estimator, setting, wall time, rel L2, total error, peak-time error, Pareto mark."""
    lines = ["| estimator | setting | wall time (s) | rel L2 | total error | peak-time error (ps) | Pareto |",
             "|---|---|---:|---:|---:|---:|:---:|"]
    for r in rows:
        lines.append(f"| {r.estimator} | {r.setting} | {r.seconds:.2f} | {r.rel_l2:.2e} | {r.total:.2e} | "
                     f"{r.peak_time * 1e12:.1f} | {'*' if r.pareto else ''} |")
    return "\n".join(lines)
