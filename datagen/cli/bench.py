"""Command line for benchmarks: ``datagen bench accuracy SCENE [--budget 60s] [--out DIR]`` and
``datagen bench accuracy --dataset CONFIG --samples N [--budget 10min]``.

The command only parses and calls the library (:mod:`datagen.analysis.reference`,
:mod:`datagen.analysis.accuracy`); :mod:`datagen.cli.main` registers the ``bench`` group on its ``main`` group.
"""
from __future__ import annotations

import os
from pathlib import Path

import click
import numpy as np

from .errors import friendly_errors


REPORT_SECONDS = 3.0
"""Wall seconds of the budget kept for writing the CSV and drawing the plot (matplotlib's import included)."""


def default_cache_dir() -> Path:
    """``$DATAGEN_CACHE`` or ``$XDG_CACHE_HOME/datagen`` (``~/.cache/datagen``), plus ``references``."""
    root = os.environ.get("DATAGEN_CACHE") or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "datagen"
    return Path(root) / "references"


@click.group()
def bench():
    """Benchmarks: what accuracy costs in time."""


@bench.command()
@click.argument("scene_file", type=click.Path(path_type=Path), required=False)
@click.option("--dataset", "dataset_file", default=None, type=click.Path(path_type=Path),
              help="instead of SCENE_FILE: a dataset config whose rooms (and simulation settings) are benchmarked")
@click.option("--samples", "n_samples", default=8, show_default=True, type=int,
              help="with --dataset: rooms (samples 0 … N-1 of --split)")
@click.option("--split", default=None, help="with --dataset: the split to draw from (default: val if present)")
@click.option("--budget", default="60s", show_default=True,
              help="wall time of the whole command, the reference included, e.g. 60s, 5min")
@click.option("--out", "out", default=None, type=click.Path(path_type=Path),
              help="output directory (default out/bench_accuracy/<scene or dataset name>)")
@click.option("--estimators", default=None,
              help="comma-separated subset of: lookin, top1, top8, exact, area, quadrature, tolerance (default: all "
                   "but tolerance; with --orders, tolerance too)")
@click.option("--orders", default=None,
              help="N or auto: the config's orders for the reference and every run (auto: the reference holds every "
                   "order, and the tolerance ladder, the area sampler's tolerance loop, adds the tracer where the "
                   "planner asks for it); default the config's")
@click.option("--rel-tol", default=None, type=float,
              help="target relative L2 error estimate of the reference (default 1e-3; 3e-3 with --dataset)")
@click.option("--reference-budget", default="30min", show_default=True,
              help="most compute spent on the reference in this call (also at most half the budget; it resumes "
                   "from the cache next time)")
@click.option("--reference-samples", default=None, type=int,
              help="hidden samples per reference replica (default datagen.analysis.reference.REFERENCE_SAMPLES)")
@click.option("--cache-dir", default=None, type=click.Path(path_type=Path),
              help="reference cache (default $DATAGEN_CACHE or ~/.cache/datagen, /references)")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="seed of the estimator runs")
@click.option("--quadrature-reference", "scan_reference", is_flag=True,
              help="for scanned captures, whose Monte Carlo reference runs once per laser point: the quadrature's "
                   "edge ladder against the quadrature at --reference-edge")
@click.option("--reference-edge", default=None, type=float,
              help="with --quadrature-reference: the reference's edge, m (default a quarter of the config's)")
