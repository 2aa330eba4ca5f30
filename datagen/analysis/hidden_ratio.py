"""The hidden counts of one object captured at two distances by one scanner, with the direct light's slow tail taken
out: the ratio a simulation of the hidden light alone is compared with (docs/real.md, "The set-up fitted on the dot
charts").

The Stanford release's measure of a confocal capture's hidden counts is the scan-summed counts of bins 600–1899 of 4
ps (2.4–7.6 ns) less 1300 times the mean of bins 1900–2047 (its README). It also counts the direct light's own slow
tail, which runs on past 2.4 ns (the SPAD's diffusion tail, docs/detector.md): on the release's two dot charts it is
5 % of the 40 cm chart's window and 9 % of the 65 cm chart's. A simulation without the direct light has no such
tail, so its ratio is to be compared with the hidden light alone.

**The measurement** (:func:`hidden_count_ratio`), on the two captures' scan-summed transients, ``near`` and ``far``:

1. *Floor and direct light.* Each transient less its floor (the mean over :data:`FLOOR_BINS`); its direct counts the
   net counts before the window.
2. *The direct tail's shape.* The far capture's net transient over its direct counts, from the window's start to
   ``far_onset`` (the bin its hidden light starts at: up to it the far capture holds the direct light alone). Both
   captures being of one scanner, the near capture's direct tail has the same shape: the two normalised transients
   are compared over the last quarter of the span before the window (``shape_check``, about 1 when they agree).
3. *Past the onset* the shape is extrapolated by an exponential fitted (least squares on the log of means over
   :data:`GROUP` bins) to the last :data:`FIT_SPAN` before ``far_onset``; a power law fitted alike gives the spread
   that this choice makes (``hidden_range``).
4. *The hidden counts*: each window's counts less the tail's share of it (its summed shape times the capture's
   direct counts).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HiddenRatio", "hidden_count_ratio", "release_hidden_counts", "WINDOW", "FLOOR_BINS", "GROUP", "FIT_SPAN"]

WINDOW = (600, 1900)
"""Bins (of 4 ps) of the release's hidden-count window, 2.4–7.6 ns: start inclusive, end exclusive."""

FLOOR_BINS = (1900, 2048)
"""Bins whose mean is each bin's floor in the release's measure."""

GROUP = 10
"""Bins averaged into one point of the tail's fit."""

FIT_SPAN = 250
"""Bins (1 ns of 4 ps) before ``far_onset`` that the extrapolating exponential (and power law) is fitted to."""


@dataclass(frozen=True)
class HiddenRatio:
    """The two captures' hidden-count ratio, near over far.

    ``release``: the release's measure (the window less the floor), the direct light's tail included.
    ``hidden``: the same with the direct light's tail taken out (exponential extrapolation past the far onset);
    ``hidden_range``: (low, high) over the exponential and power-law extrapolations.
    ``tail_share``: (near, far), the share of each window that the direct tail makes.
    ``shape_check``: the near over the far capture's normalised direct tail just before the window (about 1 for
    one scanner). ``tau``: s, the extrapolating exponential's decay constant.
    """

    release: float
    hidden: float
    hidden_range: tuple[float, float]
    tail_share: tuple[float, float]
    shape_check: float
    tau: float


def _window_tail(shape: np.ndarray, onset: int, stop: int, bin_width: float) -> tuple[float, float, float]:
    """The direct tail's summed shape from the window's start to ``stop``: measured up to ``onset``, extrapolated
    after it; (exponential, power law, τ in s)."""
    lo = onset - FIT_SPAN
    n = FIT_SPAN // GROUP
    t = (np.arange(lo, lo + n * GROUP) + 0.5) * bin_width
    y = shape[lo:lo + n * GROUP]
    tg, yg = t.reshape(n, GROUP).mean(axis=1), y.reshape(n, GROUP).mean(axis=1)
    if np.any(yg <= 0):
        raise ValueError("the far capture's direct tail reaches its floor before its hidden onset: nothing to fit")
    measured = float(shape[WINDOW[0]:onset].sum())
    after = (np.arange(onset, stop) + 0.5) * bin_width
    slope, icpt = np.polyfit(tg, np.log(yg), 1)
    power, picpt = np.polyfit(np.log(tg), np.log(yg), 1)
    exp_sum = float(np.exp(icpt + slope * after).sum())
    pow_sum = float(np.exp(picpt + power * np.log(after)).sum())
    return measured + exp_sum, measured + pow_sum, -1.0 / slope


def release_hidden_counts(summed: np.ndarray) -> float:
    """The release's hidden counts of a scan-summed transient ``summed`` (K ≥ 2048 bins of 4 ps): the counts of
    :data:`WINDOW` less its length times the mean of :data:`FLOOR_BINS` (its README; the direct light's tail
    included)."""
    net = _net(summed)
    return float(net[WINDOW[0]:WINDOW[1]].sum())


def _net(summed: np.ndarray) -> np.ndarray:
    """A scan-summed transient less its floor, the mean of :data:`FLOOR_BINS`."""
    return summed - summed[FLOOR_BINS[0]:FLOOR_BINS[1]].mean()


def hidden_count_ratio(near: np.ndarray, far: np.ndarray, far_onset: int, bin_width: float = 4e-12) -> HiddenRatio:
    """The hidden-count ratio of one object captured near and far by one scanner (module doc).

    ``near``, ``far``: (K,) float, scan-summed counts per bin of the two captures, time zero at the scanned point
    (the release's rectified bins), K ≥ 2048 bins of ``bin_width`` s. ``far_onset``: the bin the far capture's
    hidden light starts at (up to it the far capture holds its direct light and floor alone); it must lie in
    the window, at least :data:`FIT_SPAN` after its start.

    Raises ValueError (one line) on transients too short for the window and floor, an onset outside the window,
    or a direct tail that vanishes before the onset.
    """
    near, far = np.asarray(near, dtype=np.float64), np.asarray(far, dtype=np.float64)
    if near.ndim != 1 or near.shape != far.shape or near.size < FLOOR_BINS[1]:
        raise ValueError(f"hidden_count_ratio: two scan-summed transients of ≥ {FLOOR_BINS[1]} bins expected, "
                         f"got shapes {near.shape} and {far.shape}")
    if not WINDOW[0] + FIT_SPAN <= far_onset <= WINDOW[1]:
        raise ValueError(f"hidden_count_ratio: far_onset {far_onset} outside bins {WINDOW[0] + FIT_SPAN}–{WINDOW[1]}")
    nets = [_net(near), _net(far)]
    directs = [float(net[:WINDOW[0]].sum()) for net in nets]
    windows = [release_hidden_counts(s) for s in (near, far)]
    shape = nets[1] / directs[1]
    check = slice(WINDOW[0] * 3 // 4, WINDOW[0])
    shape_check = float(nets[0][check].sum() / directs[0] / shape[check].sum())
    exp_tail, pow_tail, tau = _window_tail(shape, far_onset, WINDOW[1], bin_width)

    def ratio(tail: float) -> float:
        return (windows[0] - tail * directs[0]) / (windows[1] - tail * directs[1])

    low, high = sorted((ratio(exp_tail), ratio(pow_tail)))
    return HiddenRatio(release=windows[0] / windows[1], hidden=ratio(exp_tail), hidden_range=(low, high),
                       tail_share=(exp_tail * directs[0] / windows[0], exp_tail * directs[1] / windows[1]),
                       shape_check=shape_check, tau=float(tau))
