"""The stated error as a bound: the replicas' standard error raised to an upper confidence limit (docs/accuracy.md).

The replicas' standard error ε̂ (:mod:`datagen.simulation.replicas`) estimates the root-mean-square error ε of
their mean. It is right on average, but a single result's actual error scatters about ε, and so does ε̂ itself:
both are sums of squares over bins whose errors are correlated (over the IRF, the time smoothing of the deep
orders, and across channels that share hidden samples), so each has few *effective degrees of freedom*. For an
error vector of covariance C (over the error measure's bins) the effective dimension is d = (tr C)² / tr(C²)
(Satterthwaite), and with Gaussian errors

    ‖M − μ‖² / ε²  ~  χ²_d / d          (the actual error of the mean M)
    ε̂² / ε²        ~  χ²_ν / ν,  ν = (R − 1)·d      (R replicas; independent of the mean)

so actual² / ε̂² follows Fisher's F(d, ν), and k = √F_q(d, ν), F's q-quantile, makes k·ε̂ an upper bound of the
actual error with probability q. Several independent parts (orders 1–2 and the order ≥ 3 tracer, each over its
own replicas) combine with Satterthwaite's ν = (Σ V_i)² / Σ V_i²/ν_i, V_i the variance of part i's mean; their
covariances' overlap is bounded by Cauchy–Schwarz, tr(C_a C_b) ≤ √(tr C_a² tr C_b²), which can only lower d.

tr(C²) is read from the replicas without keeping them: per bin from the replicas' fourth-moment-free estimate
s_b⁴·(R − 1)/(R + 1) (unbiased for s_b⁴'s Gaussian mean), times the correlation in time, 1 + 2 Σ_l ρ(l)²,
ρ(l) the replicas' deviations' autocorrelation pooled over every bin and channel (summed up to its first
non-positive lag), times the correlation across channels, 1 + (n − 1)·ρ̄², ρ̄ the mean correlation between
channels (from the variance of the channel sum). The pooled autocorrelation needs no more than two replicas, so
the bound holds from the first round.
"""
from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.ndimage import uniform_filter1d

CONFIDENCE = 0.95
"""Default probability q with which the stated error bounds the actual one (``SimulationConfig.error.confidence``):
measured coverage in docs/accuracy.md ("What the stated error is, and how often it bounds")."""

SMOOTHING_WINDOWS = 4
"""Correlation lengths over which the per-bin variances are averaged before they are squared (:func:`part_dimensions`)."""

WINDOW_REACH = 3
"""The autocorrelation's squares are summed up to this multiple of its first non-positive lag."""

MIN_WINDOW = 8
"""Fewest bins in that average."""

FFT_BLOCK = 1 << 20
"""Values of padded rows transformed at once by :func:`power_spectrum` (16 MiB of spectrum)."""


def power_spectrum(x: np.ndarray) -> np.ndarray:
    """Σ_c |F x[c]|² of ``x`` (n_channels, n_bins), F the real FFT zero padded to 2·n_bins (no wrap-around): the
    transform of the autocorrelation pooled over channels (:func:`lags`); float64 (n_bins + 1,). Channels are
    transformed a block of about ``FFT_BLOCK`` values at a time, so a long axis or a large scan needs a few copies
    of one block, not of the whole array."""
    n = x.shape[-1]
    rows = x.reshape(-1, n)
    out = np.zeros(n + 1)
    step = max(1, FFT_BLOCK // (2 * n))
    for i in range(0, rows.shape[0], step):
        f = np.fft.rfft(rows[i:i + step], 2 * n, axis=-1)
        power = f.real ** 2
        power += f.imag ** 2
        out += power.sum(axis=0)
    return out


def lags(spectrum: np.ndarray) -> np.ndarray:
    """The pooled lag sums Σ_c Σ_b x[c, b]·x[c, b + l], l = 0 … n_bins − 1, of a :func:`power_spectrum` (n_bins + 1,)
    (or a sum or difference of them: the transform is linear); float64 (n_bins,)."""
    n = spectrum.size - 1
    return np.fft.irfft(spectrum, 2 * n)[:n]


def time_correlation(lag_cov: np.ndarray) -> float:
    """1 + 2 Σ_l ρ(l)² of the pooled lag covariances ``lag_cov`` (n_lags,), ρ(l) = lag_cov[l] / lag_cov[0],
    summed over l ≥ 1 up to the first non-positive ρ (the window beyond which a sample autocorrelation is noise);
    1 when the deviations have no energy."""
    if lag_cov.size == 0 or lag_cov[0] <= 0:
        return 1.0
    rho = lag_cov[1:] / lag_cov[0]
    stop = np.flatnonzero(rho <= 0)
    rho = rho[: WINDOW_REACH * stop[0]] if stop.size else rho
    return 1.0 + 2.0 * float(np.sum(np.minimum(np.abs(rho), 1.0) ** 2))


def part_dimensions(var_mean: np.ndarray, mask: np.ndarray, count: int, lag_cov: np.ndarray, channel_corr: float
                    ) -> tuple[float, float]:
    """(V, T) of one part: V = Σ_b var of the mean over the measured bins ``mask``, T an estimate of tr(C²) of the
    mean's covariance there (module docstring); ``var_mean`` (n_channels, n_bins) the per-bin variances of the mean,
    ``count`` R ≥ 2 replicas, ``lag_cov`` their deviations' pooled lag covariances, ``channel_corr`` the mean
    correlation between channels.

    Σ_b σ_b⁴ is read from the variances averaged over w = ``SMOOTHING_WINDOWS`` correlation lengths τ in time (the
    variance of one bin from two replicas is χ²₁-distributed: its square alone would be noise), less the noise that
    average keeps, a share 2τ / (w (R − 1)); the squared sum V² less its own noise, 2 T / (R − 1)."""
    tau = time_correlation(lag_cov)
    width = max(int(np.ceil(SMOOTHING_WINDOWS * tau)), MIN_WINDOW)
    smooth = uniform_filter1d(var_mean, width, axis=-1, mode="nearest") if width > 1 else var_mean
    fourth = float(np.sum(smooth[mask] ** 2)) / (1.0 + 2.0 * tau / (width * (count - 1)))
    n_channels = var_mean.shape[0]
    across = 1.0 + max(n_channels - 1, 0) * min(max(channel_corr, 0.0), 1.0) ** 2
    t = fourth * tau * across
    v = float(var_mean[mask].sum())
    return float(np.sqrt(max(v * v - 2.0 * t / (count - 1), 0.0))), t


def bound_factor(parts: list[tuple[float, float, int]], confidence: float) -> float:
    """k = √F_q(d, ν) (module docstring) of independent parts given as (V, T, R): V the variance of the part's mean
    summed over the measured bins, T its tr(C²), R its replicas (≥ 2); 1 when no part has variance.

    Raises:
        ValueError: ``confidence`` outside (0, 1).
    """
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    parts = [(v, t, r) for v, t, r in parts if v > 0 and t > 0]
    if not parts:
        return 1.0
    total = sum(v for v, _, _ in parts)
    d = total ** 2 / sum(np.sqrt(t) for _, t, _ in parts) ** 2          # Cauchy–Schwarz on the overlaps
    nu = total ** 2 / sum(t / (r - 1) for _, t, r in parts)           # Σ V_i²/ν_i, ν_i = (R_i − 1)·V_i²/T_i
    return float(np.sqrt(stats.f.ppf(confidence, d, nu)))
