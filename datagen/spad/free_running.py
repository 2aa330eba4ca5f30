"""SPAD / TCSPC detector models: from an expected photon envelope to time-tagged histograms.

Notation (DESIGN.md §6).  For one laser cycle and TDC bin ``i`` the detector sees ``r_i`` expected
*avalanches* (signal already thinned by the PDE, plus PDE·ambient and dark counts, all before pile-up);
``C_i = Σ_{j<i} r_j`` is the exclusive cumulative sum and ``Λ = Σ_i r_i``.  Everywhere in this module

* ``rates`` is a float64 array of shape ``(..., bins)``: expected avalanches per laser cycle per bin.  Any
  leading axes are pixels and every function broadcasts over them.  float32 input is accepted and
  converted to float64 before any arithmetic.
* counts are int64 (float32 cannot count past 2**24); expected histograms are float64.
* time is in seconds and rates in Hz; configuration files may write ``"50ns"`` or ``"20MHz"``.

Histogram models (``DetectorConfig.model``):

``"poisson"``
    Independent Poisson counts ``N_i ~ Poisson(n·r_i)``.  Valid at low flux (Λ ≪ 1) or for detectors
    without dead time.  DESIGN.md §6, first bullet.  Above 1e12 expected counts a bin is drawn from the
    normal approximation (``POISSON_NORMAL_ABOVE``); a bin expecting more than int64 can count (9e18) is an
    error naming the flux.
``"pile_up"`` (default)
    Synchronous TCSPC, one stop per cycle, detector re-armed every cycle (first-photon model, Coates
    1968): ``P(first detection in bin i) = e^{-C_i}(1-e^{-r_i})``; ``n`` cycles give a multinomial.
``"multi_stop"``
    Multi-stop TDC reset every cycle; after a detection the SPAD is dead for ``d = round(τ/Δ)`` bins and
    then re-armed within the same cycle.  Exact recursion on the discrete-bin model (no product
    approximation).
``"free_running"``
    Free-running SPAD whose dead time crosses cycle boundaries (time-tagging TCSPC).  Exact
    continuous-time event simulation for samples; the expected histogram is the stationary distribution
    of the Markov chain on the detection phase (Rapp, Ma, Dawson & Goyal, "Dead time compensation for
    high-flux ranging", IEEE Trans. Signal Process. 67(13), 2019), or a closed form for a paralyzable dead
    time.

Timing order (DESIGN.md §6): the laser pulse shape (already in the transport envelope) and the SPAD
diffusion tail act *before* pile-up (they change which photon comes first); the Gaussian
avalanche/electronic/TDC jitter acts *after* pile-up (it moves the recorded time stamp of the photon that
already won).  At low flux the two orders agree; at high flux they do not (see :func:`apply_jitter_before`).
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from scipy import special, stats

from ..units import parse_duration

__all__ = [
    "DetectorConfig",
    "rates_from_envelope",
    "detection_pmf",
    "expected_histogram",
    "sample_histogram",
    "coates",
    "gate_fraction",
    "rebin_envelope",
    "gaussian_kernel",
    "exponential_kernel",
    "apply_jitter_before",
    "apply_jitter_after",
    "instrument_response",
    "counter_rate",
    "counter_variance",
    "sample_counter",
    "free_running_rate",
    "FWHM_PER_SIGMA",
]

# --------------------------------------------------------------------------------------------------
# Named numerical constants
# --------------------------------------------------------------------------------------------------
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
"""FWHM of a Gaussian divided by its standard deviation (≈ 2.3548)."""

NEGATIVE_ENVELOPE_RTOL = 1e-9
"""Envelope values down to ``-NEGATIVE_ENVELOPE_RTOL × max|envelope|`` (per pixel) are FFT round-off and are
clamped to 0; anything more negative is an error."""

EXP_BLOCK_LIMIT = 600.0
"""Largest exponent used inside a block of :func:`_decayed_cumsum` (e^600 ≈ 1e260 < float64 max)."""

GAUSS_TAIL_SIGMAS = 9.0
"""Gaussian kernels are truncated at ±9σ (lost mass < 1e-18) and renormalised."""

EXP_TAIL_LENGTHS = 45.0
"""Exponential kernels are truncated after 45 time constants (lost mass < 3e-20) and renormalised."""

MAX_KERNEL_TAPS = 1_000_001
"""Refuse kernels longer than this (a jitter larger than ~ the whole histogram is a configuration error)."""

DIRECT_CONVOLUTION_TAPS = 64
"""Kernels up to this length are applied by exact shift-and-add (no FFT round-off); longer ones by FFT."""

MARKOV_MAX_STATES = 60_000
"""Cap on the number of phase cells of the free-running Markov chain (per pixel)."""

MARKOV_CELL_HAZARD = 0.02
"""Automatic oversampling keeps the expected avalanches per Markov cell below this."""

MARKOV_TOL = 1e-13
"""L1 convergence tolerance of the stationary distribution of the free-running chain."""

MARKOV_MAX_ITER = 20_000
"""Power iterations before falling back to ARPACK for a slowly mixing free-running chain."""

SAMPLER_PIXEL_CHUNK = 512
"""Pixels per independent random stream in the threaded samplers.  Fixed, so results do not depend on the
number of worker threads."""

EVENT_FLUSH = 4_000_000
"""Detections buffered by the event simulator before they are binned."""

POISSON_NORMAL_ABOVE = 1e12
"""Expected counts λ of a bin above which the ``poisson`` model draws round(N(λ, λ)), clipped at 0, instead of
``rng.poisson(λ)``. numpy's Poisson sampler (2.x) refuses λ ≳ 9.2e18 and is already wrong well below that: with
10⁶ draws its variance is off by +1.7 % at λ = 3e13 (12 standard errors), +4 % at 1e15 and +40–60 % at 1e16–1e17,
while it matches λ to 0.1 % up to 1e13. At λ ≥ 1e12 the normal approximation differs from Poisson(λ) by at most
≈ the Edgeworth skewness term 1/(6√λ) ≤ 1.7e-7 in the CDF; rounding shifts the mean by < 0.5 count and adds 1/12
to the variance (≤ 1e-12 relative): far below the relative noise 1/√λ ≤ 1e-6 itself."""

MAX_EXPECTED_COUNTS = 9.0e18
"""Largest expected counts n·r_i of one bin the ``poisson`` model accepts: counts are int64 (max 9.22e18); the
margin covers fluctuations (10σ = 3e10). Jitter after pile-up keeps a bin's expectation ≤ the largest one (its
kernel sums to 1), so it cannot overflow either."""


# --------------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------------
_RATE_UNITS = {"hz": 1.0, "khz": 1e3, "mhz": 1e6, "ghz": 1e9, "cps": 1.0, "kcps": 1e3, "mcps": 1e6}
ModelName = Literal["poisson", "pile_up", "multi_stop", "free_running"]
DeadTimeKind = Literal["none", "synchronous", "free_running"]
_KIND_OF_MODEL: dict[str, str] = {
    "poisson": "none",
    "pile_up": "synchronous",
    "multi_stop": "synchronous",
    "free_running": "free_running",
}


def _parse_rate(value: Any) -> float:
    """Hz from a number or a string such as ``"20MHz"``, ``"100cps"``."""
    if isinstance(value, bool):
        raise ValueError(f"expected a rate in Hz, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    text = str(value).strip()
    number = text.rstrip("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ").strip()
    unit = text[len(number):].strip().lower() if number else ""
    try:
        magnitude = float(number)
    except ValueError:
        raise ValueError(f"cannot read {value!r} as a rate; write e.g. '20MHz' or a number in Hz") from None
    if unit == "":
        return magnitude
    if unit not in _RATE_UNITS:
        raise ValueError(f"unknown rate unit {unit!r} in {value!r}; known: Hz, kHz, MHz, GHz, cps, kcps, Mcps")
    return magnitude * _RATE_UNITS[unit]


def _duration(value: Any) -> Any:
    if value is None or isinstance(value, (list, tuple)):
        return value
    return parse_duration(value)


class DetectorConfig(BaseModel):
    """SPAD/TCSPC detector description (SI units; durations may be strings such as ``"50ns"``, rates such
    as ``"20MHz"``).  Immutable.

    Fields:
        pde: photon detection efficiency in [0, 1].  Only used to thin ``ambient_rate``: the transport
            envelope already contains the PDE (DESIGN.md §2).
        dcr: dark count rate in Hz (≥ 0).
        ambient_rate: ambient photons arriving at the detector per second, before the PDE (≥ 0).
        repetition_rate: laser repetition rate in Hz (> 0); the period is ``1/repetition_rate``.
        exposure / n_cycles: exposure time in s, or number of laser cycles.  Exactly one is given;
            :attr:`cycles` resolves ``n_cycles = round(exposure·repetition_rate)``.
        bin_width: nominal TDC bin width in s (> 0).
        bin_widths: optional true per-bin widths in s (TDC differential non-linearity); fixes the number of
            bins.  Background per bin and the gate use these widths; jitter kernels use ``bin_width``.
        t_start: time of the left edge of bin 0 within the laser cycle, s (default 0).
        gate: optional ``[start, stop]`` in s (same clock as ``t_start``): the SPAD is armed only inside;
            all avalanches (signal, ambient, dark, afterpulses) outside are suppressed.
        dead_time: SPAD dead time τ in s (default 0).
        dead_time_kind: ``"none" | "synchronous" | "free_running"``.  Derived from ``model`` when omitted
            (poisson → none, pile_up/multi_stop → synchronous, free_running → free_running); an
            inconsistent explicit value is an error.
        paralyzable: paralyzable dead time (arrivals during the dead time extend it).  Only with
            ``model="free_running"`` (and for the counter functions).
        afterpulse_probability: probability that an avalanche is followed by an afterpulse, in [0, 1).
        afterpulse_time_constant: afterpulses occur at ``t + dead_time + Exp(afterpulse_time_constant)``.
        crosstalk_probability: probability that an avalanche triggers a prompt avalanche in one of its
            4-neighbours (chosen uniformly among those inside the array), in [0, 1).
        jitter_sigma / jitter_fwhm: Gaussian avalanche + electronic + TDC jitter, applied AFTER pile-up.
            At most one is given.
        diffusion_tail: exponential time constant (s) of the SPAD diffusion tail, applied BEFORE pile-up.
        diffusion_fraction: fraction of detections in the diffusion tail (default 1: the low-flux IRF is
            the ex-Gaussian ``exponnorm``; < 1 gives a Gaussian core plus a tail).
        model: ``"poisson" | "pile_up" | "multi_stop" | "free_running"`` (see the module docstring).
        markov_oversample: cells per TDC bin of the free-running Markov chain (default: automatic).

    Raises:
        pydantic.ValidationError (a ValueError): unknown field, bad value or inconsistent combination;
            the message names the field and the value.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    pde: float = Field(1.0, ge=0.0, le=1.0)
    dcr: float = Field(0.0, ge=0.0)
    ambient_rate: float = Field(0.0, ge=0.0)
    repetition_rate: float = Field(gt=0.0)
    exposure: float | None = Field(None, gt=0.0)
    n_cycles: int | None = Field(None, ge=1)
    bin_width: float = Field(gt=0.0)
    bin_widths: tuple[float, ...] | None = None
    t_start: float = Field(0.0, ge=0.0)
    gate: tuple[float, float] | None = None
    dead_time: float = Field(0.0, ge=0.0)
    dead_time_kind: DeadTimeKind | None = None
    paralyzable: bool = False
    afterpulse_probability: float = Field(0.0, ge=0.0, lt=1.0)
    afterpulse_time_constant: float = Field(0.0, ge=0.0)
    crosstalk_probability: float = Field(0.0, ge=0.0, lt=1.0)
    jitter_sigma: float | None = Field(None, ge=0.0)
    jitter_fwhm: float | None = Field(None, ge=0.0)
    diffusion_tail: float = Field(0.0, ge=0.0)
    diffusion_fraction: float = Field(1.0, ge=0.0, le=1.0)
    model: ModelName = "pile_up"
    markov_oversample: int | None = Field(None, ge=1)

    # ---- parsing at the boundary ------------------------------------------------------------------
    @field_validator("exposure", "bin_width", "t_start", "dead_time", "afterpulse_time_constant",
                     "jitter_sigma", "jitter_fwhm", "diffusion_tail", mode="before")
    @classmethod
    def _parse_durations(cls, value: Any) -> Any:
        return _duration(value)

    @field_validator("bin_widths", "gate", mode="before")
    @classmethod
    def _parse_duration_lists(cls, value: Any) -> Any:
        if value is None:
            return None
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise ValueError(f"expected a list of durations, got {value!r}")
        return [parse_duration(v) for v in value]

    @field_validator("dcr", "ambient_rate", "repetition_rate", mode="before")
    @classmethod
    def _parse_rates(cls, value: Any) -> Any:
        return _parse_rate(value)

    @field_validator("n_cycles", mode="before")
    @classmethod
    def _parse_cycles(cls, value: Any) -> Any:
        if value is None or isinstance(value, bool):
            return value
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise ValueError(f"n_cycles must be an integer, got {value!r}") from None
        if isinstance(value, float):
            if not math.isfinite(value) or value != round(value):
                raise ValueError(f"n_cycles must be an integer, got {value!r}")
            return int(round(value))
        return value

    @field_validator("bin_widths")
    @classmethod
    def _check_widths(cls, value: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if value is not None:
            if len(value) == 0:
                raise ValueError("bin_widths must not be empty")
            bad = [w for w in value if not (math.isfinite(w) and w > 0)]
            if bad:
                raise ValueError(f"bin_widths must be finite and > 0, got {bad[0]!r}")
        return value

    @model_validator(mode="after")
    def _check_consistency(self) -> "DetectorConfig":
        if (self.exposure is None) == (self.n_cycles is None):
            raise ValueError(f"give exactly one of exposure or n_cycles (got exposure={self.exposure!r}, "
                             f"n_cycles={self.n_cycles!r})")
        if self.exposure is not None and round(self.exposure * self.repetition_rate) < 1:
            raise ValueError(f"exposure={self.exposure!r} s at repetition_rate={self.repetition_rate!r} Hz is "
                             "less than one laser cycle")
        if self.jitter_sigma is not None and self.jitter_fwhm is not None:
            raise ValueError(f"give at most one of jitter_sigma={self.jitter_sigma!r} and "
                             f"jitter_fwhm={self.jitter_fwhm!r}")
        if self.gate is not None:
            if len(self.gate) != 2 or not self.gate[0] < self.gate[1]:
                raise ValueError(f"gate must be [start, stop] with start < stop, got {list(self.gate)!r}")
        if self.t_start >= self.period:
            raise ValueError(f"t_start={self.t_start!r} s must be inside the laser period {self.period!r} s")
        expected_kind = _KIND_OF_MODEL[self.model]
        if self.dead_time_kind is not None and self.dead_time_kind != expected_kind:
            raise ValueError(f"dead_time_kind={self.dead_time_kind!r} is inconsistent with model={self.model!r} "
                             f"(which implies {expected_kind!r})")
        if self.paralyzable and self.model != "free_running":
            raise ValueError(f"paralyzable=True is only modelled for model='free_running', got model={self.model!r}")
        if self.afterpulse_probability > 0:
            if self.model != "free_running" or self.paralyzable:
                raise ValueError(f"afterpulse_probability={self.afterpulse_probability!r} needs "
                                 f"model='free_running' with a non-paralyzable dead time (got model={self.model!r}, "
                                 f"paralyzable={self.paralyzable!r})")
        if self.crosstalk_probability > 0 and self.model != "pile_up":
            raise ValueError(f"crosstalk_probability={self.crosstalk_probability!r} is only simulated for "
                             f"model='pile_up', got model={self.model!r}")
        return self

    # ---- derived quantities -----------------------------------------------------------------------
    @property
    def cycles(self) -> int:
        """Number of laser cycles in the exposure (``n_cycles`` or ``round(exposure·repetition_rate)``)."""
        if self.n_cycles is not None:
            return int(self.n_cycles)
        return int(round(self.exposure * self.repetition_rate))

    @property
    def period(self) -> float:
        """Laser period in s."""
        return 1.0 / self.repetition_rate

    @property
    def resolved_dead_time_kind(self) -> str:
        """``dead_time_kind``, derived from ``model`` when it was not given."""
        return self.dead_time_kind or _KIND_OF_MODEL[self.model]

    @property
    def jitter(self) -> float:
        """Gaussian after-pile-up jitter σ in s (0 when none is configured)."""
        if self.jitter_sigma is not None:
            return float(self.jitter_sigma)
        if self.jitter_fwhm is not None:
            return float(self.jitter_fwhm) / FWHM_PER_SIGMA
        return 0.0

    @property
    def background_rate(self) -> float:
        """Background avalanches per second before pile-up: ``pde·ambient_rate + dcr``."""
        return self.pde * self.ambient_rate + self.dcr

    def widths(self, n_bins: int) -> np.ndarray:
        """True bin widths in s, float64 shape (n_bins,).  Raises ValueError if ``bin_widths`` has another length."""
        if self.bin_widths is not None:
            if len(self.bin_widths) != n_bins:
                raise ValueError(f"bin_widths has {len(self.bin_widths)} entries but the data have {n_bins} bins")
            return np.asarray(self.bin_widths, dtype=np.float64)
        return np.full(n_bins, self.bin_width, dtype=np.float64)

    def bin_edges(self, n_bins: int) -> np.ndarray:
        """Bin edges within the laser cycle in s, float64 shape (n_bins + 1,), starting at ``t_start``."""
        edges = np.empty(n_bins + 1, dtype=np.float64)
        edges[0] = self.t_start
        np.cumsum(self.widths(n_bins), out=edges[1:])
        edges[1:] += self.t_start
        return edges

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> "DetectorConfig":
        """Read a preset such as ``configs/detectors/cmos_spad_array.yaml``.

        The file holds a mapping of the fields above (optionally under a top-level ``detector:`` key).

        Raises:
            ValueError: the file cannot be read or parsed, or a field is unknown or invalid; the message
                names the file, the field and the offending value.
        """
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise ValueError(f"{path}: cannot read detector config: {exc}") from exc
        if isinstance(data, dict) and set(data) == {"detector"}:
            data = data["detector"]
        if not isinstance(data, dict):
            raise ValueError(f"{path}: expected a mapping of detector fields, got {type(data).__name__}")
        try:
            return cls(**data)
        except ValidationError as exc:
            problems = []
            for err in exc.errors():
                field = ".".join(str(p) for p in err["loc"]) or "(config)"
                problems.append(f"field {field!r}: {err['msg']} (value: {err.get('input')!r})")
            raise ValueError(f"{path}: invalid detector config: " + "; ".join(problems)) from None


# --------------------------------------------------------------------------------------------------
# Input checking helpers
# --------------------------------------------------------------------------------------------------
def _as_rates(rates: Any, name: str = "rates") -> np.ndarray:
    """float64 copy-if-needed of ``rates`` (..., bins); ValueError for NaN/inf/negative/0-d/empty."""
    r = np.asarray(rates, dtype=np.float64)
    if r.ndim == 0 or r.shape[-1] == 0:
        raise ValueError(f"{name} must have shape (..., bins) with bins >= 1, got shape {r.shape}")
    if not np.all(np.isfinite(r)):
        bad = np.argwhere(~np.isfinite(r))[0]
        raise ValueError(f"{name} contains a non-finite value {r[tuple(bad)]!r} at index {tuple(int(b) for b in bad)}")
    if np.any(r < 0):
        bad = np.argwhere(r < 0)[0]
        raise ValueError(f"{name} must be >= 0; found {r[tuple(bad)]!r} at index {tuple(int(b) for b in bad)}")
    return r


def _clamp_envelope(envelope: Any) -> np.ndarray:
    e = np.array(envelope, dtype=np.float64)  # copy: we clamp in place
    if e.ndim == 0 or e.shape[-1] == 0:
        raise ValueError(f"envelope must have shape (..., bins) with bins >= 1, got shape {e.shape}")
    if not np.all(np.isfinite(e)):
        bad = np.argwhere(~np.isfinite(e))[0]
        raise ValueError(f"envelope contains a non-finite value {e[tuple(bad)]!r} at index "
                         f"{tuple(int(b) for b in bad)}")
    scale = np.max(np.abs(e), axis=-1, keepdims=True)
    too_negative = e < -NEGATIVE_ENVELOPE_RTOL * scale
    if np.any(too_negative):
        bad = np.argwhere(too_negative)[0]
        raise ValueError(f"envelope has a clearly negative value {e[tuple(bad)]!r} at index "
                         f"{tuple(int(b) for b in bad)} (more than {NEGATIVE_ENVELOPE_RTOL:g} of that pixel's "
                         "maximum; only FFT round-off is clamped)")
    np.maximum(e, 0.0, out=e)
    return e


def _check_cycles(n_cycles: Any) -> int:
    n = int(n_cycles)
    if n != n_cycles or n < 1:
        raise ValueError(f"n_cycles must be a positive integer, got {n_cycles!r}")
    return n


def _child_generators(rng: np.random.Generator, count: int) -> list[np.random.Generator]:
    """``count`` independent generators derived deterministically from ``rng`` (advances ``rng``)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    entropy = rng.integers(0, 2**63, size=4, dtype=np.int64)
    seeds = np.random.SeedSequence([int(x) for x in entropy]).spawn(count)
    return [np.random.Generator(type(rng.bit_generator)(s)) for s in seeds]


def _workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def _run_chunked(func, arrays: list[np.ndarray], rng: np.random.Generator) -> list:
    """Apply ``func(gen, *chunk_arrays)`` to fixed pixel chunks of 2-D ``arrays`` with one random stream per
    chunk, in threads (numpy's samplers release the GIL).  Deterministic whatever the thread count."""
    n_pix = arrays[0].shape[0]
    bounds = list(range(0, n_pix, SAMPLER_PIXEL_CHUNK)) + [n_pix] if n_pix else [0, 0]
    gens = _child_generators(rng, len(bounds) - 1)
    jobs = [(gens[k], *[a[bounds[k]:bounds[k + 1]] for a in arrays]) for k in range(len(bounds) - 1)]
    workers = min(_workers(), len(jobs))
    if workers <= 1:
        return [func(*job) for job in jobs]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(lambda job: func(*job), jobs))


# --------------------------------------------------------------------------------------------------
# Gating, DNL, kernels
# --------------------------------------------------------------------------------------------------
def gate_fraction(edges: np.ndarray, gate: tuple[float, float] | None) -> np.ndarray:
    """Fraction of each bin ``[edges[i], edges[i+1])`` inside ``gate = (start, stop)`` (all ones if None).

    Args:
        edges: float64 (bins + 1,) increasing bin edges in s.
        gate: ``(start, stop)`` in s, or None.
    Returns:
        float64 (bins,) in [0, 1].  Used by :func:`rates_from_envelope` (DESIGN.md §6: the bright first
        bounce is gated out in NLOS systems).
    """
    edges = np.asarray(edges, dtype=np.float64)
    if gate is None:
        return np.ones(edges.size - 1)
    lo = np.clip(edges[:-1], gate[0], gate[1])
    hi = np.clip(edges[1:], gate[0], gate[1])
    width = np.diff(edges)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(width > 0, (hi - lo) / np.where(width > 0, width, 1.0), 0.0)
    return np.clip(frac, 0.0, 1.0)


def rebin_envelope(fine_envelope: Any, fine_edges: Any, edges: Any) -> np.ndarray:
    """Integrate a finely binned envelope over arbitrary (e.g. unequal, DNL) bin edges.

    The envelope is taken as piecewise constant within each fine bin, so the result is exact for that
    density: bin ``k`` holds ``∫_{edges[k]}^{edges[k+1]}`` of it (DESIGN.md §5 "bins are integrals").  Mass
    outside ``[fine_edges[0], fine_edges[-1]]`` is zero.

    Args:
        fine_envelope: (..., n_fine) photons per fine bin (any real dtype; float64 internally).
        fine_edges: (n_fine + 1,) increasing edges in s.
        edges: (n + 1,) increasing target edges in s.
    Returns:
        float64 (..., n) photons per target bin.
    Raises:
        ValueError: mismatched lengths or non-increasing edges.
    """
    f = np.asarray(fine_envelope, dtype=np.float64)
    fe = np.asarray(fine_edges, dtype=np.float64)
    ne = np.asarray(edges, dtype=np.float64)
    if fe.ndim != 1 or fe.size != f.shape[-1] + 1:
        raise ValueError(f"fine_edges must have shape ({f.shape[-1] + 1},), got {fe.shape}")
    if ne.ndim != 1 or ne.size < 2:
        raise ValueError(f"edges must be a 1-D array of at least 2 edges, got shape {ne.shape}")
    if np.any(np.diff(fe) <= 0) or np.any(np.diff(ne) <= 0):
        raise ValueError("fine_edges and edges must be strictly increasing")
    cum = np.zeros(f.shape[:-1] + (fe.size,))
    np.cumsum(f, axis=-1, out=cum[..., 1:])
    x = np.clip(ne, fe[0], fe[-1])
    k = np.clip(np.searchsorted(fe, x, side="right") - 1, 0, fe.size - 2)
    frac = (x - fe[k]) / (fe[k + 1] - fe[k])
    at = cum[..., k] + frac * f[..., k]
    out = np.diff(at, axis=-1)
    return np.maximum(out, 0.0)


def _second_difference_kernel(antiderivative, offsets: np.ndarray, width: float) -> np.ndarray:
    """``K_k = [G((k+1)Δ) − 2G(kΔ) + G((k−1)Δ)]/Δ``: the bin-to-bin kernel of a CDF with antiderivative G for
    a source uniform within its bin (exact for piecewise-constant rates)."""
    x = offsets * width
    return (antiderivative(x + width) - 2.0 * antiderivative(x) + antiderivative(x - width)) / width


def gaussian_kernel(sigma: float, bin_width: float) -> tuple[np.ndarray, int]:
    """Bin-integrated zero-mean Gaussian kernel for piecewise-constant (binned) input.

    Args:
        sigma: standard deviation in s (≥ 0); bin_width: s (> 0).
    Returns:
        ``(kernel, first_offset)``: float64 taps summing to 1 for bin offsets ``first_offset, first_offset+1, …``
        (output bin = input bin + offset).  ``sigma == 0`` gives ``([1.0], 0)``.
    Raises:
        ValueError: negative sigma, non-positive bin width, or a kernel longer than MAX_KERNEL_TAPS.
    """
    if sigma < 0 or bin_width <= 0:
        raise ValueError(f"need sigma >= 0 and bin_width > 0, got sigma={sigma!r}, bin_width={bin_width!r}")
    if sigma == 0:
        return np.ones(1), 0
    half = int(math.ceil(GAUSS_TAIL_SIGMAS * sigma / bin_width)) + 1
    if 2 * half + 1 > MAX_KERNEL_TAPS:
        raise ValueError(f"jitter sigma={sigma!r} s is too wide for bin_width={bin_width!r} s")
    offsets = np.arange(-half, half + 1, dtype=np.float64)

    def antiderivative(x):  # ∫ Φ(x/σ) dx
        z = x / sigma
        return x * special.ndtr(z) + sigma * np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)

    k = np.maximum(_second_difference_kernel(antiderivative, offsets, bin_width), 0.0)
    return k / k.sum(), -half


