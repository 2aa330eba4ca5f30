"""Command line: ``datagen simulate SCENE.yaml --out DIR``. The CLI only parses and calls the library.

Defines the ``main`` group (the ``datagen`` entry point) with ``simulate`` and ``detect``, and registers the
commands of :mod:`datagen.cli.tal` (``tal-render``, ``export-tal``), :mod:`datagen.cli.dataset` (``build``,
``inspect``, ``verify``), :mod:`datagen.cli.bench` (``bench accuracy``), :mod:`datagen.cli.view` (``view``) and
:mod:`datagen.cli.sequence` (``sequence``);
those import at most :mod:`datagen.cli.errors`, never this module.
"""
from __future__ import annotations

import math
from pathlib import Path

import click
from pydantic import ValidationError

from ..transport import estimator_names
from .bench import bench
from .capture import compare_capture, export, fit_detector_cmd, import_capture
from .dataset import build, inspect, score, verify
from .estimate import estimate_capture
from .errors import announce_work, friendly_errors
from .suite import suite
from .tal import export_tal, read_result_input, tal_render
from .multizone import is_multizone_file, multizone, run_multizone
from .reconstruct import reconstruct
from .sequence import sequence
from .view import view


@click.group()
@click.version_option(package_name="datagen")
def main():
    """datagen: simulate NLOS SPAD lidar transients (Scholes & Leach 2024) and build datasets."""


def _parse_fraction(text: str, option: str, minimum: float = 0.0) -> float:
    """'1%' → 0.01, '0.01' → 0.01, in [``minimum``, 1) and > 0; click.BadParameter naming the option otherwise."""
    from ..units import parse_fraction
    try:
        value = parse_fraction(str(text))
    except ValueError:
        raise click.BadParameter(f"{option} must look like 1% or 0.01, got {text!r}") from None
    if not 0 < value < 1:
        raise click.BadParameter(f"{option} must be between 0 and 100 %, got {text!r}")
    if value < minimum:
        raise click.BadParameter(f"{option} {text} is below {minimum:g}: relative errors that small are float64 "
                                 "round-off in the sums, not measurable")
    return value


MAX_TIME_CAP_S = 86400.0
"""Largest ``--time-cap``: a day (the tolerance loop refuses projections beyond ten times the cap, so a larger cap
would let it run for weeks)."""


