"""Instrument response (IRF) and the time axis of the envelopes (docs/physics.md §5).

:class:`TimeAxis` is the uniform histogram axis: ``n_bins`` half-open bins ``[e_b, e_{b+1})``. :class:`Irf`
is the density ``h`` of the delay ``X`` = detection time − impulse time: a Gaussian of width sigma (sigma = 0:
the ideal, delta IRF), an ex-Gaussian (Gaussian jitter core plus exponential diffusion tail) or a two-tail IRF
(a Gaussian core plus two exponential tails, the slow response of real SPADs, docs/detector.md), with its CDF
``F``, survival function and the stable bin integral :meth:`Irf.interval_mass`. Binning impulses with it is
:mod:`datagen.timing.accumulator`'s job: a bin holds ``w * [F(e_{b+1} - tau) - F(e_b - tau)]``, an integral,
never the density sampled at the bin centre.

Conventions: times in seconds (strings such as ``"20ps"`` are accepted by the models, docs/physics.md §1).
``Irf.cdf(x)`` is ``P(X < x)`` so that half-open bins ``[e_b, e_{b+1})`` are handled exactly, also for the
delta IRF.
"""
from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer, model_validator
from scipy.special import ndtr
from scipy.stats import exponnorm

from ..units import parse_duration

__all__ = [
    "FWHM_PER_SIGMA",
    "ex_gaussian_cdf",
    "MARGIN_SIGMAS",
    "TAIL_MARGIN_TAUS",
    "TimeAxis",
    "Irf",
    "fwhm_to_sigma",
    "sigma_to_fwhm",
    "TWO_TAIL_FIELDS",
]

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
"""FWHM / sigma of a Gaussian, 2*sqrt(2 ln 2) ~= 2.3548."""

MARGIN_SIGMAS = 8.5
"""Gaussian support kept on each side of an impulse, in sigma: Phi(-8.5) ~ 1e-17, below float64 resolution."""

TAIL_MARGIN_TAUS = 40.0
"""Exponential-tail support kept after an impulse (ex-Gaussian), in tail constants: exp(-40) ~ 4e-18."""


TWO_TAIL_FIELDS = ("tail_weight", "tail2", "tail2_weight", "tail_delay")
"""Fields only the two-tail IRF uses (absent from a Gaussian's or an ex-Gaussian's dump, which stay as before)."""


def fwhm_to_sigma(fwhm: float) -> float:
    """Gaussian sigma (s) from its full width at half maximum (s): sigma = FWHM / (2*sqrt(2 ln 2)).

    Raises:
        ValueError: ``fwhm`` is negative or not finite.
    """
    fwhm = float(fwhm)
    if not math.isfinite(fwhm) or fwhm < 0:
        raise ValueError(f"fwhm must be finite and >= 0, got fwhm={fwhm!r}")
    return fwhm / FWHM_PER_SIGMA


def sigma_to_fwhm(sigma: float) -> float:
    """Gaussian FWHM (s) from its standard deviation (s): FWHM = 2*sqrt(2 ln 2) * sigma.

    Raises:
        ValueError: ``sigma`` is negative or not finite.
    """
    sigma = float(sigma)
    if not math.isfinite(sigma) or sigma < 0:
        raise ValueError(f"sigma must be finite and >= 0, got sigma={sigma!r}")
    return sigma * FWHM_PER_SIGMA


def ex_gaussian_cdf(x: np.ndarray | float, sigma: float, tail: float) -> np.ndarray:
    """CDF of the ex-Gaussian (a Gaussian of std ``sigma`` convolved with an exponential of mean ``tail``,
    seconds; both > 0) at delays ``x`` (seconds): ``scipy.stats.exponnorm`` in a stable form, float64 of x's
    shape. The IRF's diffusion tail (docs/physics.md §5) and the detector's jitter tail (datagen.spad) use it."""
    return exponnorm.cdf(x, tail / sigma, scale=sigma)


