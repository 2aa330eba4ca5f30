"""Command line: ``datagen reconstruct STORE --method lct|phasor|fbp --out DIR`` (docs/capture_io.md,
"Reconstructing a capture").

STORE is anything holding a confocal scan: an imported capture (``datagen import-capture``), a simulated result
(``datagen simulate``), a lab file itself, or a dataset with ``--split`` and ``--index``. The command puts the scan
on the hidden round-trip axis (:func:`datagen.analysis.confocal.align_confocal`, the per-point offsets of the file or
of the counted wall legs removed), runs :func:`datagen.analysis.reconstruct.confocal_volume` and writes
``DIR/depth.npy``, ``DIR/volume.npy``, ``DIR/volume_depths.npy`` and ``DIR/reconstruction.png``
(:func:`datagen.plot.reconstruction.plot_reconstruction`); :mod:`datagen.cli.main` registers it.
"""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ..analysis.reconstruct import FOUND_LEVEL, FOUND_PEDESTAL, MAX_BINS, METHODS
from .errors import friendly_errors


def _scan_input(path: Path, split: str | None, index: int | None, use_counts: bool):
    """(envelope (ny, nx, T), time_edges, offsets (ny, nx) s or None, scan points (ny, nx, 3), description) of a
    store, lab file or dataset sample.

    Raises:
        ValueError / DatasetError: not a confocal scan, no scan grid, no counts (one line: file, field, value)."""
    from ..dataset.integrity import is_dataset, require_complete
    from .capture import counted_legs, load_capture

    if split is not None or index is not None:
        from ..dataset.export import sample_result

        if split is None or index is None:
            raise ValueError("a dataset sample needs both --split and --index")
        require_complete(path)
        result = sample_result(path, split, index, "counts" if use_counts else "envelope")
        offsets, what = counted_legs(result), f"sample ({split}, {index}) of dataset {path}"
    else:
        if is_dataset(path):
            raise ValueError(f"{path} is a datagen dataset: give --split and --index of the sample to reconstruct")
        result, offsets, what = load_capture(path)
    ctype = (result.attrs.get("capture") or {}).get("type")
    env = np.asarray(result.envelope)
    if ctype != "confocal" or env.ndim != 3:
        raise ValueError(f"{path}: capture.type: {ctype!r} with envelope {env.shape}; reconstruct needs a confocal "
                         "scan (ny, nx, T)")
    if result.laser_points is None:
        raise ValueError(f"{path}: laser_points: none stored, so the scan has no grid to reconstruct on "
                         "(re-simulate it, or import the capture again)")
    if use_counts and split is None:
        env = np.asarray(result.counts, dtype=np.float64)
        if not env.any():
            raise ValueError(f"{path}: counts: all zero (no SPAD histogram stored); reconstruct the envelope (drop "
                             "--counts)")
    points = np.asarray(result.laser_points, dtype=np.float64).reshape(env.shape[:2] + (3,))
    return env, np.asarray(result.time_edges), offsets, points, what


@click.command("reconstruct")
@click.argument("store", type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(METHODS), default="lct", show_default=True,
              help="light-cone transform, phasor fields (RSD) or filtered backprojection")
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--split", default=None, help="STORE is a dataset: the split of the sample")
@click.option("--index", type=int, default=None, help="STORE is a dataset: the index of the sample")
@click.option("--counts", "use_counts", is_flag=True, help="reconstruct the SPAD counts, not the envelope")
@click.option("--falloff", type=click.Choice(["retroreflective", "diffuse"]), default="retroreflective",
              show_default=True, help="lct / fbp: radiometric scaling t^2 (the LCT release's default) or t^4")
@click.option("--snr", type=click.FloatRange(min=0, min_open=True), default=0.8, show_default=True,
              help="lct: the Wiener filter's signal-to-noise ratio")
@click.option("--trim", default="auto", show_default=True,
              help="direct light to zero first: auto, or a duration from the wall (e.g. 2.4ns; 0 for none)")
