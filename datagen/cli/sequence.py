"""Command line: ``datagen sequence SCENE.yaml --out DIR`` (docs/motion.md): the frames of a scene whose objects move.

Simulates every frame of the scene's ``capture.frames`` with :func:`datagen.simulation.sequence.simulate_sequence`
and writes ``DIR/sequence.zarr`` (:func:`datagen.io.store.write_sequence`) and ``DIR/sequence.png``
(:func:`datagen.plot.sequence.plot_sequence`); :mod:`datagen.cli.main` registers it.
"""
from __future__ import annotations

from pathlib import Path

import click

from .errors import announce_work, friendly_errors


@click.command()
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--method", type=click.Choice(["changes", "frames"]), default="changes", show_default=True,
              help="changes: the first frame once, then each frame's change at a fraction of the sampling; "
                   "frames: every frame in full")
@click.option("--change-split", type=click.IntRange(1, 4096), default=None,
              help="changes: a frame's change takes 1/N of the sampling (default 128)")
@click.option("--slots", type=click.IntRange(min=1), default=None,
              help="scanned captures: groups of consecutive scan points simulated at one instant (default: each "
                   "point at its own)")
@click.option("--lookins", default=None, help="lookin grid, e.g. 10x10 (default: the scene's)")
@click.option("--pixels", default=None, help="hemispherical camera pixels per lookin, e.g. 60x60")
@click.option("--samples", type=int, default=None, help="area estimator: hidden samples per laser point")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of every random stream (>= 0)")
@friendly_errors
def sequence(scene_file, out, method, change_split, slots, lookins, pixels, samples, seed):
    """Simulate the frames of SCENE_FILE's capture.frames: write OUT/sequence.zarr and OUT/sequence.png."""
    import numpy as np

    from ..io.store import SEQUENCE_NAME, write_sequence
    from ..plot.sequence import plot_sequence
    from ..scene import load_scene
    from ..scene.load import check_output_dir
    from ..simulation import resolve_config
    from ..simulation.sequence import DEFAULT_CHANGE_SPLIT, simulate_sequence

    check_output_dir(out)
    scene = load_scene(scene_file)
    config = resolve_config(scene, {"lookins": lookins, "pixels": pixels, "area_samples": samples, "seed": seed})
    announce_work(scene, config)
    seq = simulate_sequence(scene, config, method, change_split or DEFAULT_CHANGE_SPLIT, slots)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_sequence(seq, out / SEQUENCE_NAME), plot_sequence(seq, scene, out / "sequence.png")]
    frames = seq.attrs["frames"]
    click.echo(f"{len(seq.frame_times)} frames at {frames['rate']:g} Hz, {frames['exposure'] * 1e3:g} ms each "
               f"({method}): {seq.attrs['seconds']:.1f} s")
    click.echo(f"stated error per frame (95% bound): {np.min(seq.error):.2%}..{np.max(seq.error):.2%} relative L2"
               + (f"; of a step between frames: {seq.difference_error:.3%} of a frame (a step is "
                  f"{seq.attrs['mean_step']:.3%} on average)" if np.isfinite(seq.difference_error) else ""))
    for j, name in enumerate(seq.moving):
        speed = np.linalg.norm(seq.velocities[:, j], axis=1)
        click.echo(f"{name}: from {np.round(seq.positions[0, j], 3).tolist()} to "
                   f"{np.round(seq.positions[-1, j], 3).tolist()} m, speed up to {speed.max():.2f} m/s")
    click.echo("wrote " + ", ".join(str(p) for p in written))