def _parse_time_cap(text: str | None) -> float | None:
    """'120s' / '2.5' (seconds) → seconds > 0; click.BadParameter naming --time-cap otherwise."""
    if text is None:
        return None
    from ..units import parse_duration
    try:
        value = parse_duration(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--time-cap") from None
    if not (math.isfinite(value) and 0 < value <= MAX_TIME_CAP_S):
        raise click.BadParameter(f"must be a duration > 0 and at most {MAX_TIME_CAP_S:g} s (a day), got {text!r}",
                                 param_hint="--time-cap")
    return value


@main.command()
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--lookins", default=None, help="lookin grid, e.g. 10x10 (default: the scene's)")
@click.option("--pixels", default=None, help="hemispherical camera pixels per lookin, e.g. 60x60")
@click.option("--secondary", type=click.Choice(["none", "optimized", "full", "exact"]), default=None,
              help="secondary (one more hidden bounce) estimator: exact = full at O(N) cost")
@click.option("--orders", default=None, metavar="N|auto",
              help="hidden vertices per path: 1 primary, 2 + secondary, N every order up to N, auto the planner "
                   "decides (docs/physics.md §2, Orders)")
@click.option("--estimator", type=click.Choice(list(estimator_names())), default=None,
              help="lookin (the paper's sampler), area (hidden-surface area sampling) or quadrature "
                   "(deterministic, exact time binning; best for small hidden objects and point sensors)")
@click.option("--edge", type=float, default=None, help="quadrature: sub-triangle edge in metres (default 0.02)")
@click.option("--tolerance", default=None,
              help="target relative L2 error, e.g. 1%: add independent replicas (or refine the quadrature edge) "
                   "until the on-the-fly error estimate meets it")
@click.option("--time-cap", default=None,
              help="--tolerance: wall-time cap, e.g. 120s (default 600 s); no round starts that would end after "
                   "it, and the best result is written with its error estimate")
@click.option("--samples", type=int, default=None, help="area estimator: hidden samples per laser point")
@click.option("--workers", type=int, default=None, help="processes sharing the lookins (result unchanged)")
@click.option("--top-k", type=int, default=None, help="secondary paths kept per lookin and FoV point (optimized)")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of every random stream (>= 0)")
@click.option("--figures", is_flag=True,
              help="also write the paper's Figure 3 and 5 sampling views and a 3D picture of the scene")
@click.option("--like", "like", type=click.Path(path_type=Path), default=None,
              help="simulate the confocal capture this store holds (datagen import-capture's): its grid replaces the "
                   "scene's (centred on the scene's laser_grid), its bins and time zero the time axis; refused when "
                   "the scene has no confocal capture")
@click.option("--detector", "detector_file", type=click.Path(path_type=Path), default=None,
              help="YAML with detector and/or irf blocks (or one flat detector block) applied over the scene's")
@click.option("--quiet", is_flag=True, help="no progress bar")
@friendly_errors
def simulate(scene_file, out, lookins, pixels, secondary, orders, estimator, edge, tolerance, time_cap, samples,
             workers, top_k, seed,
             figures, like, detector_file, quiet):
    """Simulate SCENE_FILE: write OUT/result.zarr (envelope, components, SPAD counts) and OUT/envelope.png.

    With --like STORE the simulation is the capture STORE holds (docs/capture_io.md, "Simulating a capture"): the
    scene's confocal grid takes the capture's points and pitch about its own centre, the time axis the capture's
    bins and time zero (the hidden round trip, per-point offsets as the store keeps them), the detector the store's
    (a datagen result) or the scene's, then --detector's; the store written goes to compare-capture as it is.
    """
    from ..plot.envelope import plot_envelope
    from ..errors import ConfigError
    from ..scene import load_scene
    from ..scene.load import check_output_dir
    from ..simulation import resolve_config
    from ..simulation import simulate as run_simulation
    from ..io import write_result
    from ..io.store import RESULT_NAME

    from ..simulation.tolerance import MIN_TOLERANCE

    overrides = {"lookins": lookins, "pixels": pixels, "secondary": secondary, "top_k": top_k, "seed": seed,
                 "workers": workers, "estimator": estimator, "quadrature_edge": edge, "area_samples": samples,
                 "orders": parse_orders(orders)}
    if is_multizone_file(scene_file) and (like is not None or detector_file is not None):
        raise click.BadParameter(f"{scene_file} is a multi-zone scene (a flood and zones): --like and --detector "
                                 "apply to laser-spot scans", param_hint="--like" if like is not None else "--detector")
    if is_multizone_file(scene_file):   # a flood and zones: the multi-zone capture (datagen/cli/multizone.py)
        return run_multizone(scene_file, out, overrides, refused={"--tolerance": tolerance, "--time-cap": time_cap,
                                                                  "--figures": figures}, progress=not quiet)
    tol = _parse_fraction(tolerance, "--tolerance", MIN_TOLERANCE) if tolerance is not None else None
    check_output_dir(out)
    scene = load_scene(scene_file)
    template = None
    if like is not None:
        from .like import like_setup

        scene, like_over, template = like_setup(scene, like, detector_file, click.echo)
        overrides.update(like_over)
    elif detector_file is not None:
        from .like import read_detector_file

        det = scene.defaults.get("detector") if isinstance(scene.defaults.get("detector"), dict) else {}
        file_det, file_irf = read_detector_file(detector_file, det)
        from ..io.like_capture import merge_detector

        overrides.update({"detector": merge_detector(det, file_det), "irf": file_irf})
    config = resolve_config(scene, {**overrides, "effect_threshold": tol})
    cap = _parse_time_cap(time_cap)
    if scene.moving or (scene.capture is not None and scene.capture.frames is not None):
        frames = scene.capture.frames.count if scene.capture and scene.capture.frames else 1
        click.echo(f"note: {scene_file} moves ({', '.join(scene.moving) or 'frames'}): simulate takes its first "
                   f"instant; `datagen sequence {scene_file} --out DIR` simulates its {frames} frames", err=True)
    announce_work(scene, config)
    if tol is not None:
        from ..simulation import ToleranceOutOfReach, simulate_to_tolerance
        from ..simulation.tolerance import FIXED_LIMIT
        from ..simulation.tolerance import TIME_CAP_S
        cap = TIME_CAP_S if cap is None else cap
        def named(detail: str) -> str:   # the options, not the library's arguments
            return f"--tolerance {tolerance}: {detail.replace('the time cap of', '--time-cap')}"

        try:
            result = simulate_to_tolerance(
                scene, config, tol, max_seconds=cap, progress=not quiet,
                warn=lambda detail: click.echo(f"warning: {named(detail)}; running on to it", err=True))
        except ToleranceOutOfReach as exc:
            raise ConfigError(f"{named(exc.detail)}: loosen --tolerance or raise --time-cap") from None
        t = result.attrs["tolerance"]
        omitted = result.attrs["error"].get("omitted_orders") or 0.0
        smoothing = result.attrs["error"].get("smoothing") or 0.0
        missed = ("" if t["met"] else
                  f" — NOT met: the orders left out alone carry {omitted:.2%} (--orders auto simulates them)"
                  if omitted > FIXED_LIMIT * tol else
                  f" — NOT met: the deep orders' smoothing bias alone is {smoothing:.2%} (multibounce: "
                  "{smoothing: false} in the config removes it, at more replicas)" if smoothing > FIXED_LIMIT * tol else
                  f" — NOT met within --time-cap {cap:g} s (rounds run: {len(t['rounds'])})")
        shown = f"{tol:.2%}" if tol >= 1e-4 else f"{tol:.3g}"
        click.echo(f"tolerance {shown}: estimated error {t['estimate']:.2%}{missed}")
    elif cap is not None:
        raise click.BadParameter("--time-cap applies to --tolerance runs only", param_hint="--time-cap")
    else:
        result = run_simulation(scene, config, progress=not quiet)
    out.mkdir(parents=True, exist_ok=True)
    if template is not None:
        from .like import like_finish

        _, result = like_finish(result, template, out, config.seed)
    else:
        write_result(result, out / RESULT_NAME)
    plot_envelope(result, out / "envelope.png")
    written = [out / RESULT_NAME, out / "envelope.png"]
    if figures:
        from ..plot import write_sampling_figures
        from ..plot.view_overlay import scene_view_figure
        written += write_sampling_figures(scene, config, out)
        # the 3D picture with the run's lookins; without open3d, one note line and no picture
        written += scene_view_figure(scene, out / "scene_view.png", config, note=click.echo)
    click.echo(summary(result))
    for warning in result.attrs.get("warnings", []):   # e.g. duplicate faces removed, zero-area objects
        click.echo(f"warning: {warning}", err=True)
    click.echo("wrote " + ", ".join(str(p) for p in written))


def parse_orders(value: str | None) -> int | str | None:
    """``--orders``: an integer >= 1 or "auto" (None: the scene's); a click error naming the option otherwise."""
    from ..simulation.config import orders_option

    try:
        return orders_option(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--orders") from None


@main.command()
@click.argument("result_path", type=click.Path(path_type=Path))
@click.option("--detector", "detector_file", required=True, type=click.Path(path_type=Path),
              help="detector YAML, e.g. configs/detectors/cmos_spad_array.yaml")
@click.option("--exposure", default=None, help="exposure per capture, e.g. 10ms (overrides the file)")
@click.option("--seed", type=click.IntRange(min=0), default=0, help="noise seed")
@friendly_errors
def detect(result_path, detector_file, exposure, seed):
    """Re-draw SPAD histograms from a stored envelope (no transport): writes detections/<NAME>/counts.

    The envelope is re-binned onto the detector's TDC bins (taken as piecewise constant within the stored
    bins, so TDC bins finer than the stored ones do not gain time resolution). RESULT_PATH is the output of
    `datagen simulate`; a dataset folder is refused with one line saying what to use instead.
    """
    from .. import spad
    from ..errors import ConfigError
    from ..scene.load import format_validation_error, read_yaml
    from ..simulation.config import STREAM_NOISE, stream_rng
    from ..io import write_detection
    from ..units import parse_duration

    # a dataset folder gets one line saying what to use instead (an unfinished one: the incomplete refusal)
    result = read_result_input(result_path, "detect", "detect re-draws the counts of one `datagen simulate` "
                               "result; for a dataset draw SPAD noise with other detector settings in the loader: "
                               "NLOSDataset(PATH, noise='resample', detector_ranges={...}) (docs/datasets.md, "
                               "Loading)")
    from .. import validate
    validate.transients(result.envelope, str(result_path), "envelope", negative_hint=(
        "detect draws counts from expected photons per pulse, which cannot be negative (a background-subtracted "
        "capture holds no envelope to draw from)"))
    data = read_yaml(Path(detector_file), "detector file", ConfigError)   # bounded; names the file on any error
    if isinstance(data, dict) and set(data) == {"detector"}:
        data = data["detector"]
    if not isinstance(data, dict):
        raise ConfigError(f"{detector_file}: expected a mapping of detector fields, got {type(data).__name__}")
    data = {"t_start": float(result.time_edges[0]), **data}
    data.setdefault("bin_width", float(result.time_edges[1] - result.time_edges[0]))
    if exposure is not None:
        data.pop("n_cycles", None)
        data["exposure"] = parse_duration(exposure)
        if not data["exposure"] > 0:       # the option's value, not the detector file's
            raise click.BadParameter(f"{exposure!r}: an exposure is a duration > 0, e.g. 10ms",
                                     param_hint="--exposure")
    try:
        config = spad.DetectorConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, str(detector_file))) from None
    # the detector's TDC bins: the envelope (bins hold integrals) is re-binned onto them over the same window
    n_bins = int(round((result.time_edges[-1] - config.t_start) / config.bin_width))
    envelope = spad.rebin_envelope(result.envelope, result.time_edges, config.bin_edges(n_bins))
    rng = stream_rng(seed, STREAM_NOISE)
    counts = spad.sample_histogram(spad.rates_from_envelope(envelope, config), config, rng)
    name = Path(detector_file).stem
    path = write_detection(result_path, name, counts, {"detector": config.model_dump(mode="json"),
                                                        "seed": seed, "n_cycles": int(config.cycles)})
    click.echo(f"{name}: {int(counts.sum())} detections over {config.cycles} cycles ({config.model} model); "
               f"wrote {path}/detections/{name}/counts")


def summary(result) -> str:
    """Peak time and area of the envelope and each component, the estimated error, counts and wall time."""
    lines = [f"{'component':<12}{'peak (ns)':>10}{'area (det/pulse)':>18}{'share':>8}"]
    total = result.area()
    for name in ["total"] + list(result.components):
        area = total if name == "total" else result.area(name)
        peak = result.peak_time(None if name == "total" else name) * 1e9 if area > 0 else float("nan")
        lines.append(f"{name:<12}{peak:>10.2f}{area:>18.4e}{area / total if total else 0:>8.1%}")
    err = result.attrs.get("error")
    if err is not None:
        what = (f"stated error of the envelope ({err['confidence']:.0%} bound)" if err.get("confidence") else
                "estimated error of the envelope")
        lines.append(f"{what}: {err['rel_l2']:.2%} relative L2 ({err['replicas']} "
                     f"replica{'s' if err['replicas'] != 1 else ''} of {err['replica_setting']})")
    orders = result.attrs.get("orders")
    if orders is not None:
        lines.append(f"orders simulated: {orders['simulated']} ({orders['setting']}); " + (
            f"left out: {orders['residual_share']:.2%} of the in-window energy, counted in the error"
            if orders["residual_share"] else "nothing left out in the window"))
    t = result.attrs["timings_s"]
    lines.append(f"SPAD counts: {int(result.counts.sum())} detections over {result.attrs['n_cycles']} laser cycles "
                 f"({result.attrs['detector']['model']} model)")
    lines.append(f"wall time {t['total']:.2f} s (transport {t['transport']:.2f} s)")
    return "\n".join(lines)


main.add_command(tal_render)     # tal interop commands
main.add_command(export_tal)
main.add_command(build)          # dataset commands
main.add_command(inspect)
main.add_command(verify)
main.add_command(score)          # scoring reconstructions
main.add_command(bench)          # benchmarks: datagen bench accuracy
main.add_command(view)           # 3D pictures with open3d
main.add_command(multizone)      # flood-illuminated multi-zone captures
main.add_command(import_capture)  # real-lab capture files, detector fitting, sim-to-real
main.add_command(export)
main.add_command(fit_detector_cmd)
main.add_command(compare_capture)
main.add_command(estimate_capture)  # the detector of a capture: IRF, gain, background
main.add_command(reconstruct)    # baselines on any confocal store
main.add_command(suite)          # benchmark suites
main.add_command(sequence)       # moving objects: capture sequences


if __name__ == "__main__":
    main()
