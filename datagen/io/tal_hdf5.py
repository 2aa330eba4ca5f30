"""Interoperability with y-tal (PyPI ``y-tal``, import ``tal``): its HDF5 capture files.

Scenes from tal's render YAML are :mod:`datagen.io.tal`; a result simulated from one is written here laid out
and scaled as ``tal render`` writes it (its :class:`~datagen.io.tal.TalCapture`).

**HDF5 layout** (``tal.io.read_capture`` / ``tal.io.write_capture``, y-tal 0.20, ``FileFormat.HDF5_TAL``). One
dataset per field of ``tal.io.NLOSCaptureData``:

=================================  ================================================================================
``H``                              transient data; (T, Sx, Sy) for single and confocal scans (``HFormat.T_Sx_Sy``),
                                   (T, Lx, Ly, Sx, Sy) for exhaustive scans (``HFormat.T_Lx_Ly_Sx_Sy``)
``H_format``                       h5py enum dataset of shape (1,), names and values of ``tal.enums.HFormat``
``sensor_xyz``, ``laser_xyz``      (3,) positions of the sensor and of the laser *emitter* (not the spot)
``sensor_grid_xyz``                (Sx, Sy, 3) wall points the sensor looks at (``GridFormat.X_Y_3``)
``laser_grid_xyz``                 (Lx, Ly, 3) laser spots on the wall; (1, 1, 3) for a single spot
``*_grid_normals``                 wall normals, shaped like the grids
``*_grid_format``                  enum datasets (``tal.enums.GridFormat``)
``volume_format``                  empty (deprecated in tal; ``tal render`` writes it empty too)
``delta_t``, ``t_start``           bin width and time of the first bin edge, as *optical path length in metres*
``t_accounts_first_and_last_bounces``  whether the emitter→spot and wall→sensor legs are in the time axis
``scene_info``                     YAML-encoded string (a mapping), free-form metadata
=================================  ================================================================================

H[t, i, j] belongs to ``sensor_grid_xyz[i, j]``. datagen results (``envelope`` (Sy, Sx, T), grids (Sy, Sx, 3),
docs/physics.md §1) are written with Sx along the wall's horizontal tangent u and Sy along v, i.e. transposed.
:func:`write_tal_hdf5` writes, :func:`read_tal_hdf5` reads back a dict with the same keys and values as the
attributes of ``tal.io.read_capture(path)`` (enums as :class:`HFormat` / :class:`GridFormat`, which mirror
tal's; ``scene_info`` parsed).
"""
from __future__ import annotations

from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import DatasetError
from ..scene.load import parse_yaml
from ..units import SPEED_OF_LIGHT
from .tal import TalCapture

__all__ = [
    "HFormat", "GridFormat", "VolumeFormat", "TAL_FIELDS", "tal_arrays", "write_tal_hdf5", "read_tal_hdf5",
]


class HFormat(IntEnum):
    """Axis order of H; names and values of ``tal.enums.HFormat`` (y-tal 0.20)."""

    UNKNOWN = 0
    T_Sx_Sy = 1
    T_Lx_Ly_Sx_Sy = 2
    T_Si = 3
    T_Li_Si = 4


class GridFormat(IntEnum):
    """Axis order of a point grid; names and values of ``tal.enums.GridFormat`` (y-tal 0.20)."""

    UNKNOWN = 0
    N_3 = 1
    X_Y_3 = 2


class VolumeFormat(IntEnum):
    """``tal.enums.VolumeFormat`` (y-tal 0.20; deprecated in captures, written empty as ``tal render`` does)."""

    UNKNOWN = 0
    N_3 = 1
    X_Y_Z_3 = 2
    X_Y_3 = 3


_ENUM_FIELDS = {"H_format": HFormat, "sensor_grid_format": GridFormat, "laser_grid_format": GridFormat,
                "volume_format": VolumeFormat}
"""Fields tal stores as h5py enum datasets; an empty one reads as the enum's UNKNOWN (0), as in tal."""