@friendly_errors
def accuracy(scene_file, dataset_file, n_samples, split, budget, out, estimators, orders, rel_tol, reference_budget,
             reference_samples, cache_dir, seed, scan_reference, reference_edge):
    """Error of L(t) against wall time for each estimator, on SCENE_FILE or on --samples rooms of a --dataset
    config: writes accuracy.csv and accuracy.png (log-log; the Pareto front for a scene, median and p95 over the
    rooms for a dataset) and prints the table. --budget bounds the whole command (with --quadrature-reference, the
    ladders but not the references)."""
    import time

    t_start = time.perf_counter()
    from ..analysis.accuracy import (ESTIMATORS, available_estimators, format_table, plot_accuracy, run_accuracy,
                                     write_csv)
    from ..analysis.reference import REFERENCE_SAMPLES, check_reference_size, converged_reference
    from ..analysis.scan_accuracy import SCAN_LADDER

    budget_s = _duration(budget, "--budget")
    ref_budget_s = _duration(reference_budget, "--reference-budget")
    from ..simulation.config import orders_option

    orders = orders_option(orders, "--orders")
    names = (tuple(n.strip() for n in estimators.split(",") if n.strip()) if estimators
             else ESTIMATORS + (("tolerance",) if orders is not None else ()))
    known = available_estimators()
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"--estimators: unknown estimator(s) {unknown}; known: {', '.join(known)}")
    if (scene_file is None) == (dataset_file is None):
        raise ValueError("give a SCENE_FILE or --dataset CONFIG (one of them)")
    if scan_reference:
        if estimators and names != (SCAN_LADDER,):
            raise ValueError(f"--quadrature-reference runs the quadrature's ladder only (the other estimators run once "
                             f"per laser point), got --estimators {estimators}")
        names = (SCAN_LADDER,)
    elif reference_edge is not None:
        raise ValueError("--reference-edge goes with --quadrature-reference")
    cache = cache_dir or default_cache_dir()
    samples = reference_samples or REFERENCE_SAMPLES
    if dataset_file is not None:
        _dataset_accuracy(dataset_file, n_samples, split, budget_s - (time.perf_counter() - t_start), out, names,
                          rel_tol or 3e-3, cache, samples, seed, min(ref_budget_s, 0.5 * budget_s), scan_reference,
                          reference_edge, orders)
        return
    from ..scene import load_scene
    from ..simulation import resolve_config

    scene = load_scene(scene_file)
    config = resolve_config(scene, {"orders": orders})
    out = out or Path("out") / "bench_accuracy" / scene.name
    rel_tol = rel_tol or 1e-3
    if scan_reference:
        _scene_scan_accuracy(scene, config, reference_edge, budget_s - (time.perf_counter() - t_start), out, seed)
        return
    check_reference_size(scene, str(scene_file), samples, budget_s)

    def report(r, est):
        click.echo(f"reference replica {r}: error estimate rel L2 {est['rel_l2']:.2e}, total {est['total']:.2e}, "
                   f"peak {est['peak_time'] * 1e12:.1f} ps", err=True)

    reference = converged_reference(scene, config, rel_tol=rel_tol, cache_dir=cache, samples=samples,
                                    max_seconds=min(ref_budget_s, 0.5 * budget_s), progress=report)
    est = reference.error_estimate
    status = "converged" if reference.converged else f"NOT converged to {rel_tol:g} (budget spent; it resumes " \
                                                     f"from the cache next time)"
    click.echo(f"reference: {reference.replicas} replicas, {reference.seconds:.1f} s of compute, {status}; error "
               f"estimate rel L2 {est['rel_l2']:.2e}, total {est['total']:.2e}, peak time "
               f"{est['peak_time'] * 1e12:.1f} ps")
    left = budget_s - (time.perf_counter() - t_start) - REPORT_SECONDS
    if left <= 0:
        raise ValueError(f"--budget {budget} was spent on the reference; give more, or run again (it is cached)")
    rows = run_accuracy(scene, reference, config, budget=left, estimators=names, seed=seed, echo=click.echo)
    csv_path = write_csv(rows, out / "accuracy.csv")
    png_path = plot_accuracy(rows, out / "accuracy.png", reference, title=f"{scene.name}: error of L(t) vs time")
    click.echo(format_table(rows))
    click.echo(f"wrote {csv_path}, {png_path} ({time.perf_counter() - t_start:.1f} s of a {budget_s:g} s budget)")


def _scene_scan_accuracy(scene, config, reference_edge, budget_s, out, seed):
    """``--quadrature-reference`` on one scene: the scan's quadrature ladder against the quadrature at the
    reference edge (:mod:`datagen.analysis.scan_accuracy`)."""
    import time

    from ..analysis.accuracy import format_table, plot_accuracy, run_accuracy, write_csv
    from ..analysis.scan_accuracy import SCAN_LADDER, scan_benchmark
    from ..scene import RayCaster

    t_start = time.perf_counter()
    caster = RayCaster(scene)
    reference, table = scan_benchmark(scene, config, reference_edge, caster)
    click.echo(f"reference: quadrature h = {reference.settings['edge']:.3g} m, {reference.seconds:.1f} s; its error "
               f"estimate ‖P(h) − P(2h)‖/3 = {reference.error_estimate['rel_l2']:.2e}")
    left = budget_s - (time.perf_counter() - t_start) - REPORT_SECONDS
    if left <= 0:
        raise ValueError(f"--budget was spent on the reference ({reference.seconds:.0f} s); give more, or a coarser "
                         f"--reference-edge")
    rows = run_accuracy(scene, reference, config, budget=left, estimators=(SCAN_LADDER,), seed=seed,
                        echo=click.echo, caster=caster, ladder_table=table)
    csv_path = write_csv(rows, out / "accuracy.csv")
    png_path = plot_accuracy(rows, out / "accuracy.png", reference,
                             title=f"{scene.name}: quadrature error of L(t) vs time")
    click.echo(format_table(rows))
    click.echo(f"wrote {csv_path}, {png_path}")


