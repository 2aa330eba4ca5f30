"""Dataset commands: ``datagen build``, ``datagen inspect``, ``datagen verify`` (they only parse and call
:mod:`datagen.dataset.build` and :mod:`datagen.dataset.loader`)."""
from __future__ import annotations

import sys
from functools import wraps
from pathlib import Path

import click

from ..scene import SceneError


def _dataset_errors(func):
    """Bad input → one ``error: …`` line and exit 2; failed shards → their list and exit 1."""

    @wraps(func)
    def wrapper(*args, **kwargs):
        from ..dataset import BuildError, BuildLockedError
        try:
            return func(*args, **kwargs)
        except BuildError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)
        except (SceneError, ValueError, FileNotFoundError, FileExistsError, BuildLockedError) as exc:
            click.echo(f"error: {' '.join(str(exc).split())}", err=True)
            sys.exit(2)

    return wrapper


@click.command()
@click.argument("config_file", type=click.Path(path_type=Path))
@click.option("--out", required=True, type=click.Path(path_type=Path), help="dataset directory (Zarr v3)")
@click.option("--workers", type=int, default=None,
              help="worker processes (default: CPU count; 0: in this process) or LocalCluster workers")
@click.option("--scheduler", default=None,
              help="'local' (Dask LocalCluster) or a Dask scheduler address such as tcp://HOST:8786")
@click.option("--resume", is_flag=True, help="continue an interrupted build: skip shards already done")
@click.option("--retries", type=int, default=2, show_default=True, help="extra attempts of a failed shard")
@click.option("--tasks-per-worker", type=int, default=4, show_default=True,
              help="shards a local worker process computes before it is replaced (bounds memory)")
@click.option("--quiet", is_flag=True, help="no progress bar")
@_dataset_errors
def build(config_file, out, workers, scheduler, resume, retries, tasks_per_worker, quiet):
    """Build the dataset of CONFIG_FILE (configs/datasets/*.yaml) into OUT, shard by shard."""
    from ..dataset import build_dataset, load_dataset_config

    if workers is not None and workers < 0:
        raise ValueError(f"--workers must be >= 0, got {workers}")
    config = load_dataset_config(config_file)
    report = build_dataset(config, out, workers=workers, scheduler=scheduler, resume=resume, retries=retries,
                           max_tasks_per_child=tasks_per_worker, progress=not quiet)
    timing = report.card.get("timing", {}).get("per_sample_s", {})
    click.echo(f"{out}: {report.shards_built} shards built ({report.samples_built} samples, "
               f"{report.samples_per_second:.2f} samples/s, {report.engine}), {report.shards_skipped} already done; "
               f"status {report.card.get('status')}; per sample {timing.get('mean', float('nan')):.3f} s mean")


def card_summary(card: dict) -> str:
    """Short text summary of a dataset card: status, versions, splits and their fields, timings."""
    lines = [f"dataset {card.get('name')!r}: {card.get('status')} "
             f"({card.get('shards_done')}/{card.get('shards_total')} shards), seed {card['config']['seed']}, "
             f"shard size {card['config']['shard_size']}",
             f"code {card.get('code_version')}; zarr {card['versions'].get('zarr')}, numpy "
             f"{card['versions'].get('numpy')}, python {card['versions'].get('python')}"]
    t = card.get("time_edges")
    if t:
        lines.append(f"time axis: {t['n_bins']} bins of {t['bin_width'] * 1e12:.1f} ps "
                     f"from {t['t_start'] * 1e9:.2f} ns")
    for split, info in card.get("splits", {}).items():
        lines.append(f"split {split}: {info['count']} samples in {info['n_shards']} shards "
                     f"(split_key {info['split_key']})")
        for name, spec in info["fields"].items():
            lines.append(f"    {name:<18} {str(tuple(spec['shape'])):<16} {spec['dtype']}")
    ts = card.get("timing", {}).get("per_sample_s", {})
    if ts.get("n"):
        lines.append(f"per-sample build time: mean {ts['mean']:.3f} s, median {ts['median']:.3f} s, "
                     f"p95 {ts['p95']:.3f} s, max {ts['max']:.3f} s over {ts['n']} samples")
    for run in card.get("runs", []):
        rate = run.get("samples_per_s")
        lines.append(f"run {run['finished']}: {run['samples']} samples on {run['engine']} "
                     f"({rate:.2f} samples/s)" if rate else f"run {run['finished']}: nothing to do")
    return "\n".join(lines)


