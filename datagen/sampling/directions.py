"""Directions and grids on the unit square and the hemisphere (the sampling stage's building blocks).

- :func:`stratified_grid`: jittered (or centred) n_u×n_v grids on [0, 1]².
- :func:`square_to_hemisphere`: the concentric (Shirley–Chiu 1997) disk map lifted to the hemisphere,
  *cosine-weighted* (Malley's method, pdf cos θ/π) or *uniform* (equal-area lift z = 1 − r², pdf 1/(2π)).
- :func:`to_world`: local directions (z along the normal) into world space.
"""
from __future__ import annotations

import functools

from typing import Literal

import numpy as np

from ..scene.materials import tangent_frame

HemispherePdf = Literal["cosine", "uniform"]


def concentric_disk(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley & Chiu (1997) concentric map of [0,1]² to the unit disk, area-preserving up to a factor π.

    Returns (r, φ) arrays of u's shape.
    """
    a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
    use_a = np.abs(a) > np.abs(b)
    r = np.where(use_a, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(use_a, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r, phi   # r may be negative; (r, φ) and (−r, φ+π) are the same point


def square_to_hemisphere(u: np.ndarray, v: np.ndarray, pdf: HemispherePdf, dtype=np.float64
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Map points of the unit square to local hemisphere directions (z up).

    Args:
        u, v: arrays in [0, 1].
        pdf: "cosine" (Malley: z = √(1−r²), p = cos θ/π) or "uniform" (z = 1−r², p = 1/(2π)).
        dtype: float64, or float32 (half the memory traffic; directions good to ~1e-7, Embree's precision).
    Returns:
        directions (..., 3) unit vectors with z ≥ 0, and their pdf (...,) in 1/sr, both of ``dtype``.
    """
    r, phi = concentric_disk(np.asarray(u, dtype=dtype), np.asarray(v, dtype=dtype))
    r2 = r * r
    if pdf == "cosine":
        z = np.sqrt(np.maximum(0.0, 1.0 - r2))
        s = r
        density = z / np.pi
    elif pdf == "uniform":
        z = 1.0 - r2
        s = r * np.sqrt(np.maximum(0.0, 2.0 - r2))
        density = np.full_like(z, 1.0 / (2.0 * np.pi))
    else:
        raise ValueError(f"unknown hemisphere pdf {pdf!r}; use 'cosine' or 'uniform'")
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1), density


def stratified_grid(n_u: int, n_v: int, rng: np.random.Generator | None, count: int = 1) -> np.ndarray:
    """Points of an n_u×n_v stratified grid on [0,1]², row-major over (u, v).

    Args:
        rng: jitter each point uniformly in its cell; None puts it at the cell centre.
        count: independent grids to draw (leading axis).
    Returns:
        (count, n_u·n_v, 2) float64.
    """
    cells = _grid_cells(n_u, n_v)
    offset = rng.random((count,) + cells.shape) if rng is not None else np.full((count,) + cells.shape, 0.5)
    offset += cells
    offset /= np.array([n_u, n_v], dtype=np.float64)
    return offset


@functools.lru_cache(maxsize=16)
def _grid_cells(n_u: int, n_v: int) -> np.ndarray:
    """(n_u·n_v, 2) float64 cell corners (i, j) of an n_u×n_v grid, row-major over (u, v) (read-only)."""
    iu, iv = np.meshgrid(np.arange(n_u), np.arange(n_v), indexing="ij")
    cells = np.stack([iu.ravel(), iv.ravel()], axis=-1).astype(np.float64)
    cells.flags.writeable = False
    return cells


def to_world(local: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Rotate local directions (z along the normal) into world space. (..., 3) with normals (..., 3)."""
    t, b = tangent_frame(normals)
    return local[..., :1] * t + local[..., 1:2] * b + local[..., 2:3] * normals