def exponential_kernel(tau: float, bin_width: float, fraction: float = 1.0) -> tuple[np.ndarray, int]:
    """Bin-integrated causal kernel ``(1 − fraction)·δ(t) + fraction·Exp(mean tau)`` (SPAD diffusion tail).

    Args:
        tau: exponential time constant in s (≥ 0); bin_width: s (> 0); fraction in [0, 1].
    Returns:
        ``(kernel, 0)``: float64 taps summing to 1 for offsets 0, 1, …
    Raises:
        ValueError: invalid arguments or a kernel longer than MAX_KERNEL_TAPS.
    """
    if tau < 0 or bin_width <= 0 or not 0 <= fraction <= 1:
        raise ValueError(f"need tau >= 0, bin_width > 0, 0 <= fraction <= 1; got {tau!r}, {bin_width!r}, {fraction!r}")
    if tau == 0 or fraction == 0:
        return np.ones(1), 0
    n = int(math.ceil(EXP_TAIL_LENGTHS * tau / bin_width)) + 2
    if n > MAX_KERNEL_TAPS:
        raise ValueError(f"diffusion_tail={tau!r} s is too long for bin_width={bin_width!r} s")
    offsets = np.arange(n, dtype=np.float64)

    def antiderivative(x):  # ∫ (1 − e^{−x/τ}) dx for x ≥ 0
        xp = np.maximum(x, 0.0)
        return xp + tau * np.expm1(-xp / tau)

    k = np.maximum(_second_difference_kernel(antiderivative, offsets, bin_width), 0.0)
    k = fraction * k / k.sum()
    k[0] += 1.0 - fraction
    return k, 0


