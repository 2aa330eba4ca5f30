"""Pictures of a scanned sample (``datagen inspect`` of a scan dataset): what the scan sees beside its labels.

:func:`plot_scan_sample` draws, for one sample of a confocal scan (or a sensor grid): the peak-time image (the time
of each scan point's maximum, ns: the hidden surface's distance pattern), a few time slices of the envelope at the
strongest times, the wall-view depth label (m; a sample without objects in view, all 0, is a blank panel with a
−0.1…0.1 m colour bar) and the envelope summed over the scan points (expected detected photons per laser pulse and
bin, log scale). Every image has row 0 at the
bottom of the wall (``origin="lower"``; docs/datasets.md "Scanned captures"), so label and scan pixels align.
"""
from __future__ import annotations

import numpy as np

TIME_SLICES = 3
"""Time slices drawn: the bins where the scan's summed envelope is largest, spread apart."""

EMPTY_DEPTH_RANGE = 0.1
"""Half-range (m) of the colour bar of an empty ``wall_depth`` label (no object seen from the wall): a blank panel
with a −0.1…0.1 m bar instead of an all-NaN image whose bar matplotlib cannot scale."""


def scan_image_shape(envelope: np.ndarray) -> tuple[int, int] | None:
    """(H, W) when a stored envelope (per sample) is an image of transients, else None."""
    shape = np.shape(envelope)
    if len(shape) == 3:
        return shape[0], shape[1]
    if len(shape) == 5 and shape[2:4] == (1, 1):
        return shape[0], shape[1]
    return None


def plot_scan_sample(sample: dict, time_edges: np.ndarray, title: str | None = None, fig=None):
    """Figure of a scanned sample; returns the matplotlib Figure (Agg-safe).

    ``sample``: dict of numpy arrays or torch tensors with ``envelope`` (H, W, T) float (expected detected photons
    per pulse and bin; (H, W, 1, 1, T) is accepted too) and optionally ``wall_depth`` (H, W) float32 in metres (0
    where no object is seen). ``time_edges``: (T+1,) seconds. ``fig``: a Figure or SubFigure to draw into. Panels:
    peak time (ns), the strongest time slices, ``wall_depth`` (m), the envelope summed over the scan points
    (y axis: photons / pulse / bin, log scale)."""
    from matplotlib.figure import Figure

    env = np.asarray(sample["envelope"].numpy() if hasattr(sample["envelope"], "numpy") else sample["envelope"],
                     dtype=np.float64)
    h, w = scan_image_shape(env)
    env = env.reshape(h, w, -1)
    t_ns = 0.5 * (time_edges[1:] + time_edges[:-1]) * 1e9
    total = env.sum(axis=(0, 1))
    order = np.argsort(total)[::-1]
    slices: list[int] = []
    for b in order:                                   # strongest bins, at least T/20 bins apart
        if all(abs(int(b) - s) > max(1, len(t_ns) // 20) for s in slices):
            slices.append(int(b))
        if len(slices) == TIME_SLICES:
            break
    slices.sort()
    depth = sample.get("wall_depth")
    panels = 2 + len(slices) + (depth is not None)
    fig = fig or Figure(figsize=(3.3 * panels, 3.4), layout="constrained")
    axes = fig.subplots(1, panels, squeeze=False)[0]
    lit = env.max(axis=-1) > 0
    peak = np.where(lit, t_ns[np.argmax(env, axis=-1)], np.nan)
    im = axes[0].imshow(peak, origin="lower", cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="ns")
    axes[0].set_title("peak time")
    for ax, b in zip(axes[1:], slices):
        ax.imshow(env[:, :, b], origin="lower", cmap="magma")
        ax.set_title(f"t = {t_ns[b]:.2f} ns")
    k = 1 + len(slices)
    if depth is not None:
        d = np.asarray(depth.numpy() if hasattr(depth, "numpy") else depth, dtype=np.float64).reshape(h, w) \
            if np.size(depth) == h * w else np.asarray(depth, dtype=np.float64)
        seen = d > 0
        limits = {} if seen.any() else {"vmin": -EMPTY_DEPTH_RANGE, "vmax": EMPTY_DEPTH_RANGE}
        im = axes[k].imshow(np.where(seen, d, np.nan), origin="lower", cmap="viridis", **limits)
        fig.colorbar(im, ax=axes[k], label="m")
        axes[k].set_title("label: wall_depth")
        k += 1
    for ax in axes[:k]:
        ax.set_xticks([])
        ax.set_yticks([])
    axes[k].semilogy(t_ns, np.where(total > 0, total, np.nan), lw=1)
    axes[k].set_xlabel("time (ns)")
    axes[k].set_ylabel("photons / pulse / bin")
    axes[k].set_title("envelope, scan sum")
    if title:
        fig.suptitle(title)
    return fig
