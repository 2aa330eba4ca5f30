"""Timing stage: the time axis, the instrument response (IRF) and the binning of path impulses into envelopes.

In: path impulses from the transport stage — arrival times ``tau`` (float64 s), weights ``w`` (float64
expected detected photons per laser pulse) and a component id each (room, each hidden object, secondary…) —
or whole sub-triangles as "tents" (their three vertex times). Out: binned envelopes, (n_components, n_bins)
float64 photons per pulse per bin on a :class:`TimeAxis`, each bin the exact integral of the impulses
convolved with the :class:`Irf` (docs/physics.md §5): :meth:`EnvelopeAccumulator.binned`, plus the weight
that fell outside the window (:meth:`EnvelopeAccumulator.outside`).

Exported here: :class:`TimeAxis`, :class:`Irf`, :class:`EnvelopeAccumulator` and :func:`bin_impulses`; the rest
(FWHM conversions, tent closed forms, tuning constants) is imported from its module.

Modules (they import each other directly, never through this package):

- :mod:`~datagen.timing.irf`: :class:`TimeAxis`, :class:`Irf` (Gaussian / ex-Gaussian / two-tail, CDF and bin
  integrals), :func:`fwhm_to_sigma`, :func:`sigma_to_fwhm`;
- :mod:`~datagen.timing.accumulator`: :class:`EnvelopeAccumulator` (fine-grid splatting + FFT, or the exact
  direct mode for narrow IRFs) and the exact per-impulse reference :func:`bin_impulses`;
- :mod:`~datagen.timing.binned_sink`: :class:`~datagen.timing.binned_sink.BinnedSink`, a replica's sink that
  also takes deposits already binned (the light tracer's smoothed orders), its fine grid read only when used;
- :mod:`~datagen.timing.curvature`: the compiled (numba) deposit of those second differences;
- :mod:`~datagen.timing.impulses`: input checks of impulses and :func:`bin_impulses`;
- :mod:`~datagen.timing.tents`: closed forms of tent densities, their convolution with the IRF and their
  O(1)-per-tent second differences (:func:`tent_curvature`).
- compiled (numba) inner loops: :mod:`~datagen.timing.splat_kernel` (impulses onto the fine grid),
  :mod:`~datagen.timing.tent_kernel` (one tent onto it), :mod:`~datagen.timing.fold_kernel` (the fine histogram
  folded and binned).
"""
from .accumulator import EnvelopeAccumulator
from .impulses import bin_impulses
from .irf import Irf, TimeAxis

__all__ = ["TimeAxis", "Irf", "EnvelopeAccumulator", "bin_impulses"]
