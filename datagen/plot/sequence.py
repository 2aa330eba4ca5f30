"""Figure of a capture sequence (``datagen sequence``, docs/motion.md): the moving objects' tracks over the plan of
the room, and each frame's change from the first frame against time of flight (what the field's first trackers read).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..scene import Scene  # noqa: E402
from ..scene.parts import ROOM_LABELS  # noqa: E402
from ..simulation.sequence import SequenceResult  # noqa: E402


def plot_plan(ax, scene: Scene) -> None:
    """The room's plan on ``ax``: every static object's footprint (its vertices' x–y bounding box; walls thin, hidden
    objects filled), the laser spot (red star) and the sensor (black triangle), metres."""
    for o in scene.objects:
        if o.name in scene.moving:
            continue
        lo, hi = o.vertices[:, :2].min(axis=0), o.vertices[:, :2].max(axis=0)
        room = o.label in ROOM_LABELS
        ax.add_patch(plt.Rectangle(lo, *(hi - lo), fill=not room, color="0.75" if not room else "0.4",
                                   lw=0.8, zorder=1))
    ax.plot(*scene.laser.spot[:2], "r*", ms=10, label="laser spot", zorder=3)
    ax.plot(*scene.sensor.position[:2], "k^", ms=7, label="sensor", zorder=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def plot_sequence(seq: SequenceResult, scene: Scene, path: str | Path, tracks: dict | None = None) -> Path:
    """Write a PNG: (left) the plan with each moving object's true track (dots coloured by frame) and, from
    ``tracks`` (name → (F, 2) m estimated positions, NaN where none), estimated tracks as crosses; (right) each
    frame's envelope (summed over channels) minus the first frame's, frame against time (ns), in photons per pulse
    per bin on a symmetric colour scale."""
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.2))
    plot_plan(ax, scene)
    frames = np.arange(len(seq.frame_times))
    for j, name in enumerate(seq.moving):
        sc = ax.scatter(seq.positions[:, j, 0], seq.positions[:, j, 1], c=frames, cmap="viridis", s=10, zorder=4,
                        label=f"{name} (true)")
    for name, est in (tracks or {}).items():
        ax.plot(est[:, 0], est[:, 1], "x", color="tab:red", ms=4, zorder=5, label=f"{name} (estimated)")
    if seq.moving:
        fig.colorbar(sc, ax=ax, label="frame")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{len(frames)} frames at {seq.attrs['frames']['rate']:g} Hz")
    env = seq.envelopes.reshape(len(frames), -1, seq.envelopes.shape[-1]).sum(axis=1)
    change = env - env[:1]
    t_ns = 0.5 * (seq.time_edges[1:] + seq.time_edges[:-1]) * 1e9
    span = float(np.abs(change).max()) or 1.0
    im = ax2.imshow(change, aspect="auto", origin="lower", cmap="RdBu_r", vmin=-span, vmax=span,
                    extent=(t_ns[0], t_ns[-1], -0.5, len(frames) - 0.5), interpolation="nearest")
    fig.colorbar(im, ax=ax2, label="change from frame 0 (photons / pulse / bin)")
    ax2.set_xlabel("time (ns)")
    ax2.set_ylabel("frame")
    ax2.set_title(f"each frame minus the first\n({seq.attrs['method']}; stated error per frame up to "
                  f"{np.nanmax(seq.error):.1%})", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
