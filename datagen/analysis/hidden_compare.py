"""A measured confocal scan against its simulation, on what the hidden scene sent back: each metric next to its
Poisson noise floor (docs/capture_io.md, "Comparing a capture with its simulation").

Both scans are put on the hidden round-trip axis (:func:`~datagen.analysis.confocal.align_confocal`) at the measured
bin width. Then, in order:

1. **Direct light excluded.** The first bins, where the light off the scanned point itself arrives with its slow tail,
   are dropped from both: as many as :func:`~datagen.analysis.confocal.direct_light_bins` finds in the measured scan
   ("auto"), or a given duration. The simulation is not asked to model the direct light (real set-ups gate or
   attenuate it by a factor no file records).
2. **Background.** Each point's floor (dark counts, ambient light: it drifts over a real scan) is the mean of its
   bins where the simulation's scan-summed return (smoothed over :data:`EDGE_SMOOTHING`) is below
   :data:`SIGNAL_FREE` of its peak (plus three times its counting noise when it holds counts) (at least
   :data:`MIN_FLOOR_BINS`; else the last tenth of the window), subtracted from both scans.
3. **Gain.** Optionally each simulated point is multiplied by a gain map: "direct" estimates it from the measured
   scan's direct light (:mod:`~datagen.analysis.capture_detector`: each point's direct counts above its floor over
   their mean, raised to the power γ that the measured hidden counts over the simulated ones follow them with over
   the scan, :func:`~datagen.analysis.capture_detector.gain_exponent`; laser power scales the direct and the hidden
   light alike, focus and alignment the direct light, a point, more; no gain when the direct light is not above its
   noise at half of the points, :func:`~datagen.analysis.capture_detector.direct_light_seen`), or an (ny, nx) map
   is given, e.g. one read off another capture of the same scanner against its own simulation
   (:func:`calibrated_gain`: a flat-field calibration on a known target).
4. **Scale.** The simulation is scaled to the measured hidden counts (one factor: the model's absolute scale is its
   own, the measurement's its exposure's).

Metrics (:func:`hidden_metrics`): the scan-summed relative L2 ‖Σ_p(M − R)‖/‖Σ_p R‖; the per-point leading-edge
time difference (simulated − measured, where a transient smoothed over :data:`EDGE_SMOOTHING` first reaches half its
maximum; median and spread = half the 16–84 % range, over points whose simulated hidden counts reach
:data:`EDGE_LEVEL` of the largest); the Pearson correlation of the two hidden-count maps (reported as 1 − r); the
FWHM and the 1/e decay time after the peak of the scan-summed return (differences).

**Noise floor.** Each metric's value when the simulation is perfect: the mean, over :data:`FLOOR_DRAWS` pairs, of the
metric between a Poisson draw of the fitted model (plus the measured floor) at the measurement's level and one at the
simulation's (a draw when it holds counts, the model itself when it is an expected envelope), both put through the
same steps. A perfect simulation scores about 1× each floor; a metric many times its floor is a real difference.
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from ..spad.rates import rebin_envelope
from .compare_capture import fwhm, peak_time
from .capture_detector import direct_light_seen, gain_exponent, gain_map, hidden_gain, net_noise
from .confocal import align_confocal, direct_light_bins

__all__ = ["HiddenComparison", "hidden_comparison", "hidden_metrics", "leading_edges", "decay_time", "calibrated_gain",
           "GAIN_MODEL_FLOOR",
           "SIGNAL_FREE", "MIN_FLOOR_BINS", "EDGE_SMOOTHING", "EDGE_LEVEL", "FLOOR_DRAWS"]

SIGNAL_FREE = 0.01
"""Bins where the simulation's scan-summed hidden return (less its lowest value) is below 1 % of its peak hold only
the background."""

MIN_FLOOR_BINS = 50
"""Fewest signal-free bins the background is read from; with fewer, the last tenth of the window is used."""

EDGE_SMOOTHING = 100e-12
"""s: each point's transient is smoothed over 100 ps (a moving average) before its leading edge is read, so that
counting noise in a 4 ps bin does not set it."""

EDGE_LEVEL = 0.25
"""Points whose simulated hidden counts reach 25 % of the largest point's have a leading edge worth comparing (the
hidden object is seen there)."""

GAIN_MODEL_FLOOR = 0.01
""":func:`calibrated_gain` divides by the simulated hidden counts of a point, at least 1 % of their mean over the scan
(where the simulation sends almost no light the ratio is noise)."""

FLOOR_DRAWS = 4
"""Pairs of Poisson draws averaged for each noise floor."""

METRICS = ("rel_l2", "edge_median", "edge_spread", "map_decorrelation", "fwhm_diff", "decay_diff")
"""The metrics that have a noise floor (absolute values for the differences)."""


class HiddenComparison(dict):
    """The result of :func:`hidden_comparison`, a dict: each of :data:`METRICS` and ``floor`` {metric: noise floor};
    ``fwhm_real`` / ``fwhm_sim``, ``decay_real`` / ``decay_sim``, ``edge_points`` (points compared), ``map_corr``;
    ``trim_bins``, ``trim`` (s), ``trim_how`` ("auto" or "given"), ``floor_bins``, ``gain`` (how: "none", "direct",
    "map", or "none (…)" saying why "direct" gave no gain), ``gain_exponent`` (γ of "direct", else None),
    ``gain_note`` (why that γ is 1 when it could not be read, else None),
    ``scale``; ``counts_real`` / ``counts_sim`` (hidden counts above the floor, the simulation's before scaling); for
    drawing: ``t`` (K,) s, ``real_sum`` / ``model_sum`` (K,), ``real_map`` / ``model_map`` (ny, nx), ``real`` /
    ``model`` (ny, nx, K) hidden transients, ``bin_width``, ``t0`` (s of the first kept bin)."""


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Moving average of ``width`` bins along the last axis (same length, edges averaged over what they have)."""
    if width <= 1:
        return x
    c = np.cumsum(np.concatenate([np.zeros(x.shape[:-1] + (1,)), x], axis=-1), axis=-1)
    n = x.shape[-1]
    lo = np.clip(np.arange(n) - width // 2, 0, n)
    hi = np.clip(np.arange(n) - width // 2 + width, 0, n)
    return (c[..., hi] - c[..., lo]) / (hi - lo)


def leading_edges(transients: np.ndarray, t: np.ndarray, smoothing: float = EDGE_SMOOTHING) -> np.ndarray:
    """Leading edge (s) of each transient: where, smoothed over ``smoothing`` s, it first reaches half its maximum
    (linear interpolation between bins).

    Args:
        transients: (P, K) float; t: (K,) bin centres in s (uniform).
    Returns:
        (P,) float64 s; NaN for a transient whose maximum is ≤ 0.
    """
    x = np.asarray(transients, dtype=np.float64)
    dt = float(t[1] - t[0])
    y = _smooth(x, max(1, int(round(smoothing / dt))))
    peak = y.max(axis=-1)
    half = 0.5 * peak
    above = y >= half[:, None]
    k = np.argmax(above, axis=-1)
    rows = np.arange(len(y))
    prev = y[rows, np.maximum(k - 1, 0)]
    cur = y[rows, k]
    frac = np.where((k > 0) & (cur > prev), (half - prev) / np.where(cur > prev, cur - prev, 1.0), 1.0)
    out = t[k] - dt + frac * dt
    out = np.where(k == 0, t[0], out)
    return np.where(peak > 0, out, np.nan)


def decay_time(t: np.ndarray, y: np.ndarray) -> float:
    """Time (s) from the peak of ``y`` (bin centres ``t``) until it first falls below 1/e of the peak (linear
    interpolation); the window's end less the peak time when it never does."""
    y = np.asarray(y, dtype=np.float64)
    i = int(np.argmax(y))
    level = y[i] / np.e
    below = np.flatnonzero(y[i:] < level)
    if not below.size:
        return float(t[-1] - t[i])
    j = i + int(below[0])
    dt = float(t[1] - t[0])
    frac = (y[j - 1] - level) / (y[j - 1] - y[j]) if y[j - 1] != y[j] else 1.0
    return float(t[j - 1] + frac * dt - t[i])


def _prepare(real: np.ndarray, sim: np.ndarray, floor_bins: np.ndarray, gain: np.ndarray | None):
    """(R, M, real floor (P,), sim floor (P,), scale): floor-subtracted hidden transients (P, K), the model the
    simulation's (gain applied, scaled to the measured hidden counts)."""
    br = real[:, floor_bins].mean(axis=1)
    bs = sim[:, floor_bins].mean(axis=1)
    r = real - br[:, None]
    s = sim - bs[:, None]
    if gain is not None:
        s = s * gain[:, None]
    total_s = float(s.sum())
    scale = float(r.sum()) / total_s if total_s > 0 else 0.0
    return r, s * scale, br, bs, scale


def hidden_metrics(r: np.ndarray, m: np.ndarray, t: np.ndarray) -> dict:
    """The metrics (module docstring) of floor-subtracted hidden transients ``r`` (measured) and ``m`` (the scaled
    model), both (P, K) on bin centres ``t`` (s).

    Returns:
        {rel_l2, edge_median (s), edge_spread (s), edge_points, map_corr, map_decorrelation, fwhm_real, fwhm_sim,
        fwhm_diff, decay_real, decay_sim, decay_diff} (NaN where undefined: no point to compare, a flat map).
    """
    rs, ms = r.sum(axis=0), m.sum(axis=0)
    norm = float(np.linalg.norm(rs))
    out = {"rel_l2": float(np.linalg.norm(ms - rs) / norm) if norm > 0 else float("nan")}
    rmap, mmap = r.sum(axis=1), m.sum(axis=1)
    seen = mmap >= EDGE_LEVEL * mmap.max() if mmap.max() > 0 else np.zeros(len(mmap), bool)
    d = leading_edges(m[seen], t) - leading_edges(r[seen], t) if seen.any() else np.array([])
    d = d[np.isfinite(d)]
    out["edge_points"] = int(d.size)
    out["edge_median"] = float(np.median(d)) if d.size else float("nan")
    out["edge_spread"] = float(0.5 * np.subtract(*np.percentile(d, [84, 16]))) if d.size > 1 else float("nan")
    corr = (float(np.corrcoef(rmap, mmap)[0, 1]) if rmap.std() > 0 and mmap.std() > 0 else float("nan"))
    out["map_corr"], out["map_decorrelation"] = corr, 1.0 - corr
    sm = _smooth(np.stack([rs, ms]), max(1, int(round(0.25 * EDGE_SMOOTHING / float(t[1] - t[0])))))
    out["fwhm_real"], out["fwhm_sim"] = fwhm(t, sm[0]), fwhm(t, sm[1])
    out["fwhm_diff"] = out["fwhm_sim"] - out["fwhm_real"]
    out["decay_real"], out["decay_sim"] = decay_time(t, sm[0]), decay_time(t, sm[1])
    out["decay_diff"] = out["decay_sim"] - out["decay_real"]
    out["peak_real"], out["peak_sim"] = peak_time(t, sm[0]), peak_time(t, sm[1])
    return out


def _on_bins(scan: np.ndarray, dt: float, target_dt: float, n: int) -> np.ndarray:
    """An aligned scan (ny, nx, M) of bin width ``dt`` rebinned onto ``n`` bins of ``target_dt`` from 0."""
    if np.isclose(dt, target_dt, rtol=1e-9):
        out = scan[..., :n]
        return np.concatenate([out, np.zeros(out.shape[:-1] + (n - out.shape[-1],))], axis=-1)
    flat = scan.reshape(-1, scan.shape[-1])
    res = rebin_envelope(flat, np.arange(scan.shape[-1] + 1) * dt, np.arange(n + 1) * target_dt)
    return res.reshape(scan.shape[:-1] + (n,))


def hidden_comparison(real: np.ndarray, real_edges: np.ndarray, real_offsets: np.ndarray | None,
                      sim: np.ndarray, sim_edges: np.ndarray, sim_offsets: np.ndarray | None, *,
                      sim_is_counts: bool, trim: float | Literal["auto"] = "auto",
                      gain: Literal["none", "direct"] | np.ndarray = "none", draws: int = FLOOR_DRAWS,
                      seed: int = 0) -> HiddenComparison:
    """Compare the hidden signal of a measured confocal scan with its simulation (module docstring).

    Args:
        real: (ny, nx, T) measured counts; sim: (ny, nx, T') simulated counts or expected envelope (any scale);
        *_edges: (T+1,) / (T'+1,) s, uniform; *_offsets: (ny, nx) s or None (:func:`align_confocal`).
        sim_is_counts: the simulation is a Poisson draw (its noise floor side is drawn too), not an expectation.
        trim: the direct light to exclude: "auto" (:func:`direct_light_bins` on ``real``) or a duration in s ≥ 0.
        gain: "none", "direct" (from the measured direct light) or an (ny, nx) map multiplying the simulation.
        draws: pairs of Poisson draws per noise floor (≥ 1); seed: their generator's seed.
    Returns:
        :class:`HiddenComparison`.
    Raises:
        ValueError: grids of different shapes, fewer than 8 hidden bins left, no hidden signal in either scan, a
            gain map of the wrong shape or not finite and ≥ 0.
    """
    r_al, dt = align_confocal(real, real_edges, real_offsets)
    s_al, sdt = align_confocal(sim, sim_edges, sim_offsets)
    if r_al.shape[:2] != s_al.shape[:2]:
        raise ValueError(f"the scans' grids differ: real {r_al.shape[:2]}, sim {s_al.shape[:2]}")
    n = min(r_al.shape[-1], int(np.floor(s_al.shape[-1] * sdt / dt + 1e-9)))
    r_al = r_al[..., :n]
    s_al = _on_bins(s_al, sdt, dt, n)
    how = "auto" if isinstance(trim, str) else "given"
    n_trim = direct_light_bins(r_al, dt) if how == "auto" else int(np.ceil(float(trim) / dt - 1e-9))
    if n - n_trim < 8:
        raise ValueError(f"{n - n_trim} bins left after the direct light ({n_trim * dt * 1e9:.4g} ns) of a "
                         f"{n * dt * 1e9:.4g} ns window; the hidden signal needs more")
    shape = r_al.shape[:2]
    real_h = r_al[..., n_trim:].reshape(-1, n - n_trim)
    sim_h = s_al[..., n_trim:].reshape(-1, n - n_trim)
    t = (n_trim + np.arange(n - n_trim) + 0.5) * dt
    width = max(1, int(round(EDGE_SMOOTHING / dt)))
    ss = _smooth(sim_h.sum(axis=0), width)
    signal = ss - ss.min()
    noise = 3.0 * np.sqrt(max(float(ss.min()), 1.0) / width) if sim_is_counts else 0.0   # a drawn simulation's
    floor_bins = (signal <= SIGNAL_FREE * signal.max() + noise if signal.max() > 0 else np.ones(len(ss), bool))
    if floor_bins.sum() < MIN_FLOOR_BINS:
        floor_bins = np.zeros(len(ss), bool)
        floor_bins[-max(1, len(ss) // 10):] = True
    exponent = gain_note = None
    if isinstance(gain, str) and gain == "direct":
        br = real_h[:, floor_bins].mean(axis=1)
        g, gain_how = None, "none (direct: REAL's direct light is not above its noise at half of its points)"
        if direct_light_seen(r_al, dt, br.reshape(shape), int(floor_bins.sum())):
            direct_gain, direct = gain_map(r_al, dt, br.reshape(shape))
            bs = sim_h[:, floor_bins].mean(axis=1)
            noise = net_noise(real_h, br, int(floor_bins.sum()))
            why: list[str] = []
            exponent = gain_exponent(direct, (real_h - br[:, None]).sum(axis=1), noise,
                                     model=(sim_h - bs[:, None]).sum(axis=1), notes=why)
            g, gain_how = hidden_gain(direct_gain, exponent).reshape(-1), "direct"
            gain_note = why[0] if why else None
    elif isinstance(gain, str):
        if gain != "none":
            raise ValueError(f"gain must be 'none', 'direct' or an (ny, nx) map, got {gain!r}")
        g, gain_how = None, "none"
    else:
        g = np.asarray(gain, dtype=np.float64)
        if g.shape != shape:
            raise ValueError(f"the gain map must have the scan's shape {shape}, got shape {g.shape}")
        bad = ~(np.isfinite(g) & (g >= 0))
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ValueError(f"the gain map must hold finite values >= 0; {int(bad.sum())} do not, the first at "
                             f"({i}, {j}): {float(g[i, j])}")
        g, gain_how = g.reshape(-1), "map"
    r, m, br, bs, scale = _prepare(real_h, sim_h, floor_bins, g)
    if not (r.sum() > 0 and scale > 0):
        raise ValueError("no hidden signal above the background: " + ("the measured scan" if not r.sum() > 0
                                                                      else "the simulation") + " has none after "
                         f"the direct light ({n_trim * dt * 1e9:.4g} ns)")
    out = HiddenComparison(hidden_metrics(r, m, t))
    rng = np.random.default_rng(seed)
    floors = {k: [] for k in METRICS}
    with np.errstate(divide="ignore", invalid="ignore"):           # a gain of 0 at a point: no light there
        sim_level = np.maximum(m / scale / (g[:, None] if g is not None else 1.0), 0.0)
    sim_level = np.nan_to_num(sim_level, nan=0.0, posinf=0.0)
    for _ in range(max(1, int(draws))):
        r_star = rng.poisson(np.maximum(m + br[:, None], 0.0)).astype(np.float64)
        s_mean = sim_level + np.maximum(bs, 0.0)[:, None]
        s_star = rng.poisson(s_mean).astype(np.float64) if sim_is_counts else s_mean
        r2, m2, *_ = _prepare(r_star, s_star, floor_bins, g)
        k = hidden_metrics(r2, m2, t)
        for name in METRICS:
            floors[name].append(abs(k[name]))
    out["floor"] = {k: float(np.nanmean(v)) if np.isfinite(v).any() else float("nan") for k, v in floors.items()}
    out.update({"trim_bins": int(n_trim), "trim": n_trim * dt, "trim_how": how, "floor_bins": int(floor_bins.sum()),
                "gain": gain_how, "gain_exponent": exponent, "gain_note": gain_note, "scale": scale,
                "counts_real": float(r.sum()), "counts_sim": float((sim_h - bs[:, None]).sum()),
                "t": t, "real_sum": r.sum(axis=0), "model_sum": m.sum(axis=0),
                "real_map": r.sum(axis=1).reshape(shape), "model_map": m.sum(axis=1).reshape(shape),
                "real": r.reshape(shape + (-1,)), "model": m.reshape(shape + (-1,)), "bin_width": dt,
                "t0": n_trim * dt, "gain_map": (g if g is not None else np.ones(len(real_h))).reshape(shape)})
    return out


def calibrated_gain(comparison: HiddenComparison) -> np.ndarray:
    """(ny, nx) float64, mean 1: the per-point gain that makes a simulation's hidden-count map the measured one, of a
    :func:`hidden_comparison` of a capture of a known target with its simulation: the gain it applied times the
    measured hidden counts over the (gained, scaled) simulated ones, each point's simulated counts taken at least
    :data:`GAIN_MODEL_FLOOR` of their mean, negative counts (below the floor) as 0, then divided by the mean. Given as
    ``gain`` to the comparison of another capture of the same scanner and grid (``compare-capture --gain FILE.npy``),
    it carries what varies per scan point with the scanner (laser power, focus, the detector's alignment with the
    laser spot), not with the scene, to that capture; the model's own errors on the known target come with it.

    Raises:
        ValueError: a comparison whose simulation has no hidden counts.
    """
    model = np.asarray(comparison["model_map"], dtype=np.float64)
    if not model.mean() > 0:
        raise ValueError("the simulation has no hidden counts to calibrate a gain against")
    ratio = np.maximum(comparison["real_map"], 0.0) / np.maximum(model, GAIN_MODEL_FLOOR * model.mean())
    gain = comparison["gain_map"] * ratio
    return gain / gain.mean() if gain.mean() > 0 else np.ones_like(gain)
