"""Storage of simulation results in Zarr v3 (docs/physics.md §7).

A result directory holds ``result.zarr`` with arrays ``time_edges`` (s), ``envelope`` (expected detected
photons per pulse per bin), ``components/<name>`` (same shape, summing to the envelope) and ``counts``
(int64 SPAD histogram), the capture geometry (``laser_points``, ``sensor_points``, ``wall_normal``), and the
result's attributes (resolved config, effects, timings, versions) as the group's attributes. Arrays are
written whole; metadata is consolidated once at the end.

A capture sequence (:func:`write_sequence`, docs/motion.md) is ``sequence.zarr``: ``time_edges``, ``frame_times``
(s), ``envelopes`` and ``counts`` (frame × channels × bin), ``error`` (per frame), and the moving objects'
``positions``, ``velocities`` and ``boxes`` per frame.
"""
from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import zarr

from ..simulation import Result
from ..simulation.sequence import SequenceResult

RESULT_NAME = "result.zarr"
SEQUENCE_NAME = "sequence.zarr"
SEQUENCE_ARRAYS = {"time_edges": np.float64, "frame_times": np.float64, "envelopes": np.float64, "counts": np.int64,
                   "error": np.float64, "monte_carlo_error": np.float64, "positions": np.float64,
                   "velocities": np.float64, "boxes": np.float64}
"""The arrays of a sequence store and their dtypes (:class:`~datagen.simulation.sequence.SequenceResult`)."""


CAPTURE_ARRAYS = ("laser_points", "sensor_points", "wall_normal")
"""Capture geometry stored beside the envelope: (ly, lx, 3) and (ny, nx, 3) points (m), (3,) wall normal."""


def _jsonable(value):
    return json.loads(json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _consolidate(path: Path) -> None:
    with warnings.catch_warnings():   # consolidated metadata is a zarr-python v3 extension; we rely on it
        warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
        zarr.consolidate_metadata(str(path))


def _existing_store(path: str | Path, name: str = RESULT_NAME, what: str = "result") -> Path:
    """The ``.zarr`` store at ``path`` (the store itself or the directory holding it as ``name``).

    Raises:
        FileNotFoundError: no ``what`` store there.
    """
    path = Path(path)
    if (path / name).exists():
        path = path / name
    if not (path / "zarr.json").exists():
        raise FileNotFoundError(f"no datagen {what} store at {path}")
    return path


def _write_atomically(path: Path, fill) -> Path:
    """Write a Zarr v3 group at ``path`` through ``<path>.partial`` (``fill(group)`` writes it), renamed into
    place when complete; nothing is left behind on failure (an OSError names ``path``)."""
    tmp = path.with_name(path.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        fill(zarr.open_group(str(tmp), mode="w", zarr_format=3))
        _consolidate(tmp)
    except BaseException as exc:   # e.g. a full disk: leave no half-written store behind
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and exc.filename is None:
            raise OSError(exc.errno, f"{exc.strerror or exc} while writing {path}") from None
        raise
    if path.exists():
        shutil.rmtree(path)
    tmp.rename(path)
    return path


def write_sequence(seq: SequenceResult, path: str | Path) -> Path:
    """Write a capture sequence to ``path`` (a ``.zarr`` directory, replaced if it exists) and return the path:
    the arrays of :data:`SEQUENCE_ARRAYS`, the moving objects' names, the difference error and the attributes.

    Raises:
        OSError: the write failed (the message names ``path``); nothing is left behind.
    """
    def fill(root):
        for name, dtype in SEQUENCE_ARRAYS.items():
            root.create_array(name, data=np.asarray(getattr(seq, name), dtype=dtype))
        diff = seq.difference_error if np.isfinite(seq.difference_error) else None     # JSON has no NaN
        root.attrs.update(_jsonable({**seq.attrs, "moving": seq.moving, "difference_error": diff}))
    return _write_atomically(Path(path), fill)


def read_sequence(path: str | Path) -> SequenceResult:
    """Read a sequence written by :func:`write_sequence` (``path`` is the ``.zarr`` or its directory).

    Raises:
        FileNotFoundError: no datagen sequence store at ``path``.
    """
    root = zarr.open_group(str(_existing_store(path, SEQUENCE_NAME, "sequence")), mode="r")
    attrs = dict(root.attrs)
    arrays = {name: root[name][...] for name in SEQUENCE_ARRAYS}
    diff = attrs.pop("difference_error")
    return SequenceResult(**arrays, difference_error=float("nan") if diff is None else float(diff),
                          moving=list(attrs.pop("moving")), attrs=attrs)


def write_result(result: Result, path: str | Path, overwrite: bool = True) -> Path:
    """Write ``result`` to ``path`` (a ``.zarr`` directory) and return the path.

    The store is written to ``<path>.partial`` and renamed into place when complete, so an interrupted
    write never leaves a store that looks finished.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False.
        OSError: the write failed (e.g. a full disk; the message names ``path``); nothing is left behind.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)")

    def fill(root):
        root.create_array("time_edges", data=np.asarray(result.time_edges, dtype=np.float64))
        root.create_array("envelope", data=np.asarray(result.envelope, dtype=np.float64))
        root.create_array("counts", data=np.asarray(result.counts, dtype=np.int64))
        comps = root.create_group("components")
        for name, arr in result.components.items():
            comps.create_array(name, data=np.asarray(arr, dtype=np.float64))
        for name in CAPTURE_ARRAYS:                      # capture geometry (tal export needs it)
            value = getattr(result, name, None)
            if value is not None:
                root.create_array(name, data=np.asarray(value, dtype=np.float64))
        root.attrs.update(_jsonable(result.attrs))
    return _write_atomically(path, fill)


def read_result(path: str | Path) -> Result:
    """Read a result written by :func:`write_result` (``path`` is the ``.zarr`` or its directory).

    Raises:
        FileNotFoundError: no result store at ``path``.
    """
    path = _existing_store(path)
    root = zarr.open_group(str(path), mode="r")
    comps = root["components"]
    names = root.attrs.get("component_names", sorted(comps.array_keys()))
    geometry = {n: root[n][...] for n in CAPTURE_ARRAYS if n in root.array_keys()}
    return Result(time_edges=root["time_edges"][...], envelope=root["envelope"][...],
                  components={n: comps[n][...] for n in names}, counts=root["counts"][...],
                  attrs=dict(root.attrs), **geometry)


def write_detection(path: str | Path, name: str, counts: np.ndarray, attrs: dict) -> Path:
    """Add (or replace) ``detections/<name>/counts`` (int64) with ``attrs`` to an existing result store.

    Raises:
        FileNotFoundError: no result store at ``path``.
    """
    path = _existing_store(path)
    root = zarr.open_group(str(path), mode="a")
    group = root.require_group("detections").require_group(name)
    group.create_array("counts", data=np.asarray(counts, dtype=np.int64), overwrite=True)
    group.attrs.update(_jsonable(attrs))
    _consolidate(path)
    return path
