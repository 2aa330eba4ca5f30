"""Figure: the envelope L(t) with its components (Scholes & Leach 2024, Figure 7); the sampling views
(Figures 3 and 5) are in :mod:`datagen.plot.figures`."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..simulation import Result  # noqa: E402

COMPONENT_COLORS = {"room": "tab:blue", "box": "tab:purple", "pillar": "tab:orange", "secondary": "tab:red"}
"""The paper's Figure 7 colours: walls/roof/floor blue, box purple, pillar orange, secondary red."""

LOG_FLOOR = 1e-6
"""Lower limit of the log axis, relative to the envelope's peak."""


def plot_envelope(result: Result, path: str | Path, title: str | None = None) -> Path:
    """Write a log-scale plot of L(t) (black) and its components (coloured, dashed), and the SPAD counts.

    Args:
        result: a single-pixel result (pixel arrays are summed over pixels).
        path: PNG path.
    """
    t_ns = result.time_centers * 1e9
    width_ps = (result.time_edges[1] - result.time_edges[0]) * 1e12

    def flat(a):
        return np.asarray(a).reshape(-1, a.shape[-1]).sum(0)

    env = flat(result.envelope)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    lit = env.max() > 0
    if lit:
        ax.set_yscale("log")             # a zero envelope (all light outside the window) stays on a linear axis
    ax.plot(t_ns, env, color="black", lw=2, label="L(t) total")
    for i, (name, comp) in enumerate(result.components.items()):
        c = flat(comp)
        if c.max() <= 0:
            continue
        color = COMPONENT_COLORS.get(name, f"C{(i + 4) % 10}")
        ax.plot(t_ns, c, "--", color=color, lw=1.4, label=f"{name} ({c.sum():.3g})")
    peak = env.max() if lit else 1.0
    ax.set_ylim(peak * LOG_FLOOR if lit else -0.05, peak * 3)
    ax.set_ylabel(f"expected detections / pulse / {width_ps:.0f} ps bin")
    ax.legend(loc="upper right", fontsize=9, title="component (area)")
    ax.grid(True, which="major", alpha=0.3)
    ax.set_title(title or f"{result.attrs.get('scene', '')}: likelihood envelope L(t)")
    counts = flat(result.counts)
    ax2.step(t_ns, counts, where="mid", color="tab:gray", lw=0.8)
    det = result.attrs.get("detector", {})
    ax2.set_ylabel("SPAD counts")
    ax2.set_xlabel("time (ns)")
    ax2.set_title(f"finite-exposure histogram: {int(counts.sum())} detections, model {det.get('model', '?')}",
                  fontsize=10)
    ax2.grid(True, alpha=0.3)
    nz = np.flatnonzero(env > peak * LOG_FLOOR)
    if nz.size:
        lo, hi = t_ns[nz[0]], t_ns[nz[-1]]
        pad = 0.05 * (hi - lo + 1)
        ax.set_xlim(lo - pad, hi + pad)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
