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


def zarr_module():
    """The ``zarr`` module, imported on first use rather than when this module is imported."""
    import zarr
    return zarr


def consolidate(root: Path) -> None:
    """Consolidate the store's metadata (once, at the end). ``_done/`` and the lock file are not Zarr nodes."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
        warnings.filterwarnings("ignore", message="Object at .* is not recognized", category=UserWarning)
        zarr_module().consolidate_metadata(str(root))


def probe_fields(probe: Sample) -> dict[str, tuple[tuple[int, ...], str]]:
    """Per-sample shape and dtype of every field of ``probe`` as the card records them: dtype ``"str"`` for
    ``params``, else the numpy dtype string (``"<f4"``)."""
    return {name: (tuple(value.shape), "str" if name == "params" else value.dtype.str)
            for name, value in probe.arrays.items()}
