"""Command line for the tal interop (:mod:`datagen.io.tal`, :mod:`datagen.io.tal_hdf5`): ``datagen tal-render``
and ``datagen export-tal``.

The commands only parse and call the library; :mod:`datagen.cli.main` registers them on its ``main`` group.
"""
from __future__ import annotations

import os
from pathlib import Path

import click

from .. import validate
from ..transport import estimator_names

from .errors import friendly_errors


def check_out_file(out: Path, example: str = "capture.hdf5") -> None:
    """Refuse, before any work, an ``--out`` file that is a directory, lies under a file, or whose nearest
    existing parent directory is not writable (the HDF5 is written beside it as ``OUT.partial``, then renamed).

    ``example`` is the file name the message suggests inside a directory (its suffix: the format's).

    Raises:
        IsADirectoryError / NotADirectoryError / PermissionError: naming ``--out`` and the path.
    """
    out = Path(out)
    if out.is_dir():
        raise IsADirectoryError(f"--out {out} is a directory; give the {Path(example).suffix} file to write, e.g. "
                                f"{out / example}")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise NotADirectoryError(f"--out {out}: cannot create it, {parent} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"--out {out}: {parent} is not writable")


def read_result_input(path: Path, command: str, dataset_hint: str):
    """The :class:`datagen.simulation.Result` stored at ``path`` (the output of ``datagen simulate``: OUT or
    OUT/result.zarr) for ``command`` (``export-tal``, ``detect``).

    Raises:
        DatasetIncompleteError: ``path`` is a dataset whose build is not complete (as every reader refuses it);
        ValueError: ``path`` is a (complete) dataset (the message ends with ``dataset_hint``, what to do
        instead) or a Zarr store that is not a result; FileNotFoundError: no store at ``path``.
    """
    from ..dataset.integrity import is_dataset, require_complete
    from ..io import read_result

    path = Path(path)
    for root in (path, path.parent):                       # a dataset, or one of its split folders
        if is_dataset(root):
            require_complete(root)
            what = "a datagen dataset" if root == path else f"a split folder of the datagen dataset {root}"
            raise ValueError(f"{path} is {what}, not a result store; {dataset_hint}")
    try:
        return read_result(path)
    except (KeyError, AttributeError, TypeError):            # a Zarr store without a result's arrays
        raise ValueError(f"{path} is a Zarr store but not a datagen result (it lacks the envelope, counts or "
                         f"components arrays); {command} takes the output of `datagen simulate` (OUT or "
                         "OUT/result.zarr)") from None


def _h_summary(path: Path) -> str:
    from ..io import read_tal_hdf5

    data = read_tal_hdf5(path)
    H = data["H"]
    return (f"H {data['H_format'].name} {tuple(H.shape)}: sum {float(H.sum()):.6g}, max {float(H.max()):.6g}; "
            f"delta_t {data['delta_t']:.6g} m, t_start {data['t_start']:.6g} m (OPL), "
            f"first/last legs {'in' if data['t_accounts_first_and_last_bounces'] else 'not in'} the time axis")


@click.command("tal-render")
@click.argument("config_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output .hdf5 file")
@click.option("--lookins", default=None, help="lookin estimator with this lookin grid, e.g. 1024x1024")
@click.option("--pixels", default=None, help="hemispherical camera pixels per lookin, e.g. 60x60")
@click.option("--estimator", type=click.Choice(estimator_names()),
              default=None,
              help="quadrature (default: deterministic hidden-surface quadrature, datagen.transport.quadrature), area "
                   "(hidden-surface area sampling, datagen.transport.area) or lookin (the paper's sampler)")
@click.option("--edge", type=float, default=None,
              help="quadrature: largest hidden sub-triangle edge in metres (default 0.02)")
@click.option("--samples", type=int, default=None,
              help="area estimator: hidden samples per laser point (default 65536; quadrature: for a planned "
                   "secondary)")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of every random stream")
@click.option("--float32", "float32", is_flag=True, help="store H as float32 (as tal render does)")
@click.option("--compression", type=click.IntRange(0, 9), default=0, help="gzip level for H (0: none)")
@click.option("--quiet", is_flag=True, help="no progress bar")
@friendly_errors
def tal_render(config_file, out, lookins, pixels, estimator, edge, samples, seed, float32, compression, quiet):
    """Render a `tal render` YAML (y-tal 0.20) with datagen and write a tal HDF5 capture to OUT.

    H is what `tal render` estimates (radiance toward the sensor, tal's laser normalisation, OPL bins),
    laid out on tal's grids; it loads with tal.io.read_capture.
    """
    import time

    from ..simulation import resolve_config, simulate
    from ..io import scene_from_tal_yaml, write_tal_hdf5

    check_out_file(out)
    t0 = time.perf_counter()
    scene, tal = scene_from_tal_yaml(config_file)
    if estimator is None and (lookins or pixels):
        estimator = "lookin"          # lookin options mean the lookin estimator (the default is quadrature)
    elif estimator is None and samples is not None and edge is None:
        estimator = "area"            # and --samples alone the area estimator
    config = resolve_config(scene, {"lookins": lookins, "pixels": pixels, "estimator": estimator,
                                    "quadrature_edge": edge, "area_samples": samples, "seed": seed})
    result = simulate(scene, config, progress=not quiet)
    out.parent.mkdir(parents=True, exist_ok=True)
    args = {"command": "tal-render", "config_file": str(config_file), "lookins": lookins, "pixels": pixels,
            "estimator": estimator, "edge": edge, "samples": samples, "seed": seed, "float32": float32,
            "compression": compression}
    write_tal_hdf5(result, out, tal, compression_level=compression, dtype="float32" if float32 else "float64",
                   scene_info={"args": args})
    for note in tal.notes:
        click.echo(f"note: {note}")
    click.echo(_h_summary(out))
    click.echo(f"wall time {time.perf_counter() - t0:.2f} s (transport {result.attrs['timings_s']['transport']:.2f} s)")
    click.echo(f"wrote {out}")


@click.command("export-tal")
@click.argument("result_path", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output .hdf5 file")
@click.option("--split", default=None, help="RESULT_PATH is a dataset: the split of the sample to export")
@click.option("--index", type=int, default=None, help="RESULT_PATH is a dataset: the index of the sample in --split")
@click.option("--counts", "use_counts", is_flag=True,
              help="dataset sample: export the SPAD counts instead of the envelope as H")
@click.option("--float32", "float32", is_flag=True, help="store H as float32")
@click.option("--compression", type=click.IntRange(0, 9), default=0, help="gzip level for H (0: none)")
@friendly_errors
def export_tal(result_path, out, split, index, use_counts, float32, compression):
    """Write a datagen result, or one sample of a dataset, as a tal HDF5 capture.

    RESULT_PATH: a result directory or its result.zarr; or a dataset directory with --split and --index (the
    sample's wall grids are regenerated from the dataset's config, datagen.dataset.export). H is the envelope
    (or --counts) in its own convention (scene_info records which), Sx along the wall's horizontal tangent and Sy
    along the wall's up direction. OUT is checked before any work; a dataset whose build is not complete is
    refused (naming the shards not built and --resume).
    """
    from ..dataset.integrity import require_complete
    from ..io import write_tal_hdf5

    check_out_file(out)
    info = None
    if split is not None or index is not None:
        from ..dataset.export import sample_result

        if split is None or index is None:
            raise ValueError("a dataset sample needs both --split and --index")
        require_complete(result_path)   # an unfinished build's unbuilt samples read as zeros: refused
        result = sample_result(result_path, split, index, "counts" if use_counts else "envelope")
        info = {"dataset": result.attrs["dataset"]}
    elif use_counts:
        raise ValueError("--counts applies to a dataset sample (give --split and --index)")
    else:
        result = read_result_input(result_path, "export-tal", "give --split and --index to export one of its "
                                   "samples")
    validate.result_values(result, f"store {result_path}", allow_negative=True)   # NaN / inf named, not written
    out.parent.mkdir(parents=True, exist_ok=True)
    write_tal_hdf5(result, out, compression_level=compression, dtype="float32" if float32 else "float64",
                   scene_info=info)
    click.echo(_h_summary(out))
    click.echo(f"wrote {out}")
