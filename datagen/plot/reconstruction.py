"""A reconstruction drawn as the hidden scene seen from the wall (``datagen reconstruct``): its front view (the
maximum over depth), the depth of what it found, and its top view.

Scans and volumes are in datagen's orientation (docs/capture_io.md, "Orientation"): row up the wall, column to the
right as seen from the wall looking into the hidden scene, so the front view is drawn with ``origin="lower"`` and
reads like a photograph taken from the wall (the LCT release's captures read as in its paper).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_reconstruction"]


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
