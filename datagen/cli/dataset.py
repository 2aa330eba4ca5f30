"""Dataset commands: ``datagen build``, ``datagen inspect``, ``datagen verify`` (they only parse and call
:mod:`datagen.dataset.build` and :mod:`datagen.dataset.loader`)."""
from __future__ import annotations

import sys
from functools import wraps
from pathlib import Path

import click

from .errors import check_output_file, fail, friendly_errors


def _dataset_errors(func):
    """Bad input, a locked or damaged store, a full disk, an unreachable scheduler → one ``error: …`` line and
    exit 2 (:func:`datagen.cli.errors.friendly_errors`); failed shards → their list and exit 1."""

    @wraps(func)
    def wrapper(*args, **kwargs):
        from ..dataset import BuildError
        from ..dataset.store import BuildLockedError
        try:
            return friendly_errors(func)(*args, **kwargs)
        except BuildError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)
        except BuildLockedError as exc:
            fail(exc)

    return wrapper


@click.command()
@click.argument("config_file", type=click.Path(path_type=Path))
@click.option("--out", required=True, type=click.Path(path_type=Path), help="dataset directory (Zarr v3)")
@click.option("--workers", type=int, default=None,
              help="worker processes (default: CPU count; 0: in this process) or LocalCluster workers")
@click.option("--scheduler", default=None,
              help="'local' (Dask LocalCluster) or a Dask scheduler address such as tcp://HOST:8786 (its workers "
                   "must see --out at the same path: a shared file system)")
@click.option("--worker-timeout", type=float, default=60.0, show_default=True, metavar="SECONDS",
              help="with a scheduler address: give up when no Dask worker is connected for this long (at the "
                   "start, or when every worker is gone mid-build)")
@click.option("--resume", is_flag=True, help="continue an interrupted build: skip shards already done")
@click.option("--retries", type=int, default=2, show_default=True, help="extra attempts of a failed shard")
@click.option("--tasks-per-worker", type=int, default=4, show_default=True,
              help="shards a local worker process computes before it is replaced (bounds memory)")
@click.option("--quiet", is_flag=True, help="no progress bar")
@click.option("--splits", "split_counts", default=None, metavar="NAME=N,...",
              help="build only these splits with these counts, e.g. train=1024,val=256 (sample i is the same as in "
                   "the full build: a smaller build is a prefix of it; the other splits are left out, a split at 0 "
                   "is kept empty, at least one count must be > 0)")
@_dataset_errors
def build(config_file, out, workers, scheduler, worker_timeout, resume, retries, tasks_per_worker, quiet,
          split_counts):
    """Build the dataset of CONFIG_FILE (configs/datasets/*.yaml) into OUT, shard by shard."""
    from ..dataset import build_dataset, load_dataset_config
    from ..dataset.probe import missed_notice

    config = load_dataset_config(config_file)
    if split_counts is not None:
        config = config.model_copy(update={"splits": _cut_splits(config, split_counts, config_file)})
    report = build_dataset(config, out, workers=workers, scheduler=scheduler, resume=resume, retries=retries,
                           max_tasks_per_child=tasks_per_worker, progress=not quiet, worker_timeout=worker_timeout)
    for line in report.repairs:
        click.echo(f"repaired: {line}", err=True)
    timing = report.card.get("timing", {}).get("per_sample_s", {})
    click.echo(f"{out}: {report.shards_built} shards built ({report.samples_built} samples, "
               f"{report.samples_per_second:.2f} samples/s, {report.engine}), {report.shards_skipped} already done; "
               f"status {report.card.get('status')}; per sample {timing.get('mean', float('nan')):.3f} s mean")
    missed = missed_notice(report.card)
    if missed is not None:     # with or without --quiet: a dataset that misses its target says so
        click.echo(f"warning: {missed}", err=True)


