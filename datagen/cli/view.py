"""``datagen view``: a 3D picture of a scene YAML, a tal render YAML or one sample of a built dataset.

It only parses, finds the scene (:func:`load_view_input`) and the lookins to overlay (:func:`lookins_for`), and
calls :func:`datagen.plot.render_scene`. open3d is imported only when a picture is rendered, so this module
(and every other command) imports without it; without it ``datagen view`` prints one ``error: …`` line naming
what to install and exits with code 2.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import click
import numpy as np

from .errors import friendly_errors


def load_view_input(path: str | Path, split: str | None = None, index: int = 0):
    """What ``datagen view PATH`` pictures: a scene YAML, a tal render YAML or a dataset sample.

    Returns:
        (scene, info): the :class:`~datagen.scene.Scene` and a dict with ``kind`` ("scene" | "tal" |
        "dataset") and, for a dataset, ``room`` (:class:`~datagen.dataset.sampler.SampledRoom`), ``split``,
        ``index``, ``card``.
    Raises:
        SceneError / ConfigError / DatasetError / FileNotFoundError / ValueError: unreadable or invalid input
            (one line);
        DatasetIncompleteError (a ValueError): a dataset whose build is not complete (names the shards not
        built and ``--resume``).
    """
    from ..errors import ConfigError
    from ..scene import load_scene
    from ..scene.load import read_yaml

    path = Path(path)
    if path.is_dir():
        from ..dataset import scene_of_sample
        from ..dataset.integrity import require_complete
        require_complete(path)        # an unfinished build is refused as by every reader (names --resume)
        room, split, card = scene_of_sample(path, split, index)
        return room.scene, {"kind": "dataset", "room": room, "split": split, "index": index, "card": card}
    if split is not None:
        raise ConfigError(f"--split and --index pick a sample of a dataset directory; {path} is a file")
    data = read_yaml(path, "scene file")
    if isinstance(data, dict) and "multizone" in data:       # a flood-illuminated multi-zone scene
        from ..scene.flood import multizone_from_dict
        scene, spec = multizone_from_dict(data, str(path), path.parent)
        return scene, {"kind": "multizone", "multizone": spec}
    if isinstance(data, dict) and "objects" not in data and {"geometry", "scan_type"} & set(data):
        from ..io import scene_from_tal_yaml
        scene, _ = scene_from_tal_yaml(path)
        return scene, {"kind": "tal"}
    return load_scene(path), {"kind": "scene"}


def lookins_for(scene, info: dict, grid: str | None, seed: int | None = None) -> np.ndarray | None:
    """Lookin hit points for ``datagen view --lookins GRID``: "auto" (the lookin grid the scene or dataset
    simulates with) or "NxN"; None when ``grid`` is None.

    For a dataset sample the dataset's simulation settings and the sample's own sampling stream are used,
    so the points are the lookins the sample's simulation cast.

    Returns:
        (N, 3) float64 m (:func:`datagen.plot.view_geometry.lookin_points`) or None.
    Raises:
        ValueError: a bad grid, or a scene whose estimator casts no lookins (area, quadrature) with "auto".
    """
    if grid is None:
        return None
    from ..plot.view_geometry import lookin_points
    from ..simulation import resolve_config
    from ..transport import estimator

    overrides: dict[str, Any] = {}
    rng = None
    if info.get("kind") == "dataset":
        from ..dataset.config import config_from_json, sample_rngs
        config = config_from_json(info["card"]["config"])
        overrides = config.simulation_overrides()
        rng = sample_rngs(config.seed, info["split"], info["index"])["sampling"]
    if grid != "auto":
        overrides.update(lookins=grid, estimator="lookin")     # a lookin grid means the lookin estimator
    if seed is not None:
        overrides["seed"] = seed
    sim = resolve_config(scene, overrides)
    if not estimator(sim.estimator.kind).casts_lookins:
        raise ValueError(f"--lookins: this scene simulates with the {sim.estimator.kind!r} estimator, which casts "
                         "no lookins: give --lookins NxN")
    return lookin_points(scene, sim, rng)


def describe(scene, info: dict) -> str:
    """Title of the picture: the scene's name, or the dataset sample (split[index]) and its room."""
    if info.get("kind") == "dataset":
        room = info["room"].params["room"]
        n_obj = len(info["room"].objects)
        return (f"{info['card'].get('name', 'dataset')} {info['split']}[{info['index']}]: corridor "
                f"{room['corridor_length']:.2f} m × {room['corridor_width']:.2f} m, room "
                f"{room['room_depth']:.2f} × {room['room_length']:.2f} m, ceiling {room['ceiling']:.2f} m, "
                f"{n_obj} hidden object{'s' if n_obj != 1 else ''}")
    return f"{scene.name}" + (" (tal render config)" if info.get("kind") == "tal" else "")


