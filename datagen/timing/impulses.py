"""Input checks of path impulses and the exact per-impulse binning reference :func:`bin_impulses`
(docs/physics.md §5), used by :class:`datagen.timing.accumulator.EnvelopeAccumulator`."""
from __future__ import annotations

from typing import Any

import numpy as np

from .irf import Irf, TimeAxis
from ..vectors import matmul

__all__ = ["as_real_array", "bin_impulses", "check_finite", "check_weights", "times_weights"]

_REFERENCE_BLOCK = 1 << 21
"""Elements (impulses x edges) evaluated at once by bin_impulses."""


def as_real_array(values: Any, name: str) -> np.ndarray:
    """Flattened view of numeric ``values``, kept in its dtype (callers convert to float64 per chunk)."""
    arr = np.asarray(values)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be real numbers, got dtype {arr.dtype}") from exc
    return arr.reshape(-1)


def check_finite(arr: np.ndarray, name: str, offset: int = 0) -> None:
    """Raise ValueError naming ``name``, the count and the first index (+ ``offset``) of NaN/inf in ``arr``."""
    bad = ~np.isfinite(arr)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{name} contain {int(bad.sum())} non-finite value(s) (NaN or inf); "
            f"first at index {offset + first}: {arr[first]!r}"
        )


def check_weights(arr: np.ndarray, offset: int = 0) -> None:
    """Raise ValueError for non-finite or negative weights (photons per pulse), naming the first index."""
    check_finite(arr, "weights", offset)
    neg = arr < 0
    if neg.any():
        first = int(np.flatnonzero(neg)[0])
        raise ValueError(
            f"weights must be >= 0 (expected photons); {int(neg.sum())} negative, "
            f"first at index {offset + first}: {arr[first]!r}"
        )


def times_weights(times: Any, weights: Any) -> tuple[np.ndarray, np.ndarray]:
    """Flattened (times, weights) of one length (a scalar weight is broadcast). Raises ValueError: lengths differ
    or values are not real numbers."""
    t = as_real_array(times, "times")
    w = as_real_array(weights, "weights")
    if w.size == 1 and t.size != 1:
        w = np.broadcast_to(w, t.shape)
    if w.shape != t.shape:
        raise ValueError(f"times and weights must have the same length, got {t.size} and {w.size}")
    return t, w


def bin_impulses(times: Any, weights: Any, axis: TimeAxis, irf: Irf) -> np.ndarray:
    """Exact binned envelope of one component: ``out_b = sum_i w_i * P(e_b - tau_i <= X < e_{b+1} - tau_i)``.

    The reference for :class:`EnvelopeAccumulator` (docs/physics.md §5: bins are integrals; for a Gaussian each
    term is a difference of normal CDFs, evaluated stably by :meth:`Irf.interval_mass`). Cost O(n * n_bins):
    meant for small inputs, tests and quadrature.

    Args:
        times: impulse arrival times, seconds, any shape (flattened), float64-convertible.
        weights: expected detected photons per pulse, same shape as ``times`` (or a scalar), >= 0.
        axis: output time axis.
        irf: instrument response.

    Returns:
        (axis.n_bins,) float64, photons per pulse in each bin.

    Raises:
        ValueError: non-finite times or weights, negative weights, mismatched lengths (the message names
            which input).
    """
    t, w = times_weights(times, weights)
    t, w = t.astype(np.float64), w.astype(np.float64)
    check_finite(t, "times")
    check_weights(w)
    keep = w != 0
    t, w = t[keep], w[keep]
    edges = axis.edges
    out = np.zeros(axis.n_bins, dtype=np.float64)
    block = max(1, _REFERENCE_BLOCK // edges.size)
    for start in range(0, t.size, block):
        tb, wb = t[start : start + block], w[start : start + block]
        x = edges[None, :] - tb[:, None]
        mass = irf.interval_mass(x[:, :-1], x[:, 1:])
        out += matmul(wb, mass)
    return out
