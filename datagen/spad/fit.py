"""A detector fitted to a measurement: maximum-likelihood parameters of datagen's own detector model from the
histogram of a known return (a direct reflection, a calibration target).

The model is the one :func:`datagen.spad.sample_histogram` draws from, evaluated by the same code
(:func:`~datagen.spad.rates.rates_from_envelope` then :func:`~datagen.spad.histogram.expected_histogram`):

* the return: ``signal`` expected detected photons per laser cycle arriving at ``position`` (s, from the first
  bin edge), a Gaussian laser pulse of known ``pulse_sigma`` integrated over the bins (:func:`return_envelope`);
* the detector: diffusion tail (``diffusion_tail``, ``diffusion_fraction``, before pile-up), or with
  ``irf="two_tail"`` the two-tail IRF (a Gaussian core and two exponential tails, all before pile-up:
  :mod:`.fit_two_tail`), background
  ``background_rate`` (avalanches/s: pde·ambient + dark counts, before pile-up), Gaussian ``jitter_sigma`` (after
  pile-up), and the histogram model: ``pile_up`` (synchronous first photon), ``poisson``, or ``free_running``
  (with its ``dead_time``).

Likelihood. ``pile_up``: exact — the histogram of n cycles is multinomial over the bins plus "no detection in
the window" (jitter after pile-up moves each recorded photon independently, so it stays multinomial).
``poisson``: independent Poisson bins (exact). ``free_running``: independent Poisson bins with the model's
stationary expected histogram (a quasi-likelihood: dead time and afterpulses correlate the bins). Parameters are
fitted on log scales (logit for the tail fraction and the afterpulse probability) with ``scipy.optimize``;
uncertainties are the inverse observed Fisher information (the Hessian of −log L at the optimum) in those
coordinates, mapped back, so 95 % intervals are asymmetric in SI units. A free-running fit with afterpulsing
reports the sandwich covariance H⁻¹VH⁻¹ instead (``covariance="sandwich"``, available to any free-running fit):
V, the variance of the quasi-likelihood's score, from histograms simulated from the fitted parameters (see
:func:`fit_detector`). Goodness of fit: the Poisson deviance and Pearson χ² against bins − parameters degrees of
freedom.

Dead time modulo the period: the detection-phase chain of a free-running detector depends on the dead time only
modulo the laser period T (the next detection after a live point is the same in phase whether τ or τ + T), so τ
and τ + T differ only through the detections per cycle, which the signal and background nearly compensate. The
fit refits from τ ± T, keeps the better optimum and, when the two are within DEAD_TIME_ALIAS_MARGIN in −log L,
says in one line that the dead time is not identifiable modulo the period (bound it: ``dead_time_bounds``).

Simultaneous intervals (:attr:`DetectorFit.joint_intervals`): all k fitted parameters inside theirs at once with
probability ≥ 95 % (Bonferroni, :func:`joint_z`); docs/capture_io.md gives their measured coverage.

A parameter is *not identifiable* when the data do not constrain it: its 95 % interval spans more than a factor
:data:`IDENTIFIABLE_SPAN` or the Hessian is singular along it. The fit says so in one line per parameter
(:attr:`DetectorFit.messages`); fix it (``fixed={...}``) to the value you know.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import optimize, special, stats

from ..errors import ConfigError
from ..validate import MIN_HISTOGRAM_BINS
from .config import DetectorConfig
from .fit_numerics import (REJECTED, inverse_covariance, newton, profile_interval, profile_walk,
                           sandwich_covariance, with_coordinate)
from .fit_result import UNITS, DetectorFit
from .fit_two_tail import (TWO_TAIL_DELAY_STARTS, TWO_TAIL_PARAMETERS, check_two_tail_length, two_tail_envelope, two_tail_irf,
                           two_tail_start)
from .histogram import expected_histogram, sample_histogram
from .models import model_names
from .rates import rates_from_envelope

__all__ = [
    "IDENTIFIABLE_SPAN", "FIT_MODELS", "IRF_SHAPES", "DetectorFit", "return_envelope", "fit_detector",
    "fit_parameter_names", "joint_z", "rising_edge_missing",
]

IDENTIFIABLE_SPAN = 10.0
"""A parameter whose 95 % interval spans more than this factor (upper/lower) is reported as not identifiable."""

MAX_DEAD_TIME_PERIODS = 4.0
"""Dead times searched up to this many laser periods (longer ones make the free-running chain mix slowly)."""

DEAD_TIME_SCAN = 160
"""Dead times (log grid, two bins to MAX_DEAD_TIME_PERIODS periods: 4 % apart, about 3 bins at 4 ns in 50 ps bins)
scanned after a free-running fit with the other parameters held, to escape a local minimum (the likelihood in the
dead time has bumps a few bins wide where the recovery edge after the return meets the counts' noise)."""

DEAD_TIME_RESTARTS = 3
"""Local refits from the lowest local minima of the dead-time scan (DEAD_TIME_SCAN) more than DEAD_TIME_BASIN from
the optimum (the others held there, a minimum of the scan is not one of the likelihood: the background trades
against the dead time)."""

DEAD_TIME_BASIN = 0.1  # log units: scan minima closer than this to the optimum are its own basin

DEAD_TIME_PROFILE_SPAN = 1.2
"""Half-width (log units: a factor 3.3 each way) of the dead-time profile walked for its interval, wider than
IDENTIFIABLE_SPAN in all, so a flat profile is reported as not identifiable."""

DEAD_TIME_PROFILE_STEP = (0.005, 0.04)
"""Bounds on the profile's grid step (log units): half the quadratic σ of the dead time, within these."""

SIMPLEX_STEP = 0.1
"""Nelder-Mead's starting simplex: each log / logit parameter 0.1 from the start (10 %). scipy's default (5 % of
each coordinate) is a factor 2-3 in a log-scale time (log 5e-9 ≈ −19) and sent free-running fits to a dead time of
half the true one (docs/capture_io.md)."""

SIMPLEX_STEP_BINS = 0.5  # the same for the return's position, in bins

DEAD_TIME_ALIAS_MARGIN = 3.0
"""Two free-running optima whose dead times differ by a whole laser period (τ and τ ± T explain nearly the same
phase histogram, the signal and background compensating) whose −log L differ by less than this (a likelihood ratio
below e³ ≈ 20) make the dead time not identifiable modulo the period: the fit says so in one line."""

SANDWICH_REPLICATES = 1000
"""Simulated histograms (independent pixels of one event simulation) whose quasi-score variance gives the
sandwich covariance of a free-running fit."""

SANDWICH_CYCLES = 2000
"""Laser cycles of each simulated histogram (fewer when the data have fewer); the score variance is scaled to the
data's cycle count (it grows linearly in cycles)."""

FIT_MODELS = model_names(fittable=True)
"""The detector models a fit takes: those the registry marks ``fittable`` (:mod:`.models`)."""
IRF_SHAPES = ("gauss", "exgauss", "two_tail")
COVARIANCES = ("fisher", "sandwich")

_LOG = ("signal", "jitter_sigma", "diffusion_tail", "background_rate", "dead_time", "tail", "tail2", "tail_delay")
_LOGIT = ("diffusion_fraction", "afterpulse_probability", "tail_weight", "tail2_weight")


def return_envelope(n_bins: int, bin_width: float, position: float, signal: float,
                    pulse_sigma: float) -> np.ndarray:
    """The known return as an envelope: ``signal`` photons per cycle in a Gaussian pulse centred ``position`` s
    after the first bin edge, of std ``pulse_sigma`` s, integrated over the bins (a delta inside one bin when
    ``pulse_sigma`` is 0).

    Returns:
        float64 (n_bins,) expected detected photons per laser cycle per bin.
    """
    edges = np.arange(n_bins + 1) * bin_width
    if pulse_sigma <= 0:
        env = np.zeros(n_bins)
        k = int(position // bin_width)
        if 0 <= k < n_bins:
            env[k] = signal
        return env
    return signal * np.diff(special.ndtr((edges - position) / pulse_sigma))


def rising_edge_missing(histogram: Any) -> int | None:
    """The peak bin of a histogram whose return starts before its first bin, else None: every bin up to the peak
    of the background-subtracted counts holds more than half of it (the rising half maximum is not in the window),
    so the return's position and jitter are not in the data (a fit drives the jitter to 0). The background is the
    mean of the lowest quarter of the bins, as :func:`fit_detector` starts from."""
    h = np.asarray(histogram, dtype=np.float64)
    net = h - float(np.mean(np.sort(h)[: max(h.size // 4, 1)]))
    peak = int(np.argmax(net))
    return peak if net[peak] > 0 and bool(np.all(net[: peak + 1] > 0.5 * net[peak])) else None


def fit_parameter_names(model: str, irf: str, fit_fraction: bool, afterpulsing: bool = False) -> list[str]:
    """Free parameters of a fit, in order (before ``fixed`` removes some); ``afterpulsing`` adds
    ``afterpulse_probability`` to a free-running fit."""
    names = ["signal", "position", "jitter_sigma"]
    if irf == "exgauss":
        names.append("diffusion_tail")
        if fit_fraction:
            names.append("diffusion_fraction")
    if irf == "two_tail":
        names.extend(TWO_TAIL_PARAMETERS)
    names.append("background_rate")
    if model == "free_running":
        names.append("dead_time")
        if afterpulsing:
            names.append("afterpulse_probability")
    return names


def _to_fit(name: str, value: float) -> float:
    if name in _LOG:
        return math.log(value)
    if name in _LOGIT:
        return math.log(value / (1.0 - value))
    return value


def joint_z(k: int, level: float = 0.95) -> float:
    """The normal quantile of ``k`` simultaneous intervals at joint coverage ≥ ``level`` (Bonferroni: each
    two-sided at 1 − (1 − level)/k; 1.96 for k = 1, 2.58 for 5, 2.69 for 7)."""
    return float(stats.norm.ppf(1.0 - (1.0 - level) / (2.0 * max(int(k), 1))))


def _interval(name: str, centre: float, half: float, ok: bool, bin_width: float) -> tuple[float, float]:
    """(low, high) in SI units of fit coordinate ``centre`` ± ``half`` (log / logit / position in bins); the whole
    range when ``ok`` is False (no finite variance)."""
    if not ok:
        return (0.0, 1.0) if name in _LOGIT else (-math.inf if name not in _LOG else 0.0, math.inf)
    scale = bin_width if name == "position" else 1.0
    return float(_from_fit(name, centre - half)) * scale, float(_from_fit(name, centre + half)) * scale


def _constrained(name: str, lo: float, hi: float, ok: bool) -> bool:
    """Whether the 95 % interval (lo, hi) of parameter ``name`` pins it (module doc): a finite variance (``ok``),
    a span of at most IDENTIFIABLE_SPAN (log parameters) and less than 0.9 of [0, 1] (logit ones)."""
    span = hi / lo if (name in _LOG and lo > 0) else math.inf if name in _LOG else 1.0
    return bool(ok and span <= IDENTIFIABLE_SPAN and not (name in _LOGIT and (hi - lo) > 0.9))


def _from_fit(name: str, x: np.ndarray | float):
    if name in _LOG:
        return np.exp(x)
    if name in _LOGIT:
        return special.expit(x)
    return x


def _trial_overflow_ignored(func):
    """Run ``func`` under ``np.errstate`` that ignores overflow and division by zero: the optimiser's trial
    parameters (log scale) can reach inf, which the likelihood rejects (``REJECTED``); the result is checked
    finite, and no floating-point warning reaches the user."""
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            return func(*args, **kwargs)
    return wrapper


@_trial_overflow_ignored
def fit_detector(histogram: Any, *, bin_width: float, repetition_rate: float, n_cycles: int,
                 model: str = "pile_up", irf: str = "exgauss", t_start: float = 0.0,
                 pulse_sigma: float | None = None, fixed: dict[str, float] | None = None,
                 fit_fraction: bool = False, initial: dict[str, float] | None = None,
                 afterpulse_time_constant: float | None = None, covariance: str | None = None,
                 seed: int = 0, dead_time_bounds: tuple[float, float] | None = None,
                 allow_cropped_edge: bool = False) -> DetectorFit:
    """Maximum-likelihood fit of datagen's detector model to the histogram of a known return.

    Args:
        histogram: (bins,) counts over ``n_cycles`` laser cycles (integers ≥ 0; any numeric dtype).
        bin_width: s; repetition_rate: Hz; n_cycles: laser cycles of the exposure; t_start: s, the first bin's
            left edge within the laser period.
        model: "pile_up" (synchronous, first photon), "poisson", or "free_running" (dead time).
        irf: "gauss" (jitter only), "exgauss" (jitter + exponential diffusion tail) or "two_tail" (a Gaussian
            core of std sqrt(pulse_sigma² + jitter_sigma²) plus two exponential tails delayed alike, the
            :class:`~datagen.timing.irf.Irf` of kind ``two_tail``, all before pile-up: :mod:`.fit_two_tail`;
            :attr:`DetectorFit.irf_model` is the fitted IRF).
        pulse_sigma: the laser pulse's std in s (known; default half a bin, which only smooths the sub-bin
            position of the return).
        fixed: parameters to hold (names of :func:`fit_parameter_names`, plus ``diffusion_fraction``, default 1
            when not fitted), e.g. ``{"dead_time": 77e-9}``.
        fit_fraction: also fit ``diffusion_fraction`` (ex-Gaussian IRF with a Gaussian core share).
        initial: starting values (default: moments of the histogram).
        afterpulse_time_constant: s, the detector's afterpulse time constant τ_ap (known, held); when given, a
            ``free_running`` fit also fits ``afterpulse_probability`` (logit scale; afterpulses at
            ``t + dead_time + Exp(τ_ap)``, the expectation of datagen/spad/free_running.py).
        covariance: how the uncertainties are computed: "fisher" (inverse observed information of the
            likelihood; exact for ``pile_up`` and ``poisson``) or "sandwich" (``free_running`` only: H⁻¹VH⁻¹, H
            the Hessian of the Poisson quasi-likelihood, V the variance of its score estimated from
            SANDWICH_REPLICATES histograms of SANDWICH_CYCLES cycles simulated from the fitted parameters by
            :func:`datagen.spad.sample_histogram`, scaled to ``n_cycles``). Default: "sandwich" for a free-running
            fit with afterpulsing (correlated bins: the Poisson form's information is not the estimator's
            variance; the two compared in docs/capture_io.md), else "fisher".
        dead_time_bounds: (low, high) s, what the detector's datasheet allows for its dead time
            (``free_running`` only): the fit searches only there (default: two bins to MAX_DEAD_TIME_PERIODS
            periods). A free-running histogram determines the dead time modulo the laser period, its whole number
            of periods only weakly (τ and τ ± T give the same detection-phase chain, see DEAD_TIME_ALIAS_MARGIN);
            bounds narrower than a period exclude the aliases.
        allow_cropped_edge: fit ``position`` and ``jitter_sigma`` although the return's rising edge is before the
            first bin (a capture rectified to start at its direct light, as the Stanford LCT files are): the core's
            falling half and the tails then fix them; the result says so in :attr:`DetectorFit.messages`.
        seed: the sandwich's simulation stream, ``numpy.random.default_rng(seed)`` (int ≥ 0; results are
            deterministic in it).
    Returns:
        :class:`DetectorFit` (``settings["covariance"]`` names the method used; a sandwich fit also records
        ``sandwich_replicates``, ``sandwich_cycles`` and ``seed``).
    Raises:
        ConfigError: bad arguments (unknown model, IRF, covariance or parameter, a sandwich for a model whose
            likelihood is exact, a histogram that is empty, negative, non-integer or has no counts); the message
            names the argument and the value; a return whose rising edge is before the first bin
            (:func:`rising_edge_missing`) unless ``position`` and ``jitter_sigma`` are held (``two_tail``: unless
            ``allow_cropped_edge``); a two-tail fit of a histogram with fewer than
            :data:`~datagen.spad.fit_two_tail.TWO_TAIL_MIN_BINS` bins after the return's peak.
    """
    h = np.asarray(histogram)
    if h.ndim != 1 or h.size < MIN_HISTOGRAM_BINS:
        raise ConfigError(f"histogram must be 1-D with at least {MIN_HISTOGRAM_BINS} bins, got shape {h.shape}")
    if not np.all(np.isfinite(h)) or np.any(h < 0) or np.any(h != np.round(h)):
        raise ConfigError("histogram must hold counts (finite whole numbers >= 0)")
    h = h.astype(np.float64)
    if h.sum() <= 0:
        raise ConfigError("histogram has no counts")
    if model not in FIT_MODELS:
        raise ConfigError(f"model must be one of {', '.join(FIT_MODELS)}, got {model!r}")
    if irf not in IRF_SHAPES:
        raise ConfigError(f"irf must be one of {', '.join(IRF_SHAPES)}, got {irf!r}")
    if not (bin_width > 0 and repetition_rate > 0 and n_cycles >= 1):
        raise ConfigError(f"need bin_width > 0, repetition_rate > 0, n_cycles >= 1 (got {bin_width!r}, "
                          f"{repetition_rate!r}, {n_cycles!r})")
    n_bins = h.size
    if t_start + n_bins * bin_width > 1.0 / repetition_rate * (1 + 1e-9):
        raise ConfigError(f"the histogram window ({n_bins} bins of {bin_width:.4g} s from {t_start:.4g} s) is longer "
                          f"than the laser period {1 / repetition_rate:.4g} s")
    pulse = 0.5 * bin_width if pulse_sigma is None else float(pulse_sigma)
    if afterpulse_time_constant is not None and (model != "free_running" or not afterpulse_time_constant >= 0):
        raise ConfigError(f"afterpulse_time_constant={afterpulse_time_constant!r}: needs model 'free_running' "
                          f"(got {model!r}) and a value >= 0 s")
    if covariance is None:
        covariance = "sandwich" if afterpulse_time_constant is not None else "fisher"
    if covariance not in COVARIANCES or (covariance == "sandwich" and model != "free_running"):
        raise ConfigError(f"covariance={covariance!r}: must be one of {', '.join(COVARIANCES)}, and 'sandwich' needs "
                          f"model 'free_running' (got {model!r}; the other models' likelihoods are exact)")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be an integer >= 0, got {seed!r}")
    if dead_time_bounds is not None:
        try:
            lo_dt, hi_dt = (float(v) for v in dead_time_bounds)
        except (TypeError, ValueError):
            lo_dt = hi_dt = math.nan
        top = MAX_DEAD_TIME_PERIODS / repetition_rate
        if model != "free_running":
            raise ConfigError(f"dead_time_bounds={dead_time_bounds!r}: a dead time is fitted by model 'free_running' "
                              f"only (got {model!r})")
        if not 0 < lo_dt < hi_dt <= top:
            why = ("LOW is not below HIGH" if 0 < hi_dt <= lo_dt else "LOW must be > 0" if not lo_dt > 0 else
                   f"HIGH is above {MAX_DEAD_TIME_PERIODS:g} laser periods ({top:.4g} s)" if hi_dt > top else
                   "not two numbers")
            raise ConfigError(f"dead_time_bounds=({lo_dt:.4g} s, {hi_dt:.4g} s): {why}; give LOW,HIGH with "
                              f"0 < LOW < HIGH <= {top:.4g} s")
    else:
        lo_dt, hi_dt = 2 * bin_width, MAX_DEAD_TIME_PERIODS / repetition_rate
    names_all = fit_parameter_names(model, irf, fit_fraction, afterpulse_time_constant is not None)
    fixed = dict(fixed or {})
    peak = rising_edge_missing(h)
    if irf == "two_tail":
        check_two_tail_length(h, int(np.argmax(h)))
    cropped = peak is not None and allow_cropped_edge
    if peak is not None and not cropped and not {"position", "jitter_sigma"} <= set(fixed):
        raise ConfigError(f"histogram: the return peaks in bin {peak} of {n_bins} with every bin before it above half "
                          "its peak (its rising edge is before the first bin): position and jitter_sigma cannot be "
                          "fitted; give a histogram that holds the whole return, or hold both (fixed={...})")
    for k in fixed:
        if k not in names_all and k != "diffusion_fraction":
            raise ConfigError(f"fixed: unknown parameter {k!r} for model {model!r}, IRF {irf!r} (parameters: "
                              f"{', '.join(names_all)})")
    if dead_time_bounds is not None and "dead_time" in fixed and not lo_dt <= fixed["dead_time"] <= hi_dt:
        raise ConfigError(f"fixed dead_time={fixed['dead_time']!r} s is outside dead_time_bounds={dead_time_bounds!r}")
    if irf == "exgauss" and not fit_fraction:
        fixed.setdefault("diffusion_fraction", 1.0)
    free = [k for k in names_all if k not in fixed]
    start = _initial_guess(h, bin_width, n_cycles, model, pulse)
    if irf == "two_tail":
        start.update(two_tail_start(h, bin_width, int(np.argmax(h))))
        if cropped:                        # the core's peak at the first bin: half its width to the half maximum
            start["position"] = 0.5 * bin_width
    start.update(initial or {})
    if dead_time_bounds is not None:
        start["dead_time"] = min(max(start["dead_time"], lo_dt * 1.01), hi_dt * 0.99)
    base = {"model": model, "repetition_rate": repetition_rate, "n_cycles": int(n_cycles), "bin_width": bin_width,
            "t_start": t_start}
    if afterpulse_time_constant is not None:
        base["afterpulse_time_constant"] = float(afterpulse_time_constant)

    def params_of(x: np.ndarray) -> dict[str, float]:
        p = dict(fixed)
        for name, xi in zip(free, x):
            p[name] = float(xi) * bin_width if name == "position" else float(_from_fit(name, xi))
        return p

    def expected(p: dict[str, float]) -> np.ndarray:
        cfg = _config(base, p, irf)
        env = (two_tail_envelope(n_bins, bin_width, p, pulse) if irf == "two_tail" else
               return_envelope(n_bins, bin_width, p["position"], p["signal"], pulse))
        return expected_histogram(rates_from_envelope(env, cfg), cfg)

    def nll(x: np.ndarray) -> float:
        p = params_of(x)
        if p.get("dead_time", 0.0) > hi_dt or (dead_time_bounds is not None and p["dead_time"] < lo_dt):
            return REJECTED
        if p.get("tail_weight", 0.0) + p.get("tail2_weight", 0.0) > 1.0:
            return REJECTED
        try:
            mu = expected(p)
        except (ValueError, FloatingPointError):
            return REJECTED
        return _negative_log_likelihood(h, mu, n_cycles, model)

    x0 = np.array([start[k] / bin_width if k == "position" else _to_fit(k, start[k]) for k in free])
    steps = [1e-2 if k == "position" else 1e-3 for k in free]          # position in bins, others log / logit
    simplex_steps = [SIMPLEX_STEP_BINS if k == "position" else SIMPLEX_STEP for k in free]
    def local_fit(x_start: np.ndarray):
        simplex = x_start + np.vstack([np.zeros(len(free)), np.diag(simplex_steps)])
        res = optimize.minimize(nll, x_start, method="Nelder-Mead",
                                options={"maxfev": 600 * len(free), "xatol": 1e-4, "fatol": 1e-3, "adaptive": True,
                                         "initial_simplex": simplex})
        return newton(nll, res.x, steps)

    best, hess, converged = local_fit(x0)
    if "tail_delay" in free and "tail_delay" not in (initial or {}):
        # two tails: a delayed fast tail (a shoulder after the core) and an undelayed one are separate optima
        i = free.index("tail_delay")
        for bins in TWO_TAIL_DELAY_STARTS:
            other = local_fit(with_coordinate(x0, i, math.log(bins * bin_width)))
            if nll(other[0]) < nll(best):
                best, hess, converged = other
    alias = None                          # (the runner-up's dead time, its −log L above the best)
    if "dead_time" in free:
        # the likelihood has local minima in the dead time: scan it with the other parameters held and refit from
        # the DEAD_TIME_RESTARTS lowest local minima of the scan outside the optimum's own basin
        i = free.index("dead_time")
        grid = np.log(np.geomspace(lo_dt, hi_dt, DEAD_TIME_SCAN))
        trial = np.array([nll(with_coordinate(best, i, g)) for g in grid])
        padded = np.concatenate([[np.inf], trial, [np.inf]])
        minima = np.flatnonzero((trial <= padded[:-2]) & (trial <= padded[2:]))
        minima = minima[np.abs(grid[minima] - best[i]) > DEAD_TIME_BASIN]
        for j in minima[np.argsort(trial[minima], kind="stable")][:DEAD_TIME_RESTARTS]:
            other = local_fit(with_coordinate(best, i, grid[j]))
            if nll(other[0]) < nll(best):
                best, hess, converged = other
        # τ and τ ± one period explain nearly the same phase histogram: refit from each, keep the best, and remember
        # the runner-up (its −log L above the best) for the identifiability line
        # (only when the dead time is identifiable locally: otherwise the line below says so already)
        period = 1.0 / repetition_rate
        var = inverse_covariance(hess)[0][i, i]
        finite = bool(np.isfinite(var) and var > 0)
        lo, hi = _interval("dead_time", best[i], 1.96 * math.sqrt(var) if finite else 0.0, finite, bin_width)
        local = _constrained("dead_time", lo, hi, finite)
        for shift in (-period, period) if local else ():
            tau = float(np.exp(best[i])) + shift
            if lo_dt <= tau <= hi_dt:
                other = local_fit(with_coordinate(best, i, math.log(tau)))
                if abs(float(np.exp(other[0][i]) - np.exp(best[i]))) < 0.5 * period:
                    continue                                       # fell back to the same optimum
                if nll(other[0]) < nll(best):
                    other, (best, hess, converged) = (best, hess, converged), other
                gap = nll(other[0]) - nll(best)
                if alias is None or gap < alias[1]:
                    alias = (float(np.exp(other[0][i])), gap)
    values = params_of(best)
    cov, singular = inverse_covariance(hess)
    if covariance == "sandwich":
        m = min(int(n_cycles), SANDWICH_CYCLES)
        cov = sandwich_covariance(cov, best, steps, lambda x: expected(params_of(x)),
                                  _simulate_replicates(base, values, irf, n_bins, pulse, m, seed), int(n_cycles), m)
    errors, intervals, joint, identifiable, messages = {}, {}, {}, {}, []
    z_joint = joint_z(len(free))
    for i, name in enumerate(free):
        var = cov[i, i]
        ok = np.isfinite(var) and var > 0 and i not in singular
        sd = math.sqrt(var) if ok else math.inf
        lo, hi = _interval(name, best[i], 1.96 * sd, ok, bin_width)
        joint[name] = _interval(name, best[i], z_joint * sd, ok, bin_width)
        if name == "dead_time" and ok and hess[i, i] > 0:
            # not quadratic in τ (docs/capture_io.md): also the profile likelihood-ratio set, the others refitted
            limits, half = (math.log(lo_dt), math.log(hi_dt)), DEAD_TIME_PROFILE_SPAN
            span = (max(limits[0], best[i] - half), min(limits[1], best[i] + half))
            step = min(max(0.5 * sd, DEAD_TIME_PROFILE_STEP[0]), DEAD_TIME_PROFILE_STEP[1])
            grid, delta, at_bound = profile_walk(nll, best, i, hess, steps, step, 0.5 * z_joint ** 2 + 2, span)
            a, b = profile_interval(grid, delta, 1.96)       # the wider of it and the quadratic interval
            lo, hi, (ja, jb) = min(lo, math.exp(a)), max(hi, math.exp(b)), profile_interval(grid, delta, z_joint)
            joint[name] = (min(joint[name][0], math.exp(ja)), max(joint[name][1], math.exp(jb)))
            sd = math.log(hi / lo) / (2 * 1.96)
            # a 95 % set that runs into the end of the walk is bounded by the search, not by the data (a datasheet's
            # dead_time_bounds may bound one side: the interval stops there)
            reach = [end and rise <= 0.5 * 1.96 ** 2 for end, rise in zip(at_bound, (delta[0], delta[-1]))]
            datasheet = [dead_time_bounds is not None and span[k] == limits[k] for k in (0, 1)]
            ok = not all(reach) and not any(r and not d for r, d in zip(reach, datasheet))
        deriv = bin_width if name == "position" else 1.0
        if name in _LOG:
            deriv = values[name]
        elif name in _LOGIT:
            deriv = values[name] * (1 - values[name])
        errors[name] = abs(deriv) * sd if ok else math.inf
        intervals[name] = (lo, hi)
        good = _constrained(name, lo, hi, ok)
        identifiable[name] = good
        if not good:
            messages.append(f"{name} is not identifiable from this histogram (95 % interval {lo:.3g} .. {hi:.3g} "
                            f"{UNITS[name]}): fix it to a known value (fixed={{'{name}': ...}} / --fix {name}=...)")
    if alias is not None and identifiable["dead_time"] and alias[1] < DEAD_TIME_ALIAS_MARGIN:
        identifiable["dead_time"] = False
        messages.append(f"dead_time is not identifiable modulo the laser period from this histogram: "
                        f"{values['dead_time']:.4g} s and {alias[0]:.4g} s fit within a likelihood ratio of "
                        f"{math.exp(alias[1]):.3g} (threshold {math.exp(DEAD_TIME_ALIAS_MARGIN):.3g}): fix it to a "
                        f"known value or bound it (dead_time_bounds=(low, high) / --dead-time-bounds LOW,HIGH)")
    bad = [f"{k} = {v}" for k, v in values.items() if not np.isfinite(v)]
    if bad:
        raise ConfigError(f"the fit did not converge to finite parameters ({', '.join(bad)}): the histogram may not "
                          "be a detector's (check the counts and the bin width), or fix those parameters (--fix)")
    mu = expected(values)
    deviance, pearson, dof, p_value = _goodness(h, mu, len(free))
    if cropped:
        messages.append(f"the return's rising edge is before the first bin (its peak is in bin {peak}): position and "
                        "jitter_sigma come from the falling half of the core and the tails only")
    return DetectorFit(model, irf, values, errors, intervals, joint, {k: v for k, v in fixed.items()
                                                               if k in names_all or irf == "exgauss"},
                       identifiable, messages, deviance, pearson, dof, p_value, mu, _config(base, values, irf),
                       {"bin_width": bin_width, "repetition_rate": repetition_rate, "n_cycles": int(n_cycles),
                        "t_start": t_start, "pulse_sigma": pulse, "converged": converged,
                        "afterpulse_time_constant": afterpulse_time_constant, "covariance": covariance,
                        **({"dead_time_alias": {"dead_time": alias[0], "delta_log_likelihood": alias[1]}}
                           if alias is not None else {}),
                        **({"sandwich_replicates": SANDWICH_REPLICATES,
                            "sandwich_cycles": min(int(n_cycles), SANDWICH_CYCLES), "seed": int(seed)}
                           if covariance == "sandwich" else {})},
                       two_tail_irf(values, pulse) if irf == "two_tail" else None)


def _config(base: dict, p: dict, irf: str) -> DetectorConfig:
    # two_tail: the jitter is the IRF's core, in the envelope (.fit_two_tail)
    extra = {"dcr": p["background_rate"], "jitter_sigma": 0.0 if irf == "two_tail" else p["jitter_sigma"]}
    if irf == "exgauss":
        extra["diffusion_tail"] = p["diffusion_tail"]
        extra["diffusion_fraction"] = p.get("diffusion_fraction", 1.0)
    if base["model"] == "free_running":
        extra["dead_time"] = p["dead_time"]
        if "afterpulse_time_constant" in base:
            extra["afterpulse_probability"] = p["afterpulse_probability"]
    return DetectorConfig(**base, **extra)


def _simulate_replicates(base: dict, values: dict, irf: str, n_bins: int, pulse: float, cycles: int,
                         seed: int) -> np.ndarray:
    """SANDWICH_REPLICATES histograms of ``cycles`` cycles drawn from the fitted model (one event simulation, a
    pixel per replicate, ``numpy.random.default_rng(seed)``): int64 (replicates, bins)."""
    cfg = _config({**base, "n_cycles": cycles}, values, irf)
    env = (two_tail_envelope(n_bins, base["bin_width"], values, pulse) if irf == "two_tail" else
           return_envelope(n_bins, base["bin_width"], values["position"], values["signal"], pulse))
    rates = rates_from_envelope(env, cfg)
    return sample_histogram(np.tile(rates, (SANDWICH_REPLICATES, 1)), cfg, np.random.default_rng(seed))


def _negative_log_likelihood(h: np.ndarray, mu: np.ndarray, n: int, model: str) -> float:
    mu = np.maximum(mu, 1e-300)
    if model == "pile_up":
        p = mu / n
        rest = 1.0 - p.sum()
        if rest <= 0:
            return REJECTED
        return float(-(h * np.log(p)).sum() - (n - h.sum()) * math.log(rest))
    return float((mu - h * np.log(mu)).sum())


def _goodness(h: np.ndarray, mu: np.ndarray, k: int) -> tuple[float, float, int, float]:
    mu = np.maximum(mu, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(h > 0, h * np.log(h / mu), 0.0)
    deviance = float(2.0 * (term - (h - mu)).sum())
    pearson = float(((h - mu) ** 2 / mu).sum())
    dof = max(int(h.size - k), 1)
    return deviance, pearson, dof, float(stats.chi2.sf(deviance, dof))


def _initial_guess(h: np.ndarray, dt: float, n: int, model: str, pulse: float) -> dict[str, float]:
    """Moments of the histogram: background from the lowest quartile of bins, the return's position from the
    peak, its width from the counts above half maximum, its signal from the net counts (pile-up corrected)."""
    n_bins = h.size
    bg_per_bin = float(np.mean(np.sort(h)[: max(n_bins // 4, 1)]))
    net = np.maximum(h - bg_per_bin, 0.0)
    peak = int(np.argmax(net))
    above = np.flatnonzero(net >= 0.5 * net[peak])
    fwhm_bins = max(float(above.max() - above.min() + 1), 1.0)
    sigma = max(fwhm_bins * dt / 2.355, 0.3 * dt)
    total = float(net.sum())
    frac = min(total / n, 0.95)
    signal = -math.log1p(-frac) if model == "pile_up" else total / n
    return {"signal": max(signal, 1e-9), "position": (peak + 0.5) * dt, "jitter_sigma": sigma,
            "diffusion_tail": max(sigma, dt), "diffusion_fraction": 0.5, "afterpulse_probability": 0.05,
            "background_rate": max(bg_per_bin, 0.5) / (n * dt),
            "dead_time": _dead_time_guess(h, peak, fwhm_bins) * dt}


def _dead_time_guess(h: np.ndarray, peak: int, width: float) -> float:
    """Bins from the return's peak to where the counts step back up after the dead-time dip (the largest rise of
    a moving mean after the return's tail); 10 bins when there is no dip to see. The likelihood in the dead time
    has local minima (a short dead time explains part of the dip), so the start matters."""
    first = peak + int(3 * width) + 2
    w = max(int(width), (h.size - first) // 8, 4)
    if h.size - first < 3 * w:
        return 10.0
    c = np.concatenate([[0.0], np.cumsum(h)])
    k = np.arange(first + w, h.size - w + 1)
    rise = (c[k + w] - c[k]) / w - (c[k] - c[k - w]) / w
    return float(k[int(np.argmax(rise))] - peak)