TAL_FIELDS = ("H", "H_format", "sensor_xyz", "sensor_grid_xyz", "sensor_grid_normals", "sensor_grid_format",
              "laser_xyz", "laser_grid_xyz", "laser_grid_normals", "laser_grid_format", "volume_format",
              "delta_t", "t_start", "t_accounts_first_and_last_bounces", "scene_info")
"""Datasets of a tal HDF5 file, in ``NLOSCaptureData`` order (tal rejects any other key)."""

GRID_MATCH_TOL = 1e-6
"""Relative tolerance (of the wall size) to identify a datagen grid point with a tal grid point: both are
cell centres computed in float64 from the same rectangle, equal to ~1e-15; float32 grids match to ~1e-7."""


# ---------------------------------------------------------------------------------------------------------
# datagen Result → tal arrays


def _grid_index(src: np.ndarray, dst: np.ndarray, what: str) -> np.ndarray:
    """For each point of ``dst`` (..., 3), the index into ``src`` (N, 3) of the same point.

    Raises:
        DatasetError: a point of ``dst`` has no counterpart in ``src`` (the grids differ).
    """
    from scipy.spatial import cKDTree

    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    flat = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    scale = max(float(np.ptp(np.concatenate([src, flat]), axis=0).max()), 1.0)
    dist, idx = cKDTree(src).query(flat)
    if dist.max() > GRID_MATCH_TOL * scale:
        k = int(np.argmax(dist))
        raise DatasetError(f"{what}: tal grid point {flat[k].tolist()} is not a point of the simulated grid "
                         f"(nearest {src[idx[k]].tolist()})")
    return idx.reshape(np.shape(dst)[:-1])


def _result_capture(result) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """(type, envelope as (Ly, Lx, Sy, Sx, T), laser points (Ly, Lx, 3), sensor points (Sy, Sx, 3))."""
    from .lab_formats import refuse_flood

    refuse_flood(result, "tal")
    attrs = getattr(result, "attrs", {}) or {}
    cap = attrs.get("capture") or {}
    ctype = cap.get("type", "single")
    env = np.asarray(result.envelope, dtype=np.float64)
    sensor = getattr(result, "sensor_points", None)
    laser = getattr(result, "laser_points", None)
    if sensor is None or laser is None:
        raise DatasetError("result has no laser_points/sensor_points (written by a datagen without capture "
                         "grids); re-simulate it to export to tal")
    sensor = np.asarray(sensor, dtype=np.float64)
    laser = np.asarray(laser, dtype=np.float64)
    if ctype == "exhaustive":
        if env.ndim != 5:
            raise DatasetError(f"exhaustive result: envelope must be (Ly, Lx, Sy, Sx, T), got {env.shape}")
        return ctype, env, laser.reshape(env.shape[:2] + (3,)), sensor.reshape(env.shape[2:4] + (3,))
    if env.ndim == 1:
        env = env.reshape(1, 1, -1)
    if env.ndim != 3:
        raise DatasetError(f"{ctype} result: envelope must be (Sy, Sx, T), got {env.shape}")
    sensor = sensor.reshape(env.shape[:2] + (3,))
    if ctype == "confocal":
        return ctype, env[None, None], laser.reshape(env.shape[:2] + (3,)), sensor
    return ctype, env[None, None], laser.reshape(1, 1, 3), sensor


