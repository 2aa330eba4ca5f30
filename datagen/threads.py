"""Numba's threads for datagen's parallel compiled kernels (the quadrature's pair loop, the accumulator's fold and
binning, the shadow map): set up once, before the first parallel kernel runs.

- Threading layer: GNU OpenMP before TBB (numba tries TBB first; the TBB beside Embree here is older than numba
  needs, so that try ends in a NumbaWarning on every first parallel run), unless ``NUMBA_THREADING_LAYER`` names one.
- ``OMP_WAIT_POLICY=PASSIVE`` unless set: a thread with no work sleeps at once instead of spinning (GNU OpenMP's
  default spins for a while after every parallel region, CPU time that a dataset build's worker processes pay on
  every short kernel: measured ≈ 0.1 CPU-s per ``configs/datasets/wall.yaml`` sample). Results do not depend on it.

Every kernel's result is the same for any number of threads; ``NUMBA_NUM_THREADS`` sets it, and
:func:`threads_for` runs short kernels on one.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import numba

__all__ = ["threads_for"]

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")      # read by libgomp when numba's OpenMP layer loads it
if numba.config.THREADING_LAYER == "default":
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


@contextlib.contextmanager
def threads_for(work: float, minimum: float) -> Iterator[None]:
    """Run the kernels inside the block on all of numba's threads when ``work`` (pairs, nodes: the caller's unit)
    is at least ``minimum``, else on one: a dataset build already keeps every core busy with one worker process
    each, where threads of short kernels only add CPU time. Restores the thread count on exit; results do not
    depend on it."""
    threads = numba.get_num_threads()
    numba.set_num_threads(threads if work >= minimum else 1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)
