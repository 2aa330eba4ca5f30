"""Command line for real-lab captures (docs/capture_io.md): ``datagen import-capture``, ``datagen export``,
``datagen fit-detector`` and ``datagen compare-capture``.

The commands only parse and call the library (:mod:`datagen.io.lab_formats`, :mod:`datagen.spad.fit`,
:mod:`datagen.analysis.compare_capture`, :mod:`datagen.plot.capture`); :mod:`datagen.cli.main` registers them.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import click
import numpy as np

from .. import validate
from .errors import friendly_errors

EXPORT_FORMATS = ("lct-mat", "fk-mat", "znlos", "tal")

MAX_WALL_HALF_WIDTH_M = 100.0
"""Largest ``--width`` (half width of a scanned relay wall, m): lab scans are 0.2–1 m; more is a unit slip."""


def bin_option(text: str | None, option: str) -> float | None:
    """A bin width given on the command line (``--bin-resolution``, ``--bin-width``), in s: a duration within
    :data:`datagen.validate.BIN_WIDTH_RANGE_S`; None when not given. click.BadParameter naming the option
    otherwise (never the file: the value is the command line's)."""
    from ..units import parse_duration

    if text is None:
        return None
    try:
        seconds = parse_duration(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None
    if not seconds > 0:
        raise click.BadParameter(f"{text!r}: a bin width is a duration > 0, e.g. 4ps", param_hint=option)
    try:
        return validate.bin_width(seconds, option, "bin width")
    except validate.InputDataError:
        lo, hi = (validate.format_seconds(v) for v in validate.BIN_WIDTH_RANGE_S)
        raise click.BadParameter(f"{text!r} is {validate.format_seconds(seconds)}, not a TCSPC bin width ({lo} .. "
                                 f"{hi}); a number without a unit is seconds: write the unit, e.g. 4ps",
                                 param_hint=option) from None


def mat_options(file: str = "") -> Callable:
    """The options every command reading a lab file takes for a ``.mat`` that lacks them: ``--width`` (m) and
    ``--bin-resolution`` (a duration), parsed by :func:`width_option` and :func:`bin_option`. ``file``: which
    argument they are for (e.g. "REAL "), when a command reads two."""
    def add(command: Callable) -> Callable:
        command = click.option("--bin-resolution", "bin_resolution", default=None,
                               help=f"{file}.mat without 'bin_resolution': the bin width, e.g. 4ps")(command)
        return click.option("--width", type=float, default=None,
                            help=f"{file}.mat without 'width': half width of the scanned wall, m")(command)
    return add


def width_option(width: float | None) -> float | None:
    """``--width`` (m): finite, > 0 and at most :data:`MAX_WALL_HALF_WIDTH_M`; click.BadParameter otherwise."""
    if width is not None and not 0 < width <= MAX_WALL_HALF_WIDTH_M:
        raise click.BadParameter(f"{width!r}: the half width of the scanned wall in m, > 0 and at most "
                                 f"{MAX_WALL_HALF_WIDTH_M:g}", param_hint="--width")
    return width


def checked_store(result, path: Path, allow_negative: bool = False, negative_hint: str = validate.NEGATIVE_HINT):
    """``result``, read from the store at ``path``, after :func:`datagen.validate.result_values` (NaN, ±inf and,
    unless ``allow_negative``, negative values named as a capture file's are)."""
    validate.result_values(result, f"store {path}", allow_negative, negative_hint)
    return result


def _is_store(path: Path) -> bool:
    return (path / "zarr.json").exists() or (path / "result.zarr" / "zarr.json").exists()


def counted_legs(result) -> np.ndarray | None:
    """(ny, nx) s: the wall legs a datagen confocal result's time axis counts at each scan point (emitter → point
    when ``count_laser_leg``, point → sensor when ``count_sensor_leg``, docs/physics.md §1); None for other
    captures or a result without a laser grid."""
    from ..units import SPEED_OF_LIGHT

    cap = result.attrs.get("capture") or {}
    conf = result.attrs.get("config") or {}
    if cap.get("type") != "confocal" or result.laser_points is None:
        return None
    pts = np.asarray(result.laser_points, float).reshape(result.envelope.shape[:-1] + (3,))
    legs = np.zeros(pts.shape[:-1])
    if conf.get("count_laser_leg"):
        legs += np.linalg.norm(pts - np.asarray(cap["emitter_position"], float), axis=-1)
    if conf.get("count_sensor_leg", True):
        legs += np.linalg.norm(pts - np.asarray(cap["sensor_position"], float), axis=-1)
    return legs / SPEED_OF_LIGHT


def load_capture(path: Path, width=None, bin_resolution=None, allow_negative: bool = False,
                 negative_hint: str = validate.NEGATIVE_HINT):
    """(Result, per-point time offsets (s) or None, description) of a lab file, an imported capture store or a
    datagen result store (offsets: the counted wall legs of a confocal scan, :func:`counted_legs`). A file is read
    as import-capture reads it (``width``, ``bin_resolution``: the values a ``.mat`` lacks), a store's values are
    checked as a file's are (:func:`checked_store`)."""
    from ..io.lab_formats import read_capture_store, read_lab_capture

    path = Path(path)
    if path.is_dir():
        if not _is_store(path):
            raise FileNotFoundError(f"{path}: neither a capture file nor a datagen result store")
        result, offsets = read_capture_store(path)
        checked_store(result, path, allow_negative, negative_hint)
        if offsets is None and "lab_capture" not in result.attrs:
            offsets = counted_legs(result)
        return result, offsets, f"datagen store {path}"
    cap = read_lab_capture(path, width=width, bin_resolution=bin_resolution, allow_negative=allow_negative,
                           negative_hint=negative_hint)
    return cap.to_result(), cap.time_offsets(), f"{cap.format} file {path}"


def _kv(items, option: str) -> dict[str, float]:
    from ..units import parse_duration, parse_rate

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            raise click.BadParameter(f"expected NAME=VALUE, got {item!r}", param_hint=option)
        try:
            value = parse_rate(text) if name.strip() == "background_rate" else parse_duration(text) \
                if name.strip() in ("position", "jitter_sigma", "diffusion_tail", "dead_time", "tail", "tail2",
                                    "tail_delay") else float(text)
        except ValueError as exc:
            raise click.BadParameter(f"{name}: {exc}", param_hint=option) from None
        out[name.strip()] = float(value)
    return out


@click.command("import-capture")
@click.argument("capture_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory (result store)")
@mat_options()
@click.option("--tofgrid", "tofgrid", type=click.Path(path_type=Path), default=None,
              help="a separate .mat holding 'tofgrid' (ps), as the f-k release ships tof.mat")
@click.option("--allow-negative", "allow_negative", is_flag=True,
              help="accept negative bins (a background-subtracted capture); their count is printed")
@friendly_errors
def import_capture(capture_file, out, width, bin_resolution, tofgrid, allow_negative):
    """Read an LCT / f-k .mat (v5 or v7.3) or ZNLOS HDF5 capture into a datagen result store OUT/result.zarr.

    The file's fields are read as its public reader does (docs/capture_io.md: time zero, confocal or not, axis
    order, units); per-point time offsets (tofgrid, or ZNLOS's wall legs) are stored as time_offsets. Transients
    that are complex, NaN or ±inf are refused, negative ones too unless --allow-negative (docs/capture_io.md).
    """
    from ..io.lab_formats import read_lab_capture, write_capture_store
    from ..validate import negative_bins

    bres = bin_option(bin_resolution, "--bin-resolution")
    cap = read_lab_capture(capture_file, width=width_option(width), bin_resolution=bres, tofgrid_path=tofgrid,
                           allow_negative=allow_negative)
    store = write_capture_store(cap, Path(out) / "result.zarr")
    d = cap.data()
    edges = cap.time_edges()
    click.echo(f"{cap.format} (MAT v{cap.mat_version}) " if cap.mat_version else f"{cap.format} ", nl=False)
    click.echo(f"{cap.capture_type} capture {tuple(d.shape[:-1])} x {d.shape[-1]} bins of "
               f"{(edges[1] - edges[0]) * 1e12:.4g} ps from {edges[0] * 1e9:.4g} ns, dtype {d.dtype}, "
               f"sum {float(np.sum(d, dtype=np.float64)):.6g}; per-point time offsets "
               f"{'stored' if cap.time_offsets() is not None else 'none'}")
    negative = negative_bins(d)
    if negative:
        click.echo(f"note: {negative} of {d.size} bins are negative (--allow-negative: a background-subtracted "
                   "capture; detect refuses such an envelope)")
    if cap.capture_type == "confocal" and d.ndim == 3 and d.shape[0] != d.shape[1]:
        click.echo(f"note: a {d.shape[0]} x {d.shape[1]} confocal scan, not square: LCT and f-k need N x N points "
                   "at one pitch (export --format lct-mat / fk-mat refuses it)")
    click.echo(f"wrote {store}")


@click.command("export")
@click.argument("result_path", type=click.Path(path_type=Path))
@click.option("--format", "fmt", required=True, type=click.Choice(EXPORT_FORMATS), help="file layout to write")
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output file")
@click.option("--split", default=None, help="RESULT_PATH is a dataset: the split of the sample to export")
@click.option("--index", type=int, default=None, help="RESULT_PATH is a dataset: the index of the sample")
@click.option("--counts", "use_counts", is_flag=True, help="export the SPAD counts, not the envelope")
@click.option("--mat-version", "mat_version", type=click.Choice(["5", "7.3"]), default="5",
              help=".mat formats: MAT v5 (scipy) or v7.3 (HDF5; arrays over 2 GiB)")
@click.option("--allow-negative", "allow_negative", is_flag=True,
              help="export negative bins (a background-subtracted capture); their count is printed")
@friendly_errors
def export(result_path, fmt, out, split, index, use_counts, mat_version, allow_negative):
    """Write a datagen result, or one dataset sample, as an LCT / f-k .mat, a ZNLOS HDF5 or a tal HDF5 capture.

    LCT / f-k: confocal N x N scans; the counted wall legs and t_start go into tofgrid (ps). ZNLOS: the time
    axis must count both wall legs (ZNLOS's convention). Conventions: docs/capture_io.md. NaN or ±inf values are
    refused, negative ones too unless --allow-negative (as import-capture reads files).
    """
    from ..dataset.integrity import require_complete
    from ..io import write_tal_hdf5
    from ..io.lab_formats import capture_from_result, write_lab_capture
    from .tal import check_out_file, read_result_input

    check_out_file(out, "capture.mat" if fmt.endswith("-mat") else "capture.hdf5")
    if split is not None or index is not None:
        from ..dataset.export import sample_result

        if split is None or index is None:
            raise ValueError("a dataset sample needs both --split and --index")
        require_complete(result_path)
        result = sample_result(result_path, split, index, "counts" if use_counts else "envelope")
        checked_store(result, f"{result_path} ({split} sample {index})", allow_negative)
    else:
        result = checked_store(read_result_input(result_path, "export", "give --split and --index to export one "
                                                 "of its samples"), result_path, allow_negative)
        if use_counts:              # the drawn SPAD histogram in the envelope's place, as a lab file holds it
            import dataclasses
            result = dataclasses.replace(result, envelope=np.asarray(result.counts, dtype=np.float64), components={})
    out.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "tal":
        write_tal_hdf5(result, out)
    else:
        cap = capture_from_result(result, fmt, source=str(result_path))
        write_lab_capture(cap, out, mat_version=mat_version if fmt != "znlos" else None)
    click.echo(f"wrote {out} ({fmt}, {tuple(np.shape(result.envelope))})")
    negative = validate.negative_bins(result.envelope)
    if negative:
        click.echo(f"note: {negative} of {np.size(result.envelope)} bins are negative (--allow-negative: a "
                   "background-subtracted capture)")


def _read_failure(exc: Exception) -> str:
    """numpy's reason a histogram file failed to load, without its advice (``use `usecols` …``)."""
    text = " ".join(str(exc).split())
    if "could only read" in text or isinstance(exc, EOFError):
        return f"truncated ({text.split('. (')[0]})"
    return text.split("; use ")[0][:160]


FIT_NEGATIVE_HINT = "a detector fit needs the raw histogram, background included"
"""What a refusal of negative bins suggests to ``fit-detector`` (which has no --allow-negative)."""


def _histogram(path: Path, pixel: str | None, width: float | None = None, bin_resolution: float | None = None):
    """(counts (bins,), bin width s or None, t_start s or None, what it is) from .npy / .csv / .txt, a lab file
    (read as import-capture reads it, ``width`` and ``bin_resolution`` for a ``.mat`` without them) or a store."""
    suffix = path.suffix.lower()
    if suffix in (".npy", ".csv", ".txt"):
        if not path.is_file():
            raise FileNotFoundError(f"no histogram file at {path}")
        try:
            with warnings.catch_warnings():       # an empty file: numpy warns, the check below names it
                warnings.simplefilter("ignore", UserWarning)
                arr = np.load(path, allow_pickle=False) if suffix == ".npy" else np.loadtxt(
                    path, delimiter="," if suffix == ".csv" else None, ndmin=1)
        except (ValueError, EOFError, OSError) as exc:        # a header line, a ragged row, a truncated .npy
            kind = "a NumPy .npy array" if suffix == ".npy" else "columns of numbers (no header line, equal rows)"
            raise ValueError(f"{path}: cannot read it as {kind}: {_read_failure(exc)}") from None
        arr = np.asarray(arr)
        if arr.ndim == 2 and arr.shape[1] == 2:          # (time s, counts) columns
            t0, dt = validate.uniform_axis(arr[:, 0], str(path), "time column")
            return validate.histogram_counts(arr[:, 1], str(path), "counts column"), dt, t0, str(path)
        if arr.ndim != 1:
            raise ValueError(f"{path}: expected one column of counts (or time, counts), got shape {arr.shape}")
        return validate.histogram_counts(arr, str(path)), None, None, str(path)
    result, _, _ = load_capture(path, width, bin_resolution, negative_hint=FIT_NEGATIVE_HINT)
    data = np.asarray(result.counts if result.counts.any() else result.envelope)
    edges = np.asarray(result.time_edges)
    if pixel is not None and ":" in pixel and data.ndim == 3:        # a block i0:i1,j0:j1 of scan points, summed
        try:
            (a0, a1), (b0, b1) = (tuple(int(v) for v in part.split(":")) for part in pixel.split(","))
        except ValueError:
            raise ValueError(f"--pixel {pixel!r}: give a block of scan points as 'i0:i1,j0:j1'") from None
        if not (0 <= a0 < a1 <= data.shape[0] and 0 <= b0 < b1 <= data.shape[1]):
            raise ValueError(f"--pixel {pixel}: outside the scan of {path} ({data.shape[0]} x {data.shape[1]} points)")
        h = data[a0:a1, b0:b1].reshape(-1, data.shape[-1]).sum(0)
        return validate.histogram_counts(h, str(path)), float(edges[1] - edges[0]), float(edges[0]), \
            f"{path} points {pixel} summed"
    if pixel is not None:
        try:
            idx = tuple(int(v) for v in pixel.split(","))
        except ValueError:
            raise ValueError(f"--pixel {pixel!r}: give the scan point as integers 'i,j'") from None
        if len(idx) != data.ndim - 1:
            raise ValueError(f"--pixel {pixel}: the capture has {data.ndim - 1} scan axes {data.shape[:-1]}")
        if any(not 0 <= i < n for i, n in zip(idx, data.shape[:-1])):
            raise ValueError(f"--pixel {pixel}: outside the scan of {path}, whose points run 0..{data.shape[0] - 1}"
                             + "".join(f", 0..{n - 1}" for n in data.shape[1:-1]))
        h, what = data[idx], f"{path} point {idx}"
    else:
        h, what = data.reshape(-1, data.shape[-1]).sum(0), f"{path} (every scan point summed)"
    return validate.histogram_counts(h, str(path)), float(edges[1] - edges[0]), float(edges[0]), what


def _slice(bins: str, n: int) -> slice:
    """``--bins FIRST:STOP`` as a slice of a histogram of ``n`` bins; click.BadParameter unless 0 <= FIRST < STOP."""
    first, sep, stop = bins.partition(":")
    try:
        a, b = int(first or 0), int(stop) if stop else n
    except ValueError:
        a = b = -1
    if not sep or not 0 <= a < min(b, n):
        raise click.BadParameter(f"{bins!r}: give FIRST:STOP with 0 <= FIRST < STOP, within the histogram's {n} bins",
                                 param_hint="--bins")
    return slice(a, min(b, n))


def _window(bins: str | None, n: int, dt: float | None, t0: float | None) -> tuple[float | None, float | None]:
    """(bin width, first edge) of the histogram after ``--bins`` (the first edge moves by FIRST bins)."""
    if bins is None or dt is None:
        return dt, t0
    return dt, (t0 or 0.0) + _slice(bins, n).start * dt


@click.command("fit-detector")
@click.argument("hist", type=click.Path(path_type=Path))
@click.option("--repetition-rate", "repetition_rate", required=True, help="laser repetition rate, e.g. 20MHz")
@click.option("--n-cycles", "n_cycles", required=True, type=click.IntRange(min=1), help="laser cycles of the exposure")
@click.option("--bin-width", "--bin-resolution", "bin_width", default=None,
              help="bin width, e.g. 4ps (default: the file's; a .mat without 'bin_resolution' needs it, as "
                   "import-capture's --bin-resolution)")
@click.option("--width", type=float, default=None, help=".mat without 'width': half width of the scanned wall, m")
@click.option("--t-start", "t_start", default=None, help="first bin edge within the period (default: the file's or 0)")
@click.option("--model", type=click.Choice(["pile_up", "poisson", "free_running"]), default="pile_up",
              help="synchronous first photon (pile_up), poisson, or free_running (dead time)")
@click.option("--irf", type=click.Choice(["gauss", "exgauss", "two_tail"]), default="exgauss",
              help="gauss: a Gaussian core; exgauss: plus an exponential diffusion tail; two_tail: plus two "
                   "exponential tails (docs/detector.md)")
@click.option("--allow-cropped-edge", "allow_cropped_edge", is_flag=True,
              help="fit the return's position and core width although it starts before the first bin (the "
                   "Stanford LCT files start at their direct light)")
@click.option("--bins", "bins", default=None,
              help="fit only bins FIRST:STOP of the histogram (e.g. 0:300: a direct return without the hidden one)")
@click.option("--fit-fraction", is_flag=True, help="also fit the diffusion tail's share (default 1)")
@click.option("--pulse-sigma", "pulse_sigma", default=None, help="known laser pulse std (default half a bin)")
@click.option("--fix", "fix", multiple=True, help="hold a parameter, NAME=VALUE (e.g. dead_time=77ns)")
@click.option("--initial", "initial", multiple=True, help="start a parameter at NAME=VALUE (e.g. dead_time=50ns)")
@click.option("--pixel", default=None,
              help="a scan capture: the scan point 'i,j' or a block 'i0:i1,j0:j1' summed (default: all summed)")
@click.option("--afterpulse-time-constant", "afterpulse_tau", default=None,
              help="free_running: also fit the afterpulse probability, with this time constant (e.g. 2ns)")
@click.option("--dead-time-bounds", "dead_time_bounds", default=None,
              help="free_running: search the dead time only in LOW,HIGH (e.g. 2ns,10ns; a datasheet range)")
@click.option("--out", "out", type=click.Path(path_type=Path), default=None, help="detector YAML to write")
@friendly_errors
def fit_detector_cmd(hist, repetition_rate, n_cycles, bin_width, width, t_start, model, irf, allow_cropped_edge,
                     bins, fit_fraction, pulse_sigma, fix, initial, pixel, afterpulse_tau, dead_time_bounds, out):
    """Fit datagen's detector model to the histogram HIST of a known return (maximum likelihood).

    HIST: .npy / .csv / .txt (counts, or time s and counts), a lab capture file (read as import-capture reads it:
    --bin-width (alias --bin-resolution) and --width for a .mat without them) or a datagen store. Prints each parameter with its
    1-sigma error and 95 % interval, the goodness of fit, one line per parameter the data do not determine, and
    writes --out (a configs/detectors YAML, checked by loading it). A return whose rising edge lies before the
    histogram's first bin (the Stanford LCT files start at the direct light) is refused unless position and
    jitter_sigma are held (--fix) or --allow-cropped-edge is given. --pixel takes a scan point 'i,j' or a block
    'i0:i1,j0:j1' of them, summed.
    """
    from ..spad.fit import fit_detector, rising_edge_missing
    from ..units import parse_duration, parse_rate
    from .errors import check_output_file

    if out is not None:
        check_output_file(out, "--out")
    dt_given = bin_option(bin_width, "--bin-width / --bin-resolution")
    h, dt_file, t0_file, what = _histogram(Path(hist), pixel, width_option(width), dt_given)
    fixed = _kv(fix, "--fix")
    dt_file, t0_file = _window(bins, h.size, dt_file, t0_file)
    h = h[_slice(bins, h.size)] if bins is not None else h
    peak = rising_edge_missing(h)
    if peak is not None and not allow_cropped_edge and not {"position", "jitter_sigma"} <= set(fixed):
        raise ValueError(f"{what}: the return peaks in bin {peak} of {h.size} and every bin before it holds more than "
                         "half its peak: the histogram starts after the return's rising edge, so its position and "
                         "jitter cannot be fitted (a fit gives a degenerate detector; the Stanford LCT files are "
                         "cropped to start at the direct light); fit a histogram that holds the whole return, or "
                         "hold both with --fix position=... --fix jitter_sigma=..., or fit the falling half with "
                         "--allow-cropped-edge")
    dt = dt_given if dt_given is not None else dt_file
    if dt is None:
        raise click.BadParameter("the histogram file has no time axis: give --bin-width", param_hint="--bin-width")
    t0 = parse_duration(t_start) if t_start is not None else (t0_file or 0.0)
    bounds = None
    if dead_time_bounds is not None:
        parts = dead_time_bounds.split(",")
        if len(parts) != 2:
            raise click.BadParameter(f"expected LOW,HIGH, got {dead_time_bounds!r}", param_hint="--dead-time-bounds")
        bounds = tuple(parse_duration(p.strip()) for p in parts)
    fit = fit_detector(h, bin_width=dt, repetition_rate=parse_rate(repetition_rate), n_cycles=n_cycles, model=model,
                       irf=irf, t_start=max(t0, 0.0),
                       pulse_sigma=None if pulse_sigma is None else parse_duration(pulse_sigma),
                       fixed=fixed, fit_fraction=fit_fraction, initial=_kv(initial, "--initial") or None,
                       afterpulse_time_constant=None if afterpulse_tau is None else parse_duration(afterpulse_tau),
                       dead_time_bounds=bounds, allow_cropped_edge=allow_cropped_edge)
    if bins is not None:
        click.echo(f"fitted bins {bins} of {what}")
    click.echo(fit.summary())
    for line in fit.messages:
        click.echo(f"note: {line}")
    if out is not None:
        fit.write_yaml(out)
        click.echo(f"wrote {out}")


@click.command("compare-capture")
@click.argument("real", type=click.Path(path_type=Path))
@click.argument("sim", type=click.Path(path_type=Path))
@click.option("--png", "png", type=click.Path(path_type=Path), default=None, help="side-by-side figure to write")
@mat_options("REAL ")
@click.option("--allow-negative", "allow_negative", is_flag=True,
              help="REAL may hold negative bins (a background-subtracted capture)")
@click.option("--trim", default="auto", show_default=True,
              help="hidden signal: the direct light to exclude, auto (found in REAL) or a duration, e.g. 2.4ns")
@click.option("--gain", default="direct", show_default=True,
              help="hidden signal: per-point gain applied to SIM: direct (REAL's direct light to the power that "
                   "REAL's hidden counts over SIM's follow it with; none where that light is within its noise), "
                   "none, or a .npy (ny, nx) map")
@click.option("--draws", type=click.IntRange(min=1, max=64), default=4, show_default=True,
              help="pairs of Poisson draws per noise floor")
@click.option("--write-gain", "write_gain", type=click.Path(path_type=Path), default=None,
              help="write the per-point gain that makes SIM's hidden-count map REAL's to this .npy (a flat-field "
                   "calibration on a known target: --gain FILE.npy on another capture of the same scanner)")
@friendly_errors
def compare_capture(real, sim, png, width, bin_resolution, allow_negative, trim, gain, draws, write_gain):
    """Sim-to-real distance of REAL (a lab file or store) and SIM (a datagen result store or a lab file).

    Whole transients: both put on the hidden time axis (per-point offsets removed) at REAL's bin width and
    normalised; prints the relative L2, the per-bin chi2, the peak-time and width (FWHM) differences.

    Hidden signal (confocal scans of one grid, docs/capture_io.md "Comparing a capture with its simulation"): the
    direct light excluded (--trim), each point's background floor subtracted, SIM scaled to REAL's hidden counts
    (--gain: per point too); prints the scan-summed relative L2, the per-point leading-edge difference (median,
    spread), the hidden-count maps' correlation, the return's FWHM and decay, each with its Poisson noise floor (a
    perfect simulation scores about 1x). --png draws the count maps, transients and LCT reconstructions side by side.
    --write-gain keeps the per-point gain that makes SIM's hidden-count map REAL's, for --gain on another capture.
    """
    from ..analysis.compare_capture import compare_captures
    from ..io.lab_formats import capture_kind
    from .errors import check_output_file

    if png is not None:
        check_output_file(png, "--png")
    if write_gain is not None:
        check_output_file(write_gain, "--write-gain")
        if write_gain.suffix.lower() != ".npy":
            raise click.BadParameter(f"expected a .npy file, got {str(write_gain)!r}", param_hint="--write-gain")
    trim_s = trim_option(trim)
    gain_v = _gain_option(gain)
    r, r_off, r_desc = load_capture(real, width_option(width), bin_option(bin_resolution, "--bin-resolution"),
                                    allow_negative)
    s, s_off, s_desc = load_capture(sim)
    (r_kind, r_what), (s_kind, s_what) = capture_kind(r), capture_kind(s)
    if "zones" in (r_kind, s_kind) and r_kind != s_kind:
        raise ValueError(f"{real} is {r_what}, {sim} is {s_what}: a flood's zones and a laser spot's transients are "
                         "different measurements; compare a multi-zone result with a multi-zone capture")
    r_data = r.counts if r.counts.any() else r.envelope
    try:
        m = compare_captures(r_data, r.time_edges, r_off, s.envelope, s.time_edges, s_off)
    except ValueError as exc:
        raise ValueError(f"real {real}, sim {sim}: {exc}") from None
    click.echo(f"real: {r_desc}; sim: {s_desc}; {m['bins']} common bins")
    if r.envelope.shape[:-1] != s.envelope.shape[:-1]:
        click.echo(f"note: real is {r_what}, sim {s_what}: compared on the scan-summed transients only (no per-point "
                   "metric); simulate the capture's grid for a point-by-point comparison", err=True)
    click.echo("whole transients (direct light included, each normalised to sum 1):")
    click.echo(f"relative L2 (normalised, scan-summed) {m['rel_l2']:.4f}"
               + ("" if m["rel_l2_points"] is None else f"; per scan point (mean) {m['rel_l2_points']:.4f}"))
    click.echo(f"chi2 per bin {m['chi2_per_bin']:.4g} (real counts {m['counts_real']:.6g})")
    click.echo(f"peak time: real {m['peak_time_real'] * 1e9:.4f} ns, sim {m['peak_time_sim'] * 1e9:.4f} ns, "
               f"diff {m['peak_time_diff'] * 1e12:+.1f} ps")
    click.echo(f"FWHM: real {m['fwhm_real'] * 1e12:.1f} ps, sim {m['fwhm_sim'] * 1e12:.1f} ps, "
               f"diff {m['width_diff'] * 1e12:+.1f} ps")
    hidden = None
    if r_kind == s_kind == "confocal" and r.envelope.ndim == 3 and r.envelope.shape[:-1] == s.envelope.shape[:-1]:
        hidden = _hidden_section(r_data, r, r_off, s, s_off, trim_s, gain_v, draws, f"real {real}, sim {sim}")
    elif r_kind == s_kind == "confocal":
        click.echo("note: no hidden-signal comparison: it needs two confocal scans of one grid")
    if write_gain is not None:
        if hidden is None:
            raise ValueError(f"--write-gain {write_gain}: no hidden-signal comparison of real {real} and sim {sim} "
                             "to read a gain from (the note above says why)")
        from ..analysis.hidden_compare import calibrated_gain

        g = calibrated_gain(hidden)
        np.save(write_gain, g)
        click.echo(f"wrote {write_gain}: the per-point gain that makes sim's hidden-count map real's ({g.shape[0]} x "
                   f"{g.shape[1]}, mean 1, max/min {g.max() / max(g.min(), 1e-12):.3g}); --gain {write_gain} "
                   "applies it")
    if png is not None:
        if hidden is not None:
            from ..plot.capture import plot_hidden_comparison

            plot_hidden_comparison(hidden, png, real_label=Path(real).name, sim_label=Path(sim).name,
                                   pitch=_pitch_of(r), fronts=_fronts(hidden, _pitch_of(r)))
        else:
            from ..plot.capture import plot_capture_comparison

            plot_capture_comparison(m, png, real_label=Path(real).name, sim_label=Path(sim).name)
        click.echo(f"wrote {png}")


def trim_option(trim: str) -> str | float:
    """A ``--trim`` value: "auto" or a duration ≥ 0 in seconds (click's BadParameter naming --trim otherwise)."""
    from ..units import parse_duration

    try:
        value = "auto" if trim.strip() == "auto" else parse_duration(trim)
    except ValueError as exc:
        raise click.BadParameter(f"expected auto or a duration, e.g. 2.4ns: {exc}", param_hint="--trim") from None
    if value != "auto" and not (np.isfinite(value) and value >= 0):
        raise click.BadParameter(f"expected auto or a duration >= 0, got {trim!r}", param_hint="--trim")
    return value


def _gain_option(gain: str):
    if gain in ("none", "direct"):
        return gain
    path = Path(gain)
    if path.suffix.lower() != ".npy":
        raise click.BadParameter(f"expected none, direct or a .npy gain map, got {gain!r}", param_hint="--gain")
    if not path.is_file():
        raise FileNotFoundError(f"--gain {path}: no such file")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--gain {path}: cannot read it as a NumPy .npy array: {' '.join(str(exc).split())[:160]}") \
            from None


def _pitch_of(result) -> tuple[float, float] | None:
    if result.laser_points is None:
        return None
    from ..analysis.confocal import grid_pitches

    try:
        return grid_pitches(np.asarray(result.laser_points, float).reshape(np.shape(result.envelope)[:2] + (3,)))
    except ValueError:
        return None


def _fronts(hidden, pitch):
    """Front views (max over depth) of LCT reconstructions of the compared hidden transients (the direct light
    already excluded), or None without a grid."""
    if pitch is None:
        return None
    from ..analysis.reconstruct import confocal_volume

    out = []
    for key in ("real", "model"):
        scan = np.concatenate([np.zeros(hidden[key].shape[:2] + (hidden["trim_bins"],)), np.maximum(hidden[key], 0)],
                              axis=-1)
        vol, _, _ = confocal_volume(scan, hidden["bin_width"], pitch, "lct", trim=hidden["trim"],
                                    background=None)    # the floor is already subtracted
        out.append(vol.max(axis=-1))
    return tuple(out)


def _gain_how(h) -> str:
    """How the comparison's gain was made, for its first line."""
    if h["gain"] != "direct":
        return h["gain"]
    if h.get("gain_note"):
        return f"direct (real's direct counts as they are: {h['gain_note']})"
    return f"direct (real's direct counts to the power {h['gain_exponent']:.3f}, the hidden counts' slope on them)"


def _hidden_section(r_data, r, r_off, s, s_off, trim, gain, draws, where: str):
    """Run and print the hidden-signal comparison; returns it, or None (with a note) when it cannot run."""
    from ..analysis.hidden_compare import hidden_comparison

    sim_counts = not np.any(s.envelope) or ("lab_capture" in s.attrs)
    sim_data = s.counts if sim_counts and s.counts.any() else s.envelope
    try:
        h = hidden_comparison(r_data, r.time_edges, r_off, sim_data, s.time_edges, s_off,
                              sim_is_counts=bool(sim_counts), trim=trim, gain=gain, draws=draws)
    except ValueError as exc:
        if isinstance(gain, np.ndarray) and "gain map" in str(exc):
            raise ValueError(f"--gain: {exc}") from None
        click.echo(f"note: no hidden-signal comparison: {exc}")
        return None
    f = h["floor"]

    def vs(value: float, floor: float) -> str:
        ratio = abs(value) / floor if floor > 0 else float("inf")
        return f"(noise floor {floor:.3g}, {ratio:.3g}x)"

    def ps(x: float) -> str:
        return f"{x * 1e12:.1f} ps"

    click.echo(f"hidden signal: direct light excluded (the first {h['trim'] * 1e9:.4g} ns, {h['trim_how']}; not "
               f"modelled), background floor per point from {h['floor_bins']} signal-free bins subtracted, gain "
               f"{_gain_how(h)}, sim scaled x{h['scale']:.4g} to real's hidden counts")
    click.echo(f"hidden counts: real {h['counts_real']:.6g}, sim {h['counts_sim']:.6g} (above the floor)")
    click.echo(f"relative L2 (scan-summed hidden) {h['rel_l2']:.4f} {vs(h['rel_l2'], f['rel_l2'])}")
    click.echo(f"leading edge sim - real over {h['edge_points']} points: median {ps(h['edge_median'])} (noise floor "
               f"{ps(f['edge_median'])}), spread {ps(h['edge_spread'])} (noise floor {ps(f['edge_spread'])})")
    click.echo(f"hidden-count maps: correlation {h['map_corr']:.4f} (1 - r {h['map_decorrelation']:.3g}, noise floor "
               f"{f['map_decorrelation']:.3g})")
    click.echo(f"return FWHM: real {ps(h['fwhm_real'])}, sim {ps(h['fwhm_sim'])}, diff {ps(h['fwhm_diff'])} "
               f"(noise floor {ps(f['fwhm_diff'])}); 1/e decay after the peak: real {ps(h['decay_real'])}, sim "
               f"{ps(h['decay_sim'])}, diff {ps(h['decay_diff'])} (noise floor {ps(f['decay_diff'])})")
    return h