def _cut_splits(config, text: str, config_file) -> dict:
    """``--splits train=1024,val=256``: those splits of ``config`` (with their overrides) at those counts; the
    other splits are left out. A split may be given count 0 (it is kept, empty) as long as one has samples.

    Raises:
        ValueError: an unknown or repeated split, a count that is not an integer >= 0, or every count 0 (one
            line naming --splits and the value).
    """
    splits = {}
    for part in text.split(","):
        name, _, count = part.partition("=")
        name = name.strip()
        if name not in config.splits:
            raise ValueError(f"{config_file}: --splits: no split {name!r} (splits: {', '.join(config.splits)})")
        if name in splits:
            raise ValueError(f"--splits {text!r}: split {name!r} is given twice")
        try:
            n = int(count)
        except ValueError:
            raise ValueError(f"--splits: {part!r} is not NAME=COUNT with an integer count") from None
        if n < 0:
            raise ValueError(f"--splits: count of {name!r} must be >= 0, got {n}")
        splits[name] = config.splits[name].model_copy(update={"count": n})
    if not any(spec.count for spec in splits.values()):
        raise ValueError(f"--splits {text!r}: every split it builds has count 0 (the splits it leaves out are not "
                         "built): nothing to build; give at least one split a count > 0")
    return splits


def card_summary(card: dict) -> str:
    """Short text summary of a dataset card: status, versions, splits and their fields, the envelope errors
    against the tolerance (and the samples that missed it), timings."""
    config, versions = card.get("config") or {}, card.get("versions") or {}   # a hand-edited card may lack them
    lines = [f"dataset {card.get('name')!r}: {card.get('status')} "
             f"({card.get('shards_done')}/{card.get('shards_total')} shards), seed {config.get('seed')}, "
             f"shard size {config.get('shard_size')}",
             f"code {card.get('code_version')}; zarr {versions.get('zarr')}, numpy "
             f"{versions.get('numpy')}, python {versions.get('python')}"]
    t = card.get("time_edges")
    if t:
        lines.append(f"time axis: {t['n_bins']} bins of {t['bin_width'] * 1e12:.1f} ps "
                     f"from {t['t_start'] * 1e9:.2f} ns")
    for split, info in card.get("splits", {}).items():
        lines.append(f"split {split}: {info.get('count')} samples in {info.get('n_shards')} shards "
                     f"(split_key {info.get('split_key')})")
        for name, spec in (info.get("fields") or {}).items():
            lines.append(f"    {name:<18} {str(tuple(spec['shape'])):<16} {spec['dtype']}")
    acc = card.get("accuracy")
    if acc and acc["envelope_error"].get("n"):
        e = acc["envelope_error"]
        lines.append(f"envelope error (stated relative L2, tolerance {acc['tolerance']:.2%}, time cap "
                     f"{acc['time_cap_s']:g} s): median {e['median']:.2%}, p95 {e['p95']:.2%}, max {e['max']:.2%} "
                     f"over {e['n']} samples; {acc['n_missed']} missed the tolerance")
        for m in acc["missed"][:10]:
            lines.append(f"    missed: {m['split']}[{m['index']}] estimated error {m['envelope_error']:.2%}")
        if acc["n_missed"] > 10:
            lines.append(f"    … and {acc['n_missed'] - 10} more (the card's accuracy.missed lists them)")
    ts = card.get("timing", {}).get("per_sample_s", {})
    if ts.get("n"):
        lines.append(f"per-sample build time: mean {ts['mean']:.3f} s, median {ts['median']:.3f} s, "
                     f"p95 {ts['p95']:.3f} s, max {ts['max']:.3f} s over {ts['n']} samples")
    for run in card.get("runs", []):
        rate = run.get("samples_per_s")
        lines.append(f"run {run['finished']}: {run['samples']} samples on {run['engine']} "
                     f"({rate:.2f} samples/s)" if rate else f"run {run['finished']}: nothing to do")
    return "\n".join(lines)


PICTURE_WIDTH_IN = 6.4
"""Width in inches of a sample's 3D picture in ``datagen inspect``'s figure (its envelope and labels: 13.5)."""


def sample_pictures(path: Path, split: str, count: int, note) -> list | None:
    """3D pictures of samples 0 … count − 1 of ``split`` for ``datagen inspect``: (500, 780, 3) uint8 each,
    legend included (:func:`datagen.dataset.scene_of_sample`, :func:`datagen.plot.render_scene`).

    Returns None after one ``note`` line when open3d or a Vulkan driver is missing, the renderer fails or a
    sample's room cannot be drawn again; the caller then draws its figure without them."""
    from ..dataset import scene_of_sample
    from ..plot import ViewUnavailable, render_scene
    from ..plot.view_worker import require_open3d
    from ..errors import DatagenError

    try:
        require_open3d()
        return [render_scene(scene_of_sample(path, split, i)[0].scene, None, width=780, height=500,
                             title=f"{split}[{i}]") for i in range(count)]
    except (ViewUnavailable, RuntimeError, DatagenError) as exc:
        note(f"note: no 3D sample pictures: {' '.join(str(exc).split())}")
        return None


