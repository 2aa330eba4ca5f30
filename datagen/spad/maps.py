"""What a real confocal capture carries besides the hidden signal (docs/detector.md "Direct light, gain and
background maps"): the direct light off each scanned point attenuated by a stated factor, a per-scan-point gain
(laser power, focus, the wall's local albedo) and a background that changes over the scan.

* :class:`DirectLight` (``detector.direct``): the direct light (the ``first_bounce`` component: laser spot → FoV
  point → sensor, with its IRF tail) multiplied by ``attenuation`` at every time (a set-up that keeps the first
  bounce out of the SPAD: spot and FoV apart, a polariser, a mask); or, with ``until``, the light arriving before
  ``until`` after each scan point's direct return (a time gate with a transmission: a gated SPAD, or a
  neutral-density filter switched over the first bounce). :func:`direct_factor` is the gate's per-bin factor, exact
  for the fraction of a bin before the gate's end. Its ``counts_map`` gives the direct light its own pattern over
  the scan, as measured (a capture's direct counts, ``datagen estimate-capture``'s ``direct_counts.npy``), where the
  gain map gives the hidden light its own.
* ``detector.gain_map`` and ``detector.background_map``: (ny, nx) non-negative factors, one per scan point, given
  inline or as a ``.npy`` file (:func:`read_map`); the gain multiplies the light each point's histogram receives
  and the background map the background rate (pde·ambient + dcr) there (:func:`datagen.spad.rates_from_envelope`).
  :func:`check_map_shape` says in one line when a map does not fit the capture.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer

from ..units import parse_duration

__all__ = ["MAP_FIELDS", "DirectLight", "read_map", "maps_relative_to", "check_map_shape", "direct_factor"]

MAP_FIELDS = ("gain_map", "background_map")
"""The per-scan-point maps of a :class:`~datagen.spad.DetectorConfig`."""

MAX_MAP_POINTS = 1 << 20
"""Most scan points a map may hold (a 1024 x 1024 scan): a larger file is not a scan's map."""