class TimeAxis(BaseModel):
    """Uniform histogram time axis: ``n_bins`` half-open bins ``[e_b, e_{b+1})`` of ``bin_width`` seconds.

    Fields:
        t_start: time of the first edge, seconds (may be negative; strings such as ``"-1ns"`` accepted).
        bin_width: bin width, seconds, > 0 (e.g. ``"4ps"``).
        n_bins: number of bins, >= 1.

    Raises:
        pydantic.ValidationError (a ValueError): a field is missing, not finite, out of range or not a
            duration; the message names the field and the value (e.g. ``bin_width`` ... ``input_value=-1``).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    t_start: float = Field(allow_inf_nan=False)
    bin_width: float = Field(gt=0.0, allow_inf_nan=False)
    n_bins: int = Field(ge=1)

    @field_validator("t_start", "bin_width", mode="before")
    @classmethod
    def _parse_duration(cls, value: Any) -> Any:
        if isinstance(value, str):
            return parse_duration(value)
        return value

    @property
    def edges(self) -> np.ndarray:
        """Bin edges, shape (n_bins + 1,), float64 seconds: ``t_start + b * bin_width``."""
        return self.t_start + self.bin_width * np.arange(self.n_bins + 1, dtype=np.float64)

    @property
    def centers(self) -> np.ndarray:
        """Bin centres, shape (n_bins,), float64 seconds."""
        return self.t_start + self.bin_width * (np.arange(self.n_bins, dtype=np.float64) + 0.5)

    @property
    def t_stop(self) -> float:
        """Time of the last edge, seconds (exclusive end of the window)."""
        return self.t_start + self.bin_width * self.n_bins


class Irf(BaseModel):
    """Instrument response function: the density ``h`` of the delay X = detection time - impulse time.

    Give exactly one of ``sigma`` or ``fwhm`` (seconds, numbers or strings like ``"600ps"``); ``fwhm`` is
    converted to ``sigma`` on construction (``fwhm_to_sigma``) and is available as a property.

    Kinds:
        ``"gaussian"``: X ~ N(0, sigma^2). ``sigma = 0`` is the ideal (delta) IRF: each impulse lands wholly
            in the bin containing it.
        ``"exgaussian"``: X = N(0, sigma^2) + Exponential(mean ``tail``), the SPAD jitter core plus diffusion
            tail (docs/physics.md §5); CDF from ``scipy.stats.exponnorm`` with K = tail / sigma, scale = sigma.
            Requires sigma > 0 and tail > 0. Its mean is ``tail``, not 0.
        ``"two_tail"``: the mixture h = (1 − a1 − a2)·N(0, sigma²) + a1·EMG(sigma, tail) + a2·EMG(sigma, tail2),
            both tails delayed by ``tail_delay`` d ≥ 0 (EMG: the ex-Gaussian above; a1 = ``tail_weight``,
            a2 = ``tail2_weight``, each ≥ 0, a1 + a2 ≤ 1): a Gaussian core (jitter and laser pulse) plus the fast
            and the slow diffusion tail of a real SPAD (docs/detector.md "Two-tail IRF"). Unit area by
            construction; CDF F = (1 − a1 − a2)·Φ(x/sigma) + a1·F_EMG(x − d; tail) + a2·F_EMG(x − d; tail2), mean
            (a1 + a2)·d + a1·tail + a2·tail2, variance in :attr:`variance`. With a2 = 0, a1 = 1, d = 0 it is the
            ex-Gaussian. Requires sigma > 0, tail > 0, tail2 > 0.

    Raises:
        pydantic.ValidationError (a ValueError): both or neither of sigma/fwhm, a negative or non-finite
            width, ``tail`` given for a Gaussian or missing/non-positive for an ex-Gaussian or a two-tail IRF, a
            two-tail field given to another kind, weights outside [0, 1] or summing above 1.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    sigma: float = Field(ge=0.0, allow_inf_nan=False)
    kind: Literal["gaussian", "exgaussian", "two_tail"] = "gaussian"
    tail: float | None = Field(default=None, allow_inf_nan=False)
    tail_weight: float | None = Field(default=None, ge=0.0, le=1.0, allow_inf_nan=False)
    tail2: float | None = Field(default=None, allow_inf_nan=False)
    tail2_weight: float | None = Field(default=None, ge=0.0, le=1.0, allow_inf_nan=False)
    tail_delay: float | None = Field(default=None, ge=0.0, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _resolve_width(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        data = dict(data)
        has_sigma = data.get("sigma") is not None
        has_fwhm = data.get("fwhm") is not None
        if has_sigma == has_fwhm:
            raise ValueError(
                f"give exactly one of sigma or fwhm, got sigma={data.get('sigma')!r}, fwhm={data.get('fwhm')!r}"
            )
        if has_fwhm:
            fwhm = data.pop("fwhm")
            fwhm_s = parse_duration(fwhm) if isinstance(fwhm, str) else fwhm
            if isinstance(fwhm_s, (int, float)) and not isinstance(fwhm_s, bool):
                data["sigma"] = fwhm_to_sigma(fwhm_s)  # raises naming fwhm if negative / not finite
            else:
                raise ValueError(f"fwhm must be a duration, got fwhm={fwhm!r}")
        else:
            data.pop("fwhm", None)
        for key in ("sigma", "tail", "tail2", "tail_delay"):
            if isinstance(data.get(key), str):
                data[key] = parse_duration(data[key])
        return data

    @model_validator(mode="after")
    def _check_kind(self) -> Irf:
        if self.kind == "gaussian" and self.tail is not None:
            raise ValueError(f"tail is only used by kind='exgaussian' or 'two_tail', got tail={self.tail!r} for a "
                             "gaussian")
        if self.kind != "two_tail":
            extra = {k: getattr(self, k) for k in TWO_TAIL_FIELDS if getattr(self, k) is not None}
            if extra:
                name, value = next(iter(extra.items()))
                raise ValueError(f"{name} is only used by kind='two_tail', got {name}={value!r} for kind={self.kind!r}")
        else:
            for name in ("tail", "tail2"):
                value = getattr(self, name)
                if value is None or not value > 0:
                    raise ValueError(f"kind='two_tail' needs {name} > 0 (seconds), got {name}={value!r}")
            if not self.sigma > 0:
                raise ValueError(f"kind='two_tail' needs sigma > 0, got sigma={self.sigma!r}")
            for name in ("tail_weight", "tail2_weight"):
                if getattr(self, name) is None:
                    raise ValueError(f"kind='two_tail' needs {name} in [0, 1], got {name}=None")
            if self.tail_weight + self.tail2_weight > 1.0 + 1e-12:
                raise ValueError(f"kind='two_tail' needs tail_weight + tail2_weight <= 1, got {self.tail_weight!r} + "
                                 f"{self.tail2_weight!r}")
        if self.kind == "exgaussian":
            if self.tail is None or not self.tail > 0:
                raise ValueError(f"kind='exgaussian' needs tail > 0 (seconds), got tail={self.tail!r}")
            if not self.sigma > 0:
                raise ValueError(f"kind='exgaussian' needs sigma > 0, got sigma={self.sigma!r}")
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        data = handler(self)
        if self.kind != "two_tail" and isinstance(data, dict):       # the other kinds dump as before
            for key in TWO_TAIL_FIELDS:
                data.pop(key, None)
        return data

    @property
    def fwhm(self) -> float:
        """FWHM of the Gaussian core, seconds."""
        return sigma_to_fwhm(self.sigma)

    @property
    def components(self) -> tuple[tuple[float, float | None, float], ...]:
        """The IRF as a mixture: ((weight, tail or None for the bare Gaussian core, delay s), ...), weights summing
        to 1. A Gaussian is ((1, None, 0),), an ex-Gaussian ((1, tail, 0),), a two-tail IRF its core and tails."""
        if self.kind == "gaussian":
            return ((1.0, None, 0.0),)
        if self.kind == "exgaussian":
            return ((1.0, float(self.tail), 0.0),)
        a1, a2, d = float(self.tail_weight), float(self.tail2_weight), float(self.tail_delay or 0.0)
        return ((max(1.0 - a1 - a2, 0.0), None, 0.0), (a1, float(self.tail), d), (a2, float(self.tail2), d))

    @property
    def variance(self) -> float:
        """Var X, s²: sigma² for the Gaussian core; each tail component (weight a, tail tau, delay d) has mean
        d + tau and second moment sigma² + (d + tau)² + tau² (an ex-Gaussian's: Var = sigma² + tau²)."""
        s2 = self.sigma ** 2
        mean = self.mean
        second = sum(w * (s2 + (0.0 if tau is None else (d + tau) ** 2 + tau ** 2)) for w, tau, d in self.components)
        return float(second - mean * mean)

    @property
    def is_delta(self) -> bool:
        """True for the ideal IRF (Gaussian with sigma = 0)."""
        return self.sigma == 0.0

    @property
    def mean(self) -> float:
        """Mean delay E[X], seconds: 0 for a Gaussian, ``tail`` for an ex-Gaussian, (a1 + a2)·tail_delay +
        a1·tail + a2·tail2 for a two-tail IRF."""
        if self.kind == "two_tail":
            return float(sum(w * (d + tau) for w, tau, d in self.components if tau is not None))
        return 0.0 if self.kind == "gaussian" else float(self.tail)

    @property
    def support(self) -> tuple[float, float]:
        """(before, after), seconds: X is taken to lie in [-before, after]; mass beyond is < ~1e-17.

        before = MARGIN_SIGMAS * sigma; after adds TAIL_MARGIN_TAUS * tail for the ex-Gaussian.
        """
        before = MARGIN_SIGMAS * self.sigma
        if self.kind == "two_tail":
            return before, before + float(self.tail_delay or 0.0) + TAIL_MARGIN_TAUS * max(self.tail, self.tail2)
        after = before + (TAIL_MARGIN_TAUS * self.tail if self.kind == "exgaussian" else 0.0)
        return before, after

    def cdf(self, x: np.ndarray | float) -> np.ndarray:
        """P(X < x) for delays ``x`` (seconds), float64 array of x's shape.

        Gaussian: ``ndtr(x / sigma)``; delta: ``x > 0``; ex-Gaussian: ``exponnorm.cdf(x, tail/sigma,
        scale=sigma)``. Accurate in the left tail (no cancellation for the Gaussian).
        """
        x = np.asarray(x, dtype=np.float64)
        if self.is_delta:
            return (x > 0).astype(np.float64)
        if self.kind == "gaussian":
            return ndtr(x / self.sigma)
        if self.kind == "two_tail":
            return self._mixture(x, lambda y, tau: ndtr(y / self.sigma) if tau is None else
                                 ex_gaussian_cdf(y, self.sigma, tau))
        return ex_gaussian_cdf(x, self.sigma, self.tail)

    def sf(self, x: np.ndarray | float) -> np.ndarray:
        """P(X >= x) = 1 - cdf(x), computed directly so the right tail keeps its relative accuracy."""
        x = np.asarray(x, dtype=np.float64)
        if self.is_delta:
            return (x <= 0).astype(np.float64)
        if self.kind == "gaussian":
            return ndtr(-x / self.sigma)
        if self.kind == "two_tail":
            return self._mixture(x, lambda y, tau: ndtr(-y / self.sigma) if tau is None else
                                 exponnorm.sf(y, tau / self.sigma, scale=self.sigma))
        return exponnorm.sf(x, self.tail / self.sigma, scale=self.sigma)

    def pdf(self, x: np.ndarray | float) -> np.ndarray:
        """The density h(x), 1/s, float64 of x's shape (sigma > 0): the normal density, ``exponnorm.pdf`` or the
        two-tail mixture of both. Raises ValueError for the delta IRF (it has no density)."""
        x = np.asarray(x, dtype=np.float64)
        if self.is_delta:
            raise ValueError("the delta IRF (sigma = 0) has no density")
        return self._mixture(x, lambda y, tau: np.exp(-0.5 * (y / self.sigma) ** 2) / (math.sqrt(2.0 * math.pi) *
                             self.sigma) if tau is None else exponnorm.pdf(y, tau / self.sigma, scale=self.sigma))

    def _mixture(self, x: np.ndarray, part) -> np.ndarray:
        """Σ weight · part(x − delay, tail) over :attr:`components` (weight-0 components skipped)."""
        out = np.zeros(np.shape(x))
        for w, tau, d in self.components:
            if w > 0:
                out = out + w * part(x - d, tau)
        return out

    def interval_mass(self, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
        """P(lo <= X < hi), float64, broadcast shape of ``lo`` and ``hi`` (seconds, lo <= hi).

        The bin integral of the IRF (docs/physics.md §5; Gaussian: a difference of normal CDFs). Evaluated as a
        difference of survival functions when ``lo`` is above the median and of CDFs otherwise, so a tiny
        bin far in either tail keeps its relative accuracy instead of cancelling to 0.
        """
        lo, hi = np.broadcast_arrays(np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64))
        c_lo = self.cdf(lo)
        upper = c_lo >= 0.5
        mass = np.where(upper, self.sf(lo) - self.sf(hi), self.cdf(hi) - c_lo)
        return np.maximum(mass, 0.0)
