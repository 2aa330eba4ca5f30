"""A measured capture drawn beside its simulation: time-integrated images of both scans and their normalised
scan-summed transients on the hidden time axis (the arrays and distances of
:func:`datagen.analysis.compare_capture.compare_captures`), and the hidden signal's comparison
(:func:`datagen.analysis.hidden_compare.hidden_comparison`): count maps, transients and reconstructions side by side."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_capture_comparison", "plot_hidden_comparison"]


def plot_capture_comparison(metrics: dict, path: str | Path, real_label: str = "real",
                            sim_label: str = "simulation") -> Path:
    """Write a PNG: real image | simulated image | normalised transients (and their difference).

    Args:
        metrics: the dict of ``compare_captures`` (``t`` s, ``real_sum``, ``sim_sum``, ``real_image``,
            ``sim_image``, ``rel_l2``, ``chi2_per_bin``, ``peak_time_diff``, ``width_diff``).
        path: the .png to write.
    Returns:
        the path written.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), gridspec_kw={"width_ratios": [1, 1, 1.8]})
    for ax, key, label in ((axes[0], "real_image", real_label), (axes[1], "sim_image", sim_label)):
        img = np.asarray(metrics[key], float)
        img = img.reshape(img.shape[0], -1) if img.ndim >= 2 else img.reshape(1, -1)
        ax.imshow(img, origin="lower", cmap="magma")
        ax.set_title(f"{label}: counts over time")
        ax.set_xlabel("x index")
        ax.set_ylabel("y index")
    t_ns = np.asarray(metrics["t"]) * 1e9
    r = np.asarray(metrics["real_sum"], float)
    s = np.asarray(metrics["sim_sum"], float)
    ax = axes[2]
    ax.plot(t_ns, r / r.sum(), lw=1.0, label=real_label)
    ax.plot(t_ns, s / s.sum(), lw=1.0, label=sim_label)
    ax.plot(t_ns, s / s.sum() - r / r.sum(), lw=0.8, color="grey", label="difference")
    ax.set_xlabel("hidden time (ns): each scan point's offset removed")
    ax.set_ylabel("normalised transient (sum 1)")
    ax.set_title(f"rel. L2 {metrics['rel_l2']:.3f}, χ²/bin {metrics['chi2_per_bin']:.3g}, Δpeak "
                 f"{metrics['peak_time_diff'] * 1e12:.0f} ps, ΔFWHM {metrics['width_diff'] * 1e12:.0f} ps",
                 fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_hidden_comparison(comparison: dict, path: str | Path, real_label: str = "real",
                           sim_label: str = "simulation", pitch: tuple[float, float] | None = None,
                           fronts: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write a PNG of :func:`datagen.analysis.hidden_compare.hidden_comparison`: the two hidden-count maps, the
    scan-summed hidden transients (log scale) and, when given, the two reconstructions' front views, each pair side
    by side; maps drawn as the wall sees the hidden scene (``origin="lower"``, docs/capture_io.md "Orientation").

    Args:
        comparison: the :class:`~datagen.analysis.hidden_compare.HiddenComparison`; path: the .png to write.
        pitch: (between rows, between columns) m for the axes (None: indices).
        fronts: (real, sim) (ny, nx) front views of reconstructions (e.g. the maximum over depth of
            :func:`datagen.analysis.reconstruct.confocal_volume`), or None.
    Returns:
        the path written.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    c = comparison
    ny, nx = np.shape(c["real_map"])
    extent = None if pitch is None else [-pitch[1] * nx / 2, pitch[1] * nx / 2, -pitch[0] * ny / 2, pitch[0] * ny / 2]
    rows = 3 if fronts is not None else 2
    fig = plt.figure(figsize=(11, 4.0 * rows))
    grid = fig.add_gridspec(rows, 2)
    maps = [(c["real_map"], f"{real_label}: hidden counts"),
            (c["model_map"], f"{sim_label}: hidden counts (scaled{', gain applied' if c['gain'] != 'none' else ''})")]
    if fronts is not None:
        maps += [(fronts[0], f"{real_label}: LCT front view"), (fronts[1], f"{sim_label}: LCT front view")]
    for k, (img, title) in enumerate(maps):
        ax = fig.add_subplot(grid[0 if k < 2 else 2, k % 2])     # maps above the transients, fronts below
        ax.imshow(np.asarray(img, float), origin="lower", cmap="magma", extent=extent)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("u (m): right, seen from the wall" if extent else "column")
        ax.set_ylabel("v (m): up the wall" if extent else "row")
    ax = fig.add_subplot(grid[1, :])
    t_ns = np.asarray(c["t"]) * 1e9
    floor = c["floor"]
    ax.semilogy(t_ns, np.maximum(c["real_sum"], 1e-3), lw=0.8, label=real_label)
    ax.semilogy(t_ns, np.maximum(c["model_sum"], 1e-3), lw=0.8, label=sim_label)
    ax.set_xlabel(f"hidden round trip (ns); the first {c['trim'] * 1e9:.3g} ns (direct light) excluded")
    ax.set_ylabel("hidden counts per bin (scan-summed, floor subtracted)")
    ax.set_title(f"rel. L2 {c['rel_l2']:.3f} ({c['rel_l2'] / floor['rel_l2']:.2g}× floor), leading edge "
                 f"{c['edge_median'] * 1e12:+.0f} ps, FWHM {c['fwhm_real'] * 1e12:.0f} / {c['fwhm_sim'] * 1e12:.0f} "
                 f"ps, map r = {c['map_corr']:.3f}", fontsize=9)
    peak = max(float(np.max(c["real_sum"])), float(np.max(c["model_sum"])))
    ax.set_ylim(max(peak * 1e-4, 1e-2), peak * 2)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=64)
    plt.close(fig)
    return path
