"""How accurate a result is: independent replicas and the error estimate every result carries (docs/accuracy.md).

A Monte Carlo estimator's sampling (``area_samples``, the lookin grid) is split into R independent *replicas*
of the same setting, each drawn from its own random stream (:func:`replica_rng`: replica r of a run is
``SeedSequence(root, spawn_key=(r,))`` with ``root`` drawn once from the run's sampling stream, so replica r is
the same whatever else runs). The result is their mean M; since the replicas are independent and unbiased,
the variance of M in bin b is estimated by s_b² / R (s_b² the replicas' sample variance), and

    ε̂ = sqrt(Σ_b s_b² / R) / ‖M‖      over the bins b (of every channel) where M exceeds PEAK_FLOOR of its peak

estimates the RMS relative L2 error of M (raised to an upper confidence limit by :mod:`.confidence` where the
config asks for one) in the measure of :func:`datagen.analysis.relative_l2` (which compares
against a converged reference over the bins above 1 % of *its* peak). The estimate aggregates many bins, so
it is stable even for few replicas, and it sees every source of Monte Carlo noise (hidden samples, FoV
points, secondary partners); it cannot see a bias (there is none beyond the time binning's ~1e-5).

A deterministic estimator (the quadrature, error ∝ h^p) estimates its error from a coarser run instead:
‖E(h) − E(2h)‖ / (2^p − 1) (Richardson), added in quadrature to the replica spread of any Monte Carlo part.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..vectors import norm
from .confidence import bound_factor, lags, part_dimensions, power_spectrum

MIN_TOLERANCE = 1e-10
"""Smallest tolerance accepted: relative errors below it are float64 round-off in sums over many bins and
samples (machine epsilon 2.2e-16 times the terms summed), not something an estimate can measure or meet."""

PEAK_FLOOR = 0.01
"""Bins where the envelope exceeds this fraction of its peak enter the relative L2 (docs/accuracy.md)."""


FIRST_TRACER_REPLICAS = 2
"""Beside a deterministic estimator (the quadrature) the tracer's default paths run as this many replicas first;
the tolerance loop adds replicas of that size (:func:`datagen.simulation.tolerance.simulate_to_tolerance`)."""

def replica_root(rng: np.random.Generator) -> int:
    """The root seed of a run's replicas, drawn once from its sampling stream ``rng``."""
    return int(rng.integers(0, 2 ** 63))


def replica_rng(root: int, replica: int) -> np.random.Generator:
    """Generator of replica ``replica`` of a run: ``SeedSequence(root, spawn_key=(replica,))``."""
    return np.random.default_rng(np.random.SeedSequence(root, spawn_key=(int(replica),)))


def relative_standard_error(mean: np.ndarray, var_mean: np.ndarray) -> float:
    """sqrt(Σ var_mean) / ‖mean‖ over the bins where ``mean`` exceeds ``PEAK_FLOOR`` of its peak (arrays
    (..., n_bins) alike); 0 for an all-zero mean."""
    peak = float(mean.max()) if mean.size else 0.0
    if peak <= 0:
        return 0.0
    mask = mean > PEAK_FLOOR * peak
    return float(np.sqrt(np.maximum(var_mean[mask], 0.0).sum()) / norm(mean[mask]))


def _measured_bins(scale: np.ndarray) -> np.ndarray | None:
    """The bins where ``scale`` exceeds ``PEAK_FLOOR`` of its peak (the error measure's), or None if it is zero."""
    peak = float(scale.max()) if scale.size else 0.0
    return scale > PEAK_FLOOR * peak if peak > 0 else None


def relative_difference(a: np.ndarray, b: np.ndarray, scale: np.ndarray) -> float:
    """‖a − b‖ / ‖scale‖ over the bins where ``scale`` exceeds ``PEAK_FLOOR`` of its peak (0 if it is zero)."""
    mask = _measured_bins(scale)
    if mask is None:
        return 0.0
    return float(norm((a - b)[mask]) / norm(scale[mask]))


def relative_cross(a: np.ndarray, b: np.ndarray, scale: np.ndarray) -> float:
    """√(max(Σ a·b, 0) + √(Σ a²b²)) / ‖scale‖ over the bins of :func:`relative_difference`: for two estimates a, b of
    one quantity with independent noise, the norm of that quantity without their noise (E[Σ a·b] = Σ E[a]·E[b]),
    raised by one standard error of the sum (√(Σ a²b²) for independent noise), so that a quantity hidden in the noise
    is not read as zero: where the halves disagree by more than they share (Σ a·b < 0, often with one run per half)
    the reading is that standard error, the size of what the noise can hide."""
    mask = _measured_bins(scale)
    if mask is None:
        return 0.0
    x, y = a[mask], b[mask]
    product = max(float(np.dot(x, y)), 0.0) + float(np.sqrt(np.dot(x * x, y * y)))
    return float(np.sqrt(product) / norm(scale[mask]))


