"""SPAD / TCSPC detector models (package; the model code is in :mod:`datagen.spad.free_running` for now)."""
from .free_running import *  # noqa: F401,F403
from .free_running import (  # noqa: F401  public names outside __all__
    DIRECT_CONVOLUTION_TAPS, EVENT_FLUSH, EVENT_SEGMENT_ARRIVALS, EXP_BLOCK_LIMIT, EXP_TAIL_LENGTHS,
    GAUSS_TAIL_SIGMAS, MARKOV_CELL_HAZARD, MARKOV_CHUNK_ELEMENTS, MARKOV_MAX_ITER, MARKOV_MAX_STATES, MARKOV_TOL,
    MAX_EXPECTED_COUNTS, MAX_KERNEL_TAPS, NEGATIVE_ENVELOPE_RTOL, POISSON_NORMAL_ABOVE, SAMPLER_PIXEL_CHUNK,
    SEQUENTIAL_MAX_BINS, SEQUENTIAL_MIN_PIXELS, TICKS_PER_PERIOD, DeadTimeKind, ModelName, event_simulation,
    event_simulation_batched, first_photon_sequential, first_photon_tree,
)
from .free_running import __all__  # noqa: F401
