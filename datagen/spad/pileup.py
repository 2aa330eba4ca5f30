"""The pile-up decision: whether dead time changes the counts by more than a tolerance (docs/planner.md, pile_up).

The detector stage decides it from the envelope after transport (:func:`pile_up_from_envelope`), and draws the
counts with :func:`counting_detector`: the configured model, or its Poisson version when dead time cannot matter.
The effect planner (:mod:`datagen.planner`) previews the same rule before transport from a coarse estimate of Λ
(:func:`pile_up_decision`), which only the result's record of a *forced* pile-up keeps ("the planner would say").

The bound: the detector is dead at time t only after an avalanche in the preceding dead window, which for a
Poisson arrival process has probability 1 − e^{−M}, M the expected avalanches there, so every bin's expected
count differs from the Poisson one by a relative amount ≤ 1 − e^{−M}. M = Λ (expected avalanches per laser cycle
in the histogram window) for ``pile_up`` and ``multi_stop``, which are re-armed every cycle; a ``free_running``
detector's dead time spans ≤ ceil(τ/T) + 1 periods.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .config import DetectorConfig
from .models import detector_model
from .rates import rates_from_envelope

__all__ = ["PileUpDecision", "counting_detector", "pile_up_decision", "pile_up_from_envelope"]


@dataclass(frozen=True)
class PileUpDecision:
    """Whether the counts are drawn with dead time (``on``) or as Poisson counts.

    Attributes:
        on: draw with the configured dead-time model.
        reason: why, quoting the numbers.
        numbers: ``model`` (str), ``lambda_per_cycle`` (expected avalanches per cycle), and when they apply
            ``dead_window_avalanches`` (M), ``max_bin_distortion`` (1 − e^{−M}) and ``total_distortion``
            (1 − (1 − e^{−Λ})/Λ); floats and strings, JSON-able.
    """

    on: bool
    reason: str
    numbers: dict = field(default_factory=dict)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def pile_up_decision(detector: DetectorConfig, lam: float, window: float, tolerance: float,
                     source: str) -> PileUpDecision:
    """The pile-up decision from Λ (module doc).

    Args:
        detector: the configured detector.
        lam: Λ, expected avalanches per laser cycle in the histogram window (``math.inf``: unknown).
        window: the histogram window, s (the sum of the TDC bin widths).
        tolerance: relative change of any bin below which Poisson counts are used, in [0, 1).
        source: where Λ comes from, in words (quoted in the reason).
    Returns:
        :class:`PileUpDecision`: off for a Poisson detector; on with afterpulsing or crosstalk (which Poisson
        counts cannot model); otherwise on exactly when the bound 1 − e^{−M} ≥ ``tolerance``.
    """
    numbers: dict = {"model": detector.model, "lambda_per_cycle": lam}
    dead_time = detector_model(detector.model).dead_time
    if dead_time == "none":
        return PileUpDecision(False, "detector model is 'poisson' (configured)", numbers)
    if detector.afterpulse_probability > 0 or detector.crosstalk_probability > 0:
        return PileUpDecision(True, f"detector models afterpulsing ({_fmt(detector.afterpulse_probability)}) or "
                              f"crosstalk ({_fmt(detector.crosstalk_probability)}), which Poisson counts cannot",
                              numbers)
    m = lam
    if dead_time == "free_running":
        per_period = lam + detector.background_rate * max(detector.period - window, 0.0)
        m = per_period * (math.ceil(detector.dead_time / detector.period) + 1)
    distortion = -math.expm1(-m)
    total = 1.0 + math.expm1(-lam) / lam if lam > 0 else 0.0            # 1 − (1 − e^{−Λ})/Λ
    numbers.update(dead_window_avalanches=m, max_bin_distortion=distortion, total_distortion=total)
    what = (f"Λ = {_fmt(lam)} avalanches/cycle ({source}), dead-time bound 1 − e^(−{_fmt(m)}) = "
            f"{_fmt(distortion)} (total {_fmt(total)})")
    if distortion < tolerance:
        return PileUpDecision(False, f"{what} < tolerance {_fmt(tolerance)}: Poisson counts", numbers)
    return PileUpDecision(True, f"{what} ≥ tolerance {_fmt(tolerance)}: {detector.model} model", numbers)


def pile_up_from_envelope(envelope: np.ndarray, detector: DetectorConfig, tolerance: float,
                          rates: np.ndarray | None = None) -> PileUpDecision:
    """The pile-up decision from the envelope itself: Λ is the largest over pixels of the summed rates
    (:func:`~datagen.spad.rates.rates_from_envelope`: signal × PDE, background, gate, DNL widths).

    Args:
        envelope: (..., n_bins) float64 expected detected photons per pulse per bin (pixels on leading axes).
        detector: the configured detector; tolerance: as :func:`pile_up_decision`.
        rates: ``rates_from_envelope(envelope, detector)`` when the caller has them already (same shape).
    Returns:
        :class:`PileUpDecision` (reason "… (from the envelope) …").
    Raises:
        ValueError: an envelope :func:`~datagen.spad.rates.rates_from_envelope` refuses (non-finite, clearly
            negative, no bins).
    """
    rates = rates_from_envelope(envelope, detector) if rates is None else rates
    lam = float(np.max(rates.reshape(-1, rates.shape[-1]).sum(axis=-1))) if rates.size else 0.0
    window = float(np.sum(detector.widths(rates.shape[-1])))
    return pile_up_decision(detector, lam, window, tolerance, "from the envelope")


def counting_detector(detector: DetectorConfig, pile_up: bool) -> DetectorConfig:
    """The detector model to draw counts with: ``detector`` itself when ``pile_up`` is on (or it is Poisson
    already), else its Poisson version (same cycles, PDE, background, gate, jitter; no dead time)."""
    if pile_up or detector_model(detector.model).dead_time == "none":
        return detector
    data = detector.model_dump()
    data.update(model="poisson", dead_time_kind=None, paralyzable=False)
    return DetectorConfig.model_validate(data)