@click.option("--background", type=click.Choice(["auto", "none"]), default="auto", show_default=True,
              help="auto: subtract each point's floor (ambient light, dark counts: the mean of its quietest quarter "
                   "after the direct light) first; none: keep it")
@click.option("--level", type=click.FloatRange(min=0, max=1, min_open=True), default=FOUND_LEVEL, show_default=True,
              help="a scan point has found something where its front view reaches this share of the way from its "
                   "pedestal to its maximum")
@click.option("--pedestal", type=click.FloatRange(min=0, max=50), default=FOUND_PEDESTAL, show_default=True,
              help="the front view's pedestal (its level where nothing is): this percentile of it; 0 for none (a "
                   "share of the maximum)")
@click.option("--max-bins", "max_bins", type=click.IntRange(min=2), default=MAX_BINS, show_default=True,
              help="sum neighbouring bins until at most this many remain")
@friendly_errors
def reconstruct(store, method, out, split, index, use_counts, falloff, snr, trim, background, level, pedestal,
                max_bins):
    """Reconstruct the confocal scan in STORE (an imported capture, a simulated result, a lab file, or a dataset
    sample with --split/--index) and write OUT/depth.npy (m on the scan grid, NaN where nothing is found),
    OUT/volume.npy (ny, nx, Z), OUT/volume_depths.npy (Z,) m and OUT/reconstruction.png; prints the median depth
    of what it found. Arrays are in datagen's orientation: row up the wall, column to the right as the wall sees the
    hidden scene (docs/capture_io.md, "Orientation").
    """
    from ..analysis.confocal import align_confocal, grid_pitches
    from ..analysis.reconstruct import confocal_volume, depth_map
    from ..plot.reconstruction import plot_reconstruction
    from .capture import trim_option

    trim_s = trim_option(trim)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file, not a directory")
    env, edges, offsets, points, what = _scan_input(Path(store), split, index, use_counts)
    try:
        pitch = grid_pitches(points)
    except ValueError as exc:
        raise ValueError(f"{store}: laser_points: {exc}") from None
    scan, dt = align_confocal(env, edges, offsets)
    try:
        volume, depths, info = confocal_volume(scan, dt, pitch, method, falloff, snr, trim_s, max_bins,
                                                 None if background == "none" else "auto")
    except ValueError as exc:
        raise ValueError(f"{store}: {exc}") from None
    depth, _ = depth_map(volume, depths, level, pedestal)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "depth.npy", depth)
    np.save(out / "volume.npy", volume.astype(np.float32))
    np.save(out / "volume_depths.npy", depths)
    found = np.isfinite(depth)
    title = f"{Path(store).name}: {method}" + (f", {falloff}" if method != "phasor" else "")
    plot_reconstruction(volume, depths, depth, pitch, out / "reconstruction.png", title)
    pitches = (f"{pitch[0] * 1e3:.4g}" if pitch[0] == pitch[1] else
               f"{pitch[0] * 1e3:.4g} (between rows) x {pitch[1] * 1e3:.4g} (between columns)")
    click.echo(f"{what}: {scan.shape[0]} x {scan.shape[1]} points of pitch {pitches} mm, "
               f"{method} on {info['bin_width'] * 1e12:.4g} ps bins, direct light trimmed to "
               f"{info['trim'] * 1e9:.4g} ns ({'auto' if trim_s == 'auto' else 'given'})"
               + (", each point's floor subtracted" if background == "auto" else ""))
    median = f"median depth {np.median(depth[found]):.4f} m" if found.any() else "nothing found"
    rule = (f"{level:g} of the way from its {pedestal:g}th percentile to its maximum" if pedestal
            else f"{level:g} of its maximum")
    click.echo(f"found at {int(found.sum())} of {found.size} scan points (front view >= {rule}): {median}")
    click.echo(f"wrote {out}/depth.npy, volume.npy, volume_depths.npy, reconstruction.png")
