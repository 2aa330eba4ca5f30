"""The per-scan-point maps estimated from a capture (``datagen estimate-capture``, docs/detector.md): gain,
background, and the direct and hidden counts, side by side."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_capture_maps"]


def plot_capture_maps(maps: dict[str, np.ndarray], path: str | Path, title: str = "") -> Path:
    """Write a PNG of the (ny, nx) ``maps`` (label → float array), one panel each with its colour bar, row 0 at
    the bottom (datagen's scan order, docs/capture_io.md "Orientation"). Returns the path written."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, len(maps), figsize=(3.6 * len(maps), 3.4), squeeze=False)
    for ax, (label, values) in zip(axes[0], maps.items()):
        image = ax.imshow(np.asarray(values, dtype=np.float64), origin="lower", cmap="viridis")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("x index")
        ax.set_ylabel("y index")
        fig.colorbar(image, ax=ax, fraction=0.046)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
