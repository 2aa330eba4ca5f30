"""The detector a confocal capture was measured with, estimated from the capture alone (docs/detector.md
"Estimating the detector of a capture"; ``datagen estimate-capture``).

From the histograms of a confocal scan, (ny, nx, T) counts, on the hidden round-trip axis (bin k holds round trips
[k·Δt, (k+1)·Δt) from the scanned point, the direct light at t = 0; :func:`~datagen.analysis.confocal.align_confocal`
puts any scan there):

* the background map: each point's floor, the mean counts per bin over a run of bins without light: by default
  the run of :data:`LATE_FRACTION` of the window, after the direct light, whose scan-summed counts are lowest
  (:func:`floor_bins`), :func:`background_map`;
* the gain map: what each point's hidden light is multiplied by, relative. Its direct counts (the first
  :data:`GAIN_WINDOW` s after its direct return, less its floor) over their mean, :func:`gain_map`, raised to the
  power γ that the hidden counts follow them with over the scan, :func:`gain_exponent` (a slope of logs over groups
  of points, held to [0, 1]). Laser power scales both alike (γ = 1); the focus and the alignment of the detector's
  field of view with the laser spot scale the direct light, a point on the wall, more than the hidden light spread
  over the field of view (γ < 1). On the LCT release's dot charts γ is 0.50 / 0.38, and the gain each chart's
  simulation asks for (real over simulated hidden counts, point by point) is a power of its direct counts: their
  logs correlate at 0.95-0.96 (docs/real.md);
* the direct-to-hidden ratio: the net counts of the direct light (the bins :func:`direct_light_bins` gives) over the
  net counts after it, :func:`direct_to_hidden`. What fraction of the direct light the set-up lets through cannot be
  told from the capture alone (it needs the geometry's prediction of the hidden return): compare this ratio with a
  simulation of the scene (attenuation = real ratio / simulated ratio, ``detector.direct``);
* the IRF: a two-tail fit (:func:`datagen.spad.fit.fit_detector`) of the direct returns summed over the scan, the
  core's centre held at the middle of the bin where that return peaks (``irf_position="aligned"``, the default: on
  the aligned axis the direct light arrives in the first bin, and the LCT release's rectification puts each point's
  direct peak there; a capture whose time zero is off peaks later, and the core follows its peak) or fitted
  ("free"). A return cropped at its peak does not tell its core's position from its width: a free fit
  of the release's charts puts the centre 18 ps before the first bin, before the direct light can arrive, with a
  core of 78 ps FWHM; the aligned one gives 53 ps (docs/detector.md, "Estimating the detector of a capture"; what
  each does to a simulation of the capture: docs/real.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .confocal import direct_light_bins

__all__ = ["LATE_FRACTION", "GAIN_WINDOW", "IRF_WINDOW", "IRF_POSITIONS", "GAIN_GROUPS", "CaptureDetector",
           "FLOOR_SPREAD", "floor_bins", "background_map", "gain_map", "gain_exponent", "net_noise",
           "direct_light_seen", "hidden_gain", "direct_to_hidden", "estimate_capture_detector"]

LATE_FRACTION = 0.1
"""The background floor is read on a run of 10 % of the window's bins (205 of the LCT release's 2048)."""

GAIN_WINDOW = 0.2e-9
"""s: a point's direct counts are summed over the first 0.2 ns after its direct return (the core of the response
and its fast tail: 50 bins of the LCT release's 4 ps), where the direct light outweighs the hidden scene."""

IRF_WINDOW = 1.2e-9
"""s: the direct return the two-tail fit takes, 1.2 ns from its peak (the hidden returns of the LCT release's
scenes start after 2.4 ns)."""


GAIN_GROUPS = 8
""":func:`gain_exponent` averages the points in 8 groups by their direct counts before it reads the slope."""

IRF_POSITIONS = ("aligned", "free")
"""How the IRF fit places the core: "aligned" (the default) holds it at the middle of the bin where the scan-summed
direct return peaks (the first bin on the aligned axis, the LCT release's direct peak), "free" fits its centre."""


