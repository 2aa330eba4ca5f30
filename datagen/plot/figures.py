"""Sampling views of the lookin estimator: Scholes & Leach 2024, Figures 3 and 5.

- **Figure 3** (:func:`laser_energy`): the laser energy reaching every observed point of every lookin (§3.1).
  Three factors at an observed point x at distance R from the laser spot x_l: (a) the spreading loss 1/R²,
  (b) the laser-spot emission f_l(ω_e, ω)·cosθ_l toward x (the paper's B_1 = cos φ for a Lambertian relay
  wall, here with its 1/π), and (c) the laser irradiance at x, Φ·f_l cosθ_l·cosθ_x·V(x_l, x)/R² photons per
  m² per pulse, zero where x is in the laser's shadow (§3.2: "observed points that lie in shadow must be
  removed").
- **Figure 5** (:func:`lookin_energy`): one lookin's camera (§3.2): the lookin BRDF lobe
  f_j(ω_in = toward the spot, ω_k)·cosθ_k over its observed points, the same divided by r² (the paper's
  illustration; the estimator weighs a pixel by f·cos·Ω instead, the 1/r² cancelling against the pixel's
  footprint), and, on the relay wall, each FoV point's full primary weight f_j cosθ_k Ω times the fraction
  of photons landing there that the SPAD detects.

The data come from :mod:`datagen.plot.energy` (every weight from the estimator's per-leg physics). Views are axis-aligned orthographic projections of the room with the surfaces facing away
from the viewer culled (a cut-away: the ceiling in the plan view, the near wall in an elevation). Figure 3's
observed points are painted as z-buffered splats sized by the local sampling density; a Figure 5 lookin's
points as the quads between neighbouring camera pixels, far to near, so each reads as the surface it samples.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.colors import LogNorm, Normalize, to_rgba  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from ..scene import Scene  # noqa: E402
from ..scene.capture import FOV_PLANE_TOL  # noqa: E402
from ..scene.parts import ROOM_LABELS  # noqa: E402
from ..simulation import SimulationConfig  # noqa: E402
from ..simulation.config import STREAM_SAMPLING, stream_rng  # noqa: E402
from ..transport import LookinSampler  # noqa: E402
from ..vectors import dot, unit  # noqa: E402
from .energy import LaserEnergy, LookinEnergy, laser_energy, lookin_energy, pick_lookin  # noqa: E402

MAX_DRAWN_POINTS = 1_000_000
"""Figure 3 draws a random subsample of at most this many observed points (memory; 10×10×60×60 is 360k)."""

RASTER_CELLS = 360
"""Views are painted on a grid of this many cells along the scene's longest side (z-buffered splats)."""

SPLAT_NEIGHBOUR = 6
"""Each observed point paints the cells within the distance to its SPLAT_NEIGHBOUR-th nearest on-screen
neighbour (a local sampling spacing robust to random clumping): a surface sampled sparsely (far from the
lookins) still reads as a surface, while the outline of what a camera saw (the paper's 'triangular' pillar
view) is kept."""

MAX_SPLAT_CELLS = 6.0
"""Largest splat radius in cells: gaps wider than this stay blank (a surface the cameras did not sample)."""

DEPTH_LAYER_CELLS = 4.0
"""Depth quantum (in cells) of the z-buffer: samples within it count as one surface layer."""

DYNAMIC_RANGE = 1e4
"""Log colour scales span at most this ratio below their maximum; smaller non-zero values get the lowest
colour, exact zeros a separate grey."""

SPOT_LOBE_RANGE = 1e2
"""Colour range of the laser-spot lobe f_l·cosθ_l (Fig. 3b): its grazing tail would otherwise flatten the
cosine into one colour."""

CULL_COS = 0.15
"""A surface point is drawn in a view when its normal faces the viewer by more than this cosine: back faces
are cut away and edge-on faces (which would pile up on a line) dropped."""

COPLANAR_REL = 1e-4
"""Four neighbouring camera pixels whose observed points lie on one object, share a normal (SAME_NORMAL_COS)
and lie within this fraction of the scene size of one plane form a painted quad (no depth jump inside)."""

