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
