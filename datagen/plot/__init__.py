"""Plots: pictures of results (the top of the data flow beside analysis, datasets and I/O).

- :mod:`.envelope`: :func:`plot_envelope`, L(t) on a log scale with its components above the drawn SPAD
  histogram (the paper's Figure 7).
- :mod:`.energy` and :mod:`.figures`: the lookin estimator's sampling views (the paper's Figures 3 and 5):
  :func:`write_sampling_figures` (``datagen simulate --figures``).

matplotlib is imported with the Agg backend; nothing here changes a result.
"""
from .envelope import plot_envelope
from .energy import LaserEnergy, LookinEnergy, laser_energy, lookin_energy, pick_lookin
from .figures import write_sampling_figures

__all__ = ["plot_envelope", "LaserEnergy", "LookinEnergy", "laser_energy", "lookin_energy", "pick_lookin",
           "write_sampling_figures"]
