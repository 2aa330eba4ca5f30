"""One validation layer for the arrays datagen reads from outside: capture files, detector histograms, time axes.

Every command that reads a file it did not write (``import-capture``, ``compare-capture``, ``export`` of an imported
capture, ``fit-detector``, ``detect``) passes the arrays through these checks before any arithmetic, so a bad value
is named once, in one place, on one line: the file (``where``), the field and what was found (how many values, the
first index, an example). Each check returns the array it was given (the file's dtype kept) or raises
:class:`InputDataError`.

- :func:`transients`: real, finite and, unless negative values are allowed (background-subtracted captures),
  non-negative photon counts or intensities (docs/capture_io.md);
- :func:`time_offsets`: per-point offsets (``tofgrid``) of the scan's shape, finite;
- :func:`histogram_counts`: finite, non-negative whole counts below :data:`MAX_COUNT` (a detector fit sums and
  squares them in float64), at least :data:`MIN_HISTOGRAM_BINS` bins, not all zero;
- :func:`uniform_axis`: a time column that increases by one bin width (within :data:`AXIS_RTOL`);
- :func:`bin_width`: a histogram's bin width within :data:`BIN_WIDTH_RANGE_S` (a TCSPC bin is picoseconds to
  nanoseconds; outside is a unit slip, ``4`` meant as 4 ps);
- :func:`result_values`: the envelope, counts and time edges of a stored result (a capture store or a
  simulation's), checked as the files are when a command reads one back.

The other files read from outside are checked in one place each, where the knowledge they need lives: scene,
dataset, room and detector YAML by :func:`datagen.scene.yamlfile.read_yaml` and the pydantic models; reconstruction
predictions by :mod:`datagen.dataset.score` (their shapes come from the dataset's labels). docs/reliability.md
lists every bound.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import DatasetError

__all__ = ["InputDataError", "MAX_COUNT", "MIN_HISTOGRAM_BINS", "AXIS_RTOL", "real_values", "transients", "time_offsets", "histogram_counts",
           "uniform_axis", "negative_bins", "BIN_WIDTH_RANGE_S", "bin_width", "format_seconds",
           "result_values"]

MAX_COUNT = 2.0 ** 53
"""The largest count a histogram may hold: integers above it are not exact in float64, and their squares in a
likelihood overflow long before float64's range ends."""

MIN_HISTOGRAM_BINS = 8
"""The fewest bins a detector histogram may have (a fit has up to 7 free parameters)."""

BIN_WIDTH_RANGE_S = (1e-13, 1e-7)
"""The bin widths (s) a time-correlated photon-counting histogram may have: 0.1 ps (below the finest
time-to-digital converters, ~1 ps) to 100 ns (a bin as long as a 10 MHz laser's whole period holds no transient).
A value outside is a unit slip (``4`` read as 4 s where 4 ps was meant, ``4ms``)."""

AXIS_RTOL = 1e-3
"""A time column's steps may differ from their median by this fraction (a CSV's printed digits), no more."""


class InputDataError(DatasetError):
    """An array read from outside holds values datagen cannot use; the message names the file, the field and the
    values."""


