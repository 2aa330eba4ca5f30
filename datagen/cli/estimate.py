"""``datagen estimate-capture``: the detector a confocal capture was measured with, estimated from the capture
(docs/detector.md "Estimating the detector of a capture"): its IRF (a two-tail fit of the direct returns), its
background and gain maps and its direct-to-hidden ratio, written as ``detector.yaml`` (the ``detector:`` and
``irf:`` blocks of a scene file's ``simulation``), ``gain.npy``, ``background.npy`` and a picture of the maps.

The command only parses and calls the library (:mod:`datagen.analysis.capture_detector`,
:mod:`datagen.plot.capture_maps`); :mod:`datagen.cli.main` registers it.
"""
from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..analysis.capture_detector import IRF_POSITIONS
from .capture import mat_options
from .errors import friendly_errors


def _bins(text: str | None, option: str) -> tuple[int, int] | None:
    if text is None:
        return None
    first, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return int(first), int(stop)
    except ValueError:
        raise click.BadParameter(f"{text!r}: give FIRST:STOP bin indices", param_hint=option) from None


def _span(x: np.ndarray) -> str:
    return f"{x.max() / max(x.min(), 1e-300):.3g}"


def _power_source(est, where: str) -> str:
    """Where the gain's power came from: the hidden counts' slope, or not read (``where`` says why)."""
    return f"not read: {where} says why" if est.gain_note else "the slope of log hidden on log direct counts"


def detector_yaml(est, source: str, bin_width: float, repetition_rate: float, n_cycles: int) -> str:
    """The ``detector.yaml`` text of an estimate (:class:`~datagen.analysis.capture_detector.CaptureDetector`):
    ``detector:`` (poisson, the exposure given, the mean floor as ``dcr``, the maps as ``gain.npy`` and
    ``background.npy`` beside it) and, when the IRF was fitted, ``irf:``; the estimates as comments."""
    floor = float(est.background.mean())
    rows = [f"# Estimated by datagen estimate-capture from {source} (docs/detector.md \"detector.yaml\").",
            f"# background: mean {floor:.4g} counts per bin per scan point (range {est.background.min():.4g} .. "
            f"{est.background.max():.4g}); background.npy holds it relative (mean 1)",
            f"# gain: max/min {_span(est.gain)} (gain.npy, mean 1): the direct "
            f"counts' (max/min {_span(est.direct_gain)}) to the power {est.gain_exponent:.3f}, "
            f"{_power_source(est, 'a note in estimates.json')}",
            "# (it multiplies all light, the direct light's included; a simulation that carries the direct light",
            "# gives it its own pattern, the direct counts over their mean, with",
            "# detector.direct.counts_map: direct_counts.npy)",
            f"# direct-to-hidden ratio of net counts: {est.direct_to_hidden:.4g} (direct light: the first "
            f"{est.direct_bins} bins); detector.direct's attenuation = this / a simulation's ratio",
            "# the exposure (repetition_rate, n_cycles) is assumed when the capture does not state it: dcr holds the",
            "# floor at that exposure",
            "detector:",
            "  model: poisson",
            f"  repetition_rate: {repetition_rate!r}",
            f"  n_cycles: {int(n_cycles)}",
            f"  bin_width: {bin_width!r}",
            f"  dcr: {floor / (n_cycles * bin_width)!r}",
            "  gain_map: gain.npy",
            "  background_map: background.npy"]
    if est.fit is not None:
        rows.append("irf:")
        rows += [f"  {k}: {v!r}" for k, v in est.fit.irf_model.model_dump().items()]
        aligned = est.irf_position == "aligned"
        how = ("its core centred on the direct light's arrival, the middle of the bin where the summed direct "
               "return peaks" if aligned else "its core's position fitted")
        rows.append(f"# IRF fit ({how}): chi2/dof {est.fit.pearson_chi2 / est.fit.dof:.3g} on {est.fit.dof} dof")
    return "\n".join(rows) + "\n"


