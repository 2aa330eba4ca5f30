"""The second round trip of a confocal scan of a retroreflector: one measurement, applied alike to a real capture and
to its simulation (docs/real.md, "The second round trip").

A retroreflective hidden object sends the light of the scanned point x_l back to the wall next to x_l; the wall
scatters it again, the object returns part of that to x_l once more: a path laser spot → object → wall → object →
FoV point of order 3 (docs/physics.md §2, "Orders"), arriving at the sum of two round trips of the main return. For a
small patch facing a Lambertian wall of albedo ρ_w it carries ρ_w · F · ρ_r of the main return's light (F the form
factor from x_l to the patch, ρ_r the share of the light the patch returns, when each returned cone lands inside the
detector's spot on the wall; tests/test_second_round_trip.py checks datagen's tracer against it). Scan-summed, it is
a small, broad bump at about twice the main return's round trip on the main return's own slow tail (the SPAD's
diffusion tail, docs/detector.md), which is as large as the bump itself on the Stanford release's 40 cm dot chart:
how that tail is taken out sets the figure.

**The measurement** (:func:`second_round_trip`), on the scan-summed transient:

1. *Main return.* The transient smoothed over :data:`SMOOTHING` (a moving average) after ``hidden_from`` (the
   direct light of a real capture lies before it); its peak above the floor (the mean of the record's last
   :data:`FLOOR_TIME`), and its extent [t_on, t_end]: the bins about the peak where it stays above :data:`MAIN_LEVEL`
   of the peak.
2. *Echo window* [2 t_on, 2 t_end]: a second round trip is the sum of two round trips of the main return.
3. *Baseline*: the main return's tail and the floor, c + a·exp(−(t − 2 t_on)/τ), fitted by least squares to the
   unsmoothed transient over :data:`SIDE` on each side of the window (τ on a log grid, :data:`TAU_GRID`; c and a
   linear), and read under the window.
4. *Size*: the counts above the baseline in the window over the main return's counts above the floor from t_on to
   the window's start. *Time*: the echo's median arrival, when half of those counts have arrived (linear
   interpolation of their running sum). Both are linear in the counts, so counting noise does not bias them (a
   peak read off a noisy bump does: ``peak_size`` and ``peak_time``, the largest value of the bump smoothed over
   :data:`SMOOTHING`, are kept to compare with figures read that way).

With ``draws`` > 0 the measurement is repeated on Poisson redraws of the scan-summed counts (each bin's count the
mean of its draw): the spread of size and time is their counting noise (``size_sd``, ``time_sd``; meaningful for
counts, not for an expected envelope).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SecondRoundTrip", "second_round_trip", "SMOOTHING", "MAIN_LEVEL", "SIDE", "MIN_SIDE", "FLOOR_TIME",
           "HIDDEN_FROM", "TAU_GRID"]

SMOOTHING = 40e-12
"""s: the moving average the main return's peak and extent (and ``peak_size``) are read from (ten 4 ps bins)."""

MAIN_LEVEL = 0.1
"""The main return's extent: where its smoothed transient stays above 10 % of its peak (above the floor) about the
peak; twice its ends bound the echo window."""

SIDE = 1e-9
"""s: the baseline is fitted over 1 ns before the echo window and up to 1 ns after it (the record's end may cut
the second side)."""

MIN_SIDE = 0.25e-9
"""s: the least record after the echo window that the baseline needs; with less the echo is not measured."""

FLOOR_TIME = 0.6e-9
"""s: the floor is the mean of the record's last 0.6 ns (the Stanford release's floor bins 1900–2047 of 4 ps)."""

HIDDEN_FROM = 2.4e-9
"""s: the main return is looked for after this time (the Stanford release's script zeroes its first 600 bins of
4 ps, the direct light)."""

TAU_GRID = np.geomspace(20e-12, 50e-9, 240)
"""s: decay times tried for the baseline's exponential (a straight line is its long-τ limit)."""