def tal_arrays(result, tal: TalCapture | None = None, laser_xyz=None, sensor_xyz=None,
               scene_info: dict | None = None) -> dict:
    """The tal capture fields (:data:`TAL_FIELDS`) of a datagen result.

    Args:
        result: a :class:`datagen.simulation.detection.Result` with capture grids (``laser_points``, ``sensor_points``,
            ``wall_normal``; attrs["capture"] (type, convention, emitter_position, sensor_position) and
            attrs["config"] (count_laser_leg, count_sensor_leg)).
        tal: when the scene came from a tal render YAML, its :class:`TalCapture`: H is laid out on tal's
            exact grids (same order as ``tal render``) and multiplied by the laser scale K_l, so the numbers
            are those ``tal render`` estimates. Without it the result is written as is, Sx along the wall's
            horizontal tangent u and Sy along v.
        laser_xyz, sensor_xyz: emitter and sensor positions (default: the result's attrs["capture"]
            ``emitter_position`` / ``sensor_position``, else ``tal``'s, else empty).
        scene_info: extra entries for ``scene_info``.
    Returns:
        dict field → value; H float64 (T, Sx, Sy) or (T, Lx, Ly, Sx, Sy).
    Raises:
        DatasetError: the result's time legs cannot be expressed with tal's single flag
            (count_laser_leg != count_sensor_leg with several laser points), or grids do not match ``tal``.
    """
    ctype, env, laser, sensor = _result_capture(result)
    attrs = getattr(result, "attrs", {}) or {}
    cap = attrs.get("capture") or {}
    conf = attrs.get("config") or {}
    edges = np.asarray(result.time_edges, dtype=np.float64)
    widths = np.diff(edges)
    if not np.allclose(widths, widths[0], rtol=1e-9, atol=0):
        raise DatasetError("tal needs uniform time bins; the result's time_edges are not uniform")
    normal = np.asarray(getattr(result, "wall_normal", None) if getattr(result, "wall_normal", None) is not None
                        else (tal.normal if tal is not None else [np.nan] * 3), dtype=np.float64)
    if laser_xyz is None:
        laser_xyz = cap.get("emitter_position", tal.laser_xyz if tal is not None else None)
    if sensor_xyz is None:
        sensor_xyz = cap.get("sensor_position", tal.sensor_xyz if tal is not None else None)

    # time axis and legs
    t_start = float(edges[0]) * SPEED_OF_LIGHT
    delta_t = float(widths[0]) * SPEED_OF_LIGHT
    laser_leg = bool(conf.get("count_laser_leg", False))
    sensor_leg = bool(conf.get("count_sensor_leg", True))
    if laser_leg != sensor_leg:
        # one laser point: the emitter→spot leg is one constant, so moving t_start makes the flags agree exactly
        if laser.shape[0] * laser.shape[1] != 1 or laser_xyz is None:
            raise DatasetError(f"tal's t_accounts_first_and_last_bounces needs count_laser_leg == count_sensor_leg "
                             f"(got {laser_leg} / {sensor_leg}); re-simulate with both true or both false")
        leg = float(np.linalg.norm(np.asarray(laser_xyz, dtype=np.float64) - laser.reshape(3)))
        t_start += leg if sensor_leg else -leg
        accounts = True if sensor_leg else False
    else:
        accounts = laser_leg
    if tal is not None:
        t_start, delta_t, accounts = tal.t_start, tal.delta_t, tal.t_accounts_first_and_last_bounces

    # layout: tal's H[t, (lx, ly,) sx, sy] from datagen's envelope[(ly, lx,) sy, sx, t]
    nt = env.shape[-1]
    laser_grid = laser.transpose(1, 0, 2)                          # (Lx, Ly, 3)
    sensor_grid = sensor.transpose(1, 0, 2)                        # (Sx, Sy, 3)
    if ctype == "exhaustive":
        h = np.moveaxis(env, -1, 0).transpose(0, 2, 1, 4, 3)      # (T, Lx, Ly, Sx, Sy)
        h_format = HFormat.T_Lx_Ly_Sx_Sy
    else:
        h = np.moveaxis(env[0, 0], -1, 0).transpose(0, 2, 1)      # (T, Sx, Sy)
        h_format = HFormat.T_Sx_Sy
        if ctype == "confocal":
            laser_grid = sensor_grid
    if tal is not None:
        if tal.scan_type != ctype:
            raise DatasetError(f"result capture type {ctype!r} differs from the tal config's {tal.scan_type!r}")
        si = _grid_index(sensor_grid.reshape(-1, 3), tal.sensor_grid_xyz, "sensor grid").ravel()
        s_shape = tal.sensor_grid_xyz.shape[:2]
        if ctype == "exhaustive":
            li = _grid_index(laser_grid.reshape(-1, 3), tal.laser_grid_xyz, "laser grid").ravel()
            l_shape = tal.laser_grid_xyz.shape[:2]
            h = h.reshape(nt, -1, sensor_grid.shape[0] * sensor_grid.shape[1])[:, li][:, :, si]
            h = h.reshape((nt,) + l_shape + s_shape) * tal.laser_scale[None, :, :, None, None]
        else:
            h = h.reshape(nt, -1)[:, si].reshape((nt,) + s_shape)
            # single: one laser scale; confocal: the laser point is the sensor point
            h = h * (tal.laser_scale[None] if ctype == "confocal" else float(tal.laser_scale.reshape(-1)[0]))
        laser_grid, sensor_grid = tal.laser_grid_xyz, tal.sensor_grid_xyz
    H = h
    info = {
        "generator": "datagen",
        "datagen": {
            "version": (attrs.get("versions") or {}).get("datagen"),
            "capture": cap,
            "convention": cap.get("convention", "aperture"),
            "H_units": _h_units(cap.get("convention", "aperture"), tal is not None),
            "time_legs": {"count_laser_leg": laser_leg, "count_sensor_leg": sensor_leg},
            "attrs": attrs,
        },
    }
    if tal is not None:
        info["config"] = tal.config
        info["datagen"]["laser_scale"] = np.asarray(tal.laser_scale).tolist()
        info["datagen"]["notes"] = list(tal.notes)
    info.update(scene_info or {})
    normals = np.broadcast_to(normal, sensor_grid.shape).copy()
    return {
        "H": np.ascontiguousarray(H),
        "H_format": h_format,
        "sensor_xyz": None if sensor_xyz is None else np.asarray(sensor_xyz, dtype=np.float64),
        "sensor_grid_xyz": np.asarray(sensor_grid, dtype=np.float64),
        "sensor_grid_normals": normals,
        "sensor_grid_format": GridFormat.X_Y_3,
        "laser_xyz": None if laser_xyz is None else np.asarray(laser_xyz, dtype=np.float64),
        "laser_grid_xyz": np.asarray(laser_grid, dtype=np.float64),
        "laser_grid_normals": np.broadcast_to(normal, np.shape(laser_grid)).copy(),
        "laser_grid_format": GridFormat.X_Y_3,
        "volume_format": VolumeFormat.UNKNOWN,
        "delta_t": delta_t,
        "t_start": t_start,
        "t_accounts_first_and_last_bounces": bool(accounts),
        "scene_info": _plain(info),
    }


