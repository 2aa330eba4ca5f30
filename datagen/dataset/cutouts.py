"""Planar cut-outs of the Stanford LCT release's kind as mesh assets: letters and digits, signs, dot and bar charts
(docs/datasets.md, "The LCT release's kind of set-up"; the release's scenes: docs/real.md).

A cut-out is a binary mask of cells, the filled cells one flat sheet (:func:`datagen.scene.builders.mask_mesh`, the
scene files' ``mask`` builder: each run of filled cells along a row is one rectangle, two triangles). Here the sheet
is written in the asset frame of the shipped glyphs (``assets/meshes/alphanumeric``): the face in the y–z plane at
x = 0, its columns along +y, its rows along +z (upright), so that a room distribution's ``objects.mesh`` class
places it facing the relay wall at yaw 0 and tilts and yaws it as it does any asset (:mod:`datagen.dataset.assets`).
Surfaces are two-sided, so one sheet of zero thickness is the whole object.

* :func:`glyph_mask` rasterises a shipped glyph's face (its triangles facing ±x, projected on y–z);
* :func:`dot_chart_mask`, :func:`bar_chart_mask`, :func:`sign_mask` draw the charts and signs;
* :func:`cutout_mesh` turns a mask into the sheet; :func:`cutout_library` names every cut-out
  ``scripts/make_cutouts.py`` writes to ``assets/meshes/cutouts/``.

Every function is pure (no random draw): the library is the same on every machine, and the room sampler draws which
cut-out, its size, depth, yaw, tilt and material.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..scene.builders import mask_mesh

__all__ = ["CELLS", "SIGNS", "glyph_mask", "dot_chart_mask", "bar_chart_mask", "sign_mask", "cutout_mesh",
           "cutout_library"]

CELLS = 48
"""Cells across a cut-out's longest side: at the largest drawn size (0.7 m) a cell is 1.5 cm, finer than the 64-point
scans' 0.6–1.6 cm pitch and the quadrature's few centimetres, at about 100–300 triangles per cut-out."""

SIGNS = ("exit", "arrow", "octagon", "triangle", "diamond")
"""Sign shapes :func:`sign_mask` draws (the release's exit sign is a square with its text and arrow cut out)."""

_FACE_NORMAL = 0.9
"""|n_x| above which a glyph mesh's triangle is part of its front or back face (the caps of an extrusion along x)."""


def _grid(ny: int, nx: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (ny, nx) in [0, 1]: y from the bottom row up, x from the left column."""
    y, x = np.meshgrid((np.arange(ny) + 0.5) / ny, (np.arange(nx) + 0.5) / nx, indexing="ij")
    return y, x


def glyph_mask(path: str | Path, cells: int = CELLS) -> np.ndarray:
    """The face of a glyph mesh (extruded along x, upright along z) as a (ny, nx) bool mask, row 0 the lowest.

    Args:
        path: a mesh file (e.g. ``assets/meshes/alphanumeric/S.ply``); cells: cells across its longest face side.
    Returns:
        (ny, nx) bool, max(ny, nx) = ``cells``; columns along +y, rows along +z.
    Raises:
        ConfigError: the file cannot be read or has no triangle facing ±x (one line naming it).
    """
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files  # noqa: BLE001
        raise ConfigError(f"glyph {path}: cannot read it: {' '.join(str(exc).split())}") from None
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces, dtype=np.int64)]   # (F, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    caps = tri[keep][np.abs(normal[keep, 0] / length[keep]) > _FACE_NORMAL][..., 1:]          # (C, 3, 2): y, z
    if len(caps) == 0:
        raise ConfigError(f"glyph {path}: no triangle faces +-x (expected a glyph extruded along x)")
    lo, hi = caps.reshape(-1, 2).min(0), caps.reshape(-1, 2).max(0)
    span = float((hi - lo).max())
    ny, nx = (max(1, int(round(cells * (hi[i] - lo[i]) / span))) for i in (1, 0))
    gy, gx = _grid(ny, nx)
    p = np.stack([lo[0] + gx * (hi[0] - lo[0]), lo[1] + gy * (hi[1] - lo[1])], -1).reshape(-1, 2)   # (P, 2)
    a, b, c = caps[:, 0], caps[:, 1], caps[:, 2]

    def side(p0, p1):                                                                           # (P, C)
        return ((p1[:, 0] - p0[:, 0])[None] * (p[:, None, 1] - p0[None, :, 1])
                - (p1[:, 1] - p0[:, 1])[None] * (p[:, None, 0] - p0[None, :, 0]))
    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    return inside.any(axis=1).reshape(ny, nx)


def dot_chart_mask(rows: int = 3, cols: int = 3, dot: float = 0.4, cells: int = CELLS) -> np.ndarray:
    """A chart of ``rows`` × ``cols`` round dots on a square grid (the release's dot chart: 3 × 3 dots 4 cm across,
    10 cm apart, i.e. ``dot`` = 0.4 of the pitch). Returns (ny, nx) bool, max(ny, nx) = ``cells``.

    Raises:
        ConfigError: rows or cols < 1, or dot not in (0, 1].
    """
    if rows < 1 or cols < 1 or not 0 < dot <= 1:
        raise ConfigError(f"dot chart: rows ({rows}) and cols ({cols}) must be >= 1 and dot ({dot}) in (0, 1]")
    pitch = 1.0 / max(rows, cols)
    ny, nx = (max(1, int(round(cells * n * pitch))) for n in (rows, cols))
    gy, gx = _grid(ny, nx)
    fy, fx = gy * rows, gx * cols                                   # in pitches
    dy, dx = fy - np.floor(fy) - 0.5, fx - np.floor(fx) - 0.5
    return dy * dy + dx * dx <= (dot / 2) ** 2


def bar_chart_mask(groups: tuple[int, ...] = (2, 3, 4), cells: int = CELLS) -> np.ndarray:
    """A resolution chart: for each entry k of ``groups`` a square block of k vertical bars beside one of k horizontal
    bars (bars and gaps equally wide, 1/(2k) of the block), the blocks stacked from the coarsest at the bottom.
    Returns (ny, nx) bool, nx = ``cells``.

    Raises:
        ConfigError: no group, or a group with fewer than 1 bar.
    """
    if not groups or min(groups) < 1:
        raise ConfigError(f"bar chart: groups must be bar counts >= 1, got {list(groups)}")
    side = cells // 2
    blocks = []
    for k in groups:
        y, x = _grid(side, side)
        vertical = np.floor(x * 2 * k) % 2 == 0
        horizontal = np.floor(y * 2 * k) % 2 == 0
        blocks.append(np.concatenate([vertical, horizontal], axis=1))
    return np.concatenate(blocks, axis=0)


def sign_mask(kind: str, cells: int = CELLS) -> np.ndarray:
    """A sign of one of :data:`SIGNS`: ``exit`` a square with "EXIT" and an arrow cut out (as the release's exit sign,
    whose text and arrow are not retroreflective), ``arrow`` a right arrow, ``octagon``, ``triangle`` (point up),
    ``diamond``. Returns (cells, cells) bool.

    Raises:
        ConfigError: an unknown kind (naming it and the kinds).
    """
    y, x = _grid(cells, cells)
    u, v = x - 0.5, y - 0.5
    if kind == "exit":
        out = np.ones((cells, cells), dtype=bool)
        text = (v > 0.05) & (v < 0.35) & (np.abs(u) < 0.4) & (np.floor((u + 0.4) / 0.1) % 2 == 0)   # 4 letters
        shaft = (np.abs(v + 0.22) < 0.05) & (u > -0.35) & (u < 0.15)
        head = (u >= 0.15) & (u < 0.35) & (np.abs(v + 0.22) < 0.15 * (0.35 - u) / 0.2)
        return out & ~(text | shaft | head)
    if kind == "arrow":
        shaft = (np.abs(v) < 0.12) & (u > -0.45) & (u < 0.1)
        head = (u >= 0.1) & (u < 0.45) & (np.abs(v) < 0.4 * (0.45 - u) / 0.35)
        return shaft | head
    if kind == "octagon":
        a = np.abs(u) + np.abs(v)
        return (np.abs(u) < 0.48) & (np.abs(v) < 0.48) & (a < 0.48 * (1 + 1 / np.sqrt(2)) * 0.85)
    if kind == "triangle":
        return (v > -0.45) & (np.abs(u) < (0.45 - v) / 0.9 * 0.5)
    if kind == "diamond":
        return np.abs(u) + np.abs(v) < 0.48
    raise ConfigError(f"sign: unknown kind {kind!r} (kinds: {', '.join(SIGNS)})")


def cutout_mesh(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The filled cells of ``mask`` ((ny, nx) bool, row 0 the lowest) as one planar sheet in the glyphs' asset frame:
    x = 0, columns along +y, rows along +z, the mask's centre at the origin, cells of side 1 / max(ny, nx).

    Returns:
        (vertices (V, 3) float64, faces (F, 3) int64), the faces' normal +x (towards a relay wall at yaw 0).
    Raises:
        SceneError: an empty mask or one that is not 2-D (:func:`~datagen.scene.builders.mask_mesh`).
    """
    m = np.asarray(mask)
    return mask_mesh(m, 1.0 / max(m.shape) if m.ndim == 2 and m.size else 1.0, (0.0, 0.0, 0.0),
                     u=(0.0, 1.0, 0.0), v=(0.0, 0.0, 1.0))


def cutout_library(glyph_folder: str | Path) -> dict[str, np.ndarray]:
    """Every cut-out ``scripts/make_cutouts.py`` writes, name → (ny, nx) bool mask: the 36 shipped glyphs
    (``glyph_<c>``), the :data:`SIGNS` (``sign_<kind>``), dot charts of 2 × 2, 3 × 3 and 4 × 4 dots at 0.3 and 0.5
    of their pitch (``dots_<n>x<n>_<pct>``) and bar charts of 1–3 groups (``bars_<counts>``).

    Raises:
        ConfigError: a glyph file that cannot be read.
    """
    out = {f"glyph_{p.stem}": glyph_mask(p) for p in sorted(Path(glyph_folder).glob("*.ply"))}
    out.update({f"sign_{k}": sign_mask(k) for k in SIGNS})
    for n in (2, 3, 4):
        for dot in (0.3, 0.5):
            out[f"dots_{n}x{n}_{int(dot * 100)}"] = dot_chart_mask(n, n, dot)
    for groups in ((2,), (2, 3), (2, 3, 4)):
        out["bars_" + "".join(map(str, groups))] = bar_chart_mask(groups)
    return out
