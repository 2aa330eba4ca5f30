"""A measured capture drawn beside its simulation: time-integrated images of both scans and their normalised
scan-summed transients on the hidden time axis (the arrays and distances of
:func:`datagen.analysis.compare_capture.compare_captures`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_capture_comparison"]


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