@click.command()
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--split", default=None, help="split to draw (default: the first)")
@click.option("--samples", "n_samples", type=int, default=3, show_default=True, help="samples in the PNG")
@click.option("--png", type=click.Path(path_type=Path), default=None,
              help="figure to write (default: PATH/inspect.png)")
@click.option("--config", "show_config", is_flag=True, help="also print the full config of the card (YAML)")
@_dataset_errors
def inspect(path, split, n_samples, png, show_config):
    """Summarise the dataset at PATH (its card) and draw a few samples to a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import yaml
    from matplotlib.figure import Figure

    from ..dataset import NLOSDataset, plot_sample, read_card

    card = read_card(path)
    click.echo(card_summary(card))
    if show_config:
        click.echo(yaml.safe_dump(card["config"], sort_keys=False))
    if card.get("status") != "complete":
        click.echo("(no figure: the build is not complete)")
        return
    split = split or next((s for s, i in card["splits"].items() if i["count"] > 0), None)
    if split is None:
        return
    ds = NLOSDataset(path, split=split)
    n = max(1, min(n_samples, len(ds)))
    fig = Figure(figsize=(13.5, 3.4 * n), layout="constrained")
    subfigs = fig.subfigures(n, 1, squeeze=False)[:, 0]
    from ..dataset.figures import plot_scan_sample, scan_image_shape
    for i, sub in enumerate(subfigs):
        sample = ds.read(i)
        if "envelope" in sample and scan_image_shape(sample["envelope"]) is not None:   # a scan: images
            plot_scan_sample(sample, ds.time_edges, f"{split}[{i}]", fig=sub)
        else:
            plot_sample(sample, ds.time_edges, f"{split}[{i}]", fig=sub)
    png = png or Path(path) / "inspect.png"
    fig.savefig(png, dpi=90)
    click.echo(f"wrote {png}")


@click.command()
@click.argument("path", type=click.Path(path_type=Path))
@_dataset_errors
def verify(path):
    """Check that every shard of the dataset at PATH is present and hashes as its card says (exit 1 if not)."""
    from ..dataset import read_card, verify_dataset

    problems = verify_dataset(path)
    if problems:
        for line in problems:
            click.echo(f"BAD {line}", err=True)
        click.echo(f"{path}: {len(problems)} problem(s)", err=True)
        sys.exit(1)
    card = read_card(path)
    n_arrays = sum(len(info["fields"]) * info["n_shards"] for info in card["splits"].values())
    click.echo(f"{path}: ok, {card['shards_total']} shards ({n_arrays} shard files) match the card's sha256")


@click.command()
@click.argument("pred", type=click.Path(path_type=Path))
@click.option("--dataset", "dataset", required=True, type=click.Path(path_type=Path), help="dataset directory")
@click.option("--split", default="test", show_default=True, help="split the predictions belong to")
@click.option("--depth-field", default="wall_depth", show_default=True,
              help="label the depth predictions are compared with (wall_depth: orthographic from the scanned wall)")
@click.option("--threshold", type=float, default=0.5, show_default=True, help="occupancy: occupied above this")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="folder for scores.csv and scores.json (default: beside PRED)")
@_dataset_errors
def score(pred, dataset, split, depth_field, threshold, out):
    """Score reconstructions PRED (.npz: depth (N, H, W) m and/or occupancy (N, V, V, V), optional index (N,))
    against a split's labels: depth MAE/RMSE over the hidden objects, occupancy IoU (docs/datasets.md)."""
    from ..dataset.score import score_predictions, write_scores

    scores = score_predictions(pred, dataset, split, depth_field, threshold)
    csv_path, json_path = write_scores(scores, out or Path(pred).parent)
    s = scores["summary"]
    parts = [f"{s['samples']} samples"]
    if s.get("depth_field"):
        parts.append(f"depth MAE {s['mean_depth_mae']:.4g} m, RMSE {s['mean_depth_rmse']:.4g} m (mean over samples; "
                     f"pooled over {s['depth_pixels']} pixels: {s['pooled_depth_mae']:.4g} / "
                     f"{s['pooled_depth_rmse']:.4g} m)")
    if s.get("occupancy_threshold") is not None:
        parts.append(f"occupancy IoU {s['mean_occupancy_iou']:.4g}")
    click.echo(f"{split}: " + "; ".join(parts))
    click.echo(f"wrote {csv_path} and {json_path}")