@click.command("estimate-capture")
@click.argument("capture", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@mat_options()
@click.option("--late", default=None,
              help="bins FIRST:STOP of the floor (default: the runs of 10 % of the window after the direct light "
                   "with the fewest counts)")
@click.option("--direct-bins", "direct_bins", type=click.IntRange(min=1), default=None,
              help="bins of the direct light from t = 0 (default: where its tail ends)")
@click.option("--no-irf", "no_irf", is_flag=True, help="skip the two-tail IRF fit")
@click.option("--irf-position", "irf_position", type=click.Choice(IRF_POSITIONS), default="aligned",
              show_default=True, help="the IRF core's centre: held at the middle of the bin where the summed direct "
                                      "return peaks (the first bin of the aligned axis, where the direct light "
                                      "arrives and the LCT release puts each point's direct peak), or fitted")
@click.option("--repetition-rate", "repetition_rate", default="10MHz",
              help="the laser's repetition rate, for the floor in Hz (default 10MHz: the LCT files do not state it)")
@click.option("--n-cycles", "n_cycles", type=click.IntRange(min=1), default=1_000_000,
              help="laser cycles per scan point (default 1e6)")
@friendly_errors
def estimate_capture(capture, out, width, bin_resolution, late, direct_bins, no_irf, irf_position, repetition_rate,
                     n_cycles):
    """Estimate the detector of the confocal capture CAPTURE (a lab file or a store) and write OUT/detector.yaml,
    OUT/gain.npy, OUT/background.npy, OUT/direct_counts.npy, OUT/estimates.json and OUT/maps.png.

    Background: each point's floor over the quietest runs of bins after the direct light; gain: its direct counts
    (0.2 ns from its direct return) relative to their mean, to the power the hidden counts follow them with over
    the scan; the direct-to-hidden ratio of net counts; the IRF: a two-tail fit of the scan-summed direct return,
    its core's centre held at that return's peak or, with --irf-position free, fitted (docs/detector.md).
    """
    from ..analysis.capture_detector import estimate_capture_detector
    from ..analysis.confocal import align_confocal
    from ..plot.capture_maps import plot_capture_maps
    from ..spad import DetectorConfig
    from ..units import parse_rate
    from .capture import bin_option, load_capture, width_option

    result, offsets, desc = load_capture(capture, width_option(width), bin_option(bin_resolution, "--bin-resolution"))
    data = np.asarray(result.counts if np.any(result.counts) else result.envelope, dtype=np.float64)
    if data.ndim != 3:
        raise ValueError(f"{capture}: a confocal scan (ny, nx, T) is needed, got shape {data.shape}")
    scan, dt = align_confocal(data, result.time_edges, offsets)
    est = estimate_capture_detector(scan, dt, late=_bins(late, "--late"), direct_bins=direct_bins,
                                    fit_irf=not no_irf, repetition_rate=parse_rate(repetition_rate),
                                    n_cycles=n_cycles, irf_position=irf_position)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "gain.npy", est.gain)
    np.save(out / "direct_counts.npy", est.direct_gain)
    floor = float(est.background.mean())
    np.save(out / "background.npy", est.background / floor if floor > 0 else np.ones_like(est.background))
    (out / "detector.yaml").write_text(detector_yaml(est, desc, dt, parse_rate(repetition_rate), n_cycles))
    DetectorConfig.from_yaml(out / "detector.yaml")                # it loads, maps and all
    record = {"source": desc, "bin_width_s": dt, "background_counts_per_bin": est.background.tolist(),
              "background_mean_counts_per_bin": floor,
              "background_bins": [list(span) for span in est.floor_bins], "direct_counts": est.direct_counts.tolist(),
              "hidden_counts": est.hidden_counts.tolist(), "direct_to_hidden": est.direct_to_hidden,
              "direct_bins": est.direct_bins, "notes": est.notes, "gain_exponent": est.gain_exponent,
              "direct_gain": est.direct_gain.tolist(),
              "irf": None if est.fit is None else est.fit.irf_model.model_dump(),
              "irf_chi2_per_dof": None if est.fit is None else est.fit.pearson_chi2 / est.fit.dof}
    (out / "estimates.json").write_text(json.dumps(record))
    plot_capture_maps({f"gain (direct counts / mean)^{est.gain_exponent:.2f}": est.gain,
                       "background (counts per bin)": est.background, "net direct counts": est.direct_counts,
                       "net hidden counts": est.hidden_counts},
                      out / "maps.png", title=desc)
    click.echo(f"{desc}: {scan.shape[0]} x {scan.shape[1]} points, {scan.shape[2]} bins of {dt * 1e12:.4g} ps")
    spans = ", ".join(f"{a}:{b} ({a * dt * 1e9:.3g}-{b * dt * 1e9:.3g} ns)" for a, b in est.floor_bins)
    click.echo(f"background: mean {floor:.4g} counts per bin (range {est.background.min():.4g} .. "
               f"{est.background.max():.4g}), read over bins {spans}")
    click.echo(f"gain: max/min {_span(est.gain)}, the direct counts' (max/min {_span(est.direct_gain)}) to the power "
               f"{est.gain_exponent:.3f} ({_power_source(est, 'the note below')}); correlation with the hidden "
               f"counts {np.corrcoef(est.gain.ravel(), est.hidden_counts.ravel())[0, 1]:.3f}")
    click.echo(f"direct-to-hidden ratio (net counts) {est.direct_to_hidden:.4g}, direct light in the first "
               f"{est.direct_bins} bins ({est.direct_bins * dt * 1e9:.3g} ns)")
    if est.fit is not None:
        from ..spad.fit_two_tail import response_fwhm
        irf = est.fit.irf_model
        click.echo(f"IRF (two-tail): core FWHM {irf.fwhm * 1e12:.1f} ps, response FWHM {response_fwhm(irf) * 1e12:.1f}"
                   f" ps, tails {irf.tail * 1e12:.3g} ps ({irf.tail_weight:.3g}) and {irf.tail2 * 1e12:.3g} ps "
                   f"({irf.tail2_weight:.3g}) after {float(irf.tail_delay or 0) * 1e12:.3g} ps; chi2/dof "
                   f"{est.fit.pearson_chi2 / est.fit.dof:.3g}")
    for line in est.notes:
        click.echo(f"note: {line}")
    click.echo(f"wrote {out / 'detector.yaml'}, gain.npy, background.npy, direct_counts.npy, estimates.json, "
               "maps.png")
