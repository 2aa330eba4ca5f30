"""Counting-mode detectors (no TDC): recorded rate, variance and event simulation of a counter with
paralyzable or non-paralyzable dead time."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .arrays import check_event_count

__all__ = [
    "counter_rate",
    "counter_variance",
    "sample_counter",
]


def counter_rate(true_rate: Any, dead_time: float, paralyzable: bool = False) -> np.ndarray:
    """Mean recorded rate of a counter with dead time τ for Poisson input rate n (Hz).

    Non-paralyzable ``m = n/(1 + nτ)``; paralyzable ``m = n·e^{−nτ}`` (maximum ``1/(eτ)`` at ``nτ = 1``).
    Source: docs/physics.md §6; G. F. Knoll, *Radiation Detection and Measurement*, ch. 4.

    Args:
        true_rate: array-like of input rates in Hz (≥ 0); dead_time: s (≥ 0).
    Returns:
        float64 array, same shape, in Hz.
    Raises:
        ValueError: negative/NaN rate or negative dead time.
    """
    n = _as_counter_rate(true_rate, dead_time)
    if paralyzable:
        return n * np.exp(-n * dead_time)
    return n / (1.0 + n * dead_time)


def counter_variance(true_rate: Any, dead_time: float, window: float, paralyzable: bool = False) -> np.ndarray:
    """Asymptotic (window ≫ τ) variance of the number of counts recorded in ``window`` seconds.

    Renewal theory (Var N ≈ window·σ²/μ³ of the inter-count interval; Müller 1973): non-paralyzable
    ``n·window/(1 + nτ)³``; paralyzable ``m·window·(1 − 2nτ e^{−nτ})`` with ``m = n e^{−nτ}``.

    Args:
        true_rate: Poisson input rate n in Hz (array-like); dead_time τ and window in s.
    Returns:
        float64 array (counts²), same shape as ``true_rate``.
    Raises:
        ValueError: negative/NaN rate or negative dead time.
    """
    n = _as_counter_rate(true_rate, dead_time)
    if paralyzable:
        m = n * np.exp(-n * dead_time)
        return m * window * (1.0 - 2.0 * n * dead_time * np.exp(-n * dead_time))
    return n * window / (1.0 + n * dead_time) ** 3


def _as_counter_rate(true_rate: Any, dead_time: float) -> np.ndarray:
    n = np.asarray(true_rate, dtype=np.float64)
    if not np.all(np.isfinite(n)) or np.any(n < 0):
        raise ValueError(f"true_rate must be finite and >= 0, got {true_rate!r}")
    if not dead_time >= 0:
        raise ValueError(f"dead_time must be >= 0, got {dead_time!r}")
    return n


def sample_counter(true_rate: float, dead_time: float, window: float, rng: np.random.Generator,
                   size: int = 1, paralyzable: bool = False) -> np.ndarray:
    """Event-simulate the counts of a dead-time counter started live at t = 0 over ``window`` seconds.

    Non-paralyzable: renewal process with intervals ``Exp(n)`` (first) then ``τ + Exp(n)``.  Paralyzable:
    Poisson arrivals, an arrival is counted iff the previous arrival is ≥ τ earlier (the first always is).

    Args:
        true_rate: Poisson input rate n in Hz; dead_time τ, window in s; rng: numpy Generator; size: number of
            independent windows.
    Returns:
        int64 (size,) counts.
    Raises:
        ValueError: negative/NaN rate or negative dead time; a window or rate that is not finite; more expected
            arrivals than MAX_SIMULATED_EVENTS (:func:`datagen.spad.arrays.check_event_count`).
    """
    _as_counter_rate(true_rate, dead_time)
    n_rate = float(true_rate)
    out = np.zeros(size, dtype=np.int64)
    if n_rate == 0:
        return out
    if not (math.isfinite(window) and window >= 0 and math.isfinite(n_rate)):
        raise ValueError(f"window must be finite and >= 0 and true_rate finite, got {window!r} s, {n_rate!r} Hz")
    # Inter-arrival gaps of the Poisson input are iid Exp(n).  Non-paralyzable: a renewal process with
    # intervals τ + gap (the first without τ).  Paralyzable: an arrival is counted iff its gap ≥ τ.
    shift = 0.0 if paralyzable else dead_time
    mean_gap = shift + 1.0 / n_rate
    check_event_count(size * window / mean_gap, "sample_counter")
    per = int(window / mean_gap * 1.1 + 10 * math.sqrt(window / mean_gap) + 20)
    rows = max(1, int(4e6 // per))
    for start in range(0, size, rows):
        m = min(rows, size - start)
        gaps = rng.standard_exponential((m, per)) / n_rate
        t = np.cumsum(gaps + shift, axis=1) - shift
        while np.any(t[:, -1] <= window):  # extend the rare rows that did not reach the window end
            more = rng.standard_exponential((m, per)) / n_rate
            t = np.concatenate([t, t[:, -1:] + np.cumsum(more + shift, axis=1)], axis=1)
            gaps = np.concatenate([gaps, more], axis=1)
        inside = t <= window
        if paralyzable:
            counted = gaps >= dead_time
            counted[:, 0] = True
            inside &= counted
        out[start:start + m] = inside.sum(axis=1)
    return out
