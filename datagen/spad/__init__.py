"""SPAD / TCSPC detector models: from an expected photon envelope to time-tagged histograms.

Notation (docs/physics.md §6).  For one laser cycle and TDC bin ``i`` the detector sees ``r_i`` expected
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
    without dead time.  docs/physics.md §6, first bullet.  Above 1e12 expected counts a bin is drawn from the
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

Timing order (docs/physics.md §6): the laser pulse shape (already in the transport envelope) and the SPAD
diffusion tail act *before* pile-up (they change which photon comes first); the Gaussian
avalanche/electronic/TDC jitter acts *after* pile-up (it moves the recorded time stamp of the photon that
already won).  At low flux the two orders agree; at high flux they do not (see :func:`apply_jitter_before`).

Exported here, what users call (docs/detector.md): :class:`DetectorConfig`, :func:`rates_from_envelope`,
the histograms (:func:`expected_histogram`, :func:`sample_histogram`), :func:`coates`, :func:`rebin_envelope`,
:func:`gate_fraction`, :func:`instrument_response`, the jitter orders (:func:`apply_jitter_before`,
:func:`apply_jitter_after`) and the counting-mode detectors (:func:`counter_rate`, :func:`counter_variance`,
:func:`sample_counter`). The per-model functions and the tuning constants (chunk sizes, Markov-chain limits, ...)
are imported from their modules.

Modules (each imports only the ones above it):

* :mod:`~datagen.spad.config`: :class:`DetectorConfig` and its YAML presets.
* :mod:`~datagen.spad.arrays`: input checks and numerical helpers for ``(..., bins)`` arrays.
* :mod:`~datagen.spad.effects`: jitter and diffusion-tail kernels, instrument response, crosstalk.
* :mod:`~datagen.spad.rates`: envelope → rates (background, gate, DNL widths), rebinning.
* :mod:`~datagen.spad.synchronous`: ``poisson``, ``pile_up``, ``multi_stop`` pmfs, expectations and samplers.
* :mod:`~datagen.spad.free_running`: free-running dead time (Markov chain with afterpulsing, closed form, event
  simulation).
* :mod:`~datagen.spad.free_running_batched`: the batched free-running simulator (no afterpulsing).
* :mod:`~datagen.spad.correction`: Coates pile-up correction.
* :mod:`~datagen.spad.counters`: counting-mode detectors (no TDC).
* :mod:`~datagen.spad.histogram`: :func:`expected_histogram` and :func:`sample_histogram` for every model.
* :mod:`~datagen.spad.fit_numerics`: Newton polishing, inverse information and sandwich covariance of the fit.
* :mod:`~datagen.spad.maps`: the direct light gated by a stated factor, per-scan-point gain and background maps.
* :mod:`~datagen.spad.fit_two_tail`: the two-tail IRF in a detector fit (envelope, starts, length check).
* :mod:`~datagen.spad.fit`: detector parameters fitted to a measured histogram (docs/capture_io.md).
* :mod:`~datagen.spad.models`: the detector-model registry (each model's expected histogram, sampler, dead time,
  torch and fit support), filled by the modules that implement the models.
* :mod:`~datagen.spad.fit_result`: a fit's values, intervals, goodness of fit and its detector YAML.
* :mod:`~datagen.spad.markov_kernel`: the compiled transition of the free-running chain.
* :mod:`~datagen.spad.pileup`: whether dead time changes the counts beyond a tolerance (the planner's pile-up).
* :mod:`~datagen.spad.ranges`: detector randomisation ranges and how a sample's detector is drawn.
* :mod:`~datagen.spad.map_draws`: gain fields and background bands drawn per sample (torch).
* :mod:`~datagen.spad.torch_noise`: :class:`SPADNoise`, batched SPAD noise on the training device (torch).
"""
from __future__ import annotations

from .config import DetectorConfig
from .counters import counter_rate, counter_variance, sample_counter
from .correction import coates
from .effects import apply_jitter_after, apply_jitter_before, instrument_response
from .histogram import expected_histogram, sample_histogram
from .rates import gate_fraction, rates_from_envelope, rebin_envelope

__all__ = [
    "DetectorConfig", "rates_from_envelope", "expected_histogram", "sample_histogram", "coates", "rebin_envelope",
    "gate_fraction", "instrument_response", "apply_jitter_before", "apply_jitter_after", "counter_rate",
    "counter_variance", "sample_counter",
]
