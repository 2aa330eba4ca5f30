"""Pile-up correction: the Coates (1968) estimator inverting the synchronous first-photon model."""
from __future__ import annotations

from typing import Any

import numpy as np

from .arrays import exclusive_cumsum

__all__ = [
    "coates",
]


def _check_cycles(n_cycles: Any) -> int:
    n = int(n_cycles)
    if n != n_cycles or n < 1:
        raise ValueError(f"n_cycles must be a positive integer, got {n_cycles!r}")
    return n


def coates(counts: Any, n_cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Coates (1968) pile-up correction: ``r̂_i = −log1p(−N_i/D_i)``, ``D_i = n − Σ_{j<i} N_j``.

    It is the maximum-likelihood inverse of the synchronous first-photon model and inverts exact expected
    counts exactly (to rounding).  At large N it is unbiased with delta-method variance
    ``Var r̂_i ≈ p_i / (E[D_i](1 − p_i))``, ``p_i = 1 − e^{−r_i}``.

    Args:
        counts: (..., bins) int or float counts (expected counts allowed), ≥ 0, with ``Σ counts ≤ n_cycles``.
        n_cycles: number of laser cycles (positive int).
    Returns:
        ``(rate_estimate, valid)``: float64 (..., bins) and bool (..., bins).  Bins with ``D_i = 0`` (no
        surviving cycles: no information) or ``N_i = D_i`` (saturated: the MLE is +inf) are flagged
        ``valid = False`` and their estimate is set to the sentinel **0.0** (never NaN or inf).
    Raises:
        ValueError: NaN/inf or negative counts, or a pixel with more counts than cycles.
    """
    n = _check_cycles(n_cycles)
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim == 0 or c.shape[-1] == 0:
        raise ValueError(f"counts must have shape (..., bins) with bins >= 1, got {c.shape}")
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError("counts must be finite and >= 0")
    prior, total = exclusive_cumsum(c)
    if np.any(total > n * (1 + 1e-12)):
        raise ValueError(f"a pixel has {float(total.max())!r} counts, more than n_cycles={n}")
    remaining = np.maximum(n - prior, 0.0)
    valid = (remaining > 0) & (c < remaining)
    ratio = np.divide(c, remaining, out=np.zeros_like(c), where=valid)
    est = np.where(valid, -np.log1p(-ratio), 0.0)
    return est, valid
