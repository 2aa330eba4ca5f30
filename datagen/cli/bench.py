"""Command line for benchmarks: ``datagen bench accuracy SCENE [--budget 60s] [--out DIR]``.

The command only parses and calls the library (:mod:`datagen.analysis.reference`,
:mod:`datagen.analysis.accuracy`); :mod:`datagen.cli.main` registers the ``bench`` group on its ``main`` group.
"""
from __future__ import annotations

import os
from pathlib import Path

import click

from .errors import friendly_errors


def default_cache_dir() -> Path:
    """``$DATAGEN_CACHE`` or ``$XDG_CACHE_HOME/datagen`` (``~/.cache/datagen``), plus ``references``."""
    root = os.environ.get("DATAGEN_CACHE") or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "datagen"
    return Path(root) / "references"


@click.group()
def bench():
    """Benchmarks: what accuracy costs in time."""


@bench.command()
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--budget", default="60s", show_default=True, help="wall time per estimator, e.g. 60s, 5min")
@click.option("--out", "out", default=None, type=click.Path(path_type=Path),
              help="output directory (default out/bench_accuracy/<scene name>)")
@click.option("--estimators", default=None, help="comma-separated subset of: lookin, top1, top8, exact, area, quadrature (default: all)")
@click.option("--rel-tol", default=1e-3, show_default=True, type=float,
              help="target relative L2 error estimate of the reference")
@click.option("--reference-budget", default="30min", show_default=True,
              help="most compute spent on the reference in this call (it resumes from the cache next time)")
@click.option("--reference-samples", default=None, type=int,
              help="hidden samples per reference replica (default datagen.analysis.reference.REFERENCE_SAMPLES)")
@click.option("--cache-dir", default=None, type=click.Path(path_type=Path),
              help="reference cache (default $DATAGEN_CACHE or ~/.cache/datagen, /references)")
@click.option("--seed", default=0, show_default=True, type=int, help="seed of the estimator runs")
@friendly_errors
def accuracy(scene_file, budget, out, estimators, rel_tol, reference_budget, reference_samples, cache_dir, seed):
    """Error of L(t) against wall time for each estimator on SCENE_FILE: writes accuracy.csv and accuracy.png
    (log-log, one curve per estimator, Pareto front marked) and prints the table."""
    from ..analysis.accuracy import (
        ESTIMATORS,
        format_table,
        plot_accuracy,
        run_accuracy,
        write_csv,
    )
    from ..analysis.reference import REFERENCE_SAMPLES, converged_reference
    from ..scene import load_scene
    from ..simulation import resolve_config

    scene = load_scene(scene_file)
    config = resolve_config(scene)
    budget_s = _duration(budget, "--budget")
    ref_budget_s = _duration(reference_budget, "--reference-budget")
    names = tuple(n.strip() for n in estimators.split(",") if n.strip()) if estimators else ESTIMATORS
    unknown = [n for n in names if n not in ESTIMATORS]
    if unknown:
        raise ValueError(f"--estimators: unknown estimator(s) {unknown}; known: {', '.join(ESTIMATORS)}")
    out = out or Path("out") / "bench_accuracy" / scene.name
    cache = cache_dir or default_cache_dir()

    def report(r, est):
        click.echo(f"reference replica {r}: error estimate rel L2 {est['rel_l2']:.2e}, total {est['total']:.2e}, "
                   f"peak {est['peak_time'] * 1e12:.1f} ps", err=True)

    reference = converged_reference(scene, config, rel_tol=rel_tol, cache_dir=cache,
                                    samples=reference_samples or REFERENCE_SAMPLES, max_seconds=ref_budget_s,
                                    progress=report)
    est = reference.error_estimate
    status = "converged" if reference.converged else f"NOT converged to {rel_tol:g} (budget spent)"
    click.echo(f"reference: {reference.replicas} replicas, {reference.seconds:.1f} s of compute, {status}; error "
               f"estimate rel L2 {est['rel_l2']:.2e}, total {est['total']:.2e}, peak time "
               f"{est['peak_time'] * 1e12:.1f} ps")
    rows = run_accuracy(scene, reference, config, budget=budget_s, estimators=names, seed=seed, echo=click.echo)
    csv_path = write_csv(rows, out / "accuracy.csv")
    png_path = plot_accuracy(rows, out / "accuracy.png", reference, title=f"{scene.name}: error of L(t) vs time")
    click.echo(format_table(rows))
    click.echo(f"wrote {csv_path}, {png_path}")


def _duration(value: str, name: str) -> float:
    from ..units import parse_duration

    text = str(value).strip()
    if text.endswith("min"):
        seconds = float(text[:-3]) * 60.0
    elif text.endswith("h"):
        seconds = float(text[:-1]) * 3600.0
    else:
        seconds = parse_duration(text)
    if not seconds > 0:
        raise ValueError(f"{name} must be a positive duration such as 60s or 5min, got {value!r}")
    return seconds