class DirectLight(BaseModel):
    """The direct light attenuated (``detector.direct``): the whole direct component, or a time gate.

    Fields:
        attenuation: the factor (0 < attenuation ≤ 1; e.g. 1e-4). Without ``until`` it multiplies the direct light
            (the ``first_bounce`` component, its IRF tail included) at every time and nothing else; with ``until``
            it multiplies all the light that arrives before ``until`` after each scan point's direct return.
        until: s (> 0; strings such as "300ps") or None (default): how long after each scan point's direct return
            the gate lasts (light after it is untouched); None: no gate, the direct component attenuated.
        counts_map: None (default), or a (ny, nx) map (inline, or a ``.npy`` path relative to the file that names
            it) of the direct light's counts over the scan: the simulated direct light (``first_bounce``) is scaled
            point by point so that what the detector sees of it, ``detector.gain_map`` included, follows this map,
            its scan total unchanged (:func:`datagen.simulation.detection.attenuate_direct`). A capture's direct
            counts carry the direct light's own geometry and its gain (focus, alignment), which on the LCT release
            vary 5-16x over a scan while its hidden light follows them to a power of about 0.5 (docs/detector.md).

    Raises:
        pydantic.ValidationError (a ValueError): a value out of range, naming the field and the value.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    attenuation: float = Field(gt=0.0, le=1.0)
    until: float | None = Field(None, gt=0.0)
    counts_map: tuple[tuple[float, ...], ...] | None = None

    @field_validator("until", mode="before")
    @classmethod
    def _duration(cls, value: Any) -> Any:
        return parse_duration(value) if isinstance(value, str) else value

    @field_validator("counts_map", mode="before")
    @classmethod
    def _read_counts_map(cls, value: Any) -> Any:
        return None if value is None else read_map(value, "direct.counts_map")

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        data = handler(self)
        if isinstance(data, dict) and data.get("counts_map") is None:   # without it, dumped as before
            data.pop("counts_map", None)
        return data


def maps_relative_to(detector: dict, base: str | Path) -> dict:
    """``detector`` (a detector mapping) with its map paths (:data:`MAP_FIELDS` and ``direct.counts_map`` given as
    relative ``.npy`` paths) made relative to ``base``, the folder of the file that names them; other fields as they
    are (a copy)."""
    def moved(v):
        return str(Path(base) / v) if isinstance(v, str) and not Path(v).is_absolute() else v

    out = {k: (moved(v) if k in MAP_FIELDS else v) for k, v in detector.items()}
    if isinstance(out.get("direct"), dict) and "counts_map" in out["direct"]:
        out["direct"] = {**out["direct"], "counts_map": moved(out["direct"]["counts_map"])}
    return out


def read_map(value: Any, field: str, base: Path | None = None) -> tuple[tuple[float, ...], ...]:
    """A per-scan-point map from its setting: a (ny, nx) nested list of numbers, or the path of a ``.npy`` file
    holding a (ny, nx) array (relative paths from ``base``, the folder of the file that names it, else the working
    directory). Returns the values as a tuple of rows (float).

    Raises:
        ValueError: one line naming the field, the file and the shape or value: a file that cannot be read, not 2-D,
            empty, non-finite or negative values.
    """
    where = field
    if isinstance(value, (str, Path)):
        path = Path(value).expanduser()
        if not path.is_absolute() and base is not None:
            path = Path(base) / path
        where = f"{field} ({path})"
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise ValueError(f"{where}: cannot read a .npy array: {' '.join(str(exc).split())[:160]}") from None
    else:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{field}: expected a (ny, nx) array of numbers or a .npy path, got "
                             f"{str(value)[:80]!r}") from None
    arr = np.asarray(arr)
    if arr.ndim != 2 or arr.size == 0 or arr.size > MAX_MAP_POINTS:
        raise ValueError(f"{where}: expected a (ny, nx) map of the scan points, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise ValueError(f"{where}: expected real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr) | (arr < 0)
    if bad.any():
        i = tuple(int(v) for v in np.argwhere(bad)[0])
        raise ValueError(f"{where}: values must be finite and >= 0, got {arr[i]!r} at {i}")
    return tuple(tuple(float(v) for v in row) for row in arr)


def check_map_shape(values: Any, field: str, shape: tuple[int, ...], where: str = "") -> np.ndarray:
    """The map as float64 (ny, nx) when it has the capture's scan shape ``shape`` (the envelope's leading axes).

    Raises:
        ValueError: one line naming ``where`` (a prefix such as "detector."), the field and both shapes.
    """
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != tuple(shape):
        raise ValueError(f"{where}{field} has shape {arr.shape} but the capture has {tuple(shape)} scan points "
                         f"(one value per point: a (ny, nx) map of the confocal scan)")
    return arr


def direct_factor(edges: np.ndarray, direct_times: np.ndarray, direct: DirectLight) -> np.ndarray:
    """Per-bin factor of the direct-light attenuation: ``attenuation`` on the part of bin [e_b, e_{b+1}) before
    ``t_d + until`` (t_d each scan point's direct-return time), 1 after it; a bin the gate's end cuts gets the
    mix of the two in proportion of its width (exact for light uniform within the bin).

    Args:
        edges: (T + 1,) float64 bin edges, s; direct_times: (...) s, each scan point's direct return on that axis.
    Returns:
        float64 (..., T) factors in [attenuation, 1].
    """
    e = np.asarray(edges, dtype=np.float64)
    end = np.asarray(direct_times, dtype=np.float64)[..., None] + direct.until
    width = np.diff(e)
    before = np.clip((end - e[:-1]) / width, 0.0, 1.0)            # the fraction of each bin before the gate's end
    return 1.0 - (1.0 - direct.attenuation) * before
