"""The finished 3D picture: the render with a legend panel, a scale bar and the world axes (matplotlib), and
the entry points ``datagen view`` and ``datagen simulate --figures`` call.

:func:`render_scene` renders a scene (:func:`datagen.plot.view_render.render_scene_image`), composes it with
its legend (:func:`compose`) and writes the PNG; :func:`scene_view_figure` does that for ``simulate
--figures`` with the run's lookins, and degrades to a one-line note without open3d.
"""
from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Callable

import numpy as np

from ..scene import Scene
from ..simulation import SimulationConfig
from ..transport import estimator
from .view_geometry import LOOKIN_COLOR, Drawables, lookin_points
from .view_render import SUPERSAMPLE, SceneImage, render_scene_image, require_display, show_drawables
from .view_worker import ViewUnavailable, require_open3d

LEGEND_WIDTH = 0.25
"""Fraction of the PNG's width taken by the legend panel on the right."""

DEFAULT_SIZE = (1400, 860)
"""Default PNG size (width, height) in pixels of ``datagen view``."""

SCALE_BAR_FRACTION = 0.22
"""The scale bar is the longest 1, 2 or 5 × 10^k m not above this fraction of the picture's width."""


def nice_length(target: float) -> float:
    """The largest of 1, 2, 5 × 10^k metres not above ``target`` (> 0) m."""
    k = np.floor(np.log10(target))
    for m in (5, 2, 1):
        if m * 10 ** k <= target:
            return float(m * 10 ** k)
    return float(10 ** k)


def draw_scene_image(ax, shot: SceneImage, *, scale_bar: bool = True, axes_triad: bool = True,
                     fontsize: float = 9.0) -> None:
    """Show ``shot`` on a matplotlib Axes with a scale bar (bottom left; the camera is orthographic, so it
    holds across the picture plane) and the world axes x, y, z as seen by the camera (bottom right)."""
    from matplotlib.patches import Rectangle

    img = shot.image
    h, w = img.shape[:2]
    ax.imshow(img, interpolation="antialiased")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_axis_off()
    cam = shot.camera
    if scale_bar:
        mpp = cam.metres_per_pixel(w)
        length = nice_length(SCALE_BAR_FRACTION * w * mpp)
        px = length / mpp
        x0, y0 = 0.04 * w, 0.95 * h
        seg = 5
        for k in range(seg):
            ax.add_patch(Rectangle((x0 + k * px / seg, y0 - 0.012 * h), px / seg, 0.012 * h,
                                   facecolor="black" if k % 2 == 0 else "white", edgecolor="black", lw=0.8))
        ax.text(x0 + px / 2, y0 - 0.022 * h, f"{length:g} m", ha="center", va="bottom", fontsize=fontsize)
        ax.text(x0, y0 + 0.008 * h, "orthographic: true to scale in the picture plane", ha="left", va="top",
                fontsize=fontsize * 0.8, color="0.35")
    if axes_triad:
        origin = np.array([0.93 * w, 0.90 * h])
        arm = 0.055 * min(w, h)
        for k, (name, color) in enumerate((("x", "#d62728"), ("y", "#2ca02c"), ("z", "#1f77b4"))):
            e = np.eye(3)[k]
            vec = np.array([e @ cam.right, -(e @ cam.up)])
            tip = origin + arm * vec
            ax.annotate("", tip, origin, arrowprops=dict(arrowstyle="-|>", color=color, lw=1.5))
            label = origin + 1.35 * arm * vec if np.hypot(*vec) > 0.15 else origin + [0.3 * arm, -0.3 * arm]
            ax.text(*label, name, color=color, ha="center", va="center", fontsize=fontsize, weight="bold")


