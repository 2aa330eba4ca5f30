"""Analysis: how accurate a simulation is and what accuracy costs (above the simulation layer).

Exported here, what users call: :func:`relative_l2` and :func:`envelope_error` (the error measure),
:func:`converged_reference` and :func:`run_accuracy` (the error-against-time benchmark). Everything else is
imported from its module.

- :mod:`.accuracy`: the error measure (:func:`relative_l2`, :func:`envelope_error`: relative L2 of the binned
  envelope over bins above 1 % of the peak, error of the total and of the peak time), the ladders of settings
  per estimator (:data:`~datagen.analysis.accuracy.LADDERS`) and the error-against-time benchmark
  (:func:`run_accuracy`, ``datagen bench accuracy``).
- :mod:`.reference`: the converged reference (:func:`converged_reference`: the area sampler averaged over
  replicas until its own error estimate meets ``rel_tol``; cached).
- :mod:`.scan_accuracy`: a scan's benchmark, whose Monte Carlo reference would run once per laser point: the
  quadrature's edge ladder against the quadrature at a quarter of the config's edge (``--quadrature-reference``).
- :mod:`.rooms_accuracy`: the benchmark over a dataset's rooms (``--dataset CONFIG``), median and p95 per setting.
- :mod:`.oracle`: the brute-force area quadrature the tests use as an independent oracle; deliberately written
  without the transport code.
- :mod:`.adaptive`: the analysis-layer names of simulating to a tolerance (the loop itself is
  :func:`datagen.simulation.simulate_to_tolerance`, ``simulate --tolerance``).
- :mod:`.compare_capture`: the sim-to-real distance of a measured capture and its simulation on one time axis
  (``datagen compare-capture``); :mod:`.hidden_compare`: the hidden signal of a confocal capture against its
  simulation (direct light excluded, floor, gain, scale), each metric beside its Poisson noise floor.
- :mod:`.capture_detector`: a confocal capture's detector estimated from it: background and gain maps, the
  direct-to-hidden ratio and a two-tail IRF fit (``datagen estimate-capture``).
- :mod:`.second_round_trip`: a retroreflector's second round trip (object → wall → object) in a confocal scan, its
  size and time measured alike on a capture and on its simulation, the main return's tail fitted on both sides.
- :mod:`.hidden_ratio`: the hidden counts of one object captured at two distances, the direct light's slow tail
  taken out (the ratio a simulation without direct light is compared with).
- reconstructions of confocal scans, the benchmark's baselines: :mod:`.backprojection` (filtered backprojection),
  :mod:`.lct` (the light-cone transform, O'Toole et al. 2018), :mod:`.phasor` (phasor fields with
  Rayleigh–Sommerfeld diffraction, Liu et al. 2019); :mod:`.confocal` puts any confocal scan on their time axis and
  finds its direct light, :mod:`.reconstruct` runs one of them and maps depth (``datagen reconstruct``).
"""
from .accuracy import envelope_error, relative_l2, run_accuracy
from .reference import converged_reference

__all__ = ["relative_l2", "envelope_error", "converged_reference", "run_accuracy"]