@dataclass
class CaptureDetector:
    """What :func:`estimate_capture_detector` estimates.

    Attributes:
        background: float64 (ny, nx) counts per bin of each point's floor.
        gain: float64 (ny, nx) the hidden light's gain, ``direct_gain ** gain_exponent`` over its mean (mean 1).
        direct_counts, hidden_counts: float64 (ny, nx) net counts (floor removed) of the direct light and after it.
        direct_to_hidden: total net direct over total net hidden counts.
        direct_bins: the number of leading bins that hold the direct light (:func:`direct_light_bins`).
        fit: the two-tail :class:`~datagen.spad.fit_result.DetectorFit` of the scan-summed direct return, or None.
        notes: one line each for what the estimate could not do.
        irf_position: how the fit placed the IRF's core (:data:`IRF_POSITIONS`).
        direct_gain: float64 (ny, nx) each point's net direct counts over their mean (:func:`gain_map`).
        gain_exponent: γ, how the hidden counts follow the direct counts (:func:`gain_exponent`).
        gain_note: why γ was not read (it is then 1), or why there is no gain (``gain`` all 1); None when it was.
        floor_bins: the spans (first, stop) of bins the floor was read over (:func:`floor_bins`, or as given).
    """

    background: np.ndarray
    gain: np.ndarray
    direct_counts: np.ndarray
    hidden_counts: np.ndarray
    direct_to_hidden: float
    direct_bins: int
    fit: object | None = None
    notes: list[str] = field(default_factory=list)
    irf_position: str = "aligned"
    direct_gain: np.ndarray | None = None
    gain_exponent: float = 1.0
    gain_note: str | None = None
    floor_bins: list[tuple[int, int]] | None = None


FLOOR_SPREAD = 4.0
""":func:`floor_bins` reads the floor over every run whose scan-summed mean is within 4 standard errors (Poisson) of
the lowest run's."""