def legend_handles(shot: SceneImage) -> tuple[list, list[str]]:
    """matplotlib handles and texts of ``shot``'s legend (class colours, laser, sensor, FoV, lookins)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, texts = [], []
    for text, kind, color in shot.drawables.legend:
        if kind == "patch":
            handles.append(Patch(facecolor=color, edgecolor="0.3", lw=0.6))
        elif kind == "point":
            handles.append(Line2D([], [], ls="none", marker="o", ms=4, color=color))
        elif kind == "ringed":          # lookins: points ringed in LOOKIN_COLOR
            handles.append(Line2D([], [], ls="none", marker="o", ms=6, mfc=color, mec=LOOKIN_COLOR, mew=1.5))
        else:
            handles.append(Line2D([], [], color=color, lw=2))
        texts.append(text)
    return handles, texts


def compose(shot: SceneImage, title: str | None = None, legend_width: float = LEGEND_WIDTH,
            dpi: float = 100.0) -> np.ndarray:
    """The picture with its legend panel on the right (``title`` above it), a scale bar and the world axes:
    (H, W', 3) uint8 with W' = W / (1 − legend_width)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    h, w = shot.image.shape[:2]
    total_w = int(round(w / (1 - legend_width)))
    fig = Figure(figsize=(total_w / dpi, h / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    fs = float(np.clip(h / 80.0, 6.5, 11.0))
    draw_scene_image(fig.add_axes([0, 0, w / total_w, 1]), shot, fontsize=fs)
    side = fig.add_axes([w / total_w, 0, 1 - w / total_w, 1])
    side.set_axis_off()
    handles, texts = legend_handles(shot)
    chars = max(16, int((total_w - w) / (0.62 * fs * dpi / 72)) - 6)     # characters per legend line
    texts = [textwrap.fill(t, chars) for t in texts]
    top = 0.985
    if title:
        wrapped = textwrap.fill(title, int(chars * 0.9))
        side.text(0.04, top, wrapped, transform=side.transAxes, ha="left", va="top", fontsize=fs * 1.1,
                  weight="bold")
        line = 1.25 * fs * 1.1 * dpi / 72 / h                          # one title line, in axes fraction
        top -= line * (wrapped.count("\n") + 1.6)
    side.legend(handles, texts, loc="upper left", bbox_to_anchor=(0.02, top), fontsize=fs, frameon=False,
                handlelength=1.6, borderaxespad=0.2, labelspacing=0.6)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()


def _fit(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pad with white or crop (by at most a pixel or two of rounding) to exactly height × width."""
    out = np.full((height, width, 3), 255, dtype=np.uint8)
    h, w = min(height, image.shape[0]), min(width, image.shape[1])
    out[:h, :w] = image[:h, :w]
    return out


def render_scene(scene: Scene, path: str | Path | None = None, *, width: int = DEFAULT_SIZE[0],
                 height: int = DEFAULT_SIZE[1], lookins: np.ndarray | None = None, show: bool = False,
                 title: str | None = None, shading: str = "shaded", supersample: int = SUPERSAMPLE,
                 extra: Drawables | None = None) -> np.ndarray:
    """Render ``scene`` with its legend, scale bar and axes; write a PNG and/or open an interactive window.

    Args:
        path: PNG to write (parent folders created), or None.
        width, height: size of the PNG in pixels (the 3D picture takes the left 1 − :data:`LEGEND_WIDTH`).
        lookins: (N, 3) m lookin hit points to overlay (:func:`~datagen.plot.view_geometry.lookin_points`).
        show: also open open3d's interactive window on the same geometry (needs a display).
        title: text above the legend (default: the scene's name).
        shading, supersample: see :func:`~datagen.plot.view_render.render_scene_image`.
        extra: more lines and legend entries, e.g. a multi-zone scene's lit patch and zones
            (:func:`datagen.plot.view_flood.flood_drawables`).
    Returns:
        (height, width, 3) uint8 RGB image (what the PNG holds).
    Raises:
        ViewUnavailable: open3d, a Vulkan driver or (with ``show``) a display is missing.
        SceneError: the scene's capture cannot be resolved.
        RuntimeError: the renderer failed or kept stalling.
    """
    if show:
        require_display()
    render_w = int(round(width * (1 - LEGEND_WIDTH)))
    shot = render_scene_image(scene, render_w, height, lookins=lookins, shading=shading, supersample=supersample,
                              extra=extra)
    image = _fit(compose(shot, title if title is not None else scene.name), width, height)
    if path is not None:
        from PIL import Image
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(path, optimize=True)
    if show:
        show_drawables(shot.drawables, title or scene.name)
    return image


def scene_view_figure(scene: Scene, path: str | Path, config: SimulationConfig | None = None,
                      note: Callable[[str], None] | None = None, **kwargs) -> list[Path]:
    """Write the scene's 3D picture to ``path`` for ``simulate --figures``, with the lookins the run cast
    (when ``config`` uses the lookin estimator). Without open3d or a Vulkan driver, or when the renderer
    fails, nothing is written and ``note`` gets one line saying why.

    Args:
        kwargs: passed to :func:`render_scene`.
    Returns:
        [path] when written, else [].
    """
    try:
        require_open3d()
        casts = config is not None and estimator(config.estimator.kind).casts_lookins
        lookins = lookin_points(scene, config) if casts else None
        render_scene(scene, path, lookins=lookins, **kwargs)
    except (ViewUnavailable, RuntimeError) as exc:
        if note is not None:
            note(f"note: no 3D scene picture: {' '.join(str(exc).split())}")
        return []
    return [Path(path)]