@click.command()
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--split", default=None, help="split to draw (default: the first)")
@click.option("--samples", "n_samples", type=int, default=3, show_default=True, help="samples in the PNG")
@click.option("--png", type=click.Path(path_type=Path), default=None,
              help="figure to write (default: PATH/inspect.png)")
@click.option("--config", "show_config", is_flag=True, help="also print the full config of the card (YAML)")
@click.option("--no-3d", "no_3d", is_flag=True,
              help="no 3D pictures of the samples' rooms (faster: no open3d renderer is started)")
@_dataset_errors
def inspect(path, split, n_samples, png, show_config, no_3d):
    """Summarise the dataset at PATH (its card) and draw a few samples to a PNG (with a 3D picture of each
    sample's room when open3d can render, unless --no-3d). An unfinished build gets its summary, then one
    ``error:`` line naming the shards not built and ``--resume`` (exit 2)."""
    import matplotlib
    matplotlib.use("Agg")
    import yaml
    from matplotlib.figure import Figure

    from ..dataset import NLOSDataset, plot_sample, read_card
    from ..dataset.integrity import require_complete

    if png is not None:
        check_output_file(png, "--png")
    card = read_card(path)
    click.echo(card_summary(card))
    if show_config:
        click.echo(yaml.safe_dump(card["config"], sort_keys=False))
    require_complete(path, card)   # the summary shows the progress; no figure of an unfinished build
    split = split or next((s for s, i in card["splits"].items() if i["count"] > 0), None)
    if split is None:
        return
    ds = NLOSDataset(path, split=split)
    n = max(1, min(n_samples, len(ds)))
    pictures = None if no_3d else sample_pictures(path, split, n, note=click.echo)
    fig = Figure(figsize=(13.5 + (PICTURE_WIDTH_IN if pictures else 0), (4.2 if pictures else 3.4) * n),
                 layout="constrained")
    subfigs = fig.subfigures(n, 1, squeeze=False)[:, 0]
    from ..dataset.figures import plot_scan_sample, scan_image_shape
    for i, sub in enumerate(subfigs):
        if pictures:                          # the sample's 3D picture on the left of its envelope and labels
            pic, sub = sub.subfigures(1, 2, width_ratios=[PICTURE_WIDTH_IN, 13.5])
            ax = pic.add_subplot()
            ax.imshow(pictures[i])
            ax.set_axis_off()
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
@click.option("--quiet", is_flag=True, help="no progress bar")
@_dataset_errors
def verify(path, quiet):
    """Check that every shard of the dataset at PATH is present and hashes as its card says (exit 1 if not)."""
    from ..dataset import read_card, verify_dataset

    notes: list[str] = []
    problems = verify_dataset(path, notes, progress=not quiet)
    for line in notes:
        click.echo(f"note: {line}", err=True)
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
              help="folder for PRED_scores.csv and PRED_scores.json (default: beside PRED)")
@_dataset_errors
def score(pred, dataset, split, depth_field, threshold, out):
    """Score reconstructions PRED (.npz: depth (N, H, W) m and/or occupancy (N, V, V, V), optional index (N,))
    against a split's labels: depth MAE/RMSE over the hidden objects, occupancy IoU (docs/datasets.md)."""
    from ..dataset.score import score_predictions, write_scores

    scores = score_predictions(pred, dataset, split, depth_field, threshold)
    csv_path, json_path = write_scores(scores, out or Path(pred).parent, f"{Path(pred).stem}_scores")
    s = scores["summary"]
    parts = [f"{s['samples']} samples"]
    if s.get("depth_field"):
        parts.append(f"depth MAE {s['mean_depth_mae']:.4g} m, RMSE {s['mean_depth_rmse']:.4g} m (mean over the "
                     f"{s['depth_samples']} samples with object pixels; pooled over {s['depth_pixels']} pixels: "
                     f"{s['pooled_depth_mae']:.4g} / {s['pooled_depth_rmse']:.4g} m)")
    if s.get("occupancy_threshold") is not None:
        parts.append(f"occupancy IoU {s['mean_occupancy_iou']:.4g}")
    click.echo(f"{split}: " + "; ".join(parts))
    click.echo(f"wrote {csv_path} and {json_path}")