def _h_units(convention: str, tal_scaled: bool) -> str:
    if convention == "point_radiance":
        if tal_scaled:
            return ("radiance leaving the wall point toward the sensor (1/(m²·sr)) times the laser scale "
                    "K_l = π·e_sum·cos θ_e/d_e² (tal render's normalisation), per bin of OPL")
        return "radiance leaving the wall point toward the sensor per unit power at the laser spot, 1/(m²·sr), per bin"
    return "expected detected photons per laser pulse per bin"


def _plain(value):
    """Nested dicts/lists of plain Python scalars (YAML-safe): numpy → lists/floats, tuples → lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


# ---------------------------------------------------------------------------------------------------------
# HDF5 I/O


def write_tal_hdf5(result, path: str | Path, tal: TalCapture | None = None, *, compression_level: int = 0,
                   dtype: str = "float64", **kwargs) -> Path:
    """Write ``result`` as a tal HDF5 capture (layout in the module docstring); returns the path.

    The file is written to ``<path>.partial`` and renamed into place; on any failure the partial file is
    removed, so nothing is left behind.

    Args:
        result: a datagen Result with capture grids (see :func:`tal_arrays`).
        tal: the :class:`TalCapture` of a tal render YAML (lay out and scale H as ``tal render`` does).
        compression_level: gzip level 0–9 for H (0: none), as ``tal.io.write_capture``.
        dtype: "float64" (exact round trip) or "float32" (what ``tal render`` writes; half the size).
        kwargs: ``laser_xyz``, ``sensor_xyz``, ``scene_info`` (see :func:`tal_arrays`).
    Raises:
        DatasetError: see :func:`tal_arrays`; ValueError: bad compression level or dtype; IsADirectoryError:
        ``path`` is a directory; OSError: the write failed (e.g. a full disk).
    """
    import h5py

    if not (isinstance(compression_level, int) and 0 <= compression_level <= 9):
        raise ValueError(f"compression_level must be an integer 0..9, got {compression_level!r}")
    if dtype not in ("float64", "float32"):
        raise ValueError(f"dtype must be 'float64' or 'float32', got {dtype!r}")
    data = tal_arrays(result, tal, **kwargs)
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a directory; give the .hdf5 file to write")
    try:
        with h5py.File(tmp, "w") as f:
            for key in TAL_FIELDS:
                value = data[key]
                if key in _ENUM_FIELDS:
                    if value is None or (key == "volume_format" and value == VolumeFormat.UNKNOWN):
                        f[key] = h5py.Empty("f8")     # as tal render writes it; reads back as UNKNOWN
                        continue
                    enum = type(value)
                    dt = h5py.enum_dtype({m.name: m.value for m in enum}, basetype="i")
                    ds = f.create_dataset(key, (1,), dtype=dt)
                    ds[0] = int(value)
                elif value is None:
                    f[key] = h5py.Empty("f8")
                elif key == "scene_info":
                    f[key] = yaml.safe_dump(value, sort_keys=False)
                elif key == "H":
                    arr = np.asarray(value, dtype=dtype)
                    if compression_level:
                        f.create_dataset(key, data=arr, compression="gzip", compression_opts=compression_level)
                    else:
                        f[key] = arr
                elif key == "t_accounts_first_and_last_bounces":
                    f[key] = np.bool_(value)
                else:
                    f[key] = value
        tmp.replace(path)
    except BaseException:   # a full disk, an interrupt, a target that cannot be replaced: leave nothing behind
        tmp.unlink(missing_ok=True)
        raise
    return path


def read_tal_hdf5(path: str | Path, skip_H: bool = False) -> dict:
    """Read a tal HDF5 capture as ``tal.io.read_capture`` does, into a dict of its fields.

    Same parsing rules as tal 0.20's ``read_hdf5`` + ``NLOSCaptureData``: empty datasets → None (enum fields:
    their UNKNOWN member), size-1 arrays → scalars, enum fields → :class:`HFormat` / :class:`GridFormat` /
    :class:`VolumeFormat`, ``scene_info`` YAML → dict.

    Raises:
        FileNotFoundError: no file; DatasetError: a key tal does not know (tal rejects such files too).
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no tal HDF5 file at {path}")
    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        for key in f.keys():
            if key not in TAL_FIELDS:
                raise DatasetError(f"{path}: unknown tal capture field {key!r}")
            raw = f[key]
            if skip_H and key == "H":
                out[key] = None
                continue
            if isinstance(raw, h5py.Group):
                raise DatasetError(f"{path}: field {key!r} is a group; tal stores datasets")
            value = raw[()]
            empty = isinstance(value, h5py.Empty) or raw.shape is None
            if key in _ENUM_FIELDS:
                out[key] = _ENUM_FIELDS[key](0 if empty else int(np.squeeze(value)[()]))
                continue
            if empty:
                out[key] = None
                continue
            if isinstance(value, np.ndarray) and value.size == 1:
                value = np.squeeze(value)[()]
            if key == "scene_info":
                text = value.decode() if isinstance(value, bytes) else value
                out[key] = parse_yaml(text, f"{path}: scene_info")   # the bounded, duplicate-refusing reader
            elif key == "t_accounts_first_and_last_bounces":
                out[key] = bool(value)
            elif key in ("delta_t", "t_start"):
                out[key] = float(value)
            else:
                out[key] = value
    return out
