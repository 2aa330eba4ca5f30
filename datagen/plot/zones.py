"""Figure of a multi-zone capture (docs/multizone.md): the Z_y × Z_x grid of zone histograms as small multiples,
laid out as the zones sit on the relay wall (row 0 at the bottom: rows grow up the wall), and the total."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..simulation import Result  # noqa: E402


def plot_zones(result: Result, path: str | Path, title: str | None = None) -> Path:
    """Write the zones' histograms of a multi-zone result: per zone its SPAD counts (grey steps) and expected
    signal counts (envelope × laser cycles, black line), on shared axes; on the right, the same summed over zones.

    Args:
        result: a multi-zone :class:`~datagen.simulation.detection.Result` (:func:`datagen.simulation.multizone.
            simulate_multizone`): ``envelope`` and ``counts`` (Z_y, Z_x, T).
        path: PNG path.
    Returns:
        ``path`` as a Path.
    Raises:
        ValueError: the envelope is not (Z_y, Z_x, T).
    """
    env = np.asarray(result.envelope, dtype=np.float64)
    if env.ndim != 3:
        raise ValueError(f"plot_zones needs zone envelopes (Z_y, Z_x, T), got shape {env.shape}")
    counts = np.asarray(result.counts, dtype=np.float64)
    cycles = float(result.attrs.get("n_cycles", 1))
    zy, zx, _ = env.shape
    t_ns = result.time_centers * 1e9
    expected = env * cycles
    top = max(float(counts.max()), float(expected.max()), 1.0) * 1.05
    fig = plt.figure(figsize=(4 + 2.2 * zx, 1.2 + 1.6 * zy), constrained_layout=True)
    grid = fig.add_gridspec(zy, zx + 2)
    first = None
    for iy in range(zy):
        for ix in range(zx):
            ax = fig.add_subplot(grid[zy - 1 - iy, ix], sharex=first, sharey=first)
            first = first or ax
            ax.step(t_ns, counts[iy, ix], where="mid", color="0.6", lw=0.8)
            ax.plot(t_ns, expected[iy, ix], color="black", lw=1.0)
            ax.set_ylim(0, top)
            ax.text(0.97, 0.92, f"zone ({iy}, {ix})", transform=ax.transAxes, ha="right", va="top", fontsize=7)
            ax.tick_params(labelsize=6)
            if iy != 0:
                ax.tick_params(labelbottom=False)
            if ix != 0:
                ax.tick_params(labelleft=False)
            if iy == 0:
                ax.set_xlabel("t (ns)", fontsize=7)
            if ix == 0:
                ax.set_ylabel("counts / bin", fontsize=7)
    total = fig.add_subplot(grid[:, zx:])
    total.step(t_ns, counts.sum(axis=(0, 1)), where="mid", color="0.5", lw=1.0, label="SPAD counts")
    total.plot(t_ns, expected.sum(axis=(0, 1)), color="black", lw=1.5, label="expected signal (envelope × cycles)")
    total.set_xlabel("t (ns)")
    total.set_ylabel("counts / bin, all zones")
    total.set_title("total", fontsize=9)
    total.legend(fontsize=7)
    fig.suptitle(title or f"{result.attrs.get('scene', '')}: {zx}×{zy} zones, {int(cycles)} laser cycles", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
