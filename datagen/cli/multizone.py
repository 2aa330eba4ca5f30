"""``datagen multizone``: simulate a flood-illuminated multi-zone scene (docs/multizone.md).

SCENE_FILE is a scene YAML with a ``multizone`` block (scene_library/multizone_room.yaml); the result is written
as ``datagen simulate`` writes its own (OUT/result.zarr, OUT/envelope.png), with the zones as the sensor grid:
envelope and counts (Z_y, Z_x, T).
"""
from __future__ import annotations

from pathlib import Path

import click

from .errors import friendly_errors


@click.command("multizone")
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--nodes", default=None, help="flood quadrature nodes per side, e.g. 8x8 (default: the scene's)")
@click.option("--edge", type=float, default=None, help="quadrature: sub-triangle edge in metres")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of every random stream (>= 0)")
@friendly_errors
def multizone(scene_file, out, nodes, edge, seed):
    """Simulate SCENE_FILE's flood and zones: write OUT/result.zarr (zone envelopes, counts) and OUT/envelope.png."""
    from ..io import write_result
    from ..io.store import RESULT_NAME
    from ..plot.envelope import plot_envelope
    from ..scene.flood import load_multizone_scene
    from ..scene.load import check_output_dir
    from ..simulation import resolve_config
    from ..simulation.multizone import simulate_multizone

    check_output_dir(out)
    scene, spec = load_multizone_scene(scene_file)
    if nodes is not None:
        parts = str(nodes).lower().replace("×", "x").split("x")
        try:
            n = tuple(int(p) for p in parts)
            if len(n) != 2:
                raise ValueError
        except ValueError:
            raise click.BadParameter(f"must look like 8x8, got {nodes!r}", param_hint="--nodes") from None
        from ..scene.flood import MultizoneSpec
        from ..errors import SceneError
        from pydantic import ValidationError
        try:
            spec = MultizoneSpec.model_validate({**spec.model_dump(), "flood": {**spec.flood.model_dump(),
                                                                                "nodes": n}})
        except ValidationError as exc:
            from ..scene.load import format_validation_error
            raise SceneError(format_validation_error(exc, "--nodes", head="multizone")) from None
    config = resolve_config(scene, {"quadrature_edge": edge, "seed": seed})
    result = simulate_multizone(scene, spec, config)
    out.mkdir(parents=True, exist_ok=True)
    write_result(result, out / RESULT_NAME)
    plot_envelope(result, out / "envelope.png")
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
    click.echo(f"wrote {out / RESULT_NAME}, {out / 'envelope.png'}")
