"""Command line: ``datagen simulate SCENE.yaml --out DIR``. The CLI only parses and calls the library."""
from __future__ import annotations

import sys
from functools import wraps
from pathlib import Path

import click

from .scene import SceneError


def _friendly_errors(func):
    """Turn invalid-input exceptions into a one-line ``error: …`` on stderr and exit code 2."""

    @wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (SceneError, ValueError, FileNotFoundError, FileExistsError) as exc:
            message = " ".join(str(exc).split())
            click.echo(f"error: {message}", err=True)
            sys.exit(2)

    return wrapper


@click.group()
@click.version_option(package_name="datagen")
def main():
    """datagen: simulate NLOS SPAD lidar transients (Scholes & Leach 2024) and build datasets."""


@main.command()
@click.argument("scene_file", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="output directory")
@click.option("--lookins", default=None, help="lookin grid, e.g. 10x10 (default: the scene's)")
@click.option("--pixels", default=None, help="hemispherical camera pixels per lookin, e.g. 60x60")
@click.option("--secondary", type=click.Choice(["none", "optimized", "full"]), default=None,
              help="secondary (one more hidden bounce) estimator")
@click.option("--top-k", type=int, default=None, help="secondary paths kept per lookin and FoV point (optimized)")
@click.option("--seed", type=int, default=None, help="root seed of every random stream")
@click.option("--figures", is_flag=True, help="also write the paper's Figure 3 and 5 sampling views")
@click.option("--quiet", is_flag=True, help="no progress bar")
@_friendly_errors
def simulate(scene_file, out, lookins, pixels, secondary, top_k, seed, figures, quiet):
    """Simulate SCENE_FILE: write OUT/result.zarr (envelope, components, SPAD counts) and OUT/envelope.png."""
    from .plot import plot_envelope
    from .scene import load_scene
    from .simulate import resolve_config
    from .simulate import simulate as run_simulation
    from .store import RESULT_NAME, write_result

    scene = load_scene(scene_file)
    config = resolve_config(scene, {"lookins": lookins, "pixels": pixels, "secondary": secondary,
                                    "top_k": top_k, "seed": seed})
    result = run_simulation(scene, config, progress=not quiet)
    out.mkdir(parents=True, exist_ok=True)
    write_result(result, out / RESULT_NAME)
    plot_envelope(result, out / "envelope.png")
    written = [out / RESULT_NAME, out / "envelope.png"]
    if figures:
        from .figures import write_sampling_figures
        written += write_sampling_figures(scene, config, out)
    click.echo(summary(result))
    click.echo("wrote " + ", ".join(str(p) for p in written))


def summary(result) -> str:
    """Peak time and area of the envelope and each component, counts and wall time, as a short table."""
    lines = [f"{'component':<12}{'peak (ns)':>10}{'area (det/pulse)':>18}{'share':>8}"]
    total = result.area()
    for name in ["total"] + list(result.components):
        area = total if name == "total" else result.area(name)
        peak = result.peak_time(None if name == "total" else name) * 1e9 if area > 0 else float("nan")
        lines.append(f"{name:<12}{peak:>10.2f}{area:>18.4e}{area / total if total else 0:>8.1%}")
    t = result.attrs["timings_s"]
    lines.append(f"SPAD counts: {int(result.counts.sum())} detections over {result.attrs['n_cycles']} laser cycles "
                 f"({result.attrs['detector']['model']} model)")
    lines.append(f"wall time {t['total']:.2f} s (transport {t['transport']:.2f} s)")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