def _dataset_accuracy(dataset_file, n_samples, split, budget_s, out, names, rel_tol, cache, samples, seed,
                      reference_budget, scan_reference=False, reference_edge=None, orders=None):
    import time

    from ..analysis.rooms_accuracy import (format_rooms_table, plot_rooms, run_rooms_accuracy, summarize,
                                           write_rooms_csv)
    from ..analysis.reference import check_reference_size
    from ..dataset import load_dataset_config, sample_setup

    t0 = time.perf_counter()
    config = load_dataset_config(dataset_file)
    split = split or ("val" if "val" in config.splits else next(iter(config.splits)))
    if split not in config.splits:
        raise ValueError(f"--split: {split!r} is not a split of {dataset_file} ({', '.join(config.splits)})")
    count = config.splits[split].count
    if not 1 <= n_samples <= count:
        raise ValueError(f"--samples must be in [1, {count}] (split {split!r} of {dataset_file}), got {n_samples}")
    rooms = [(f"{split}[{i}]", *sample_setup(config, split, i)) for i in range(n_samples)]
    if orders is not None:
        from ..simulation.config import SimulationConfig, merge_overrides

        rooms = [(name, scene,
                  SimulationConfig.model_validate(merge_overrides(sim.model_dump(), {"orders": orders})[0]))
                 for name, scene, sim in rooms]
    if not scan_reference:
        check_reference_size(rooms[0][1], f"{dataset_file} ({split}[0])", samples, budget_s)   # rooms scan alike
    budget_s -= REPORT_SECONDS
    out = out or Path("out") / "bench_accuracy" / f"dataset_{config.name}"
    share = min(0.5, reference_budget / max(budget_s, 1e-9))          # of each room's share of the budget
    rows, refs = run_rooms_accuracy(rooms, budget_s - (time.perf_counter() - t0), estimators=names, rel_tol=rel_tol,
                                    cache_dir=cache, reference_share=max(share, 1e-3), reference_samples=samples,
                                    seed=seed, echo=click.echo, scan_reference=scan_reference,
                                    reference_edge=reference_edge)
    summary = summarize(rows)
    csv_path = write_rooms_csv(rows, summary, out / "accuracy.csv")
    png_path = plot_rooms(summary, out / "accuracy.png",
                          title=f"{config.name}: error of L(t) vs time over {len(refs)} rooms of {split!r}")
    ref_err = [r.error_estimate["rel_l2"] for r in refs]
    converged = (f"; {sum(r.converged for r in refs)} converged to {rel_tol:g}" if not scan_reference else
                 " (the quadrature at the reference edge, ‖P(h) − P(2h)‖/3)")
    median, largest = (float(np.median(ref_err)), max(ref_err)) if ref_err else (float("nan"), float("nan"))
    click.echo(f"references: {len(refs)} rooms, error estimate median {median:.2e}, max {largest:.2e}{converged}")
    click.echo(format_rooms_table(summary))
    click.echo(f"wrote {csv_path}, {png_path}")


def _duration(value: str, name: str) -> float:
    """``value`` ("60s", "5min", "2h", a number of seconds) in seconds > 0 (:func:`datagen.units.parse_duration`)."""
    from ..errors import ConfigError
    from ..units import parse_duration

    try:
        seconds = parse_duration(str(value).strip())
    except ValueError as exc:
        raise ConfigError(f"{name}: {exc}") from None
    if not seconds > 0:
        raise ConfigError(f"{name} must be a positive duration such as 60s or 5min, got {value!r}")
    return seconds
