"""Numba's threads for datagen's parallel compiled kernels (the quadrature's pair loop, the accumulator's fold and
binning, the shadow map): set up once, before the first parallel kernel runs.

- Threading layer: GNU OpenMP before TBB (numba tries TBB first; the TBB beside Embree here is older than numba
  needs, so that try ends in a NumbaWarning on every first parallel run), unless ``NUMBA_THREADING_LAYER`` names one.
- numpy's BLAS (OpenBLAS) on one thread inside the pipeline's entry points (:func:`one_blas_thread`): its calls
  there are norms and small products, where its threads only spin, and a threaded dot product's partial sums make a stored error
  estimate depend on the machine's core count in its last digit.
- ``OMP_WAIT_POLICY=PASSIVE`` unless set: a thread with no work sleeps at once instead of spinning (GNU OpenMP's
  default spins for a while after every parallel region, CPU time that a dataset build's worker processes pay on
  every short kernel). Results do not depend on it. The measurements behind both: docs/performance_history.md.

Every kernel's result is the same for any number of threads; ``NUMBA_NUM_THREADS`` sets it, and
:func:`threads_for` runs short kernels on one.
"""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread", "threads_for"]

LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
"""numba's threading layers in the order tried (GNU OpenMP first)."""


def _set_threading_layer() -> None:
    """GNU OpenMP first, without importing numba: through ``NUMBA_THREADING_LAYER_PRIORITY`` (read when numba is
    first imported, here or in a worker process), or on numba's config when numba is already imported; a layer
    named by ``NUMBA_THREADING_LAYER`` is left alone."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # read by libgomp when numba's OpenMP layer loads it
    numba = sys.modules.get("numba")
    if numba is not None:
        if numba.config.THREADING_LAYER == "default":
            numba.config.THREADING_LAYER_PRIORITY = list(LAYER_PRIORITY)
    elif not os.environ.get("NUMBA_THREADING_LAYER"):
        os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", " ".join(LAYER_PRIORITY))


_set_threading_layer()


@contextlib.contextmanager
def threads_for(work: float, minimum: float) -> Iterator[None]:
    """Run the kernels inside the block on all of numba's threads when ``work`` (pairs, nodes: the caller's unit)
    is at least ``minimum``, else on one: a dataset build already keeps every core busy with one worker process
    each, where threads of short kernels only add CPU time. Restores the thread count on exit; results do not
    depend on it."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(threads if work >= minimum else 1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)


_CONTROLLER: list[ThreadpoolController] = []       # made on first use (it inspects the loaded libraries once)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with the BLAS libraries numpy and scipy loaded (OpenBLAS here) on one thread, by threadpoolctl;
    numba's threads are not touched. Restores the previous counts on exit. Used as a decorator on
    :func:`datagen.simulate`, :func:`datagen.simulation.simulate_to_tolerance` and
    :func:`datagen.dataset.make_sample`: results then do not depend on the machine's core count (a threaded dot
    product sums in an order that does), and no BLAS thread spins beside a dataset build's workers. The limit is
    per process: Python threads that simulate at the same time share it."""
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    with _CONTROLLER[0].limit(limits=1, user_api="blas"):
        yield
