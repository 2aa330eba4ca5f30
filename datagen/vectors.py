"""Small vector helpers shared by every stage (utilities layer: imports nothing from datagen).

All functions work on the last axis of float arrays: ``(..., 3)`` → ``(...,)`` or ``(..., 3)``.
"""
from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product over the last axis: (..., k), (..., k) → (...,) (broadcasting)."""
    return np.einsum("...k,...k->...", a, b)


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` divided by its Euclidean norm over the last axis: (..., k) → (..., k). Zero rows give NaN."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def distinct_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct (D, k), index (V,) int64) of points (V, k) float64: each row once, in lexicographic order, and
    points = distinct[index] (rows compared with ==, so −0.0 and 0.0 are one; ``numpy.unique(axis=0)``'s result by a
    lexsort, several times faster)."""
    order = np.lexsort(points.T[::-1])
    ranked = points[order]
    new = np.ones(len(points), dtype=bool)
    new[1:] = (ranked[1:] != ranked[:-1]).any(axis=1)
    index = np.empty(len(points), dtype=np.int64)
    index[order] = np.cumsum(new) - 1
    return ranked[new], index