def _convolve_last(x: np.ndarray, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """out[..., i] = Σ_k kernel[k]·x[..., i − (first_offset + k)], truncated to the input's bins."""
    n = x.shape[-1]
    if kernel.size == 1 and first_offset == 0:
        return x * kernel[0]
    if kernel.size <= DIRECT_CONVOLUTION_TAPS:
        out = np.zeros_like(x)
        for k, w in enumerate(kernel):
            shift = first_offset + k
            if shift >= n or -shift >= n:
                continue
            if shift >= 0:
                out[..., shift:] += w * x[..., : n - shift]
            else:
                out[..., : n + shift] += w * x[..., -shift:]
        return out
    from scipy.signal import oaconvolve

    kern = kernel.reshape((1,) * (x.ndim - 1) + (-1,))
    full = oaconvolve(x, kern, mode="full", axes=-1)
    # full[m] = Σ_j x[j] kernel[m − j]; output index i = m + first_offset.
    start = -first_offset
    idx = np.arange(n) + start
    valid = (idx >= 0) & (idx < full.shape[-1])
    out = np.zeros_like(x)
    out[..., valid] = full[..., idx[valid]]
    return np.maximum(out, 0.0)  # FFT round-off


def apply_jitter_before(rates: Any, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """Convolve per-cycle avalanche rates with a timing kernel BEFORE pile-up (laser pulse shape, diffusion tail).

    Use it for processes that delay photons before the first-photon race is decided.  Compared with
    :func:`apply_jitter_after` at the same kernel the result agrees to O(Λ) at low flux; at high flux the
    before-order keeps the pile-up skew of the blurred rates (the histogram shape is
    ``e^{-C}(1-e^{-r})`` of the blurred rates), whereas the after-order blurs an already skewed histogram.
    Both preserve the total detection probability ``1 − e^{−Λ}`` when no mass leaves the window.

    Args:
        rates: (..., bins) expected avalanches per cycle per bin.
        kernel, first_offset: from :func:`gaussian_kernel` / :func:`exponential_kernel`.
    Returns:
        float64 (..., bins); mass shifted outside the window is lost.
    """
    return _convolve_last(_as_rates(rates), np.asarray(kernel, dtype=np.float64), int(first_offset))


def apply_jitter_after(histogram: Any, kernel: np.ndarray, first_offset: int) -> np.ndarray:
    """Convolve an expected histogram with a timing kernel AFTER pile-up (electronic/TDC jitter).

    Args:
        histogram: (..., bins) expected counts (float64 result).
        kernel, first_offset: from :func:`gaussian_kernel`.
    Returns:
        float64 (..., bins); counts shifted outside the window are lost.
    """
    h = np.asarray(histogram, dtype=np.float64)
    return _convolve_last(h, np.asarray(kernel, dtype=np.float64), int(first_offset))


def _jitter_counts(counts: np.ndarray, kernel: np.ndarray, first_offset: int,
                   rng: np.random.Generator) -> np.ndarray:
    """Move every count by an independent kernel-distributed bin offset (exact multinomial redistribution
    drawn as sequential conditional binomials over the taps)."""
    if kernel.size == 1:
        return counts
    n = counts.shape[-1]
    out = np.zeros_like(counts)
    remaining = counts.copy()
    tail = np.cumsum(kernel[::-1])[::-1]  # mass of taps k..end
    for k, w in enumerate(kernel):
        if k == kernel.size - 1:
            moved = remaining
        else:
            prob = min(1.0, w / tail[k]) if tail[k] > 0 else 0.0
            moved = rng.binomial(remaining, prob)
            remaining = remaining - moved
        shift = first_offset + k
        if shift >= n or -shift >= n:
            continue
        if shift >= 0:
            out[..., shift:] += moved[..., : n - shift]
        else:
            out[..., : n + shift] += moved[..., -shift:]
    return out


def instrument_response(config: DetectorConfig, n_bins: int, first_bin: int = 0) -> np.ndarray:
    """Low-flux instrument response of the detector for a photon arriving uniformly in bin ``first_bin``.

    This is the continuous ex-Gaussian (``scipy.stats.exponnorm``: Gaussian σ = ``config.jitter`` convolved
    with the diffusion tail) mixed with the pure Gaussian core for ``1 − diffusion_fraction``, integrated over
    the bins (DESIGN.md §5).  At low flux :func:`expected_histogram` of a one-bin envelope equals
    ``n_cycles × r × instrument_response`` up to the piecewise-constant approximation inside bins.

    Args:
        config: detector description (uses jitter, diffusion_tail, diffusion_fraction, bin_width).
        n_bins: length of the returned histogram; first_bin: bin in which the photon arrives.
    Returns:
        float64 (n_bins,) probabilities (sum ≤ 1; mass outside the window is lost).
    """
    dt = config.bin_width
    sigma, tau, f = config.jitter, config.diffusion_tail, config.diffusion_fraction
    nodes, weights = np.polynomial.legendre.leggauss(64)
    s = (nodes + 1.0) * 0.5 * dt  # source position within its bin
    w = weights * 0.5
    edges = (np.arange(n_bins + 1) - first_bin) * dt

    def cdf(x):
        if sigma == 0 and tau == 0:
            return (x >= 0).astype(float)
        if tau == 0 or f == 0:
            core = special.ndtr(x / sigma) if sigma > 0 else (x >= 0).astype(float)
            return core
        if sigma == 0:
            tail = np.where(x > 0, -np.expm1(-np.maximum(x, 0) / tau), 0.0)
            return (1 - f) * (x >= 0) + f * tail
        tail = stats.exponnorm.cdf(x, tau / sigma, loc=0.0, scale=sigma)
        return (1 - f) * special.ndtr(x / sigma) + f * tail

    c = np.zeros(n_bins + 1)
    for si, wi in zip(s, w):
        c += wi * cdf(edges - si)
    return np.maximum(np.diff(c), 0.0)


# --------------------------------------------------------------------------------------------------
# Rates and first-photon statistics
# --------------------------------------------------------------------------------------------------
def rates_from_envelope(envelope: Any, config: DetectorConfig) -> np.ndarray:
    """Expected avalanches per laser cycle per bin from a detected-photon envelope.

    ``rates = K_tail ⊗ envelope + (pde·ambient_rate + dcr)·width_i``, multiplied by the gate fraction of each
    bin.  The envelope already contains the PDE (DESIGN.md §2), so only ambient light is thinned here; the
    diffusion tail (``diffusion_tail``, ``diffusion_fraction``) acts before pile-up (DESIGN.md §6).  Widths
    are ``config.bin_widths`` when given (DNL), else ``bin_width``.

    Args:
        envelope: (..., bins) detected photons per pulse per bin, any real dtype (float64 internally).
        config: detector description.
    Returns:
        float64 (..., bins) rates ≥ 0.
    Raises:
        ValueError: NaN/inf in the envelope, values more negative than FFT round-off
            (``NEGATIVE_ENVELOPE_RTOL`` × the pixel maximum; smaller ones are clamped to 0), or a bin count
            different from ``len(config.bin_widths)``.
    """
    e = _clamp_envelope(envelope)
    n_bins = e.shape[-1]
    widths = config.widths(n_bins)
    if config.diffusion_tail > 0 and config.diffusion_fraction > 0:
        kernel, first = exponential_kernel(config.diffusion_tail, config.bin_width, config.diffusion_fraction)
        e = _convolve_last(e, kernel, first)
    rates = e + config.background_rate * widths
    if config.gate is not None:
        rates *= gate_fraction(config.bin_edges(n_bins), config.gate)
    return rates


def _accurate_cumsum(x: np.ndarray) -> np.ndarray:
    """Inclusive float64 cumulative sum along the last axis, compensated: the exact rounding error of every
    step of ``np.cumsum`` is recovered with Knuth's TwoSum and added back, so each prefix sum is accurate to a
    few ulps even over 10^6 bins (a plain cumsum drifts by ~n·ε and breaks Σ pmf = 1 at 1e-12)."""
    s = np.cumsum(x, axis=-1)
    prev = np.zeros_like(s)
    prev[..., 1:] = s[..., :-1]
    bp = s - prev
    err = (prev - (s - bp)) + (x - bp)
    return s + np.cumsum(err, axis=-1)


def _exclusive_cumsum(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, Λ): exclusive float64 (compensated) cumulative sum along the last axis and the total."""
    total = _accurate_cumsum(r)
    c = np.empty_like(r)
    c[..., 0] = 0.0
    c[..., 1:] = total[..., :-1]
    return c, total[..., -1]


def detection_pmf(rates: Any) -> np.ndarray:
    """First-detection probabilities of one synchronous laser cycle (Coates 1968; DESIGN.md §6).

    ``pmf[..., i] = exp(−C_i)·(−expm1(−r_i))`` for ``i < bins`` and ``pmf[..., bins] = exp(−Λ)`` (no
    detection), with ``C_i`` the exclusive float64 cumulative sum.  Sums to 1 (to ~1e-13) for any rates,
    including zeros, 1e-300 and Λ ~ 1e4 (no NaN/inf: exp underflows to 0).

    Args:
        rates: (..., bins) expected avalanches per cycle per bin, ≥ 0 (float32 accepted).
    Returns:
        float64 (..., bins + 1).
    Raises:
        ValueError: NaN, inf or negative rates.
    """
    r = _as_rates(rates)
    c, lam = _exclusive_cumsum(r)
    out = np.empty(r.shape[:-1] + (r.shape[-1] + 1,))
    np.multiply(np.exp(-c), -np.expm1(-r), out=out[..., :-1])
    out[..., -1] = np.exp(-lam)
    return out


# --------------------------------------------------------------------------------------------------
# Synchronous models: poisson, pile_up, multi_stop
# --------------------------------------------------------------------------------------------------
def first_photon_sequential(gen: np.random.Generator, r: np.ndarray, n: int) -> np.ndarray:
    """Exact first-photon (pile-up) counts of ``n`` synchronous laser cycles by sequential conditional binomials
    ``N_i ~ Bin(D_i, 1 − e^{−r_i})``, ``D_0 = n``, ``D_{i+1} = D_i − N_i`` (DESIGN.md §6); one vectorised binomial
    call per bin over all pixels of the chunk.

    Args:
        gen: numpy Generator (advanced by the call).
        r: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0 (not checked).
        n: number of laser cycles (int ≥ 0).
    Returns:
        int64 (pixels, bins) counts; each row sums to at most ``n``.  Same distribution as
        :func:`first_photon_tree` (but other draws for the same ``gen``).
    """
    p = -np.expm1(-r)
    out = np.zeros(r.shape, dtype=np.int64)
    remaining = np.full(r.shape[0], n, dtype=np.int64)
    for i in range(r.shape[1]):
        ni = gen.binomial(remaining, p[:, i])
        out[:, i] = ni
        remaining -= ni
        if not remaining.any():
            break
    return out


def first_photon_tree(gen: np.random.Generator, r: np.ndarray, n: int) -> np.ndarray:
    """The same multinomial drawn top-down on a binary tree of bin blocks: the number of cycles detecting in a
    block is split between its halves with ``P(left | block) = (1 − e^{−R_left}) / (1 − e^{−R_block})`` (the
    e^{−C} factors cancel, so no cancellation; block sums are pairwise).  Exact; log2(bins) vectorised calls,
    which is what makes 10^6 bins fast.

    Args:
        gen: numpy Generator (advanced by the call).
        r: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0 (not checked).
        n: number of laser cycles (int ≥ 0).
    Returns:
        int64 (pixels, bins) counts; each row sums to at most ``n``.
    """
    n_pix, bins = r.shape
    size = 1 << max(0, (bins - 1).bit_length())
    leaf = np.zeros((n_pix, size))
    leaf[:, :bins] = r
    levels = [leaf]
    while levels[-1].shape[1] > 1:
        levels.append(levels[-1].reshape(n_pix, -1, 2).sum(axis=-1))
    counts = gen.binomial(n, -np.expm1(-levels[-1][:, 0]))[:, None].astype(np.int64)
    for lev in range(len(levels) - 2, -1, -1):
        child = levels[lev].reshape(n_pix, -1, 2)
        parent = -np.expm1(-levels[lev + 1])
        left = -np.expm1(-child[..., 0])
        p = np.divide(left, parent, out=np.zeros_like(left), where=parent > 0)
        np.minimum(p, 1.0, out=p)
        n_left = gen.binomial(counts, p)
        counts = np.stack([n_left, counts - n_left], axis=-1).reshape(n_pix, -1)
    return counts[:, :bins]


SEQUENTIAL_MAX_BINS = 4096
"""Histograms with up to this many bins are drawn by sequential binomials (fastest for image-sized arrays);
longer ones by the binary tree (log2(bins) Python calls instead of bins)."""

SEQUENTIAL_MIN_PIXELS = 64
"""Below this many pixels the per-bin Python calls of the sequential draw dominate (a single-pixel 1536-bin
draw took 14 ms), so the binary tree is used whatever the bin count (~0.3 ms)."""


def _sample_first_photon(rates2d: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exact multinomial first-photon counts of (pixels, bins) rates over n cycles (int64)."""
    sequential = rates2d.shape[1] <= SEQUENTIAL_MAX_BINS and rates2d.shape[0] >= SEQUENTIAL_MIN_PIXELS
    draw = first_photon_sequential if sequential else first_photon_tree
    return np.concatenate(_run_chunked(lambda gen, rr: draw(gen, rr, n), [rates2d], rng), axis=0)


def _multi_stop_dead_bins(config: DetectorConfig) -> int:
    return int(round(config.dead_time / config.bin_width))


def _multi_stop_expected(r2: np.ndarray, n: int, d: int) -> np.ndarray:
    """Exact expected counts of the discrete multi-stop model: ``E[N_i] = L_i p_i``,
    ``L_{i+1} = L_i − E[N_i] + E[N_{i−d}]``, ``L_0 = n``."""
    p = -np.expm1(-r2)
    bins = r2.shape[1]
    out = np.zeros_like(r2)
    live = np.full(r2.shape[0], float(n))
    for i in range(bins):
        out[:, i] = live * p[:, i]
        live = live - out[:, i]
        if i - d >= 0:
            live = live + out[:, i - d]
    return out


def _multi_stop_sample(r2: np.ndarray, n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    """Exact sampler of the discrete multi-stop model: the cycles are exchangeable, so it suffices to track
    how many are live: ``N_i ~ Bin(L_i, p_i)``, ``L_{i+1} = L_i − N_i + N_{i−d}``."""
    p = -np.expm1(-r2)

    def draw(gen, pp):
        out = np.zeros(pp.shape, dtype=np.int64)
        live = np.full(pp.shape[0], n, dtype=np.int64)
        for i in range(pp.shape[1]):
            ni = gen.binomial(live, pp[:, i])
            out[:, i] = ni
            live -= ni
            if i - d >= 0:
                live += out[:, i - d]
        return out

    return np.concatenate(_run_chunked(draw, [p], rng), axis=0)


# --------------------------------------------------------------------------------------------------
# Crosstalk (per-cycle event simulation of a synchronous array)
# --------------------------------------------------------------------------------------------------
def _row_search(cum: np.ndarray, rows: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Vectorised binary search: for each k find b with cum[rows[k], b] < target[k] <= cum[rows[k], b+1].
    ``cum`` is (pixels, cells + 1), nondecreasing along the last axis with cum[:, 0] = 0 < target."""
    lo = np.zeros(rows.size, dtype=np.int64)
    hi = np.full(rows.size, cum.shape[1] - 1, dtype=np.int64)
    for _ in range(int(math.ceil(math.log2(max(cum.shape[1], 2)))) + 1):
        mid = (lo + hi) // 2
        right = cum[rows, mid] < target
        lo = np.where(right, mid, lo)
        hi = np.where(right, hi, mid)
    return lo


def _neighbour_table(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(neighbours (h·w, 4) flat indices padded with -1, count (h·w,)) of the 4-neighbourhood."""
    idx = np.arange(h * w).reshape(h, w)
    nb = np.full((h, w, 4), -1, dtype=np.int64)
    nb[1:, :, 0] = idx[:-1, :]
    nb[:-1, :, 1] = idx[1:, :]
    nb[:, 1:, 2] = idx[:, :-1]
    nb[:, :-1, 3] = idx[:, 1:]
    nb = nb.reshape(h * w, 4)
    order = np.argsort(nb < 0, axis=1, kind="stable")  # valid neighbours first
    nb = np.take_along_axis(nb, order, axis=1)
    return nb, (nb >= 0).sum(axis=1)


def _sample_pile_up_crosstalk(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Pile-up histograms of an (..., H, W, bins) array with prompt optical crosstalk, by event simulation of
    the cycles in which something happens.

    Per pixel, the set of cycles with a primary avalanche is a uniformly random subset of size
    ``K ~ Bin(n, 1 − e^{−Λ})``; in each, the first primary avalanche time is drawn from the piecewise-constant
    intensity (continuous time).  Every avalanche triggers, with ``crosstalk_probability``, an avalanche at the
    same instant in one uniformly chosen 4-neighbour; each pixel records its earliest avalanche of the cycle
    (primary or crosstalk) and is then held until the next cycle.  Cascades are followed to a fixed point.
    Cost O(avalanches), so low-flux exposures of 10^6 cycles are cheap."""
    if rates.ndim < 3:
        raise ValueError(f"crosstalk_probability > 0 models a pixel array and needs rates of shape (..., H, W, bins), "
                         f"got {rates.shape}; use a detector without crosstalk for a single-pixel capture")
    h, w, bins = rates.shape[-3:]
    n_pix = h * w
    n = config.cycles
    widths = config.widths(bins)
    edges = np.concatenate([[0.0], np.cumsum(widths)])
    neighbours, n_nb = _neighbour_table(h, w)
    frames = rates.reshape(-1, n_pix, bins)
    out = np.zeros(frames.shape, dtype=np.int64)
    p_ct = config.crosstalk_probability

    def draw_destinations(pixels):
        sends = rng.random(pixels.size) < p_ct
        choice = np.minimum((rng.random(pixels.size) * n_nb[pixels]).astype(np.int64), 3)
        dest = neighbours[pixels, choice]
        return np.where(sends & (n_nb[pixels] > 0), dest, -1)

    for f in range(frames.shape[0]):
        q = frames[f]
        cum = np.zeros((n_pix, bins + 1))
        np.cumsum(q, axis=1, out=cum[:, 1:])
        lam = cum[:, -1]
        p_hit = -np.expm1(-lam)
        k = rng.binomial(n, p_hit)
        cycles = np.concatenate([rng.choice(n, size=int(kk), replace=False) for kk in k]) if k.sum() else \
            np.zeros(0, dtype=np.int64)
        pix = np.repeat(np.arange(n_pix), k)
        target = -np.log1p(-rng.random(pix.size) * p_hit[pix])  # Exp(1) truncated to (0, Λ)
        target = np.clip(target, np.finfo(float).tiny, lam[pix])
        b = _row_search(cum, pix, target)
        t = edges[b] + (target - cum[pix, b]) / q[pix, b] * widths[b]
        keys = cycles.astype(np.int64) * n_pix + pix
        order = np.argsort(keys)
        keys, t, pix = keys[order], t[order], pix[order]
        dest = draw_destinations(pix)
        changed = np.ones(keys.size, dtype=bool)
        while True:
            src = np.flatnonzero(changed & (dest >= 0))
            if src.size == 0:
                break
            cand_key = (keys[src] // n_pix) * n_pix + dest[src]
            cand_t = t[src]
            pos = np.searchsorted(keys, cand_key)
            exists = (pos < keys.size) & (keys[np.minimum(pos, keys.size - 1)] == cand_key)
            changed = np.zeros(keys.size, dtype=bool)
            # existing avalanches made earlier by crosstalk
            ep, et = pos[exists], cand_t[exists]
            earlier = et < t[ep]
            if earlier.any():
                np.minimum.at(t, ep[earlier], et[earlier])
                changed[ep[earlier]] = True
            # new avalanches in pixels that had none in that cycle
            new_key, new_t = cand_key[~exists], cand_t[~exists]
            if new_key.size:
                uniq, first = np.unique(new_key, return_index=True)
                best = np.full(uniq.size, np.inf)
                np.minimum.at(best, np.searchsorted(uniq, new_key), new_t)
                new_pix = uniq % n_pix
                keys = np.concatenate([keys, uniq])
                t = np.concatenate([t, best])
                pix = np.concatenate([pix, new_pix])
                dest = np.concatenate([dest, draw_destinations(new_pix)])
                changed = np.concatenate([changed, np.ones(uniq.size, dtype=bool)])
                order = np.argsort(keys, kind="stable")
                keys, t, pix, dest, changed = keys[order], t[order], pix[order], dest[order], changed[order]
        tb = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
        out[f] = np.bincount(pix * bins + tb, minlength=n_pix * bins).reshape(n_pix, bins)
    return out.reshape(rates.shape)


# --------------------------------------------------------------------------------------------------
# Free-running dead time: period cells, Markov chain, closed form (paralyzable), event simulation
# --------------------------------------------------------------------------------------------------
def _period_cells(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cover the whole laser period with cells: the histogram bins plus background cells before/after the
    window (avalanche rate ``background_rate`` × gate).  Returns (edges (cells+1,) in s within the period,
    q (pixels, cells) expected avalanches per cycle, cell_bin (cells,) histogram bin or -1)."""
    bins = r2.shape[1]
    T = config.period
    win = config.bin_edges(bins)
    if win[-1] > T * (1 + 1e-9):
        raise ValueError(f"the histogram window [{win[0]!r}, {win[-1]!r}] s exceeds the laser period {T!r} s; "
                         "free-running time tags are taken modulo the period")
    parts = [win]
    n_pre = int(round(win[0] / config.bin_width))
    if win[0] > 0:
        parts.insert(0, np.linspace(0.0, win[0], max(n_pre, 1) + 1)[:-1])
    tail = T - win[-1]
    if tail > 1e-9 * T:
        n_post = max(int(round(tail / config.bin_width)), 1)
        parts.append(np.linspace(win[-1], T, n_post + 1)[1:])
    edges = np.concatenate(parts)
    if tail <= 1e-9 * T:
        edges[-1] = T  # window ends at the period (within round-off)
    n_before = 0 if win[0] <= 0 else parts[0].size
    n_cells = edges.size - 1
    cell_bin = np.full(n_cells, -1, dtype=np.int64)
    cell_bin[n_before:n_before + bins] = np.arange(bins)
    bg = config.background_rate * np.diff(edges) * gate_fraction(edges, config.gate)
    q = np.broadcast_to(bg, (r2.shape[0], n_cells)).copy()
    q[:, n_before:n_before + bins] = r2
    return edges, q, cell_bin


def _decayed_cumsum(v: np.ndarray, c: np.ndarray) -> np.ndarray:
    """U[..., t] = Σ_{s ≤ t} v[..., s]·exp(−(c[..., t] − c[..., s])) for nondecreasing c, computed in blocks
    so that no exponent exceeds EXP_BLOCK_LIMIT (no overflow for totals ~1e4)."""
    out = np.empty_like(v)
    increments = np.max(np.diff(c, axis=-1, prepend=c[..., :1]), axis=tuple(range(c.ndim - 1)))
    span = np.cumsum(increments)
    n = c.shape[-1]
    start = 0
    carry = np.zeros(v.shape[:-1])
    c_prev = c[..., 0]
    while start < n:
        stop = int(np.searchsorted(span, span[start] + EXP_BLOCK_LIMIT, side="right"))
        stop = min(max(stop, start + 1), n)
        cb = c[..., start:stop] - c[..., start:start + 1]
        part = np.cumsum(v[..., start:stop] * np.exp(cb), axis=-1)
        decay0 = np.exp(-(c[..., start] - c_prev))
        out[..., start:stop] = (part + (carry * decay0)[..., None]) * np.exp(-cb)
        carry = out[..., stop - 1]
        c_prev = c[..., stop - 1]
        start = stop
    return out


def _scatter_columns(values: np.ndarray, dest: np.ndarray, n_cols: int) -> np.ndarray:
    """out[:, c] = Σ_{j: dest[j] = c} values[:, j] (fast replacement for np.add.at over columns)."""
    order = np.argsort(dest, kind="stable")
    sorted_dest = dest[order]
    starts = np.flatnonzero(np.r_[True, sorted_dest[1:] != sorted_dest[:-1]])
    out = np.zeros((values.shape[0], n_cols))
    out[:, sorted_dest[starts]] = np.add.reduceat(values[:, order], starts, axis=1)
    return out


class _Chain:
    """Discretised free-running chain on the detection phase for a batch of pixels (Rapp et al. 2019).

    Cells j (avalanches q_j per cycle) cover the period.  A detection in cell j is taken at the cell centre,
    so the detector is live again at centre_j + τ: inside cell a_j, with a live fraction φ_j of that cell.
    From there the next detection is the first avalanche of the periodic Poisson process: in cell a_j with
    probability 1 − e^{−φ_j q_a}, otherwise distributed by the full-period kernel
    F(b, j') = e^{−(C_{j'} − C_b)} (1 − e^{−q_{j'}}) / (1 − e^{−Λ}) from b = a_j + 1 (whole empty periods
    summed geometrically).  Applying the transition costs O(cells) per pixel (decayed prefix sums)."""

    def __init__(self, q: np.ndarray, edges: np.ndarray, dead_time: float):
        self.q, self.edges, self.dead_time = q, edges, dead_time
        self.T = edges[-1]
        self.M = q.shape[1]
        centre = 0.5 * (edges[:-1] + edges[1:])
        live = np.mod(centre + dead_time, self.T)
        a = np.clip(np.searchsorted(edges, live, side="right") - 1, 0, self.M - 1)
        phi = np.clip((edges[a + 1] - live) / (edges[a + 1] - edges[a]), 0.0, 1.0)
        self.a, self.b = a, (a + 1) % self.M
        self.p = -np.expm1(-q)
        q2 = np.concatenate([q, q], axis=1)
        self.c2 = np.zeros_like(q2)
        np.cumsum(q2[:, :-1], axis=1, out=self.c2[:, 1:])
        self.lam = q.sum(axis=1)
        self.one_minus_survival = -np.expm1(-self.lam)
        qa = q[:, a]
        self.stay = -np.expm1(-phi[None, :] * qa)   # detect inside the partial cell a_j
        self.go = np.exp(-phi[None, :] * qa)        # survive it

    def step(self, pi: np.ndarray) -> np.ndarray:
        """One transition of a batch of row distributions pi (pixels, cells)."""
        M = self.M
        y = _scatter_columns(pi * self.stay, self.a, M)
        v2 = np.zeros((pi.shape[0], 2 * M))
        v2[:, :M] = _scatter_columns(pi * self.go, self.b, M)
        u = _decayed_cumsum(v2, self.c2)
        oms = self.one_minus_survival[:, None]
        wrap = np.divide(u[:, M:], oms, out=np.zeros_like(u[:, M:]), where=oms > 0)
        y += self.p * (u[:, :M] + wrap)
        return y

    def window_mass(self, pi: np.ndarray) -> np.ndarray:
        """(Wπ)_j: mass of detections in (centre_j − τ, centre_j], periodic, π uniform within cells."""
        cum = np.zeros((pi.shape[0], self.M + 1))
        np.cumsum(pi, axis=1, out=cum[:, 1:])
        total = cum[:, -1:]
        centre = 0.5 * (self.edges[:-1] + self.edges[1:])

        def at(t):
            k = np.floor(t / self.T)
            u = t - k * self.T
            idx = np.clip(np.searchsorted(self.edges, u, side="right") - 1, 0, self.M - 1)
            frac = (u - self.edges[idx]) / (self.edges[idx + 1] - self.edges[idx])
            return k[None, :] * total + cum[:, idx] + frac[None, :] * pi[:, idx]

        return at(centre) - at(centre - self.dead_time)


def _stationary(chain: _Chain) -> np.ndarray:
    """Stationary detection-phase distribution (pixels, cells): vectorised power iteration started from the
    low-flux guess π ∝ q, then ARPACK for any pixel whose chain mixes too slowly."""
    q = chain.q
    pi = q / np.where(chain.lam[:, None] > 0, chain.lam[:, None], 1.0)
    todo = np.arange(q.shape[0])
    sub = chain
    for _ in range(MARKOV_MAX_ITER):
        nxt = sub.step(pi[todo])
        s = nxt.sum(axis=1, keepdims=True)
        nxt /= np.where(s > 0, s, 1.0)
        diff = np.abs(nxt - pi[todo]).sum(axis=1)
        pi[todo] = nxt
        keep = diff >= MARKOV_TOL
        if not keep.any():
            return pi
        if not keep.all():
            todo = todo[keep]
            sub = _Chain(q[todo], chain.edges, chain.dead_time)
    from scipy.sparse.linalg import LinearOperator, eigs

    for k in todo:  # only for slowly mixing, nearly periodic chains
        one = _Chain(q[k:k + 1], chain.edges, chain.dead_time)
        op = LinearOperator((chain.M, chain.M), matvec=lambda x, c=one: c.step(np.real(x).reshape(1, -1))[0],
                            dtype=np.float64)
        _, vec = eigs(op, k=1, which="LR", v0=pi[k], tol=1e-14, maxiter=100_000)
        vec = np.abs(vec[:, 0].real)
        pi[k] = vec / vec.sum()
    return pi


def _refine_cells(edges: np.ndarray, q: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if factor == 1:
        return edges, q, np.arange(q.shape[1])
    frac = np.arange(factor) / factor
    fine = (edges[:-1, None] + frac[None, :] * np.diff(edges)[:, None]).ravel()
    fine = np.append(fine, edges[-1])
    return fine, np.repeat(q / factor, factor, axis=1), np.repeat(np.arange(q.shape[1]), factor)


def _auto_oversample(q: np.ndarray, edges: np.ndarray, dead_time: float) -> int:
    n_cells = q.shape[1]
    cap = max(1, MARKOV_MAX_STATES // n_cells)
    need_hazard = math.ceil(float(q.max(initial=0.0)) / MARKOV_CELL_HAZARD) if q.size else 1
    need_time = math.ceil(8.0 * float(np.diff(edges).max()) / dead_time) if dead_time > 0 else 1
    return int(min(cap, max(4, need_hazard, need_time)))


def _free_running_nonparalyzable(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    edges, q, cell_bin = _period_cells(r2, config)
    factor = config.markov_oversample or _auto_oversample(q, edges, config.dead_time)
    fine_edges, fine_q, parent = _refine_cells(edges, q, factor)
    chain = _Chain(fine_q, fine_edges, config.dead_time)
    pi = _stationary(chain)
    wpi = chain.window_mass(pi) if config.dead_time > 0 else np.zeros_like(pi)
    rho = chain.lam / (1.0 + np.sum(fine_q * wpi, axis=1))  # detections per cycle (dead-fraction identity)
    per_cell = rho[:, None] * pi
    fine_bin = cell_bin[parent]
    hist = np.zeros_like(r2)
    inside = fine_bin >= 0
    np.add.at(hist, (slice(None), fine_bin[inside]), per_cell[:, inside])
    return hist, rho


def _free_running_paralyzable(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Closed form: an avalanche at t is counted iff no avalanche in (t − τ, t), so the stationary detection
    density is λ(t)·exp(−∫_{t−τ}^{t} λ); integrated exactly over sub-intervals on which both ends are linear."""
    edges, q, cell_bin = _period_cells(r2, config)
    T, tau = config.period, config.dead_time
    cum = np.zeros((q.shape[0], q.shape[1] + 1))
    np.cumsum(q, axis=1, out=cum[:, 1:])
    lam = cum[:, -1:]
    # E(t) = R(t) − R(t − τ) is linear between cell edges and the points where t − τ crosses an edge
    breaks = np.unique(np.concatenate([edges, np.mod(edges + tau, T)]) if tau > 0 else edges)
    breaks = breaks[(breaks >= 0) & (breaks <= T)]
    breaks = np.unique(np.concatenate([[0.0, T], breaks]))
    lo, hi = breaks[:-1], breaks[1:]
    keep = hi - lo > 1e-12 * T
    lo, hi = lo[keep], hi[keep]

    def big_r(t):  # cumulative intensity on the unrolled time axis, (pixels, len(t))
        k = np.floor(t / T)
        u = t - k * T
        idx = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, q.shape[1] - 1)
        frac = (u - edges[idx]) / (edges[idx + 1] - edges[idx])
        return k, cum[:, idx] + frac[None, :] * q[:, idx]

    def exposure_term(t):  # ∫_{t−τ}^{t} λ
        k1, r1 = big_r(t)
        k0, r0 = big_r(t - tau)
        return (k1 - k0)[None, :] * lam + r1 - r0

    e_lo, e_hi = exposure_term(lo), exposure_term(hi)
    mid = 0.5 * (lo + hi)
    cell = np.clip(np.searchsorted(edges, mid, side="right") - 1, 0, q.shape[1] - 1)
    density = q[:, cell] / (edges[cell + 1] - edges[cell])[None, :]
    x = e_hi - e_lo
    small = np.abs(x) < 1e-8
    safe_x = np.where(small, 1.0, x)
    phi = np.where(small, 1.0 - 0.5 * x, -np.expm1(-x) / safe_x)
    piece = density * (hi - lo)[None, :] * np.exp(-e_lo) * phi
    hist = np.zeros_like(r2)
    b = cell_bin[cell]
    inside = b >= 0
    np.add.at(hist, (slice(None), b[inside]), piece[:, inside])
    return hist, piece.sum(axis=1)


MARKOV_CHUNK_ELEMENTS = 4_000_000
"""Pixels are processed in chunks so that one chunk's (pixels × cells) arrays stay below this size."""


def _free_running_expected(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """(per-cycle expected histogram (pixels, bins), detections per cycle (pixels,)), in pixel chunks."""
    solver = _free_running_paralyzable if config.paralyzable else _free_running_nonparalyzable
    cells = _period_cells(r2[:1], config)[1].shape[1]
    per_pixel = cells * (2 if config.paralyzable else 2 * (config.markov_oversample or 8))
    chunk = max(1, MARKOV_CHUNK_ELEMENTS // per_pixel)
    hist = np.zeros_like(r2)
    rho = np.zeros(r2.shape[0])
    for start in range(0, r2.shape[0], chunk):
        hist[start:start + chunk], rho[start:start + chunk] = solver(r2[start:start + chunk], config)
    return hist, rho


def free_running_rate(rates: Any, config: DetectorConfig) -> np.ndarray:
    """Stationary detections per laser cycle of a free-running SPAD (all phases, in or out of the window).

    Non-paralyzable: from the Markov chain on the detection phase (Rapp et al. 2019) and the exact identity
    ``ρ = Λ / (1 + Σ_j q_j (Wπ)_j)`` (the detector is dead at t iff it detected in (t − τ, t]); for a constant
    rate it reduces to the counter law m = n/(1 + nτ).  Paralyzable: closed form (m = n·e^{−nτ} for a
    constant rate).

    Args:
        rates: (..., bins) expected avalanches per cycle per bin; config with ``model="free_running"``.
    Returns:
        float64 (...,) detections per cycle (multiply by ``repetition_rate`` for Hz).
    Raises:
        ValueError: invalid rates, another model, or a histogram window longer than the period.
    """
    r = _as_rates(rates)
    _require_model(config, "free_running")
    _, rho = _free_running_expected(r.reshape(-1, r.shape[-1]), config)
    return rho.reshape(r.shape[:-1])


def event_simulation(r2: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Exact continuous-time simulation of a free-running SPAD over ``n_cycles`` periods, vectorised over pixels
    (one round = one avalanche per pixel).  Used when afterpulsing is on (afterpulses depend on the recorded
    history); otherwise :func:`event_simulation_batched` simulates the same process faster.  The avalanche
    intensity is piecewise constant on the period cells;
    the next avalanche after time s is found by inverting the cumulative intensity with an Exp(1) draw,
    skipping whole empty periods in O(1).  Non-paralyzable: the detector is live again at t + τ.  Paralyzable:
    every avalanche restarts the dead time and is recorded only if the previous one is ≥ τ earlier.
    Afterpulses: each recorded avalanche schedules, with probability P_ap, an afterpulse at
    t + τ + Exp(afterpulse_time_constant) and cancels any pending one (one trap per pixel); afterpulses falling
    outside the gate are lost.  The detector starts live at t = 0; time stamps are phases modulo the period.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle in each histogram bin (window
            ``config.bin_edges(bins)``, s; outside it the rate is ``background_rate`` × gate), ≥ 0 (not checked).
        config: detector description (period, cycles, dead_time in s, paralyzable, afterpulse_probability,
            afterpulse_time_constant in s, gate).
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) recorded detections per bin over ``config.cycles`` laser periods.
    Raises:
        ValueError: the histogram window exceeds the laser period.
    """
    edges, q, cell_bin = _period_cells(r2, config)
    n_pix, n_cells = q.shape
    bins = r2.shape[1]
    T, tau, n = config.period, config.dead_time, config.cycles
    widths = np.diff(edges)
    cum = np.zeros((n_pix, n_cells + 1))
    np.cumsum(q, axis=1, out=cum[:, 1:])
    lam = cum[:, -1].copy()
    gate_ok = gate_fraction(edges, config.gate) > 0
    p_ap, tau_ap = config.afterpulse_probability, config.afterpulse_time_constant
    paralyzable = config.paralyzable
    tiny = np.finfo(np.float64).tiny
    never = np.iinfo(np.int64).max
    last_phase_value = np.nextafter(T, 0.0)

    cycle = np.zeros(n_pix, dtype=np.int64)   # where the search for the next avalanche starts
    phase = np.zeros(n_pix)
    last_cycle = np.full(n_pix, -1, dtype=np.int64)   # paralyzable: previous avalanche (-1: none yet)
    last_phase = np.zeros(n_pix)
    ap_cycle = np.full(n_pix, never, dtype=np.int64)  # pending afterpulse
    ap_phase = np.zeros(n_pix)
    active = lam > 0
    buffers: list[np.ndarray] = []
    buffered = 0
    hist = np.zeros(n_pix * bins, dtype=np.int64)

    def add_time(c, u, dt):
        total = u + dt
        k = np.floor(total / T)
        u2 = total - k * T
        wrap = u2 >= T
        return c + (k + wrap).astype(np.int64), np.clip(np.where(wrap, u2 - T, u2), 0.0, last_phase_value)

    while True:
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        c0, u0, lam_i = cycle[idx], phase[idx], lam[idx]
        cell0 = np.clip(np.searchsorted(edges, u0, side="right") - 1, 0, n_cells - 1)
        r_start = cum[idx, cell0] + (u0 - edges[cell0]) / widths[cell0] * q[idx, cell0]
        target = r_start + rng.standard_exponential(idx.size)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            same = target <= lam_i
            rem = target - lam_i
            skip = np.where(same, 0.0, np.floor(rem / lam_i))
            inner = np.where(same, target, rem - skip * lam_i)
            inner = np.where(np.isfinite(inner), inner, lam_i)
            over = (~same) & (inner > lam_i)
            inner = np.where(over, inner - lam_i, inner)
            new_cycle = c0 + np.where(same, 0.0, 1.0 + skip + over)
        inner = np.clip(inner, tiny, lam_i)
        beyond = ~(new_cycle < n)
        b = _row_search(cum, idx, inner)
        with np.errstate(divide="ignore", invalid="ignore"):
            u1 = edges[b] + (inner - cum[idx, b]) / q[idx, b] * widths[b]
        u1 = np.where(beyond, 0.0, np.clip(u1, edges[b], np.nextafter(edges[b + 1], 0.0)))
        c1 = np.where(beyond, float(n), new_cycle).astype(np.int64)
        is_ap = np.zeros(idx.size, dtype=bool)
        if p_ap > 0:
            apc, apu = ap_cycle[idx], ap_phase[idx]
            is_ap = (apc < c1) | ((apc == c1) & (apu < u1))
            c1 = np.where(is_ap, apc, c1)
            u1 = np.where(is_ap, apu, u1)
        done = c1 >= n
        active[idx[done]] = False
        go = ~done
        idx, c1, u1, is_ap = idx[go], c1[go], u1[go], is_ap[go]
        if idx.size == 0:
            continue
        cell1 = np.clip(np.searchsorted(edges, u1, side="right") - 1, 0, n_cells - 1)
        if paralyzable:
            lc, lp = last_cycle[idx], last_phase[idx]
            gap = (c1 - lc).astype(np.float64) * T + (u1 - lp)
            record = (lc < 0) | (gap >= tau)
            last_cycle[idx], last_phase[idx] = c1, u1
            cycle[idx], phase[idx] = c1, u1
        else:
            lost = is_ap & ~gate_ok[cell1]
            record = ~lost
            nc, nu = add_time(c1, u1, tau)
            cycle[idx] = np.where(lost, c1, nc)
            phase[idx] = np.where(lost, u1, nu)
        if p_ap > 0:
            ap_cycle[idx[record | is_ap]] = never
            spawn = record & (rng.random(idx.size) < p_ap)
            if spawn.any():
                delay = tau + tau_ap * rng.standard_exponential(int(spawn.sum()))
                ac, au = add_time(c1[spawn], u1[spawn], delay)
                ap_cycle[idx[spawn]], ap_phase[idx[spawn]] = ac, au
        hist_bin = cell_bin[cell1]
        keep = record & (hist_bin >= 0)
        if keep.any():
            buffers.append(idx[keep] * bins + hist_bin[keep])
            buffered += int(keep.sum())
            if buffered >= EVENT_FLUSH:
                hist += np.bincount(np.concatenate(buffers), minlength=n_pix * bins)
                buffers, buffered = [], 0
    if buffers:
        hist += np.bincount(np.concatenate(buffers), minlength=n_pix * bins)
    return hist.reshape(n_pix, bins)


TICKS_PER_PERIOD = 1 << 24
"""Time resolution of the batched free-running simulator: the period is split into 2**24 integer ticks
(3 fs at 20 MHz), so that sorting and dead-time comparisons are exact integer operations."""

EVENT_SEGMENT_ARRIVALS = 4_000_000
"""Expected avalanches (all pixels) generated per segment of the batched free-running simulator."""


def _dead_time_path(key: np.ndarray, pix: np.ndarray, dead: int, start: np.ndarray) -> np.ndarray:
    """Indices of the avalanches recorded by a non-paralyzable detector.

    ``key`` (A,) int64 sorted times (pixel-offset ticks), ``pix`` (A,) pixel of each, ``start`` (pixels,) index
    of each pixel's first recorded avalanche (A: none).  next[k] = first avalanche of the same pixel at or after
    key[k] + dead; the recorded ones are the path start → next → next …, enumerated for all pixels at once by
    pointer doubling (level m adds the nodes 2^m steps further), O(A log L)."""
    size = key.size
    nxt = np.searchsorted(key, key + dead, side="left")
    bad = nxt >= size
    nxt[bad] = size
    ok = ~bad
    ok[ok] = pix[nxt[ok]] == pix[ok]
    nxt[~ok] = size
    jump = np.append(nxt, size)
    nodes = start[start < size]
    while True:
        add = jump[nodes]
        add = add[add < size]
        if add.size == 0:
            return nodes
        nodes = np.concatenate([nodes, add])
        jump = jump[jump]


def event_simulation_batched(r2: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Exact free-running simulation without afterpulsing, in segments of whole cycles, vectorised over all
    avalanches.  Avalanche counts per (pixel, cell, segment) are Poisson(S·q); positions are uniform within the
    cell (constant intensity there) and the cycle uniform within the segment; times are integer ticks
    (TICKS_PER_PERIOD per period).  Non-paralyzable dead time: :func:`_dead_time_path`; paralyzable: an avalanche
    is recorded iff the previous avalanche of that pixel is ≥ τ earlier.  State (live-from / last avalanche)
    carries across segments, so the result is the same process as :func:`event_simulation`.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle in each histogram bin (window
            ``config.bin_edges(bins)``, s; outside it the rate is ``background_rate`` × gate), ≥ 0 (not checked).
        config: detector description (period, cycles, dead_time in s, paralyzable, gate); afterpulsing is
            ignored (use :func:`event_simulation`).
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) recorded detections per bin over ``config.cycles`` laser periods.
    Raises:
        ValueError: the histogram window exceeds the laser period.
    """
    edges, q, cell_bin = _period_cells(r2, config)
    n_pix, n_cells = q.shape
    bins = r2.shape[1]
    n, T = config.cycles, config.period
    dead = int(round(config.dead_time / T * TICKS_PER_PERIOD))
    total_rate = float(q.sum())
    hist = np.zeros(n_pix * bins, dtype=np.int64)
    if total_rate == 0.0 or n_pix == 0:
        return hist.reshape(n_pix, bins)
    max_cycles_by_overflow = (np.iinfo(np.int64).max // 4) // (max(n_pix, 1) * TICKS_PER_PERIOD) - 2
    seg = int(max(1, min(n, EVENT_SEGMENT_ARRIVALS / total_rate, max_cycles_by_overflow)))
    cell_lo = np.floor(edges[:-1] / T * TICKS_PER_PERIOD).astype(np.int64)
    cell_span = np.maximum(np.floor(edges[1:] / T * TICKS_PER_PERIOD).astype(np.int64) - cell_lo, 1)
    never = np.iinfo(np.int64).min // 4
    carry = np.full(n_pix, never, dtype=np.int64)  # live-from (non-paralyzable) or last avalanche, in ticks
    paralyzable = config.paralyzable
    pix_ids = np.arange(n_pix, dtype=np.int64)
    done = 0
    while done < n:
        s = min(seg, n - done)
        span = s * TICKS_PER_PERIOD
        big = span + TICKS_PER_PERIOD
        counts = rng.poisson(s * q).ravel()
        flat = np.repeat(np.arange(counts.size, dtype=np.int64), counts)
        pix, cell = np.divmod(flat, n_cells)
        local = (rng.integers(0, s, flat.size, dtype=np.int64) * TICKS_PER_PERIOD + cell_lo[cell]
                 + (rng.random(flat.size) * cell_span[cell]).astype(np.int64))
        key = pix * big + local
        order = np.argsort(key, kind="stable")
        key, pix, cell, local = key[order], pix[order], cell[order], local[order]
        if paralyzable:
            prev = np.empty_like(local)
            prev[1:] = local[:-1]
            first = np.ones(key.size, dtype=bool)
            first[1:] = pix[1:] != pix[:-1]
            prev[first] = carry[pix[first]]
            recorded = np.flatnonzero((local - prev) >= dead)
            if key.size:
                last = np.ones(key.size, dtype=bool)
                last[:-1] = pix[1:] != pix[:-1]
                carry[pix[last]] = local[last]
        else:
            start = np.searchsorted(key, pix_ids * big + np.maximum(carry, 0), side="left")
            valid = start < key.size
            valid[valid] = pix[start[valid]] == pix_ids[valid]
            start[~valid] = key.size
            recorded = _dead_time_path(key, pix, dead, start)
            if recorded.size:
                rec_pix = pix[recorded]
                last_local = np.full(n_pix, never, dtype=np.int64)
                np.maximum.at(last_local, rec_pix, local[recorded])
                has = last_local > never
                carry[has] = last_local[has] + dead
        carry = np.where(carry > never, carry - span, never)
        carry = np.maximum(carry, never)
        hb = cell_bin[cell[recorded]]
        inside = hb >= 0
        hist += np.bincount(pix[recorded][inside] * bins + hb[inside], minlength=n_pix * bins)
        done += s
    return hist.reshape(n_pix, bins)


# --------------------------------------------------------------------------------------------------
# Public model dispatch
# --------------------------------------------------------------------------------------------------
def _require_model(config: DetectorConfig, model: str) -> None:
    if config.model != model:
        raise ValueError(f"this function needs model={model!r}, got model={config.model!r}")


def _check_window(r: np.ndarray, config: DetectorConfig) -> None:
    config.widths(r.shape[-1])  # raises on a DNL length mismatch


def expected_histogram(rates: Any, config: DetectorConfig) -> np.ndarray:
    """Expected counts over the exposure for ``config.model`` (then Gaussian jitter after pile-up).

    * ``poisson``: ``n·r_i`` — low-flux limit (DESIGN.md §6).
    * ``pile_up``: ``n·e^{−C_i}(1 − e^{−r_i})`` — synchronous first photon, Coates 1968.
    * ``multi_stop``: exact recursion ``E[N_i] = L_i p_i``, ``L_{i+1} = L_i − E[N_i] + E[N_{i−d}]``,
      ``d = round(dead_time/bin_width)`` bins blocked after each detection, re-armed every cycle.
    * ``free_running``: ``n·ρ·π`` with π the stationary detection-phase distribution of the Markov chain
      (Rapp, Ma, Dawson, Goyal, IEEE TSP 2019; discretised on ``markov_oversample`` cells per bin) and ρ the
      detections per cycle; paralyzable dead time uses the exact closed form λ(t)e^{−∫_{t−τ}^{t}λ}.
      Stationary: the start-up transient (≤ one dead time) is ignored.

    Args:
        rates: (..., bins) expected avalanches per cycle per bin (float32 accepted).
        config: detector description.
    Returns:
        float64 (..., bins) expected counts.
    Raises:
        ValueError: invalid rates, DNL length mismatch, window longer than the period (free_running).
        NotImplementedError: crosstalk or afterpulsing (no closed form; average :func:`sample_histogram`).
    """
    r = _as_rates(rates)
    _check_window(r, config)
    if config.crosstalk_probability > 0 or config.afterpulse_probability > 0:
        raise NotImplementedError("crosstalk and afterpulsing have no closed-form expected histogram here; "
                                  "average sample_histogram draws (event simulation)")
    n = config.cycles
    shape = r.shape
    r2 = r.reshape(-1, shape[-1])
    if config.model == "poisson":
        hist = n * r2
    elif config.model == "pile_up":
        hist = n * detection_pmf(r2)[:, :-1]
    elif config.model == "multi_stop":
        hist = _multi_stop_expected(r2, n, _multi_stop_dead_bins(config))
    else:
        per_cycle, _ = _free_running_expected(r2, config)
        hist = n * per_cycle
    if config.jitter > 0:
        kernel, first = gaussian_kernel(config.jitter, config.bin_width)
        hist = _convolve_last(hist, kernel, first)
    return hist.reshape(shape)


def _sample_poisson(lam: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """int64 counts ~ Poisson(lam) for (pixels, bins) expected counts; round(N(λ, λ)) clipped at 0 where
    λ > POISSON_NORMAL_ABOVE (the same draws as ``rng.poisson(lam)`` when no bin is that large).

    Raises:
        ValueError: a bin expects more than MAX_EXPECTED_COUNTS counts (int64 overflow).
    """
    if np.any(lam > MAX_EXPECTED_COUNTS):
        raise ValueError(
            f"poisson detector: a bin expects {float(lam.max()):.3g} counts per exposure (n_cycles × rate), "
            f"more than int64 counts can hold (limit {MAX_EXPECTED_COUNTS:.3g}): the flux is too high. Lower the "
            f"laser's photons_per_pulse (or pulse_energy), the PDE, the aperture, n_cycles or the exposure")
    big = lam > POISSON_NORMAL_ABOVE
    if not big.any():
        return rng.poisson(lam).astype(np.int64)
    counts = rng.poisson(np.where(big, 0.0, lam)).astype(np.int64)
    lam_big = lam[big]
    counts[big] = np.maximum(np.rint(lam_big + np.sqrt(lam_big) * rng.standard_normal(lam_big.size)),
                             0.0).astype(np.int64)
    return counts


def sample_histogram(rates: Any, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Draw one exposure's histogram for ``config.model`` (then Gaussian jitter after pile-up).

    * ``poisson``: ``rng.poisson(n·r)``; bins expecting more than POISSON_NORMAL_ABOVE (1e12) counts draw the
      normal approximation round(N(λ, λ)) clipped at 0 (see the constant for its accuracy and why).
    * ``pile_up``: exact multinomial as sequential binomials ``N_i ~ Bin(D_i, 1 − e^{−r_i})``,
      ``D_0 = n``, ``D_{i+1} = D_i − N_i`` (DESIGN.md §6), vectorised over pixels (histograms longer than
      SEQUENTIAL_MAX_BINS: the same conditional binomials on a binary tree of bins).  With crosstalk: event
      simulation of the (…, H, W) array over the cycles in which some pixel avalanches.
    * ``multi_stop``: exact sampler of the discrete model tracking the number of live cycles.
    * ``free_running``: exact continuous-time event simulation (dead time across cycles, paralyzable or not,
      afterpulsing).
    The pile-up and multi-stop samplers draw pixels in fixed chunks of SAMPLER_PIXEL_CHUNK with independent
    child streams of ``rng``, in threads; the result depends only on ``rng``'s state, not on the core count.

    Args:
        rates: (..., bins) expected avalanches per cycle per bin (float32 accepted).
        config: detector description.
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (..., bins) counts.
    Raises:
        ValueError: invalid rates; (``poisson``) a bin expecting more than MAX_EXPECTED_COUNTS counts, beyond
            int64 (the message names the flux and the laser's photons_per_pulse). TypeError: rng is not a
            numpy Generator.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    r = _as_rates(rates)
    _check_window(r, config)
    n = config.cycles
    shape = r.shape
    r2 = r.reshape(-1, shape[-1])
    if config.model == "poisson":
        counts = _sample_poisson(n * r2, rng)
    elif config.model == "pile_up":
        if config.crosstalk_probability > 0:
            counts = _sample_pile_up_crosstalk(r, config, rng).reshape(r2.shape)
        else:
            counts = _sample_first_photon(r2, n, rng)
    elif config.model == "multi_stop":
        counts = _multi_stop_sample(r2, n, _multi_stop_dead_bins(config), rng)
    elif config.afterpulse_probability > 0:
        counts = event_simulation(r2, config, rng)
    else:
        counts = event_simulation_batched(r2, config, rng)
    if config.jitter > 0:
        kernel, first = gaussian_kernel(config.jitter, config.bin_width)
        counts = _jitter_counts(counts, kernel, first, rng)
    return counts.reshape(shape)


# --------------------------------------------------------------------------------------------------
# Inversion
# --------------------------------------------------------------------------------------------------
def coates(counts: Any, n_cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Coates (1968) pile-up correction: ``r̂_i = −log1p(−N_i/D_i)``, ``D_i = n − Σ_{j<i} N_j``.

    It is the maximum-likelihood inverse of the synchronous first-photon model and inverts exact expected
    counts exactly (to rounding).  At large N it is unbiased with delta-method variance
    ``Var r̂_i ≈ p_i / (E[D_i](1 − p_i))``, ``p_i = 1 − e^{−r_i}``.

    Args:
        counts: (..., bins) int or float counts (expected counts allowed), ≥ 0, with ``Σ counts ≤ n_cycles``.
        n_cycles: number of laser cycles (positive int).
    Returns:
        ``(rate_estimate, valid)``: float64 (..., bins) and bool (..., bins).  Bins with ``D_i = 0`` (no
        surviving cycles: no information) or ``N_i = D_i`` (saturated: the MLE is +inf) are flagged
        ``valid = False`` and their estimate is set to the sentinel **0.0** (never NaN or inf).
    Raises:
        ValueError: NaN/inf or negative counts, or a pixel with more counts than cycles.
    """
    n = _check_cycles(n_cycles)
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim == 0 or c.shape[-1] == 0:
        raise ValueError(f"counts must have shape (..., bins) with bins >= 1, got {c.shape}")
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError("counts must be finite and >= 0")
    prior, total = _exclusive_cumsum(c)
    if np.any(total > n * (1 + 1e-12)):
        raise ValueError(f"a pixel has {float(total.max())!r} counts, more than n_cycles={n}")
    remaining = np.maximum(n - prior, 0.0)
    valid = (remaining > 0) & (c < remaining)
    ratio = np.divide(c, remaining, out=np.zeros_like(c), where=valid)
    est = np.where(valid, -np.log1p(-ratio), 0.0)
    return est, valid


# --------------------------------------------------------------------------------------------------
# Counting-mode detectors (no TDC): paralyzable and non-paralyzable dead time
# --------------------------------------------------------------------------------------------------
def counter_rate(true_rate: Any, dead_time: float, paralyzable: bool = False) -> np.ndarray:
    """Mean recorded rate of a counter with dead time τ for Poisson input rate n (Hz).

    Non-paralyzable ``m = n/(1 + nτ)``; paralyzable ``m = n·e^{−nτ}`` (maximum ``1/(eτ)`` at ``nτ = 1``).
    Source: DESIGN.md §6; G. F. Knoll, *Radiation Detection and Measurement*, ch. 4.

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
        ValueError: negative/NaN rate or negative dead time.
    """
    _as_counter_rate(true_rate, dead_time)
    n_rate = float(true_rate)
    out = np.zeros(size, dtype=np.int64)
    if n_rate == 0:
        return out
    # Inter-arrival gaps of the Poisson input are iid Exp(n).  Non-paralyzable: a renewal process with
    # intervals τ + gap (the first without τ).  Paralyzable: an arrival is counted iff its gap ≥ τ.
    shift = 0.0 if paralyzable else dead_time
    mean_gap = shift + 1.0 / n_rate
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
