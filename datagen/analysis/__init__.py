"""Analysis: how accurate a simulation is and what accuracy costs (above the simulation layer).

- :mod:`.accuracy`: the error measure (:func:`relative_l2`, :func:`envelope_error`: relative L2 of the binned
  envelope over bins above 1 % of the peak, error of the total and of the peak time), the ladders of settings
  per estimator (:data:`LADDERS`) and the error-against-time benchmark (:func:`run_accuracy`,
  ``datagen bench accuracy``).
- :mod:`.reference`: the converged reference (:func:`converged_reference`: the area sampler averaged over
  replicas until its own error estimate meets ``rel_tol``; cached).
- :mod:`.oracle`: the brute-force area quadrature the tests use as an independent oracle; deliberately written
  without the transport code.
- :mod:`.adaptive`: simulate to a tolerance (:func:`simulate_to_tolerance`, ``simulate --tolerance``).
"""
from .accuracy import (ESTIMATORS, LADDERS, AccuracyRow, Ladder, envelope_error, format_table, pareto_front,
                       plot_accuracy, relative_l2, run_accuracy, run_estimator, write_csv)
from .adaptive import TIME_CAP_S, describe_setting, replica_error, simulate_to_tolerance
from .oracle import primary_area_quadrature
from .reference import PEAK_FLOOR, REFERENCE_SAMPLES, REFERENCE_SEED, Reference, converged_reference, peak_time

__all__ = ["ESTIMATORS", "LADDERS", "AccuracyRow", "Ladder", "envelope_error", "format_table", "pareto_front",
           "plot_accuracy", "relative_l2", "run_accuracy", "run_estimator", "write_csv", "describe_setting", "replica_error",
           "simulate_to_tolerance", "primary_area_quadrature", "PEAK_FLOOR", "REFERENCE_SAMPLES",
           "REFERENCE_SEED", "Reference", "converged_reference", "peak_time", "TIME_CAP_S"]
