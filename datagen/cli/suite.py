"""Benchmark suites: ``datagen suite build NAME``, ``datagen suite verify PATH``, ``datagen suite score NAME PRED``
(they only parse and call :mod:`datagen.dataset.suite` and :mod:`datagen.dataset.suite_score`; docs/benchmark.md)."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from .errors import friendly_errors

DEFAULT_ROOT = Path("suites")
"""Where ``suite build`` puts a suite without ``--out``, and where ``suite score`` looks for it: ``suites/NAME``."""


@click.group()
def suite():
    """Frozen benchmark suites (configs/suites/*.yaml): build, verify, score (docs/benchmark.md)."""


@suite.command("list")
@friendly_errors
def list_suites():
    """The named suites, their variants and recorded content hashes."""
    from ..dataset.suite import load_suite, suite_names

    for name in suite_names():
        s = load_suite(name)
        counts = ", ".join(f"{k} {v.count}" for k, v in s.config.splits.items())
        click.echo(f"{name}: {s.spec.description} ({counts}; variants {', '.join(s.spec.variants)}; "
                   f"content sha256 {s.spec.content_sha256 or 'not recorded'})")


@suite.command()
@click.argument("name")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="dataset directory (default: suites/NAME)")
@click.option("--workers", type=int, default=None, help="worker processes (default: CPU count; 0: in this process)")
@click.option("--resume", is_flag=True, help="continue an interrupted build")
@click.option("--quiet", is_flag=True, help="no progress bar")
@friendly_errors
def build(name, out, workers, resume, quiet):
    """Build suite NAME (configs/suites/NAME.yaml, or a suite YAML path) and print its content hash."""
    from ..dataset.suite import build_suite, hash_verdict, load_suite

    suite_def = load_suite(name)
    out = out or DEFAULT_ROOT / suite_def.name
    report, digest = build_suite(name, out, workers=workers, resume=resume, progress=not quiet)
    accepted, verdict = hash_verdict(suite_def, digest)
    click.echo(f"{out}: suite {suite_def.name}, {report.samples_built} samples built in {report.seconds:.1f} s, "
               f"{report.shards_skipped} shards already done")
    click.echo(f"content sha256 {digest} ({verdict if accepted else verdict.replace('differs', 'DIFFERS', 1)})")
    if not accepted:
        sys.exit(1)


@suite.command()
@click.argument("path", type=click.Path(path_type=Path))
@friendly_errors
def verify(path):
    """Check a built suite: every shard against its card, the content hash against the suite file (exit 1 if
    not)."""
    from ..dataset.suite import verify_suite

    notes: list[str] = []
    problems, digest = verify_suite(path, notes)
    for line in notes:
        click.echo(f"note: {line}", err=True)
    if problems:
        for line in problems:
            click.echo(f"BAD {line}", err=True)
        sys.exit(1)
    click.echo(f"{path}: ok, content sha256 {digest}")


@suite.command()
@click.argument("name")
@click.argument("pred", type=click.Path(path_type=Path))
@click.option("--dataset", type=click.Path(path_type=Path), default=None,
              help="the built suite (default: suites/NAME)")
@click.option("--variant", default=None, help="the variant the method reconstructed from (default: the first, clean)")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="folder for PRED_scores.csv / .json (default: beside PRED)")
@friendly_errors
def score(name, pred, dataset, variant, out):
    """Score a method's PRED (.npz: depth (N, H, W) m on the test split's wall-view grid, optional normal
    (N, H, W, 3), occupancy, index) on suite NAME: depth MAE / RMSE, δ-accuracy, normal angle, occupancy IoU."""
    from ..dataset.suite_score import score_suite, write_suite_scores

    scores = score_suite(pred, dataset or DEFAULT_ROOT / name, name, variant)
    csv_path, json_path = write_suite_scores(scores, out or Path(pred).parent, f"{Path(pred).stem}_scores")
    s = scores["summary"]
    parts = [f"{s['samples']} samples"]
    if s.get("depth_field"):
        parts.append(f"depth MAE {s['mean_depth_mae']:.4g} m, RMSE {s['mean_depth_rmse']:.4g} m, "
                     f"δ<1.25 {s['mean_delta_1.25']:.3f} (means over the {s['depth_samples']} samples with "
                     "object pixels)")
    if "mean_normal_angle_mean_deg" in s:
        parts.append(f"normal angle {s['mean_normal_angle_mean_deg']:.1f}°")
    if s.get("occupancy_threshold") is not None:
        parts.append(f"occupancy IoU {s['mean_occupancy_iou']:.4g}")
    click.echo(f"{s['suite']} ({s['variant']}, split {s['split']}): " + "; ".join(parts))
    click.echo(f"wrote {csv_path} and {json_path}")
