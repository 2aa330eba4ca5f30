"""The fields of a lab capture file checked once it is read (:func:`datagen.io.lab_formats.read_lab_capture`):
shapes, the transients' values (:mod:`datagen.validate`), the scalar fields and their plausibility.

A field the file does not hold but the caller gave (``width=``, ``bin_resolution=``: the command line's
``--width`` / ``--bin-resolution``) is named as given, not as the file's, so a bad value is blamed on whoever
wrote it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import validate
from ..errors import DatasetError
from ..units import SPEED_OF_LIGHT

__all__ = ["MAT_FORMATS", "check_mat_fields", "check_znlos_fields"]

MAT_FORMATS = {"lct-mat": "rect_data", "fk-mat": "meas"}
"""Field holding the transients in each ``.mat`` layout."""

HINTS = {"width": "half width of the scanned wall in m (--width)",
         "bin_resolution": "bin width in s (--bin-resolution)"}
"""What a ``.mat`` file's scalar fields hold, and the option that gives one the file lacks."""


def _scalar(cap, path: Path, key: str, given: set[str]) -> float:
    """The one finite number > 0 of field ``key`` (DatasetError naming the file, or the argument that gave it)."""
    if key not in cap.raw:
        raise DatasetError(f"{path}: no '{key}' field; give the {HINTS[key]}")
    name = f"{key} (given: the file has none)" if key in given else key
    v = np.asarray(validate.real_values(cap.raw[key], str(path), name, "lengths and durations"), dtype=np.float64)
    if v.size != 1 or not (np.isfinite(v).all() and float(v.reshape(())) > 0):
        raise DatasetError(f"{path}: {name}: expected one number > 0, got {v.ravel()[:4].tolist()}")
    return float(v.reshape(()))


def check_mat_fields(cap, path: Path, allow_negative: bool = False, given: set[str] = frozenset(),
                     negative_hint: str = validate.NEGATIVE_HINT) -> None:
    """Check an LCT / f-k capture (:class:`~datagen.io.lab_formats.LabCapture`): (N, N, T) transients of at least
    2 bins (:func:`datagen.validate.transients`), ``width`` one number > 0, ``bin_resolution`` a TCSPC bin width
    (:func:`datagen.validate.bin_width`), ``tofgrid`` of the scan's shape. ``given``: the fields that came from the
    caller, not the file; ``negative_hint``: what a refusal of negative bins suggests (the reading command's way).

    Raises:
        DatasetError: naming the file, the field and the value.
    """
    name = MAT_FORMATS[cap.format]
    d = np.asarray(cap.raw[name])
    if d.ndim != 3 or min(d.shape[:2]) < 1:
        raise DatasetError(f"{path}: {name}: expected (N, N, T) transients, got shape {d.shape}")
    if d.shape[2] < 2:
        raise DatasetError(f"{path}: {name}: {d.shape[2]} time bin(s) per transient (shape {d.shape}); a transient "
                           "needs at least 2")
    validate.transients(d, str(path), name, allow_negative, negative_hint)
    _scalar(cap, path, "width", given)
    dt = _scalar(cap, path, "bin_resolution", given)
    validate.bin_width(dt, str(path), "bin_resolution (given: the file has none)" if "bin_resolution" in given
                       else "bin_resolution")
    tof = cap.raw.get("tofgrid")
    if tof is not None:
        validate.time_offsets(tof, str(path), "tofgrid", d.shape[:2])


def check_znlos_fields(cap, path: Path, allow_negative: bool = False,
                       negative_hint: str = validate.NEGATIVE_HINT) -> None:
    """Check a ZNLOS capture: its required fields, the data's and grids' shapes, the transients' values,
    ``deltaT`` a TCSPC bin width in metres of path (:func:`datagen.validate.bin_width` of deltaT / c) and ``t0``.

    Raises:
        DatasetError: naming the file, the field and the value.
    """
    for key in ("data", "deltaT", "t0", "cameraPosition", "laserPosition", "cameraGridPositions",
                "cameraGridNormals"):
        if key not in cap.raw:
            raise DatasetError(f"{path}: ZNLOS field '{key}' is missing")
    d = cap.raw["data"]
    if d.ndim not in (5, 7):
        raise DatasetError(f"{path}: data: expected (colors, T, bounces, ny, nx[, ly, lx]), got shape {d.shape}")
    if cap.sensor_points().shape[:2] != d.shape[3:5]:
        raise DatasetError(f"{path}: cameraGridPositions {np.shape(cap.raw['cameraGridPositions'])} does not match "
                           f"data's grid {d.shape[3:5]}")
    if d.ndim == 7 and cap.capture_type == "exhaustive" and "laserGridPositions" not in cap.raw:
        raise DatasetError(f"{path}: ZNLOS field 'laserGridPositions' is missing")
    validate.transients(d, str(path), "data", allow_negative, negative_hint)
    for key in ("deltaT", "t0"):
        v = validate.real_values(cap.raw[key], str(path), key, "times")
        if v.size != 1 or not np.isfinite(v).all() or (key == "deltaT" and float(v.reshape(())) <= 0):
            raise DatasetError(f"{path}: {key}: expected one finite number{' > 0' if key == 'deltaT' else ''}, got "
                               f"{np.ravel(v)[:4].tolist()}")
    delta = float(np.reshape(cap.raw["deltaT"], ()))
    lo, hi = validate.BIN_WIDTH_RANGE_S
    if not lo <= delta / SPEED_OF_LIGHT <= hi:
        raise DatasetError(f"{path}: deltaT: {delta:.4g} m of path ({validate.format_seconds(delta / SPEED_OF_LIGHT)} "
                           f"a bin) is not a TCSPC bin width ({validate.format_seconds(lo)} .. "
                           f"{validate.format_seconds(hi)}); ZNLOS stores deltaT in metres of optical path")
