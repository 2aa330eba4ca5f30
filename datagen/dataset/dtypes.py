"""Stored dtypes of a dataset's fields that a config chooses (``store.counts_dtype``), checked as a sample is made."""
from __future__ import annotations

import numpy as np

from ..errors import DatasetError


def stored_counts(counts: np.ndarray, dtype: str, where: str) -> np.ndarray:
    """SPAD ``counts`` (*S, T) integers ≥ 0 as the store's ``counts_dtype`` ("int64", "uint32", "uint16").

    A pile-up detector counts at most one detection per laser cycle, so uint16 holds its counts whenever the
    exposure has ≤ 65 535 cycles and uint32 any exposure; a Poisson detector has no such bound.

    Raises:
        DatasetError: a count above the dtype's maximum (names ``where``, the largest count and the dtype).
    """
    out_dtype = np.dtype(dtype)
    counts = np.asarray(counts)
    if out_dtype != np.int64 and counts.size:
        most = int(counts.max())
        if most > np.iinfo(out_dtype).max:
            raise DatasetError(f"{where}: counts reach {most} in a bin, more than store.counts_dtype {dtype} holds "
                               f"({np.iinfo(out_dtype).max}); set store.counts_dtype to uint32 or int64")
    return np.asarray(counts, dtype=out_dtype)