@dataclass
class ReplicaSums:
    """Running sums of the replicas' envelopes: what the error estimate needs, independent of R in size.

    The sums are kept in units of ``scale``, a power of two near the first non-zero replica's peak, so that the
    squares neither underflow nor overflow at extreme fluxes (Φ = 1e-200 photons per pulse gives bins of ~1e-209,
    whose squares are 0 in float64); a power of two makes the scaling exact, so the mean is the same bits as an
    unscaled sum.

    Attributes:
        envelope: (n_channels, n_bins) Σ_r of each replica's envelope (summed over components) / ``scale``.
        envelope_sq: (n_channels, n_bins) Σ_r of its square, in ``scale``² units.
        count: R, replicas added.
        scale: photons per pulse per unit of the sums (0 until a replica with energy arrives).
        exact: the envelope comes from a deterministic estimator run once (the quadrature beside the tracer): its
            variance is 0, not unknown.
        spectrum: (n_bins + 1,) Σ_r of each replica's power spectrum pooled over channels
            (:func:`~datagen.simulation.confidence.power_spectrum`), in ``scale``² units: the transform of their lag
            sums, whose correlation in time the stated error's confidence factor reads
            (:mod:`datagen.simulation.confidence`); summed in the frequency domain, transformed back once per reading
            (empty without channels: a tracer that does not run).
        channel_sq: (n_bins,) Σ_r of the square of each replica's channel sum, in ``scale``² units: the correlation
            across channels (empty for one channel).
    """

    envelope: np.ndarray
    envelope_sq: np.ndarray
    spectrum: np.ndarray
    channel_sq: np.ndarray
    count: int = 0
    scale: float = 0.0
    exact: bool = False

    @classmethod
    def zeros(cls, n_channels: int, n_bins: int) -> ReplicaSums:
        return cls(np.zeros((n_channels, n_bins)), np.zeros((n_channels, n_bins)),
                   np.zeros(n_bins + 1 if n_channels else 0), np.zeros(n_bins if n_channels > 1 else 0))

    def add(self, envelope: np.ndarray) -> None:
        """Add one replica's envelope (n_channels, n_bins)."""
        if self.scale == 0.0:
            peak = float(np.abs(envelope).max()) if envelope.size else 0.0
            if peak > 0 and np.isfinite(peak):
                self.scale = float(2.0 ** np.round(np.log2(peak)))
        scaled = envelope / self.scale if self.scale else envelope
        self.envelope += scaled
        self.envelope_sq += scaled ** 2
        if scaled.size:
            self.spectrum += power_spectrum(scaled)
            if self.channel_sq.size:
                self.channel_sq += scaled.sum(axis=0) ** 2
        self.count += 1

    def mean(self) -> np.ndarray:
        """(n_channels, n_bins) mean envelope of the replicas, photons per pulse."""
        return self.envelope / max(self.count, 1) * (self.scale or 1.0)

    def error(self, confidence: float | None = None) -> float:
        """ε̂, the relative standard error of the mean envelope (module docstring), raised to its upper
        ``confidence`` limit when that is given (:func:`combined_error`); inf for fewer than 2 replicas (unless the
        envelope is zero: then 0)."""
        return combined_error([self], confidence)

    def dimensions(self, var_mean: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
        """(V, T) of :func:`~datagen.simulation.confidence.part_dimensions` for this part, from its variance of the
        mean per bin ``var_mean`` (in any unit: V and T come in it) and the measured bins ``mask``; the correlations
        are read from the sums (unitless); needs ≥ 2 replicas."""
        r = self.count
        mean = self.envelope / r
        lag_cov = lags(self.spectrum - r * power_spectrum(mean)) / (r - 1)
        n_channels = mean.shape[0]
        channel_corr = 0.0
        if n_channels > 1:
            per_channel = float((self.envelope_sq - r * mean ** 2).sum())
            of_sum = float((self.channel_sq - r * mean.sum(axis=0) ** 2).sum())
            if per_channel > 0:
                channel_corr = (of_sum / per_channel - 1.0) / (n_channels - 1)
        return part_dimensions(var_mean, mask, r, lag_cov, channel_corr)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance of the mean) per bin, (n_channels, n_bins) each, in units of ``scale`` (its square for
        the variance); the variance is inf for fewer than 2 replicas."""
        mean = self.envelope / max(self.count, 1)
        if self.exact:
            return mean, np.zeros_like(mean)
        if self.count < 2:
            return mean, np.full_like(mean, np.inf)
        return mean, np.maximum(self.envelope_sq / self.count - mean ** 2, 0.0) / (self.count - 1)


def _moments_in_common_units(parts: list[ReplicaSums]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each part's (mean, variance of the mean) per bin in one unit, the first non-zero ``scale`` (each part keeps
    its own; a power of two, so the conversion is exact)."""
    ref = next((p.scale for p in parts if p.scale), 1.0)
    out = []
    for p in parts:
        m, v = p.moments()
        k = (p.scale or 1.0) / ref
        out.append((m, v) if k == 1.0 else (m * k, v * (k * k)))
    return out