SAME_NORMAL_COS = 0.999
"""Two faces (or observed points) whose unit normals agree to this cosine lie on one flat surface."""

CMAP = "viridis"
ZERO_COLOR = "0.8"
HIDDEN_COLOR = "0.45"
HIDDEN, OUTSIDE = -1.0, -2.0
"""Codes painted into the FoV close-up for FoV points hidden from the SPAD and wall points outside the FoV."""
FOV_COLOR = "limegreen"
EDGE_COLOR = "0.35"


@dataclass(frozen=True)
class View:
    """An axis-aligned orthographic view: screen axes are world axes (index, sign); the viewer looks along
    −toward, toward = right × up."""

    name: str
    right: tuple[int, int]
    up: tuple[int, int]

    @property
    def toward(self) -> np.ndarray:
        e = np.eye(3)
        return np.cross(self.right[1] * e[self.right[0]], self.up[1] * e[self.up[0]])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates shown on the screen axes (axes with sign −1 are drawn inverted). (n, 3) → 2×(n,)."""
        return points[..., self.right[0]], points[..., self.up[0]]

    def setup(self, ax) -> None:
        names = "xyz"
        ax.set_xlabel(f"{names[self.right[0]]} (m)")
        ax.set_ylabel(f"{names[self.up[0]]} (m)")
        if self.right[1] < 0:
            ax.invert_xaxis()
        if self.up[1] < 0:
            ax.invert_yaxis()
        ax.set_aspect("equal")
        ax.set_facecolor("white")


PLAN = View("plan view from above (ceiling cut away)", (0, 1), (1, 1))
ELEVATION_Y = View("elevation from −y (near wall cut away)", (0, 1), (2, 1))
ELEVATION_X = View("elevation from −x (near wall cut away)", (1, -1), (2, 1))
ELEVATION_PX = View("elevation from +x (near wall cut away)", (1, 1), (2, 1))
ELEVATION_PY = View("elevation from +y (near wall cut away)", (0, -1), (2, 1))
VIEWS = (PLAN, ELEVATION_Y, ELEVATION_X, ELEVATION_PX, ELEVATION_PY)


def _feature_edges(scene: Scene) -> np.ndarray:
    """(E, 2, 3) mesh edges that outline the scene: boundary edges and creases (the diagonals of flat quads
    are dropped)."""
    out = []
    for o in scene.objects:
        tri = o.vertices[o.faces]
        n = unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) + 1e-300)
        edges = np.concatenate([o.faces[:, [0, 1]], o.faces[:, [1, 2]], o.faces[:, [2, 0]]])
        face = np.tile(np.arange(len(o.faces)), 3)
        key = np.sort(edges, axis=1)
        _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        _, last_rev = np.unique(key[::-1], axis=0, return_index=True)
        last = len(key) - 1 - last_rev
        flat = (counts == 2) & (np.abs(dot(n[face[first]], n[face[last]])) > SAME_NORMAL_COS)
        out.append(o.vertices[edges[first[~flat]]])
    return np.concatenate(out) if out else np.zeros((0, 2, 3))


def _draw_outline(ax, view: View, edges: np.ndarray) -> None:
    h, v = view.project(edges)
    seg = np.stack([h, v], axis=-1)
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=-1)      # edges seen end-on collapse to points
    ax.add_collection(LineCollection(seg[length > 1e-6], colors=EDGE_COLOR, linewidths=0.6, alpha=0.8,
                                     zorder=3))


def _draw_capture(ax, view: View, capture, legend: bool = False) -> None:
    c = capture
    hu, hv = 0.5 * c.fov_size[0] * c.fov_u, 0.5 * c.fov_size[1] * c.fov_v
    corners = c.fov_center + np.array([-hu - hv, hu - hv, hu + hv, -hu + hv, -hu - hv])
    h, v = view.project(corners)
    ax.plot(h, v, color=FOV_COLOR, lw=2.2, zorder=5, label="SPAD FoV" if legend else None)
    h, v = view.project(c.spot)
    ax.plot(h, v, marker="*", ms=14, color="red", mec="black", mew=0.6, ls="none", zorder=6,
            label="laser spot" if legend else None)


def _log_norm(values: np.ndarray, dynamic_range: float = DYNAMIC_RANGE) -> LogNorm:
    """Log scale from the 99.9th percentile of the positive values down by at most ``dynamic_range``."""
    pos = values[values > 0]
    if pos.size == 0:
        return LogNorm(1e-3, 1.0, clip=True)
    hi = float(np.percentile(pos, 99.9))
    lo = max(float(pos.min()), hi / dynamic_range)
    return LogNorm(lo, hi if hi > lo else lo * 10, clip=True)


def _splat(h: np.ndarray, v: np.ndarray, depth: np.ndarray, values: np.ndarray, extent: tuple, cell: float
           ) -> np.ndarray:
    """Z-buffered splat image of screen points (h, v).

    Each sample paints a disc of radius its local sampling spacing (see SPLAT_NEIGHBOUR; at least one cell,
    at most MAX_SPLAT_CELLS). A cell takes the value of the nearest layer to the viewer (depth quantised to
    DEPTH_LAYER_CELLS cells) and, within it, of the sample whose centre is closest; cells no disc reaches are
    nan.

    Args:
        h, v, depth, values: (n,) float64 screen coordinates (m), depth toward the viewer (m), value.
        extent: (h0, h1, v0, v1) of the image; cell: cell size (m).
    Returns:
        (rows, cols) float64 image, row 0 at v0.
    """
    h0, h1, v0, v1 = extent
    cols, rows = max(1, int(np.ceil((h1 - h0) / cell))), max(1, int(np.ceil((v1 - v0) / cell)))
    img = np.full((rows, cols), np.nan)
    if len(h) == 0:
        return img
    fx, fy = (h - h0) / cell, (v - v0) / cell
    if len(h) > 1:
        k = min(SPLAT_NEIGHBOUR, len(h) - 1)
        d, _ = cKDTree(np.stack([fx, fy], axis=-1)).query(np.stack([fx, fy], axis=-1), k=k + 1)
        radius = np.clip(d[:, k], 1.0, MAX_SPLAT_CELLS)
    else:
        radius = np.ones(1)
    by_radius = np.argsort(-radius)                          # samples reaching an offset form a prefix
    sorted_radius = -radius[by_radius]
    ix0, iy0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    layer = np.round(depth / (DEPTH_LAYER_CELLS * cell))
    r = int(np.ceil(MAX_SPLAT_CELLS))
    cells, keys = [], []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            reach = np.hypot(dx, dy)
            sel = by_radius[:np.searchsorted(sorted_radius, -reach, side="right")]
            if sel.size == 0:
                continue
            ix, iy = ix0[sel] + dx, iy0[sel] + dy
            ok = (ix >= 0) & (ix < cols) & (iy >= 0) & (iy < rows)
            sel, ix, iy = sel[ok], ix[ok], iy[ok]
            cells.append(np.stack([iy * cols + ix, sel]))
            keys.append(np.hypot(ix + 0.5 - fx[sel], iy + 0.5 - fy[sel]))
    flat, src = np.concatenate(cells, axis=1)
    dist = np.concatenate(keys)
    order = np.lexsort((dist, -layer[src], flat))           # per cell: nearest layer, then closest centre
    first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]
    img.flat[flat[first]] = values[src[first]]
    return img


def _colors(values: np.ndarray, norm, cmap: str) -> np.ndarray:
    """RGBA of values; on a log scale values ≤ 0 are grey (ZERO_COLOR). (n,) → (n, 4)."""
    out = plt.get_cmap(cmap)(norm(np.where(values > 0, values, 1.0) if isinstance(norm, LogNorm) else values))
    if isinstance(norm, LogNorm):
        out[values <= 0] = to_rgba(ZERO_COLOR)
    return out


def _rgba(img: np.ndarray, norm, cmap: str, special: dict[float, str] | None = None) -> np.ndarray:
    """Colour an image (see :func:`_colors`): nan transparent, exact ``special`` codes in their colour."""
    out = np.zeros(img.shape + (4,))
    have = ~np.isnan(img)
    out[have] = _colors(img[have], norm, cmap)
    for code, color in (special or {}).items():
        out[have & (img == code)] = to_rgba(color)
    return out


def _extent(view: View, scene: Scene, pad: float = 0.15) -> tuple[float, float, float, float]:
    b = scene.bounds()
    h0, v0 = view.project(b[0])
    h1, v1 = view.project(b[1])
    return h0 - pad, h1 + pad, v0 - pad, v1 + pad


def _paint(ax, view: View, scene: Scene, points: np.ndarray, normals: np.ndarray, values: np.ndarray, norm,
           cmap: str) -> plt.cm.ScalarMappable:
    """Paint the points facing the viewer into ``ax`` (cut-away view). Returns the colour mappable."""
    toward = view.toward
    keep = dot(normals, toward) > CULL_COS
    p = points[keep]
    h, v = view.project(p)
    ext = _extent(view, scene)
    cell = float(np.max(np.diff(scene.bounds(), axis=0))) / RASTER_CELLS
    img = _splat(h, v, p @ toward, values[keep], ext, cell)
    ax.imshow(_rgba(img, norm, cmap), extent=ext, origin="lower", interpolation="nearest", zorder=1)
    view.setup(ax)
    ax.set_xlim(*(ext[:2] if view.right[1] > 0 else ext[1::-1]))
    ax.set_ylim(*(ext[2:] if view.up[1] > 0 else ext[3:1:-1]))
    return plt.cm.ScalarMappable(norm=norm, cmap=cmap)


def _paint_camera(ax, view: View, scene: Scene, le: LookinEnergy, values: np.ndarray, norm, cmap: str
                  ) -> plt.cm.ScalarMappable:
    """Paint one lookin's observed points as the quads between neighbouring camera pixels (pixel centres
    as corners) that lie on one flat surface, far to near; a cut-away as in :func:`_paint`."""
    l, p = le.n_pixels
    pts = np.nan_to_num(le.points).reshape(l, p, 3)
    nrm = le.normals.reshape(l, p, 3)
    hit = le.hit.reshape(l, p)
    obj = le.object_id_obs.reshape(l, p)
    val = values.reshape(l, p)
    corner = [(slice(None, -1), slice(None, -1)), (slice(1, None), slice(None, -1)),
              (slice(1, None), slice(1, None)), (slice(None, -1), slice(1, None))]
    q = np.stack([pts[c] for c in corner], axis=2)                  # (l-1, p-1, 4, 3)
    n0 = nrm[corner[0]]
    ok = np.all([hit[c] for c in corner], axis=0)
    ok &= np.all([obj[c] == obj[corner[0]] for c in corner[1:]], axis=0)
    ok &= np.all([dot(nrm[c], n0) > SAME_NORMAL_COS for c in corner[1:]], axis=0)
    tol = COPLANAR_REL * float(np.max(np.diff(scene.bounds(), axis=0)))
    ok &= np.all(np.abs(dot(q - q[:, :, :1], n0[:, :, None])) < tol, axis=-1)
    ok &= dot(n0, view.toward) > CULL_COS
    q, v = q[ok], np.mean([val[c][ok] for c in corner], axis=0)
    order = np.argsort(q.mean(axis=1) @ view.toward)
    h, vv = view.project(q[order])
    colors = _colors(v[order], norm, cmap)
    ax.add_collection(PolyCollection(np.stack([h, vv], axis=-1), facecolors=colors, edgecolors=colors,
                                     linewidths=0.3, antialiased=False, zorder=1, rasterized=True))
    ext = _extent(view, scene)
    view.setup(ax)
    ax.set_xlim(*(ext[:2] if view.right[1] > 0 else ext[1::-1]))
    ax.set_ylim(*(ext[2:] if view.up[1] > 0 else ext[3:1:-1]))
    return plt.cm.ScalarMappable(norm=norm, cmap=cmap)


def plot_laser_energy(scene: Scene, data: LaserEnergy, transport: LookinSampler, path: Path,
                      rng: np.random.Generator) -> Path:
    """Figure 3: three factors of the laser energy at the observed points, in a plan and an elevation."""
    n = len(data.points)
    sub = rng.choice(n, MAX_DRAWN_POINTS, replace=False) if n > MAX_DRAWN_POINTS else np.arange(n)
    p, nrm = data.points[sub], data.normals[sub]
    panels = [      # values, colour range (ratio), title, colour-bar label
        (data.inv_square[sub], DYNAMIC_RANGE, "(a) spreading loss 1/R²",
         "1/R²  (m⁻²);  R = distance from the laser spot"),
        (data.spot_emission[sub], SPOT_LOBE_RANGE, "(b) laser-spot BRDF × cosine  f_l·cosθ_l",
         "f_l(ω_e, ω)·cosθ_l  (sr⁻¹);  Lambertian: ρ·cosθ_l / π"),
        (data.irradiance[sub], DYNAMIC_RANGE, "(c) laser irradiance  Φ·f_l cosθ_l·cosθ_x·V / R²",
         "photons m⁻² per pulse;  grey: 0 (laser shadow, or facing away from the spot)"),
    ]
    views = (PLAN, ELEVATION_Y)
    ratios = [(e[3] - e[2]) / (e[1] - e[0]) for e in (_extent(v, scene) for v in views)]
    width = 6.2
    fig, axes = plt.subplots(len(views), 3, figsize=(3 * width, width * sum(ratios) + 2.2), squeeze=False,
                             gridspec_kw={"height_ratios": ratios}, layout="constrained")
    edges = _feature_edges(scene)
    shown = np.any([dot(nrm, view.toward) > CULL_COS for view in views], axis=0)
    for col, (values, dyn, title, clabel) in enumerate(panels):
        norm = _log_norm(values[shown], dyn)     # colour range of what the views show
        for row, view in enumerate(views):
            ax = axes[row, col]
            mappable = _paint(ax, view, scene, p, nrm, values, norm, CMAP)
            _draw_outline(ax, view, edges)
            _draw_capture(ax, view, transport.capture, legend=(row == 0 and col == 0))
            ax.set_title(f"{title}\n{view.name}" if row == 0 else view.name, fontsize=10)
        cb = fig.colorbar(mappable, ax=axes[:, col], orientation="horizontal", shrink=0.9, aspect=30)
        cb.set_label(clabel, fontsize=9)
    axes[0, 0].legend(loc="upper left", fontsize=8, framealpha=0.9)
    shadow = (data.spot_emission > 0) & (data.cos_in > 0) & ~data.lit
    fig.suptitle(f"{scene.name}: laser energy reaching the observed points (Scholes & Leach 2024, Fig. 3)\n"
                 f"{n:,} observed points of {transport.settings.lookins[0]}×{transport.settings.lookins[1]} "
                 f"lookins × {transport.settings.pixels[0]}×{transport.settings.pixels[1]} pixels; "
                 f"{100 * shadow.mean() if n else 0:.0f} % of them in the laser's shadow; "
                 f"Φ = {data.photons:.3g} photons per pulse", fontsize=11)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _auto_view(normal: np.ndarray, capture) -> View:
    """The axis-aligned view looking along the lookin's normal (the surfaces it lights face the viewer);
    near-ties go to the view that shows the FoV face on."""
    scores = [-float(dot(view.toward, normal)) + 0.05 * float(dot(view.toward, capture.fov_normal) > 0.9)
              for view in VIEWS]
    return VIEWS[int(np.argmax(scores))]


def _fov_closeup(ax, le: LookinEnergy, transport: LookinSampler) -> plt.cm.ScalarMappable:
    """Relay wall around the FoV seen from the sensor side; FoV points coloured by their final weight."""
    c = transport.capture
    names = "xyz"
    # screen axes: u (or −u) to the right as seen from the sensor side, v up
    right = np.cross(-c.fov_normal, c.fov_v)
    flip = float(dot(right, c.fov_u)) < 0
    iu, iv = int(np.argmax(np.abs(c.fov_u))), int(np.argmax(np.abs(c.fov_v)))
    aligned = abs(c.fov_u[iu]) > 0.999 and abs(c.fov_v[iv]) > 0.999
    ou = float(c.fov_center @ c.fov_u) if aligned else 0.0   # plot world coordinates when axis-aligned
    ov = float(c.fov_center @ c.fov_v) if aligned else 0.0
    y = np.nan_to_num(le.points)
    rel = y - c.fov_center
    a, b = rel @ c.fov_u + ou, rel @ c.fov_v + ov
    on_wall = le.hit & (np.abs(rel @ c.fov_normal) <= FOV_PLANE_TOL * transport.caster.offset)
    margin = 0.3 * max(c.fov_size)
    ext = (ou - 0.5 * c.fov_size[0] - margin, ou + 0.5 * c.fov_size[0] + margin,
           ov - 0.5 * c.fov_size[1] - margin, ov + 0.5 * c.fov_size[1] + margin)
    contrib = le.contribution[le.in_fov]
    norm = _log_norm(contrib)
    code = np.where(le.in_fov, np.where(le.contribution > 0, le.contribution, HIDDEN), OUTSIDE)
    img = _splat(a[on_wall], b[on_wall], np.zeros(int(on_wall.sum())), code[on_wall], ext,
                 (ext[1] - ext[0]) / 240)
    ax.imshow(_rgba(img, norm, CMAP, {HIDDEN: HIDDEN_COLOR, OUTSIDE: ZERO_COLOR}), extent=ext, origin="lower",
              interpolation="nearest")
    hu, hv = 0.5 * c.fov_size[0], 0.5 * c.fov_size[1]
    ax.plot([ou - hu, ou + hu, ou + hu, ou - hu, ou - hu], [ov - hv, ov - hv, ov + hv, ov + hv, ov - hv],
            color=FOV_COLOR, lw=2.2, zorder=5, label="SPAD FoV")
    rs = c.spot - c.fov_center
    ax.plot(rs @ c.fov_u + ou, rs @ c.fov_v + ov, marker="*", ms=14, color="red", mec="black", mew=0.6,
            ls="none", zorder=6, label="laser spot")
    ax.fill_between([], [], color=ZERO_COLOR, label="relay wall outside the FoV")
    ax.fill_between([], [], color=HIDDEN_COLOR, label="in the FoV, hidden from the SPAD (V = 0)")
    ax.set_xlim(*(ext[1::-1] if flip else ext[:2]))
    ax.set_ylim(*ext[2:])
    ax.set_aspect("equal")
    ax.set_xlabel(f"{names[iu]} (m)" if aligned else "FoV u (m)")
    ax.set_ylabel(f"{names[iv]} (m)" if aligned else "FoV v (m)")
    return plt.cm.ScalarMappable(norm=norm, cmap=CMAP)


def plot_lookins(scene: Scene, lookins: list[tuple[str, LookinEnergy]], transport: LookinSampler, path: Path) -> Path:
    """Figure 5: for each lookin its BRDF lobe, the lobe over r², and the FoV close-up with final weights."""
    c = transport.capture
    edges = _feature_edges(scene)
    fig = plt.figure(figsize=(20, 4.7 * len(lookins) + 0.8), layout="constrained")
    subfigs = np.atleast_1d(fig.subfigures(len(lookins), 1, hspace=0.03))
    for sf, (tag, le) in zip(subfigs, lookins):
        view = _auto_view(le.normal, c)
        obj = scene.objects[le.object_id]
        ext = _extent(view, scene)
        aspect = (ext[1] - ext[0]) / (ext[3] - ext[2])
        axes = sf.subplots(1, 3, width_ratios=[aspect, aspect, 1.1])
        lobe_max = float(le.brdf_cos.max()) if le.brdf_cos.max() > 0 else 1.0
        panels = [
            (le.brdf_cos, Normalize(0.0, lobe_max), "lookin BRDF × cosine  f_j(ω_in, ω_k)·cosθ_k  (linear scale)",
             "f_j·cosθ_k  (sr⁻¹)"),
            (le.brdf_cos_r2, _log_norm(le.brdf_cos_r2[le.hit & (dot(le.normals, view.toward) > CULL_COS)]),
             "× inverse-square loss:  f_j·cosθ_k / r²  (illustrative, as in the paper)",
             "f_j·cosθ_k / r²  (sr⁻¹ m⁻²);  r = lookin → observed point"),
        ]
        for ax, (values, norm, title, clabel) in zip(axes, panels):
            m = _paint_camera(ax, view, scene, le, values, norm, CMAP)
            _draw_outline(ax, view, edges)
            _draw_capture(ax, view, c, legend=True)
            h, v = view.project(le.position)
            ax.plot(h, v, marker="^", ms=13, color="0.6", mec="black", mew=1.0, ls="none", zorder=7,
                    label="lookin (arrow: its normal)")
            nh, nv = view.project(le.normal)
            if np.hypot(nh, nv) > 0.2:                     # the normal's arrow, unless it points at the viewer
                ax.annotate("", (h + 0.6 * nh, v + 0.6 * nv), (h, v), zorder=7,
                            arrowprops=dict(arrowstyle="-|>", color="black", lw=1.2))
            ax.set_title(f"({tag}) {title}\n{view.name}", fontsize=10)
            cb = sf.colorbar(m, ax=ax, orientation="horizontal", shrink=0.8, aspect=35)
            cb.set_label(clabel, fontsize=9)
        m = _fov_closeup(axes[2], le, transport)
        axes[2].set_title(f"({tag}) relay wall around the FoV, seen from the sensor:\nfinal bounce of "
                          f"{int(le.in_fov.sum())} FoV points (Σ = {float(le.contribution.sum()):.3g})",
                          fontsize=10)
        cb = sf.colorbar(m, ax=axes[2], shrink=0.9)
        cb.set_label("f_j cosθ_k Ω · q f_y cosθ_y A_ap cosθ_ap V / d²\n"
                     "(SPAD detections per photon at the lookin)", fontsize=8.5)
        normal = np.round(le.normal + 0.0, 2).tolist()
        sf.suptitle(f"({tag}) lookin (grey triangle) on {obj.name!r} ({le.label}, {obj.material.kind} BRDF) at "
                    f"{np.round(le.position, 2).tolist()} m, normal {normal}: {int(le.hit.sum()):,} observed points",
                    fontsize=11, weight="bold", x=0.01, ha="left")
    l, p = lookins[0][1].n_pixels
    handles = [*subfigs[0].axes[0].get_legend_handles_labels()[0], *subfigs[0].axes[2].get_legend_handles_labels()[0]]
    labels = [*subfigs[0].axes[0].get_legend_handles_labels()[1], *subfigs[0].axes[2].get_legend_handles_labels()[1]]
    keep = {lab: h for h, lab in zip(handles, labels)}
    fig.legend(keep.values(), keep.keys(), loc="outside lower center", ncol=len(keep), fontsize=9, frameon=False)
    fig.suptitle(f"{scene.name}: energy distribution of single lookins (Scholes & Leach 2024, Fig. 5) — "
                 f"{l}×{p} camera per lookin (Ω = {lookins[0][1].solid_angle:.2e} sr per pixel); "
                 f"ω_in points to the laser spot", fontsize=12)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_sampling_figures(scene: Scene, config: SimulationConfig, out_dir: Path) -> list[Path]:
    """Write the paper's sampling views for ``scene`` into ``out_dir``.

    Files: ``fig3_laser_energy.png`` (laser energy at every observed point, Fig. 3) and ``fig5_lookin.png``
    (a lookin on the wall nearest the laser spot and one on the pillar — or on another non-room object when
    there is no pillar — Fig. 5; not written when the scene has neither).

    Args:
        scene: the scene.
        config: sampling settings (lookins, pixels, lookin_pdf, jitter, seed).
        out_dir: created if missing.
    Returns:
        The paths written.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = LookinSampler(scene, config.transport_settings())
    rng = stream_rng(config.seed, STREAM_SAMPLING)
    data = laser_energy(scene, config, t, rng)
    paths = [plot_laser_energy(scene, data, t, out_dir / "fig3_laser_energy.png", rng)]
    look = data.lookins
    chosen = []
    wall = pick_lookin(t, look, ("wall",))
    if wall is not None:
        chosen.append(("a", lookin_energy(t, *wall)))
    other = pick_lookin(t, look, ("pillar",))
    if other is None:
        labels = tuple(sorted({o.label for o in scene.objects} - set(ROOM_LABELS)))
        other = pick_lookin(t, look, labels) if labels else None
    if other is not None:
        chosen.append(("b", lookin_energy(t, *other)))
    if chosen:
        paths.append(plot_lookins(scene, chosen, t, out_dir / "fig5_lookin.png"))
    return paths
