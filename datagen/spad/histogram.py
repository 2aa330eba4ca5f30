"""Public model dispatch: :func:`expected_histogram` and :func:`sample_histogram` for ``DetectorConfig.model``
through the detector-model registry (:mod:`.models`: ``poisson``, ``pile_up``, ``multi_stop``, ``free_running``),
then the Gaussian jitter after pile-up."""
from __future__ import annotations

from typing import Any

import numpy as np

from .arrays import as_rates
from .config import DetectorConfig
from .effects import convolve_last, gaussian_kernel, jitter_counts
from . import free_running_batched, synchronous  # noqa: F401  (importing them registers their models)
from .models import detector_model

__all__ = [
    "expected_histogram",
    "sample_histogram",
]


def _check_window(r: np.ndarray, config: DetectorConfig) -> None:
    config.widths(r.shape[-1])  # raises on a DNL length mismatch


def expected_histogram(rates: Any, config: DetectorConfig) -> np.ndarray:
    """Expected counts over the exposure for ``config.model`` (then Gaussian jitter after pile-up).

    * ``poisson``: ``n·r_i`` — low-flux limit (docs/physics.md §6).
    * ``pile_up``: ``n·e^{−C_i}(1 − e^{−r_i})`` — synchronous first photon, Coates 1968.
    * ``multi_stop``: exact recursion ``E[N_i] = L_i p_i``, ``L_{i+1} = L_i − E[N_i] + E[N_{i−d}]``,
      ``d = round(dead_time/bin_width)`` bins blocked after each detection, re-armed every cycle.
    * ``free_running``: ``n·ρ·π`` with π the stationary detection-phase distribution of the Markov chain
      (Rapp, Ma, Dawson, Goyal, IEEE TSP 2019; discretised on ``markov_oversample`` cells per bin) and ρ the
      detections per cycle; paralyzable dead time uses the exact closed form λ(t)e^{−∫_{t−τ}^{t}λ}. Afterpulsing
      (non-paralyzable, no gate) is in the same chain: the pending afterpulse is cancelled by the next detection.
      Stationary: the start-up transient (≤ one dead time) is ignored.

    Args:
        rates: (..., bins) expected avalanches per cycle per bin (float32 accepted).
        config: detector description.
    Returns:
        float64 (..., bins) expected counts.
    Raises:
        ValueError: invalid rates, DNL length mismatch, window longer than the period (free_running).
        NotImplementedError: crosstalk, or afterpulsing with a gate (average :func:`sample_histogram`).
    """
    r = as_rates(rates)
    _check_window(r, config)
    if config.crosstalk_probability > 0:
        raise NotImplementedError("crosstalk has no closed-form expected histogram here; "
                                  "average sample_histogram draws (event simulation)")
    shape = r.shape
    hist = detector_model(config.model).expected(r, config).reshape(-1, shape[-1])
    if config.jitter > 0:
        kernel, first = gaussian_kernel(config.jitter, config.bin_width)
        hist = convolve_last(hist, kernel, first)
    return hist.reshape(shape)


def sample_histogram(rates: Any, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Draw one exposure's histogram for ``config.model`` (then Gaussian jitter after pile-up).

    * ``poisson``: ``rng.poisson(n·r)``; bins expecting more than POISSON_NORMAL_ABOVE (1e12) counts draw the
      normal approximation round(N(λ, λ)) clipped at 0 (see the constant for its accuracy and why).
    * ``pile_up``: exact multinomial as sequential binomials ``N_i ~ Bin(D_i, 1 − e^{−r_i})``,
      ``D_0 = n``, ``D_{i+1} = D_i − N_i`` (docs/physics.md §6), vectorised over pixels (histograms longer than
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
    r = as_rates(rates)
    _check_window(r, config)
    shape = r.shape
    counts = detector_model(config.model).sample(r, config, rng).reshape(-1, shape[-1])
    if config.jitter > 0:
        kernel, first = gaussian_kernel(config.jitter, config.bin_width)
        counts = jitter_counts(counts, kernel, first, rng)
    return counts.reshape(shape)