def floor_bins(scan: np.ndarray, first: int = 0) -> list[tuple[int, int]]:
    """The bins a capture's floor is read over: of the runs of :data:`LATE_FRACTION` of its bins from ``first`` on
    (after the direct light; runs a quarter of their length apart), the quietest, by their scan-summed counts, and
    every run within :data:`FLOOR_SPREAD` standard errors of it, passing over runs that hold a bin with no count
    anywhere in the scan (a window edited out). Taking every run a flat floor fills keeps the floor unbiased (the
    quietest run alone lies about two standard errors low); leaving out the runs with light keeps a hidden return
    that reaches the record's end out of the floor, which a fixed late window takes for background: the LCT
    release's "S U" letters, whose U returns until 8.19 ns, have a floor 6.4 times too high over their last 10 %
    (2755 counts per bin scan-summed, against 430 between the letters' returns), and the exit sign's return tail
    doubles it (960 against 248). On the charts the two agree within 0.1 %.

    Args:
        scan: (ny, nx, T) counts ≥ 0. first: the first bin a run may start at (0 ≤ first < T).
    Returns:
        the spans (first, stop) of bins, in order, not overlapping; the last run of the window when every run
        holds an edited-out bin.
    """
    s = np.asarray(scan, dtype=np.float64).reshape(-1, np.shape(scan)[-1]).sum(axis=0)
    n = s.size
    size = max(1, int(round(LATE_FRACTION * n)))
    first = min(max(int(first), 0), n - size)
    cum = np.concatenate([[0.0], np.cumsum(s)])
    empty = np.concatenate([[0], np.cumsum(s == 0)])
    starts = np.arange(first, n - size + 1, max(1, size // 4))
    if starts[-1] != n - size:
        starts = np.append(starts, n - size)
    starts = starts[(empty[starts + size] - empty[starts]) == 0]
    if starts.size == 0:
        return [(n - size, n)]
    sums = cum[starts + size] - cum[starts]
    quiet = starts[sums <= sums.min() + FLOOR_SPREAD * np.sqrt(max(sums.min(), 1.0))]
    spans: list[tuple[int, int]] = []
    for start in quiet:                                   # merge overlapping runs
        if spans and start <= spans[-1][1]:
            spans[-1] = (spans[-1][0], int(start) + size)
        else:
            spans.append((int(start), int(start) + size))
    return spans


def _spans(late) -> list[tuple[int, int]]:
    """``late`` as a list of spans (first, stop): one span, or a list of them (:func:`floor_bins`)."""
    return [(int(a), int(b)) for a, b in ([late] if np.ndim(late) == 1 else late)]


def _late(n_bins: int, late) -> np.ndarray:
    """The bins of ``late``: None (the last :data:`LATE_FRACTION` of the window), one span (first, stop) or a list
    of spans."""
    if late is None:
        return np.arange(n_bins - max(1, int(round(LATE_FRACTION * n_bins))), n_bins)
    spans = _spans(late)
    for first, stop in spans:
        if not 0 <= first < stop <= n_bins:
            raise ValueError(f"late bins {first}:{stop} are not within the capture's {n_bins} bins")
    return np.unique(np.concatenate([np.arange(first, stop) for first, stop in spans]))


def background_map(scan: np.ndarray, late=None) -> np.ndarray:
    """Each point's floor: the mean counts per bin over the bins ``late``: one span (first, stop) or a list of them
    (:func:`floor_bins`); None, the last :data:`LATE_FRACTION` of the window. scan: (ny, nx, T) counts ≥ 0.
    Returns float64 (ny, nx). Its relative standard error is 1/sqrt(floor × bins) per point."""
    s = np.asarray(scan, dtype=np.float64)
    return s[..., _late(s.shape[-1], late)].mean(axis=-1)


def _gain_bins(n_bins: int, bin_width: float) -> int:
    """The bins of the first :data:`GAIN_WINDOW` s of a window of ``n_bins`` bins (at least 1)."""
    return max(1, min(n_bins, int(round(GAIN_WINDOW / bin_width))))


def gain_map(scan: np.ndarray, bin_width: float, background: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gain, net direct counts): each point's counts over the first :data:`GAIN_WINDOW` s of the aligned axis less
    ``background`` (counts per bin) times those bins (at least 0: a gain is never negative), and that over its
    mean. scan: (ny, nx, T) aligned counts;
    returns float64 (ny, nx) twice. Raises ValueError when the direct light holds no net counts."""
    s = np.asarray(scan, dtype=np.float64)
    k = _gain_bins(s.shape[-1], bin_width)
    direct = np.maximum(s[..., :k].sum(axis=-1) - k * background, 0.0)   # a noisy floor above a dark point: no gain
    mean = float(direct.mean())
    if not mean > 0:
        raise ValueError("the scan's first bins hold no net counts above the floor: no direct light to read a gain "
                         "from (is the capture on the hidden round-trip axis, its direct light at t = 0?)")
    return direct / mean, direct


def gain_exponent(direct: np.ndarray, hidden: np.ndarray, hidden_noise: np.ndarray,
                  model: np.ndarray | None = None, notes: list[str] | None = None) -> float:
    """γ: the power of a point's direct counts that its hidden counts follow over the scan (module doc).

    The points with direct counts > 0 are split into :data:`GAIN_GROUPS` groups of equal size by their direct
    counts; γ is the least-squares slope of log mean hidden counts against log mean direct counts over the groups,
    held to [0, 1]. Averaging before the log keeps counting noise out of the slope (a log of single points' noisy
    hidden counts, or a cut on them, pulls it towards 0). The scene's own variation over the scan (where the hidden
    object is) enters too: without ``model`` it averages out within a group only where it does not follow the direct
    light (an object on the bright side of the scan reads a larger γ, on the dim side a smaller one); with
    ``model``, a simulation's hidden counts at each point without the gain (any scale), each group's mean hidden
    counts are divided by the model's, which takes the scene out. γ is 1 (the light as it is) when a group's mean
    hidden counts are not three times their noise (the hidden light too weak, or its floor over-subtracted, to
    tell), a group's model mean is not > 0, or fewer than :data:`GAIN_GROUPS` points have direct light.

    Args:
        direct, hidden: (ny, nx) net counts (floor removed) of each point's direct light and of what follows it.
        hidden_noise: (ny, nx) the standard deviation of ``hidden`` (counting noise of the counts and of the floor).
        model: (ny, nx) or None: the scene's hidden counts per point without the gain.
        notes: a list that gets one line saying why, when γ is 1 because it could not be read.
    Returns:
        float in [0, 1].
    """
    def cannot(why: str) -> float:
        if notes is not None:
            notes.append(f"the gain's power is 1: {why}")
        return 1.0

    d = np.asarray(direct, dtype=np.float64).ravel()
    h = np.asarray(hidden, dtype=np.float64).ravel()
    var = np.asarray(hidden_noise, dtype=np.float64).ravel() ** 2
    lit = (d > 0) & np.isfinite(d) & np.isfinite(h) & np.isfinite(var)
    if lit.sum() < GAIN_GROUPS:
        return cannot(f"fewer than {GAIN_GROUPS} points have direct light")
    order = np.argsort(d[lit], kind="stable")
    groups = np.array_split(order, GAIN_GROUPS)
    dd, hh, vv = d[lit], h[lit], var[lit]
    mean_d = np.array([dd[g].mean() for g in groups])
    mean_h = np.array([hh[g].mean() for g in groups])
    noise = np.array([np.sqrt(vv[g].sum()) / g.size for g in groups])
    scene = np.ones(GAIN_GROUPS)
    if model is not None:
        mm = np.asarray(model, dtype=np.float64).ravel()[lit]
        scene = np.array([mm[g].mean() for g in groups])
    if not (mean_h > 3.0 * noise).all():
        return cannot("the hidden counts of some points, grouped by their direct counts, are not 3 times their noise "
                      "above the floor (too weak, or the floor read over late hidden light)")
    if not (scene > 0).all():
        return cannot("the simulation sends no hidden light to some points, grouped by their direct counts")
    if not np.ptp(np.log(mean_d)) > 0:
        return cannot("the direct counts do not vary over the scan")
    slope = float(np.polyfit(np.log(mean_d), np.log(mean_h / scene), 1)[0])
    return float(min(max(slope, 0.0), 1.0))


def net_noise(window: np.ndarray, floor: np.ndarray, floor_bins: int) -> np.ndarray:
    """The standard deviation of a window's net counts (its counts less ``floor`` per bin, the floor the mean of
    ``floor_bins`` bins): sqrt(counts + K² · floor / floor_bins) for K bins, Poisson counts. window: (..., K)
    counts; floor: (...) counts per bin. Returns float64 (...)."""
    w = np.asarray(window, dtype=np.float64)
    return np.sqrt(w.sum(axis=-1) + w.shape[-1] ** 2 * np.maximum(floor, 0.0) / max(int(floor_bins), 1))


def direct_light_seen(scan: np.ndarray, bin_width: float, floor: np.ndarray, floor_bins: int) -> bool:
    """Whether a scan's direct light can give a gain: at least half of its points hold net counts in the first
    :data:`GAIN_WINDOW` s (:func:`gain_map`'s) above three times their noise (:func:`net_noise`). A capture whose
    direct light was cut, or a simulation without it, holds only the floor's noise there, and a gain read off it is
    noise too. scan: (ny, nx, T) counts on the aligned axis; floor: (ny, nx) counts per bin, the mean of
    ``floor_bins`` bins."""
    s = np.asarray(scan, dtype=np.float64)
    k = _gain_bins(s.shape[-1], bin_width)
    window = s[..., :k]
    net = window.sum(axis=-1) - k * np.asarray(floor, dtype=np.float64)
    return bool(np.mean(net > 3.0 * net_noise(window, floor, floor_bins)) >= 0.5)


def hidden_gain(direct_gain: np.ndarray, exponent: float) -> np.ndarray:
    """The hidden light's gain: ``direct_gain ** exponent`` (:func:`gain_map`, :func:`gain_exponent`) over its
    mean. Returns float64 of ``direct_gain``'s shape, mean 1 (all ones when it is all zero)."""
    g = np.asarray(direct_gain, dtype=np.float64) ** float(exponent)
    mean = float(g.mean())
    return g / mean if mean > 0 else np.ones_like(g)


def direct_to_hidden(scan: np.ndarray, background: np.ndarray, direct_bins: int) -> tuple[float, np.ndarray,
                                                                                          np.ndarray]:
    """(ratio, net direct counts (ny, nx), net hidden counts (ny, nx)): the counts of the first ``direct_bins``
    bins and of the rest, each less the floor ``background`` (counts per bin) times its bins; the ratio of the
    totals (inf when the hidden counts are not above the floor)."""
    s = np.asarray(scan, dtype=np.float64)
    n = s.shape[-1]
    direct = s[..., :direct_bins].sum(axis=-1) - direct_bins * background
    hidden = s[..., direct_bins:].sum(axis=-1) - (n - direct_bins) * background
    total = float(hidden.sum())
    return (float(direct.sum()) / total if total > 0 else float("inf")), direct, hidden


def estimate_capture_detector(scan: np.ndarray, bin_width: float, *, late: tuple[int, int] | None = None,
                              direct_bins: int | None = None, fit_irf: bool = True, repetition_rate: float = 10e6,
                              n_cycles: int = 1_000_000, irf_position: str = "aligned") -> CaptureDetector:
    """Background, gain, direct-to-hidden ratio and IRF of a confocal capture (module doc).

    Args:
        scan: (ny, nx, T) counts ≥ 0 on the hidden round-trip axis (:func:`~.confocal.align_confocal`).
        bin_width: Δt, s. late: (first, stop) bins of the floor (default :func:`floor_bins` after the direct
            light).
        direct_bins: bins of the direct light (default :func:`~.confocal.direct_light_bins`).
        fit_irf: fit the two-tail IRF to the scan-summed direct return (:data:`IRF_WINDOW`).
        repetition_rate, n_cycles: the exposure, for the fit's background rate in Hz (the IRF's shape does not
            depend on them; the LCT files do not state them).
        irf_position: one of :data:`IRF_POSITIONS` (module doc).
    Returns:
        :class:`CaptureDetector`.
    Raises:
        ValueError: not an (ny, nx, T) scan of counts, late bins outside the window, no direct light.
    """
    if irf_position not in IRF_POSITIONS:
        raise ValueError(f"irf_position must be one of {', '.join(IRF_POSITIONS)}, got {irf_position!r}")
    s = np.asarray(scan, dtype=np.float64)
    if s.ndim != 3 or s.shape[-1] < 2 or not np.isfinite(s).all() or (s < 0).any():
        raise ValueError(f"expected a confocal scan of counts (ny, nx, T) >= 0, got shape {s.shape}")
    n_direct = direct_light_bins(s, bin_width) if direct_bins is None else int(direct_bins)
    window = floor_bins(s, max(n_direct, 0)) if late is None else late
    background = background_map(s, window)
    direct_gain, direct_net = gain_map(s, bin_width, background)
    notes = []
    if n_direct <= 0:
        notes.append("no direct light found at t = 0: the direct-to-hidden ratio is not estimated")
    ratio, direct, hidden = direct_to_hidden(s, background, max(n_direct, 1))
    n, k = s.shape[-1], max(n_direct, 1)
    late_bins = _late(n, window).size
    why: list[str] = []
    if direct_light_seen(s, bin_width, background, late_bins):
        exponent = gain_exponent(direct_net, hidden, net_noise(s[..., k:], background, late_bins), notes=why)
        gain = hidden_gain(direct_gain, exponent)
    else:
        exponent, gain = 1.0, np.ones_like(direct_gain)
        why.append("the direct light is not above its noise at half of the points: no gain (gain.npy all 1)")
    notes += why
    fit = None
    if fit_irf:
        from ..errors import ConfigError
        from ..spad.fit import fit_detector

        summed = s.reshape(-1, s.shape[-1]).sum(axis=0)
        peak = int(np.argmax(summed[:_gain_bins(summed.size, bin_width)]))
        stop = min(summed.size, peak + int(round(IRF_WINDOW / bin_width)))
        h = np.rint(summed[:stop])
        try:
            fixed = {"position": (peak + 0.5) * bin_width} if irf_position == "aligned" else None
            fit = fit_detector(h, bin_width=bin_width, repetition_rate=repetition_rate, n_cycles=n_cycles,
                               model="poisson", irf="two_tail", allow_cropped_edge=True, fixed=fixed)
        except ConfigError as exc:
            notes.append(f"the IRF was not fitted: {exc}")
    return CaptureDetector(background, gain, direct, hidden, ratio, n_direct, fit, notes, irf_position,
                           direct_gain, exponent, why[0] if why else None, _spans(window))
