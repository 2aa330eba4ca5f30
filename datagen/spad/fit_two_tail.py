"""The two-tail IRF in a detector fit (:func:`datagen.spad.fit.fit_detector` with ``irf="two_tail"``): the
return's envelope, the starting values and the length check.

With ``irf="two_tail"`` the whole response acts before pile-up, as the simulation's ``irf:`` block does
(docs/detector.md "Two-tail IRF"): the return is ``signal`` photons per cycle at ``position`` convolved with the
:class:`~datagen.timing.irf.Irf` of kind ``two_tail`` whose core is the laser pulse and the jitter together
(sigma² = pulse_sigma² + jitter_sigma²), integrated over the bins exactly (:meth:`Irf.interval_mass`); the
detector then adds the background and draws the histogram model (no further jitter or diffusion kernel). At the
low flux of a direct return seen through the attenuation of a confocal set-up, jitter before or after pile-up
gives the same histogram (docs/physics.md §6).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..timing.irf import FWHM_PER_SIGMA, Irf

__all__ = ["TWO_TAIL_PARAMETERS", "TWO_TAIL_MIN_BINS", "TWO_TAIL_DELAY_STARTS", "two_tail_irf", "two_tail_envelope", "two_tail_start",
           "check_two_tail_length", "response_fwhm"]

TWO_TAIL_PARAMETERS = ("tail_weight", "tail", "tail2_weight", "tail2", "tail_delay")
"""The two-tail IRF's parameters a fit adds after ``jitter_sigma`` (the core), named as the :class:`Irf` fields."""

TWO_TAIL_MIN_BINS = 40
"""Bins a histogram must hold from the return's peak on for the two-tail fit: two tail constants and their weights
need the decay over tens of bins (fewer leave the slow tail and the background to trade against each other)."""

TWO_TAIL_DELAY_STARTS = (8.0, 16.0)
"""Further starting values of ``tail_delay``, in bins, refitted after the first start (2 bins): the likelihood has
an optimum with the tails at the core (a plain two-tail decay) and one with them delayed (a shoulder after the
core, as the LCT release's dot-chart captures show 40-80 ps after their direct peak); the best is kept."""

FWHM_GRID_STEP = 0.05e-12
"""s: the step of the grid on which :func:`response_fwhm` reads the response's half maximum (0.05 ps)."""


def two_tail_irf(values: dict[str, float], pulse_sigma: float) -> Irf:
    """The :class:`Irf` of kind ``two_tail`` of fit parameters ``values`` (SI units; the core sigma is
    sqrt(pulse_sigma² + jitter_sigma²), pulse_sigma in s)."""
    sigma = math.hypot(float(pulse_sigma), float(values["jitter_sigma"]))
    return Irf(kind="two_tail", sigma=sigma, tail=values["tail"], tail_weight=values["tail_weight"],
               tail2=values["tail2"], tail2_weight=values["tail2_weight"], tail_delay=values["tail_delay"])


def two_tail_envelope(n_bins: int, bin_width: float, values: dict[str, float], pulse_sigma: float) -> np.ndarray:
    """The return as an envelope: ``values["signal"]`` photons per cycle at ``values["position"]`` (s after the
    first bin edge) convolved with :func:`two_tail_irf`, integrated over the bins. float64 (n_bins,) photons per
    cycle per bin. Raises ValueError: parameters the :class:`Irf` refuses (e.g. weights summing above 1)."""
    irf = two_tail_irf(values, pulse_sigma)
    edges = np.arange(n_bins + 1) * bin_width - values["position"]
    return values["signal"] * irf.interval_mass(edges[:-1], edges[1:])


def two_tail_start(h: np.ndarray, bin_width: float, peak: int) -> dict[str, float]:
    """Starting values of the tails: a fast tail of 10 bins (40 ps at 4 ps) holding 30 % of the return, a slow one
    of a fifth of the window after the peak holding 20 %, delayed by 2 bins."""
    after = max(h.size - peak, 1)
    return {"tail_weight": 0.3, "tail": 10 * bin_width, "tail2_weight": 0.2,
            "tail2": max(0.2 * after, 20) * bin_width, "tail_delay": 2 * bin_width}


def check_two_tail_length(h: np.ndarray, peak: int, what: str = "histogram") -> None:
    """ConfigError (one line) when ``h`` holds fewer than :data:`TWO_TAIL_MIN_BINS` bins from the return's peak
    (bin ``peak``) on."""
    after = int(h.size - peak)
    if after < TWO_TAIL_MIN_BINS:
        raise ConfigError(f"{what}: {h.size} bins with the return's peak in bin {peak} leave {after} bins for its "
                          f"tails; the two-tail fit needs at least {TWO_TAIL_MIN_BINS} after the peak (give a longer "
                          "histogram, or fit irf 'exgauss')")


def response_fwhm(irf: Irf) -> float:
    """Full width at half maximum (s) of the whole response ``irf.pdf`` (core and tails), read on a grid of
    :data:`FWHM_GRID_STEP` over the core ± 8 sigma plus the tails' delay (linear between grid points). For a
    Gaussian it is 2 sqrt(2 ln 2) sigma (the core's, :attr:`Irf.fwhm`)."""
    if irf.kind == "gaussian":
        return irf.fwhm
    before, _ = irf.support
    x = np.arange(-before, before + 4 * FWHM_PER_SIGMA * irf.sigma + float(irf.tail_delay or 0.0) +
                  2 * float(irf.tail or 0.0), FWHM_GRID_STEP)
    p = irf.pdf(x)
    half = 0.5 * float(p.max())
    above = np.flatnonzero(p >= half)
    i, j = int(above[0]), int(above[-1])

    def cross(a: int, b: int) -> float:               # linear interpolation between grid points a, b
        return float(x[a] + (half - p[a]) * (x[b] - x[a]) / (p[b] - p[a]))

    lo = cross(i - 1, i) if i > 0 else float(x[0])
    hi = cross(j, j + 1) if j + 1 < x.size else float(x[-1])
    return hi - lo