def _index(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def real_values(values, where: str, field: str, what: str) -> np.ndarray:
    """``values`` as an ndarray of real numbers (bool, int, float), else :class:`InputDataError` naming complex or
    non-numeric values; ``what`` says what they should be ("photon counts and intensities")."""
    arr = np.asarray(values)
    if arr.dtype.kind == "c":
        bad = np.imag(arr) != 0
        example = f"; e.g. {arr[_index(bad)]} at index {_index(bad)}" if bad.any() else ""
        raise InputDataError(f"{where}: {field}: complex values ({int(bad.sum())} with an imaginary part{example}); "
                             f"{what} are real")
    if arr.dtype.kind in "US":
        text = "".join(str(x) for x in arr.ravel()[:40].tolist())
        raise InputDataError(f"{where}: {field}: text ({text!r}), not a number; {what} are stored as numbers")
    if arr.dtype.kind not in "biuf":
        raise InputDataError(f"{where}: {field}: {arr.dtype} values, not numbers; {what} are real numbers")
    return arr


def _finite(arr: np.ndarray, where: str, field: str, hint: str = "") -> None:
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            n_nan = int(np.isnan(arr).sum())
            raise InputDataError(f"{where}: {field}: {int(bad.sum())} of {arr.size} values are not finite ({n_nan} "
                                 f"NaN, {int(bad.sum()) - n_nan} ±inf), the first at index {_index(bad)}{hint}")


def negative_bins(values) -> int:
    """How many values are below zero."""
    return int((np.asarray(values) < 0).sum())


NEGATIVE_HINT = "a background-subtracted capture is read with --allow-negative"


def transients(values, where: str, field: str, allow_negative: bool = False,
               negative_hint: str = NEGATIVE_HINT, finite_hint: str = "") -> np.ndarray:
    """Check transients (any shape, time last): real, finite and, unless ``allow_negative``, ≥ 0.

    Args:
        values: the array as read; where: the file (or what it came from); field: its name in the file;
        allow_negative: accept negative bins (a background-subtracted capture; the caller reports how many);
        negative_hint: what the message about negative bins suggests; finite_hint: appended to the message about
        NaN / ±inf values.
    Returns:
        ``values`` as an ndarray, its dtype unchanged.
    Raises:
        InputDataError: complex, non-numeric, NaN or ±inf values, or negative ones when not allowed (the count,
        the first index and the smallest value, and the option that accepts them).
    """
    arr = real_values(values, where, field, "photon counts and intensities")
    _finite(arr, where, field, finite_hint)
    if not allow_negative:
        neg = arr < 0
        if neg.any():
            raise InputDataError(f"{where}: {field}: {int(neg.sum())} of {arr.size} bins are negative (smallest "
                                 f"{float(arr.min()):.6g}, the first at index {_index(neg)}); photon counts are ≥ 0: "
                                 f"{negative_hint}")
    return arr


def time_offsets(values, where: str, field: str, shape: tuple[int, ...]) -> np.ndarray:
    """Check per-scan-point time offsets: real, finite, of the scan's ``shape``. Returns the array."""
    arr = real_values(values, where, field, "time offsets")
    if arr.shape != tuple(shape):
        raise InputDataError(f"{where}: {field}: shape {arr.shape} differs from the scan {tuple(shape)}")
    _finite(arr, where, field)
    return arr


def histogram_counts(values, where: str, field: str = "counts") -> np.ndarray:
    """Check a detector histogram: one axis of at least :data:`MIN_HISTOGRAM_BINS` bins holding whole numbers,
    finite, ≥ 0 and ≤ :data:`MAX_COUNT`, not all zero. Returns the array."""
    arr = transients(values, where, field, negative_hint="a detector fit needs the raw histogram, background "
                                                         "included")
    if arr.ndim != 1 or arr.size < MIN_HISTOGRAM_BINS:
        raise InputDataError(f"{where}: {field}: shape {arr.shape}; a histogram is one axis of at least "
                             f"{MIN_HISTOGRAM_BINS} bins")
    if float(arr.max()) > MAX_COUNT:
        big = arr > MAX_COUNT
        raise InputDataError(f"{where}: {field}: {int(big.sum())} bins exceed {MAX_COUNT:.3g} counts (largest "
                             f"{float(arr.max()):.4g}, the first at index {_index(big)}); a histogram holds "
                             "photon counts")
    frac = arr != np.round(arr)
    if frac.any():
        raise InputDataError(f"{where}: {field}: {int(frac.sum())} of {arr.size} bins are not whole numbers (e.g. "
                             f"{float(arr[_index(frac)]):.4g} at index {_index(frac)}); a histogram holds photon "
                             "counts")
    if not arr.any():
        raise InputDataError(f"{where}: {field}: every bin is 0; a fit needs counts")
    return arr


def uniform_axis(times, where: str, field: str = "time") -> tuple[float, float]:
    """Check a time column (bin starts, s): finite, at least 2 values, increasing in equal steps.

    Returns:
        (first value, step) in the column's units.
    Raises:
        InputDataError: fewer than 2 values, not finite, not increasing (the first step that is not, with its
        value), or steps that differ by more than :data:`AXIS_RTOL` (the smallest and largest).
    """
    t = np.asarray(real_values(times, where, field, "times"), dtype=np.float64).ravel()
    if t.size < 2:
        raise InputDataError(f"{where}: {field}: {t.size} value(s); a time axis needs at least 2")
    _finite(t, where, field)
    steps = np.diff(t)
    down = steps <= 0
    if down.any():
        i = int(np.argmax(down))
        raise InputDataError(f"{where}: {field}: not increasing: row {i + 1} ({t[i + 1]:.6g}) follows row {i} "
                             f"({t[i]:.6g}); the column holds each bin's start time, in order")
    step = float(np.median(steps))
    if np.any(np.abs(steps - step) > AXIS_RTOL * step):
        raise InputDataError(f"{where}: {field}: uneven steps from {steps.min():.6g} to {steps.max():.6g} (median "
                             f"{step:.6g}); a histogram's bins are of one width")
    return float(t[0]), step


def format_seconds(seconds: float) -> str:
    """``seconds`` in the unit that reads best ("4 s", "4 ms", "-5 ps"; 1e-3 s is "1 ms"), as
    :func:`datagen.units.parse_duration` reads it back (µs for microseconds)."""
    s = float(seconds)
    if not math.isfinite(s) or s == 0:
        return f"{s:g} s"
    for unit, scale, floor in (("s", 1.0, 1.0), ("ms", 1e-3, 1e-3), ("µs", 1e-6, 1e-6), ("ns", 1e-9, 1e-9),
                               ("ps", 1e-12, 1e-13)):
        if abs(s) >= floor * (1 - 1e-9):
            return f"{s / scale:.4g} {unit}"
    return f"{s / 1e-15:.4g} fs"


def bin_width(seconds: float, where: str, field: str) -> float:
    """Check a histogram's bin width (s): finite and within :data:`BIN_WIDTH_RANGE_S`. Returns it as a float.

    Raises:
        InputDataError: "``where``: ``field``: 4 s is not a TCSPC bin width (0.1 ps .. 100 ns) …", saying that the
        field holds seconds.
    """
    s = float(seconds)
    lo, hi = BIN_WIDTH_RANGE_S
    if not (math.isfinite(s) and lo <= s <= hi):
        what = "is not > 0" if not s > 0 else f"is not a TCSPC bin width ({format_seconds(lo)} .. {format_seconds(hi)})"
        raise InputDataError(f"{where}: {field}: {format_seconds(s)} {what}; the field holds seconds (4 ps is "
                             "4e-12)")
    return s


def result_values(result, where: str, allow_negative: bool = False, negative_hint: str = NEGATIVE_HINT) -> None:
    """Check a stored result as :func:`transients` checks a capture file: its envelope (real, finite, ≥ 0 unless
    ``allow_negative``), its counts (≥ 0) and its time edges (finite, increasing).

    Args:
        result: a :class:`~datagen.simulation.Result` read back from a store; where: the store (the messages
            start with it); negative_hint: what the message about negative bins suggests.
    Raises:
        InputDataError: naming the store, the array, how many values are wrong and the first index.
    """
    damaged = "; no store datagen writes holds them: write it again (import-capture, simulate)"
    transients(result.envelope, where, "envelope", allow_negative, negative_hint, damaged)
    transients(result.counts, where, "counts", negative_hint="detections are counted, never negative")
    edges = np.asarray(real_values(result.time_edges, where, "time_edges", "times"), dtype=np.float64)
    _finite(edges, where, "time_edges", damaged)
    if edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise InputDataError(f"{where}: time_edges: {edges.size} edges, not increasing (from {edges[:3].tolist()}); "
                             "a result's bins follow one another")