@dataclass(frozen=True)
class SecondRoundTrip:
    """The second round trip of a scan-summed transient (module docstring).

    Attributes:
        size: the echo's counts above the baseline over the main return's counts above the floor (dimensionless).
        time: the echo's median arrival, s (on the input's time axis).
        main_time: the main return's peak, s; main_counts, echo_counts: the two sums of ``size`` (input units).
        window: (start, stop) of the echo window, s; floor: the floor (input units per bin).
        baseline: (c, a, τ): the fitted c + a·exp(−(t − window start)/τ), τ in s.
        peak_size, peak_time: the largest value of the bump smoothed over :data:`SMOOTHING` over the main return's
            smoothed peak, and its time (s); counting noise biases this size upwards.
        baseline_chi2: for counts, the baseline's mean (y − b)²/b over the bins it was fitted to: about 1 when one
            exponential and the floor describe the main return's tail within counting noise (the Stanford 40 cm
            chart: 1.06); well above 1, the tail needs another term and the size is biased.
        size_sd, time_sd: the spread of size and time over Poisson redraws (NaN without ``draws``).
    """

    size: float
    time: float
    main_time: float
    main_counts: float
    echo_counts: float
    window: tuple[float, float]
    floor: float
    baseline: tuple[float, float, float]
    peak_size: float
    peak_time: float
    baseline_chi2: float
    size_sd: float = float("nan")
    time_sd: float = float("nan")


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Moving average of ``width`` bins (same length; edges averaged over what they have)."""
    if width <= 1:
        return x
    c = np.concatenate([[0.0], np.cumsum(x)])
    n = len(x)
    lo = np.clip(np.arange(n) - width // 2, 0, n)
    hi = np.clip(np.arange(n) - width // 2 + width, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)


def _baseline(t: np.ndarray, y: np.ndarray, t0: float) -> tuple[float, float, float]:
    """(c, a, τ) of the least-squares c + a·exp(−(t − t0)/τ) through (t, y), τ the best of :data:`TAU_GRID`."""
    best = (np.inf, 0.0, 0.0, float(TAU_GRID[-1]))
    for tau in TAU_GRID:
        design = np.column_stack([np.ones_like(t), np.exp(-(t - t0) / tau)])
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        res = float(np.sum((design @ coef - y) ** 2))
        if res < best[0]:
            best = (res, float(coef[0]), float(coef[1]), float(tau))
    return best[1], best[2], best[3]


def _measure(s: np.ndarray, edges: np.ndarray, hidden_from: float) -> SecondRoundTrip:
    """The measurement of one scan-summed transient ``s`` (K,) on bins ``edges`` (K+1,) s."""
    dt = float(edges[1] - edges[0])
    t = 0.5 * (edges[:-1] + edges[1:])
    n = len(s)
    floor = float(s[t >= t[-1] - FLOOR_TIME].mean())
    sm = _smooth(s, max(1, int(round(SMOOTHING / dt))))
    first = int(np.searchsorted(t, hidden_from))
    if first >= n - 1:
        raise ValueError(f"no record after hidden_from = {hidden_from:.3g} s (the record ends at {edges[-1]:.3g} s)")
    i = first + int(np.argmax(sm[first:]))
    peak = float(sm[i] - floor)
    if not peak > 0:
        raise ValueError("no main return above the floor")
    above = sm - floor >= MAIN_LEVEL * peak
    on, end = i, i
    while on > first and above[on - 1]:
        on -= 1
    while end < n - 1 and above[end + 1]:
        end += 1
    # the window in time, then in bins (a round trip twice as long: twice the time from zero round trip)
    lo = int(np.searchsorted(edges, 2 * t[on], side="right")) - 1
    hi = int(np.searchsorted(edges, 2 * t[end], side="right"))
    side, least = int(round(SIDE / dt)), int(np.ceil(MIN_SIDE / dt))
    if hi + least > n:
        raise ValueError(f"the echo window {2 * t[on]:.3g}–{2 * t[end]:.3g} s leaves less than {MIN_SIDE:.2g} s of "
                         f"the record (it ends at {edges[-1]:.3g} s) to fit the baseline after it")
    fit = np.r_[max(lo - side, end + 1):lo, hi:min(hi + side, n)]
    c, a, tau = _baseline(t[fit], s[fit], t[lo])
    chi2 = float(np.mean((s[fit] - c - a * np.exp(-(t[fit] - t[lo]) / tau)) ** 2 / np.maximum(s[fit], 1.0)))
    w = np.arange(lo, hi)
    base = c + a * np.exp(-(t[w] - t[lo]) / tau)
    bump = s[w] - base
    echo = float(bump.sum())
    main = float(np.sum(s[on:lo] - floor))
    run = np.cumsum(bump)
    k = int(np.argmax(run >= 0.5 * echo)) if echo > 0 else 0
    before = run[k - 1] if k > 0 else 0.0
    frac = (0.5 * echo - before) / (run[k] - before) if run[k] != before else 0.5
    j = int(np.argmax(sm[w] - base))
    return SecondRoundTrip(size=echo / main, time=float(edges[lo + k] + np.clip(frac, 0.0, 1.0) * dt),
                           main_time=float(t[i]), main_counts=main, echo_counts=echo,
                           window=(float(edges[lo]), float(edges[hi])), floor=floor, baseline=(c, a, tau),
                           peak_size=float((sm[lo + j] - base[j]) / peak), peak_time=float(t[lo + j]),
                           baseline_chi2=chi2)


def second_round_trip(data: np.ndarray, time_edges: np.ndarray, *, hidden_from: float = HIDDEN_FROM,
                      draws: int = 0, rng: np.random.Generator | None = None) -> SecondRoundTrip:
    """The second round trip of a confocal scan (module docstring): its size relative to the main return and its
    median arrival time, with the main return's tail taken out by a baseline fitted on both sides.

    Args:
        data: (..., K) counts or expected counts, the last axis time (summed over every other axis).
        time_edges: (K+1,) s, uniform bins; time zero where the round trip from the scanned point is zero (an
            imported capture's and ``simulate --like``'s axis).
        hidden_from: s, the main return is looked for after it (:data:`HIDDEN_FROM`).
        draws: Poisson redraws of the scan-summed counts for ``size_sd`` and ``time_sd`` (0: none); rng: their
            generator (required with ``draws``).
    Returns:
        :class:`SecondRoundTrip`.
    Raises:
        ValueError: bins not uniform or not matching ``data``; no main return; an echo window too close to the
            record's end to fit the baseline after it; ``draws`` without ``rng``.
    """
    s = np.asarray(data, dtype=np.float64)
    s = s.reshape(-1, s.shape[-1]).sum(axis=0)
    edges = np.asarray(time_edges, dtype=np.float64)
    if edges.shape != (len(s) + 1,):
        raise ValueError(f"time_edges has shape {edges.shape}, the data {len(s)} bins")
    widths = np.diff(edges)
    if not np.allclose(widths, widths[0], rtol=1e-6):
        raise ValueError("the bins must be uniform")
    out = _measure(s, edges, hidden_from)
    if draws:
        if rng is None:
            raise ValueError("draws need an rng")
        again = [_measure(rng.poisson(np.clip(s, 0, None)).astype(np.float64), edges, hidden_from)
                 for _ in range(int(draws))]
        out = SecondRoundTrip(**{**out.__dict__, "size_sd": float(np.std([m.size for m in again], ddof=1)),
                                 "time_sd": float(np.std([m.time for m in again], ddof=1))})
    return out
