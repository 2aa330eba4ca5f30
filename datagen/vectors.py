"""Small vector helpers shared by every stage (utilities layer: imports nothing from datagen).

All functions work on the last axis of float arrays: ``(..., 3)`` → ``(...,)`` or ``(..., 3)``, except
:func:`matmul` and :func:`norm`.

Products and norms here never call BLAS: numpy's ``@``, ``dot`` and ``linalg.norm`` (without an axis) do, and
OpenBLAS picks its kernels by CPU model, each summing in its own order, so their last bits (and with them a
scene's vertices, an envelope's and a stored error estimate's) would depend on the machine. numpy's own loops
(``einsum``, ``sum``) sum in one order on every CPU (tests/test_reproducibility.py).
"""
from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product over the last axis: (..., k), (..., k) → (...,) (broadcasting)."""
    return np.einsum("...k,...k->...", a, b)


def matmul(a, b) -> np.ndarray:
    """``a @ b`` (numpy's rules: a 1-D operand is a vector, more dimensions are stacks of matrices that broadcast)
    without BLAS (module doc): (n,)·(n,) → (), (..., m, n)·(n,) → (..., m), (n,)·(..., n, k) → (..., k),
    (..., m, n)·(..., n, k) → (..., m, k)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.ndim == 1:
        return np.einsum("j,j->" if b.ndim == 1 else "j,...jk->...k", a, b)
    return np.einsum("...j,j->..." if b.ndim == 1 else "...ij,...jk->...ik", a, b)


def norm(v) -> float:
    """Euclidean norm of all of ``v``'s entries, as ``numpy.linalg.norm(v)`` without an axis but without BLAS
    (module doc)."""
    v = np.asarray(v, dtype=np.float64)
    return float(np.sqrt(np.sum(v * v)))


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
