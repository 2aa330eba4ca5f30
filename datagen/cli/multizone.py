"""Multi-zone scenes on the command line (docs/multizone.md): ``datagen simulate SCENE`` on a scene YAML with a
``multizone`` block runs :func:`run_multizone`, and ``datagen multizone SCENE`` is the same run with the flood's
``--nodes`` as an option.

SCENE_FILE is a scene YAML with a ``multizone`` block (scene_library/multizone_room.yaml); the result is written
as ``datagen simulate`` writes its own (OUT/result.zarr, OUT/envelope.png), with the zones as the sensor grid:
envelope and counts (Z_y, Z_x, T), and OUT/zones.png, the zones' histograms (:func:`datagen.plot.zones.plot_zones`).
"""
from __future__ import annotations

from pathlib import Path

import click

from ..errors import ConfigError
from .errors import announce_work, friendly_errors


def is_multizone_file(path: Path) -> bool:
    """Whether ``path`` is a readable YAML mapping with a top-level ``multizone`` block (any read error: False,
    and the ordinary scene loader reports it)."""
    from ..errors import DatagenError
    from ..scene.load import read_yaml
    try:
        data = read_yaml(Path(path), "scene file")
    except (DatagenError, OSError):
        return False
    return isinstance(data, dict) and "multizone" in data


def run_multizone(scene_file: Path, out: Path, overrides: dict, nodes: str | None = None,
                  refused: dict | None = None, progress: bool = True) -> None:
    """Simulate SCENE_FILE's flood and zones; write OUT/result.zarr, OUT/envelope.png, OUT/zones.png and echo the
    summary (zones, flood, per-component peak and area, transport error, counts).

    Args:
        overrides: :func:`datagen.simulation.resolve_config` overrides (e.g. ``quadrature_edge``, ``seed``).
        nodes: the flood's nodes per side, e.g. "8x8" (default: the scene's).
        refused: option name → value of ``datagen simulate`` options a multi-zone run does not take (any value
            other than None / False is refused).
        progress: show a progress bar over the transport (``--quiet``: False).
    Raises:
        ConfigError: a refused option given; click.BadParameter: a malformed ``nodes``; SceneError, ConfigError: as
            :func:`datagen.simulation.multizone.simulate_multizone`.
    """
    import warnings

    from ..errors import DatagenWarning
    from ..io import write_result
    from ..io.store import RESULT_NAME
    from ..plot.envelope import plot_envelope
    from ..plot.zones import plot_zones
    from ..scene.flood import load_multizone_scene
    from ..scene.load import check_output_dir
    from ..simulation import resolve_config
    from ..simulation.multizone import simulate_multizone

    for option, value in (refused or {}).items():
        if value not in (None, False):
            raise ConfigError(f"{option} does not apply to the multi-zone scene {scene_file} (a flood's zones are "
                              "simulated in one run: docs/multizone.md)")
    check_output_dir(out)
    scene, spec = load_multizone_scene(scene_file)
    if nodes is not None:
        spec = _with_nodes(spec, nodes)
    config = resolve_config(scene, overrides)
    announce_work(scene, config)
    result = simulate_multizone(scene, spec, config, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    write_result(result, out / RESULT_NAME)
    plot_envelope(result, out / "envelope.png")
    plot_zones(result, out / "zones.png")
    zx, zy = spec.zones.zones
    nx, ny = spec.flood.nodes
    click.echo(f"{zx}×{zy} zones, flood of {nx}×{ny} nodes over {spec.flood.size[0]:g}×{spec.flood.size[1]:g} m "
               f"({spec.flood.profile.kind})")
    total = result.area()
    for name in ["total"] + list(result.components):
        area = total if name == "total" else result.area(name)
        peak = f"{result.peak_time(None if name == 'total' else name) * 1e9:.2f} ns" if area > 0 else "-"
        click.echo(f"{name:<12} peak {peak:>10}  {area:.4e} detected photons per pulse")
    err = result.attrs["error"]
    click.echo(f"transport error of the nodes' envelopes: {err['rel_l2']:.2%} relative L2 ({err['replica_setting']})")
    click.echo(f"SPAD counts: {int(result.counts.sum())} detections over {result.attrs['n_cycles']} laser cycles "
               f"({result.attrs['detector']['model']} model)")
    for warning in result.attrs.get("warnings", []):   # one `warning:` line each; the CLI's printer skips those
        warnings.warn(DatagenWarning(warning), stacklevel=2)  # already shown (the zone coverage, before the work)
    click.echo(f"wrote {out / RESULT_NAME}, {out / 'envelope.png'}, {out / 'zones.png'}")


def _with_nodes(spec, nodes: str):
    """``spec`` with the flood's nodes from "NxM"; click.BadParameter or SceneError naming --nodes otherwise."""
    from pydantic import ValidationError

    from ..errors import SceneError
    from ..scene.flood import MultizoneSpec
    from ..scene.load import format_validation_error

    parts = str(nodes).lower().replace("×", "x").split("x")
    try:
        n = tuple(int(p) for p in parts)
        if len(n) != 2:
            raise ValueError
    except ValueError:
        raise click.BadParameter(f"must look like 8x8, got {nodes!r}", param_hint="--nodes") from None
    try:
        return MultizoneSpec.model_validate({**spec.model_dump(), "flood": {**spec.flood.model_dump(), "nodes": n}})
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, "--nodes", head="multizone")) from None


@click.command("multizone")
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--nodes", default=None, help="flood quadrature nodes per side, e.g. 8x8 (default: the scene's)")
@click.option("--edge", type=float, default=None, help="quadrature: sub-triangle edge in metres")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of every random stream (>= 0)")
@click.option("--quiet", is_flag=True, help="no progress bar")
@friendly_errors
def multizone(scene_file, out, nodes, edge, seed, quiet):
    """Simulate SCENE_FILE's flood and zones (as `datagen simulate` does, with --nodes): write OUT/result.zarr
    (zone envelopes, counts), OUT/envelope.png and OUT/zones.png."""
    run_multizone(scene_file, out, {"quadrature_edge": edge, "seed": seed}, nodes, progress=not quiet)