MAX_SIDE = 8192
"""Largest side of a ``view`` picture, pixels. It is rendered 2× larger (``datagen.plot.view_render.SUPERSAMPLE``)
and 16384 is the largest image side Vulkan drivers commonly allow (``maxImageDimension2D``)."""

MAX_PIXELS = 3840 * 2160
"""Most pixels of a ``view`` picture (4K UHD). Rendered 2× larger, that is 25 Mpx; on the 2-core machine with
llvmpipe's Vulkan a 4K picture rendered (or stalled, under load) while 5800×5800 (100 Mpx rendered) made open3d
abort with "Unable to bind image" (out of image memory) and 100000×100000 was blamed on the Vulkan driver."""


def parse_size(text: str) -> tuple[int, int]:
    """'1400x860' → (1400, 860) pixels.

    Raises:
        ValueError: naming --size and the value: not WIDTHxHEIGHT, a side below 64 or above :data:`MAX_SIDE`, or
            more than :data:`MAX_PIXELS` pixels in all.
    """
    parts = str(text).lower().replace("×", "x").split("x")
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"--size must look like 1400x860, got {text!r}") from None
    if min(width, height) < 64:
        raise ValueError(f"--size must be at least 64x64, got {text!r}")
    if max(width, height) > MAX_SIDE or width * height > MAX_PIXELS:
        raise ValueError(f"--size {text}: at most {MAX_SIDE} pixels a side and {MAX_PIXELS} pixels in all (3840x2160), "
                         f"got {width}x{height} = {width * height}: the picture is rendered 2x larger and open3d's "
                         "Vulkan renderer stalls or runs out of image memory beyond")
    return width, height


@click.command("view")
@click.argument("path", type=click.Path(path_type=Path))
@click.option("--out", "out", type=click.Path(path_type=Path), default=None, help="PNG to write")
@click.option("--show", is_flag=True, help="also open open3d's interactive window (needs a display)")
@click.option("--split", default=None, help="dataset: split of the sample (default: the first with samples)")
@click.option("--index", type=int, default=None, help="dataset: index of the sample in its split (default 0)")
@click.option("--lookins", default=None,
              help="overlay the lookins of a run: NxN (as `simulate --lookins NxN`) or 'auto' (the scene's or "
                   "the dataset's own lookin grid; a dataset sample's own lookins)")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="root seed of the run whose lookins are drawn")
@click.option("--size", default=None, help="PNG size in pixels, WIDTHxHEIGHT (default 1400x860)")
@click.option("--flat", is_flag=True, help="flat class colours (no shading)")
@friendly_errors
def view(path, out, show, split, index, lookins, seed, size, flat):
    """Render a 3D picture of PATH: a scene YAML, a tal render YAML or a dataset directory (one sample).

    Objects are coloured by class; walls and ceiling in front of the scene are cut away (outline only);
    the emitter, laser beam and spot(s), the sensor, its FoV or scan grid and optionally the lookins of a
    run are drawn; the PNG has a legend, a scale bar and the world axes.
    """
    from ..plot import ViewUnavailable, render_scene
    from ..plot.view_overlay import DEFAULT_SIZE

    if out is None and not show:
        raise ValueError("give --out FILE.png and/or --show")
    if (split is not None or index is not None) and not path.is_dir():
        raise ValueError(f"--split and --index pick a sample of a dataset directory; {path} is not one")
    width, height = parse_size(size) if size else DEFAULT_SIZE
    t0 = time.perf_counter()
    scene, info = load_view_input(path, split, 0 if index is None else index)
    points = lookins_for(scene, info, lookins, seed)
    extra = None
    if info["kind"] == "multizone":
        from ..plot.view_flood import flood_drawables
        extra = flood_drawables(scene, info["multizone"])
    try:
        render_scene(scene, out, width=width, height=height, lookins=points, show=show,
                     title=describe(scene, info), shading="flat" if flat else "shaded", extra=extra)
    except ViewUnavailable as exc:           # open3d, Vulkan or a display missing: bad environment, exit 2
        click.echo(f"error: {' '.join(str(exc).split())}", err=True)
        sys.exit(2)
    except RuntimeError as exc:              # the renderer failed or kept stalling
        click.echo(f"error: {' '.join(str(exc).split())}", err=True)
        sys.exit(1)
    if out is not None:
        extra = f", {len(points)} lookins" if points is not None else ""
        click.echo(f"wrote {out} ({width}×{height}{extra}) in {time.perf_counter() - t0:.2f} s")
