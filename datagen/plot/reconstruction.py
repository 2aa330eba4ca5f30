"""A reconstruction drawn as the hidden scene seen from the wall (``datagen reconstruct``): its front view (the
maximum over depth), the depth of what it found, and its top view; and a grid of depth maps, methods by exposures,
of one capture (``benchmarks/real_low_light.py --png``).

Scans and volumes are in datagen's orientation (docs/capture_io.md, "Orientation"): row up the wall, column to the
right as seen from the wall looking into the hidden scene, so the front view is drawn with ``origin="lower"`` and
reads like a photograph taken from the wall (the LCT release's captures read as in its paper).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_reconstruction", "plot_depth_grid"]


def plot_reconstruction(volume: np.ndarray, depths: np.ndarray, depth: np.ndarray,
                        pitch: float | tuple[float, float], path: str | Path, title: str = "") -> Path:
    """Write a PNG: front view | depth map | top view of a reconstruction.

    Args:
        volume: (ny, nx, Z) reconstruction ≥ 0; depths: (Z,) m of its last axis.
        depth: (ny, nx) m, NaN where nothing was found (:func:`datagen.analysis.reconstruct.depth_map`).
        pitch: the scan grid's pitch (m), or (between rows, between columns): the axes run over ±pitch·(N − 1)/2
            about the scan's centre.
        path: the .png to write; title: above the panels.
    Returns:
        the path written.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vol = np.asarray(volume, dtype=np.float64)
    ny, nx = vol.shape[:2]
    pv, pu = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    hu, hv = pu * nx / 2, pv * ny / 2
    wall = [-hu, hu, -hv, hv]
    found = np.isfinite(depth)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    ax = axes[0]
    ax.imshow(vol.max(axis=-1), origin="lower", extent=wall, cmap="gray")
    ax.set_title("front view (max over depth), seen from the wall")
    ax = axes[1]
    im = ax.imshow(np.where(found, depth, np.nan), origin="lower", extent=wall, cmap="viridis")
    fig.colorbar(im, ax=ax, label="depth (m)")
    ax.set_title(f"depth where found: median {np.median(depth[found]):.4f} m" if found.any() else "nothing found")
    for ax in axes[:2]:
        ax.set_xlabel("u (m): right, seen from the wall")
        ax.set_ylabel("v (m): up the wall")
    ax = axes[2]
    ax.imshow(vol.max(axis=0).T, origin="lower", aspect="auto", cmap="gray",
              extent=[wall[0], wall[1], float(depths[0]), float(depths[-1])])
    ax.set_title("top view (max over v)")
    ax.set_xlabel("u (m)")
    ax.set_ylabel("depth from the wall (m)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_depth_grid(cells: list[list[tuple[np.ndarray, str]]], rows: list[str], columns: list[str],
                    pitch: float | tuple[float, float], path: str | Path, title: str = "",
                    outline: np.ndarray | None = None, depth_range: tuple[float, float] | None = None) -> Path:
    """Write a PNG of depth maps in a grid, one colour scale for all (e.g. methods down, exposures across).

    Args:
        cells: ``cells[i][j]`` = ((ny, nx) depth m, NaN where nothing was found; its caption) of row i, column j.
        rows, columns: the rows' and columns' labels.
        pitch: the scan grid's pitch (m), or (between rows, between columns), as :func:`plot_reconstruction`.
        path: the .png to write; title: above the grid.
        outline: (ny, nx) bool drawn as a white contour on every map (a reference mask), or None.
        depth_range: (low, high) m of the colour scale; default the 2nd–98th percentile of every found depth.
    Returns:
        the path written.
    Raises:
        ValueError: ``cells`` not len(rows) × len(columns).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if len(cells) != len(rows) or any(len(r) != len(columns) for r in cells):
        raise ValueError(f"plot_depth_grid: cells must be {len(rows)} × {len(columns)}")
    maps = [np.asarray(d, dtype=np.float64) for r in cells for d, _ in r]
    ny, nx = maps[0].shape
    pv, pu = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    wall = [-pu * nx / 2, pu * nx / 2, -pv * ny / 2, pv * ny / 2]
    if depth_range is None:
        found = np.concatenate([d[np.isfinite(d)] for d in maps])
        depth_range = tuple(np.percentile(found, [2, 98])) if found.size else (0.0, 1.0)
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(2.6 * len(columns) + 1, 2.5 * len(rows)),
                             squeeze=False, layout="constrained")    # room for the title, labels and colour bar
    image = None
    for i, row in enumerate(cells):
        for j, (depth, caption) in enumerate(row):
            ax = axes[i][j]
            ax.set_facecolor("0.15")
            image = ax.imshow(np.asarray(depth, dtype=np.float64), origin="lower", extent=wall, cmap="viridis",
                              vmin=depth_range[0], vmax=depth_range[1], interpolation="nearest")
            if outline is not None and np.any(outline):
                ax.contour(np.asarray(outline, dtype=float), levels=[0.5], colors="white", linewidths=0.6,
                           origin="lower", extent=wall)
            ax.set_title(f"{columns[j]}\n{caption}" if i == 0 else caption, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(rows[i])
    fig.colorbar(image, ax=axes, label="depth from the wall (m)", shrink=0.6)
    if title:
        fig.suptitle(title, wrap=True)          # wrapped to the figure's width (a grid of one or two maps is narrow)
    path = Path(path)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