def combined_error(parts: list[ReplicaSums], confidence: float | None = None) -> float:
    """ε̂ of the sum of independent means, each over its own replicas (orders 1–2 and the order ≥ 3 tracer run
    different numbers of replicas): sqrt(Σ_b Σ_i var_i,b) / ‖Σ_i mean_i‖ over the bins above ``PEAK_FLOOR`` of the
    summed mean's peak (module docstring); with a ``confidence`` q, that times the factor k ≥ 1 that makes it an
    upper bound of the actual error with probability q (:func:`~datagen.simulation.confidence.bound_factor`).
    inf while a part with energy has fewer than 2 replicas, 0 for an all-zero mean."""
    mean, var, used = None, None, []
    for p, (m, v) in zip(parts, _moments_in_common_units(parts)):
        if p.count < 2 and not p.exact:
            if m.any():
                return float("inf")
            continue                                                 # no energy: adds nothing
        mean = m if mean is None else mean + m
        var = v if var is None else var + v
        used.append((p, v))
    if mean is None:
        return 0.0
    error = relative_standard_error(mean, var)
    if confidence is None or error == 0.0:
        return error
    mask = _measured_bins(mean)
    noisy = [(*p.dimensions(v, mask), p.count) for p, v in used if not p.exact]
    return error * bound_factor(noisy, confidence)


def neyman_split(base: ReplicaSums, tracer: ReplicaSums, base_cost: float, tracer_cost: float
                 ) -> tuple[float, float, float] | None:
    """The split of the work between two independent estimators of one sum (orders 1–2 and the order ≥ 3 tracer):
    (v_b, v_t, ρ) with v the relative variance of one replica of each (summed over the error's bins, over the summed
    mean's norm squared) and ρ = R_t/R_b = sqrt(v_t c_b / (v_b c_t)), the ratio that meets an error target in the
    least work (Neyman allocation: ε² = v_b/R_b + v_t/R_t at cost c_b R_b + c_t R_t), c the nominal seconds per
    replica (counted work: the split depends on the seed, never on the machine). None while either has fewer than 2
    replicas, a cost is unknown or the base has no spread."""
    if base.count < 2 or tracer.count < 2 or base_cost <= 0 or tracer_cost <= 0:
        return None
    (mb, vb), (mt, vt) = _moments_in_common_units([base, tracer])
    mean = mb + mt
    peak = float(mean.max())
    if peak <= 0:
        return None
    mask = mean > PEAK_FLOOR * peak
    norm2 = float(np.sum(mean[mask] ** 2))
    v_b = float(vb[mask].sum()) * base.count / norm2
    v_t = float(vt[mask].sum()) * tracer.count / norm2
    if v_b <= 0:
        return None
    return v_b, v_t, float(np.sqrt(v_t * base_cost / (v_b * tracer_cost)))


TRACER_MAX_RATIO = 64
"""Most replicas of the order ≥ 3 tracer per replica of orders 1–2."""


def tracer_replicas_wanted(base: ReplicaSums, tracer: ReplicaSums, base_cost: float, tracer_cost: float,
                           base_count: int | None = None) -> int:
    """How many tracer replicas go with ``base_count`` (default ``base.count``) replicas of orders 1–2: ρ·R_b
    (:func:`neyman_split`), never fewer than already run nor than 2, at most :data:`TRACER_MAX_RATIO` per base
    replica; as many as the base while the split is unknown."""
    r_b = base.count if base_count is None else int(base_count)
    split = neyman_split(base, tracer, base_cost, tracer_cost)
    if split is None:
        return max(tracer.count, r_b)
    wanted = int(np.ceil(split[2] * r_b))
    return int(min(max(wanted, tracer.count, 2), TRACER_MAX_RATIO * r_b))


def whole_split(v_b: float, v_t: float, base_cost: float, tracer_cost: float, base_count: int, tracer_count: int,
                variance: float) -> tuple[int, int] | None:
    """The replica counts (R_b, R_t) of orders 1–2 and of the tracer, at least those already run, of least cost
    c_b R_b + c_t R_t with v_b/R_b + v_t/R_t ≤ ``variance`` (relative variances of one replica, :func:`neyman_split`).

    The Neyman split rounded as a whole: rounding each count up on its own costs a whole tracer replica where a few
    more of the cheaper replicas of orders 1–2 would carry the difference (two tracer replicas needing 2.3 go to
    three: 50 % more of the tracer for 15 %). Every tracer count from the one run up to the rounded-up Neyman count
    (and two beyond) is tried with the fewest base replicas it allows. None when ``variance`` or a variance or cost is not > 0."""
    if min(v_b, v_t, base_cost, tracer_cost, variance) <= 0:
        return None
    rho = float(np.sqrt(v_t * base_cost / (v_b * tracer_cost)))
    neyman_t = int(np.ceil(rho * (v_b + v_t / rho) / variance))
    best = None
    for r_t in range(max(tracer_count, 2), max(neyman_t, tracer_count, 2) + 3):
        rest = variance - v_t / r_t
        if rest <= 0:
            continue
        r_b = max(base_count, int(np.ceil(v_b / rest * (1 - 1e-12))))    # (not one more for round-off)
        cost = base_cost * r_b + tracer_cost * r_t
        if best is None or cost < best[0]:
            best = (cost, r_b, r_t)
    return None if best is None else (best[1], best[2])
