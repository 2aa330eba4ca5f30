"""Array conventions shared by the detector models: validation of ``(..., bins)`` rate arrays, compensated
cumulative sums and a row-wise binary search (see :mod:`datagen.spad` for the notation)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "MAX_SIMULATED_EVENTS",
    "check_event_count",
    "as_rates",
    "exclusive_cumsum",
    "row_search",
]


def as_rates(rates: Any, name: str = "rates") -> np.ndarray:
    """float64 copy-if-needed of ``rates`` (..., bins); ValueError for NaN/inf/negative/0-d/empty.

    The input convention of every function of the package that takes rates (see :mod:`datagen.spad`).

    Args:
        rates: (..., bins) expected avalanches per laser cycle per bin, any real dtype (float32 is converted).
        name: argument name used in the error messages.
    Returns:
        float64 (..., bins); the input itself when it already is a float64 array.
    Raises:
        ValueError: 0-d input or an empty last axis, NaN/inf, or a negative value (the message gives its index).
    """
    r = np.asarray(rates, dtype=np.float64)
    if r.ndim == 0 or r.shape[-1] == 0:
        raise ValueError(f"{name} must have shape (..., bins) with bins >= 1, got shape {r.shape}")
    if not np.all(np.isfinite(r)):
        bad = np.argwhere(~np.isfinite(r))[0]
        raise ValueError(f"{name} contains a non-finite value {float(r[tuple(bad)])!r} at index {tuple(int(b) for b in bad)}")
    if np.any(r < 0):
        bad = np.argwhere(r < 0)[0]
        raise ValueError(f"{name} must be >= 0; found {r[tuple(bad)]!r} at index {tuple(int(b) for b in bad)}")
    return r


MAX_SIMULATED_EVENTS = 2e8
"""Most avalanches an event simulation (free-running dead time, crosstalk, counters) may draw one by one: about
a minute at the ~3e6 avalanches/s measured for the batched free-running simulator (far slower with afterpulsing,
see :func:`check_event_count`). Longer exposures are refused before any work, naming the count; their mean is
:func:`datagen.spad.expected_histogram` (exact, cost independent of the exposure)."""


def check_event_count(expected: float, what: str, per_step: float | None = None) -> None:
    """Refuse an event simulation expected to draw more than :data:`MAX_SIMULATED_EVENTS` avalanches in all, or
    (``per_step``, for simulators that advance one avalanche per pixel per Python step, e.g. afterpulsing) more
    than MAX_SIMULATED_EVENTS / 100 steps.

    Args:
        expected: expected avalanches over the exposure, all pixels (n_cycles × avalanches per cycle).
        what: the model, for the message (e.g. "free_running event simulation").
        per_step: expected avalanches of the busiest pixel (sequential steps), or None.
    Raises:
        ValueError: naming the model, the expected count and the bound.
    """
    steps_bound = MAX_SIMULATED_EVENTS / 100
    if not expected <= MAX_SIMULATED_EVENTS or (per_step is not None and not per_step <= steps_bound):
        count = expected if not expected <= MAX_SIMULATED_EVENTS else per_step
        bound = MAX_SIMULATED_EVENTS if not expected <= MAX_SIMULATED_EVENTS else steps_bound
        raise ValueError(f"{what}: the exposure holds ~{count:.3g} expected avalanches to simulate one by one, more "
                         f"than {bound:.3g} (MAX_SIMULATED_EVENTS; minutes of work): shorten the exposure "
                         "(n_cycles or exposure), or use expected_histogram for the mean histogram")


def _accurate_cumsum(x: np.ndarray) -> np.ndarray:
    """Inclusive float64 cumulative sum along the last axis, compensated: the exact rounding error of every
    step of ``np.cumsum`` is recovered with Knuth's TwoSum and added back, so each prefix sum is accurate to a
    few ulps even over 10^6 bins (a plain cumsum drifts by ~n·ε and breaks Σ pmf = 1 at 1e-12)."""
    with np.errstate(invalid="ignore", over="ignore"):
        s = np.cumsum(x, axis=-1)
        prev = np.zeros_like(s)
        prev[..., 1:] = s[..., :-1]
        bp = s - prev
        err = (prev - (s - bp)) + (x - bp)
        if not np.isfinite(s[..., -1:]).all():   # overflow to inf (sums near 1.8e308): inf stays inf, and the
            err[~np.isfinite(err)] = 0.0           # inf − inf of the error terms must not turn later sums into NaN
        return s + np.cumsum(err, axis=-1)


def exclusive_cumsum(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, Λ): exclusive float64 (compensated) cumulative sum along the last axis and the total.

    Args:
        r: float64 (..., bins), e.g. rates (avalanches per cycle per bin) or counts.
    Returns:
        ``(C, Λ)``: float64 (..., bins) with ``C[..., 0] = 0`` and ``C[..., i] = Σ_{j<i} r[..., j]``, and float64
        (...,) ``Λ = Σ_j r[..., j]``; same units as ``r``, each prefix sum accurate to a few ulps.
    """
    total = _accurate_cumsum(r)
    c = np.empty_like(r)
    c[..., 0] = 0.0
    c[..., 1:] = total[..., :-1]
    return c, total[..., -1]


def row_search(cum: np.ndarray, rows: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Vectorised binary search: for each k find b with cum[rows[k], b] < target[k] <= cum[rows[k], b+1].
    ``cum`` is (pixels, cells + 1), nondecreasing along the last axis with cum[:, 0] = 0 < target.

    Args:
        cum: float64 (pixels, cells + 1) cumulative intensity (expected avalanches) at the cell edges.
        rows: int64 (k,) pixel (row of ``cum``) of each query.
        target: float64 (k,) cumulative intensity to locate, in ``(0, cum[rows, -1]]``.
    Returns:
        int64 (k,) cell index b in ``[0, cells − 1]``.
    """
    lo = np.zeros(rows.size, dtype=np.int64)
    hi = np.full(rows.size, cum.shape[1] - 1, dtype=np.int64)
    for _ in range(int(math.ceil(math.log2(max(cum.shape[1], 2)))) + 1):
        mid = (lo + hi) // 2
        right = cum[rows, mid] < target
        lo = np.where(right, mid, lo)
        hi = np.where(right, hi, mid)
    return lo
