"""The files of real NLOS labs, both ways: Stanford LCT / f-k ``.mat`` (MAT v5 through ``scipy.io``, v7.3
through ``h5py``) and the Zaragoza ZNLOS HDF5 (``h5py``). Conventions of each, and where each was checked, are
in docs/capture_io.md.

A file is read into a :class:`LabCapture`: the format's own fields exactly as stored (``raw``, native dtypes, the
file's index order as MATLAB or the ZNLOS writer sees it), plus what datagen needs from them (:meth:`data` in
datagen's order, :meth:`time_edges`, the scan grids, per-point time offsets). Writing a :class:`LabCapture`
writes ``raw`` back unchanged, so read → write → read is bit-exact. :func:`capture_from_result` turns a datagen
:class:`~datagen.simulation.Result` (or a dataset sample) into one, :meth:`LabCapture.to_result` the other way;
:func:`write_capture_store` keeps an imported capture as a datagen result store (``result.zarr`` plus the
per-point ``time_offsets``), :func:`read_capture_store` reads it back.

Shapes (datagen order, docs/physics.md §1): confocal (ny, nx, T); single (ny, nx, T) with one laser point;
exhaustive (ly, lx, ny, nx, T). LCT files are turned into that order and back by :mod:`datagen.io.orientation`
(the release's ``rect_data(i, j, t)`` is datagen's scan anti-transposed). Times in s inside datagen; the files keep their own units (LCT/f-k: s and ps,
ZNLOS: optical path in metres).
"""
from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import validate
from ..errors import DatasetError
from ..units import SPEED_OF_LIGHT
from .lab_checks import MAT_FORMATS, check_mat_fields, check_znlos_fields
from .orientation import LCT_WALL_NORMAL, lct_half_width, lct_scan_points, lct_to_scan, scan_to_lct, square_pitch

__all__ = [
    "FORMATS", "MAT_FORMATS", "LabCapture", "read_lab_capture", "write_lab_capture", "capture_from_result",
    "write_capture_store", "read_capture_store", "detect_format",
]

FORMATS = ("lct-mat", "fk-mat", "znlos")
"""Lab formats read and written here (tal's HDF5 is :mod:`datagen.io.tal_hdf5`)."""

ZNLOS_FIELDS = ("data", "deltaT", "t0", "cameraPosition", "cameraGridPositions", "cameraGridNormals",
                "cameraGridPoints", "cameraGridSize", "laserPosition", "laserGridPositions", "laserGridNormals",
                "laserGridPoints", "laserGridSize", "isConfocal", "hiddenVolumePosition", "hiddenVolumeRotation",
                "hiddenVolumeSize", "t")
"""Datasets of a ZNLOS HDF5 file (the field names of the Zaragoza dataset's readers, docs/capture_io.md)."""

MAT73_HEADER = 512
"""A MAT v7.3 file is HDF5 behind a 512-byte MATLAB header (the user block)."""

_MATLAB_CLASS = {np.dtype("float64"): b"double", np.dtype("float32"): b"single", np.dtype("int8"): b"int8",
                 np.dtype("int16"): b"int16", np.dtype("int32"): b"int32", np.dtype("int64"): b"int64",
                 np.dtype("uint8"): b"uint8", np.dtype("uint16"): b"uint16", np.dtype("uint32"): b"uint32",
                 np.dtype("uint64"): b"uint64", np.dtype("bool"): b"logical"}


@dataclass
class LabCapture:
    """One capture in a lab format.

    Attributes:
        format: "lct-mat" | "fk-mat" | "znlos".
        raw: the file's fields as stored (numpy arrays in native dtypes; ``.mat`` arrays in MATLAB index order,
            ZNLOS arrays in the order h5py reads them).
        mat_version: "5" or "7.3" for ``.mat`` files, None for ZNLOS.
        source: where it was read from (or what it was made from).
        meta: datagen-side metadata kept with an export (not written into ``.mat`` files).
    """

    format: str
    raw: dict[str, Any]
    mat_version: str | None = None
    source: str = ""
    meta: dict = field(default_factory=dict)

    # ---- what datagen reads from the fields ------------------------------------------------------------
    @property
    def capture_type(self) -> str:
        """"confocal" (LCT / f-k, ZNLOS with isConfocal), "single" (one laser point) or "exhaustive"."""
        if self.format in MAT_FORMATS:
            return "confocal"
        d = self.raw["data"]
        if d.ndim == 5:
            return "confocal"
        return "single" if d.shape[5] * d.shape[6] == 1 else "exhaustive"

    def data(self) -> np.ndarray:
        """Transients in datagen's order and the file's dtype: (ny, nx, T) or (ly, lx, ny, nx, T). LCT:
        ``rect_data`` anti-transposed (:func:`~datagen.io.orientation.lct_to_scan`, a view); f-k: ``meas`` as
        stored; ZNLOS: colour and bounce axes summed."""
        if self.format == "lct-mat":
            return lct_to_scan(self.raw["rect_data"])
        if self.format in MAT_FORMATS:
            return self.raw[MAT_FORMATS[self.format]]
        d = self.raw["data"]                            # (C, T, B, sy, sx[, ly, lx])
        d = d.sum(axis=(0, 2), dtype=d.dtype)           # (T, sy, sx[, ly, lx])
        if d.ndim == 3:
            return np.moveaxis(d, 0, -1)
        d = d.transpose(3, 4, 1, 2, 0)                  # (ly, lx, sy, sx, T)
        return d[0, 0] if self.capture_type == "single" else d

    @property
    def n_bins(self) -> int:
        return int(self.data().shape[-1])

    def bin_width(self) -> float:
        """Bin width in s."""
        if self.format in MAT_FORMATS:
            return float(np.squeeze(self.raw["bin_resolution"]))
        return float(np.squeeze(self.raw["deltaT"])) / SPEED_OF_LIGHT

    def time_edges(self) -> np.ndarray:
        """(T+1,) bin edges in s. LCT / f-k: the TDC clock, bin 0 from 0 (the light reaches scan point p at
        :meth:`time_offsets` [p]); ZNLOS: from t0, the whole path laser → wall → hidden → wall → camera."""
        t0 = 0.0 if self.format in MAT_FORMATS else float(np.squeeze(self.raw["t0"])) / SPEED_OF_LIGHT
        return t0 + np.arange(self.n_bins + 1) * self.bin_width()

    def time_offsets(self) -> np.ndarray | None:
        """Per scan point (ny, nx), the time in s that its transient's time axis holds beyond the hidden round
        trip: LCT / f-k ``tofgrid`` (ps → s, in the order of :meth:`data`; None without one); ZNLOS confocal:
        the emitter → point → camera legs (None for other scans: the legs differ per laser/sensor pair)."""
        if self.format in MAT_FORMATS:
            tof = self.raw.get("tofgrid")
            if tof is None:
                return None
            tof = np.asarray(tof, dtype=np.float64) * 1e-12
            return lct_to_scan(tof).copy() if self.format == "lct-mat" else tof
        if self.capture_type != "confocal":
            return None
        pts = self.sensor_points()
        legs = (np.linalg.norm(pts - self.laser_position(), axis=-1)
                + np.linalg.norm(pts - self.sensor_position(), axis=-1))
        return legs / SPEED_OF_LIGHT

    def _grid(self, key: str) -> np.ndarray:
        g = np.asarray(self.raw[key], dtype=np.float64)
        if g.shape[0] == 3 and g.ndim == 3:               # (3, sy, sx) as h5py reads the dataset's files
            return g.transpose(1, 2, 0)
        if g.ndim == 3 and g.shape[-1] == 3:              # (sx, sy, 3), tal's X_Y_3
            return g.transpose(1, 0, 2)
        raise DatasetError(f"{self.source}: {key}: expected (3, ny, nx) or (nx, ny, 3) points, got {g.shape}")

    def sensor_points(self) -> np.ndarray:
        """(ny, nx, 3) scan points in m, in the order of :meth:`data`. LCT / f-k: the file has no frame; the
        release's grid ``linspace(−width, width, N)`` on the vertical wall y = 0, columns along +x, rows up +z
        (:func:`~datagen.io.orientation.lct_scan_points`)."""
        if self.format in MAT_FORMATS:
            return lct_scan_points(float(np.squeeze(self.raw["width"])), self.data().shape[:2])
        return self._grid("cameraGridPositions")

    def laser_points(self) -> np.ndarray:
        """(ly, lx, 3) laser points in m (confocal: the scan points)."""
        if self.format in MAT_FORMATS or self.capture_type == "confocal":
            return self.sensor_points()
        return self._grid("laserGridPositions")

    def wall_normal(self) -> np.ndarray:
        """(3,) wall normal: +y for LCT / f-k (the hidden side of the wall y = 0, by datagen's choice), the
        file's first grid normal for ZNLOS."""
        if self.format in MAT_FORMATS:
            return LCT_WALL_NORMAL.copy()
        n = self._grid("cameraGridNormals").reshape(-1, 3)[0]
        return n / np.linalg.norm(n)

    def laser_position(self) -> np.ndarray | None:
        return None if self.format in MAT_FORMATS else np.asarray(self.raw["laserPosition"], float).reshape(3)

    def sensor_position(self) -> np.ndarray | None:
        return None if self.format in MAT_FORMATS else np.asarray(self.raw["cameraPosition"], float).reshape(3)

    def to_result(self):
        """A datagen :class:`~datagen.simulation.Result` of the capture: envelope float64 (datagen order), counts
        int64 (the data when it holds whole numbers, else zeros), time_edges, grids, and attrs ``capture`` /
        ``config`` (which legs the time axis counts) / ``lab_capture`` (format, source, per-file conventions)."""
        from ..simulation import Result

        data = self.data()
        env = np.asarray(data, dtype=np.float64)
        whole = bool(np.all(np.isfinite(env)) and np.all(env == np.round(env)) and np.all(env >= 0))
        counts = env.astype(np.int64) if whole else np.zeros(env.shape, np.int64)
        legs = self.format == "znlos"
        lp, sp = self.laser_position(), self.sensor_position()
        attrs = {
            "capture": {"type": self.capture_type, "convention": "counts" if whole else "measured",
                        "emitter_position": None if lp is None else lp.tolist(),
                        "sensor_position": None if sp is None else sp.tolist()},
            "config": {"count_laser_leg": legs, "count_sensor_leg": legs},
            "lab_capture": {"format": self.format, "mat_version": self.mat_version, "source": self.source,
                            "dtype": str(np.asarray(data).dtype), "time_offsets": self.time_offsets() is not None,
                            "conventions": "docs/capture_io.md"},
        }
        laser = self.laser_points()
        return Result(self.time_edges(), env, {}, counts, attrs, laser_points=laser,
                      sensor_points=self.sensor_points(), wall_normal=self.wall_normal())


# -------------------------------------------------------------------------------------------------------------
# reading


def detect_format(path: str | Path) -> tuple[str, str | None]:
    """(format, mat version) of a lab file from its content: a MAT v5 header, or HDF5 (a MAT v7.3 user block, or
    ZNLOS's ``data`` + ``deltaT``).

    Raises:
        FileNotFoundError: no file; DatasetError: none of the lab formats (the message names what was found).
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no capture file at {path}")
    with open(path, "rb") as f:
        head = f.read(128)
    if head.startswith(b"MATLAB 5.0 MAT-file"):
        keys = _mat5_keys(path)
        return _mat_layout(path, keys), "5"
    if not h5py.is_hdf5(path):
        raise DatasetError(f"{path}: not a MAT v5 file nor HDF5 (MAT v7.3, ZNLOS); cannot read it as a capture")
    with open_hdf5(path) as f:
        keys = set(f.keys())
    if head.startswith(b"MATLAB 7.3 MAT-file"):
        return _mat_layout(path, keys), "7.3"
    if {"data", "deltaT"} <= keys:
        return "znlos", None
    if "H" in keys:
        raise DatasetError(f"{path}: a tal HDF5 capture; read it with datagen.io.read_tal_hdf5 (format 'tal')")
    raise DatasetError(f"{path}: HDF5 without ZNLOS's 'data' and 'deltaT' (found {sorted(keys)[:8]})")


def open_hdf5(path: Path):
    """``h5py.File(path, "r")``; a file h5py cannot open (truncated, damaged) is a :class:`DatasetError` naming it.

    HDF5's own text ("truncated file: eof = …") says which: the message keeps its gist, not its internals."""
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        text = " ".join(str(exc).split())
        gist = "truncated (shorter than its header says)" if "truncated file" in text else f"damaged ({text[:120]})"
        raise DatasetError(f"{path}: cannot read the HDF5 (MAT v7.3) file: {gist}") from None


def _mat5_keys(path: Path) -> set[str]:
    from scipy.io import whosmat

    try:
        return {name for name, _, _ in whosmat(str(path))}
    except Exception as exc:   # scipy raises several types for a damaged file
        raise DatasetError(f"{path}: cannot read the MAT v5 file: {' '.join(str(exc).split())}") from None


def _mat_layout(path: Path, keys: set[str]) -> str:
    if "rect_data" in keys:
        return "lct-mat"
    if "meas" in keys:
        return "fk-mat"
    raise DatasetError(f"{path}: a .mat file without 'rect_data' (LCT) or 'meas' (f-k) (found {sorted(keys)[:8]})")


def read_lab_capture(path: str | Path, *, width: float | None = None, bin_resolution: float | None = None,
                     tofgrid_path: str | Path | None = None, allow_negative: bool = False,
                     negative_hint: str = validate.NEGATIVE_HINT) -> LabCapture:
    """Read an LCT / f-k ``.mat`` (v5 or v7.3) or ZNLOS HDF5 capture.

    Args:
        path: the file; its format is detected from its content (:func:`detect_format`).
        width, bin_resolution: half width of the scanned wall (m) and bin width (s) for ``.mat`` files that do not
            hold them (the f-k release keeps them in its script); a value in the file wins over these.
        tofgrid_path: a separate ``.mat`` holding ``tofgrid`` (the f-k release ships ``tof.mat`` beside the
            measurement).
        allow_negative: accept negative bins (a background-subtracted capture); otherwise they are refused, the
            message suggesting ``negative_hint``.
    Returns:
        :class:`LabCapture` with the fields as stored.
    Raises:
        FileNotFoundError: no file; DatasetError: another format, a missing or misshapen field (one line naming the
        file, the field and what was found); :class:`datagen.validate.InputDataError` (a DatasetError): transients
        that are complex, NaN, ±inf or (unless ``allow_negative``) negative, time offsets that are not finite
        (:mod:`datagen.validate`).
    """
    fmt, version = detect_format(path)
    path = Path(path)
    if fmt == "znlos":
        raw = _read_hdf5_fields(path, ZNLOS_FIELDS, transpose=False)
        cap = LabCapture(fmt, raw, None, str(path))
        check_znlos_fields(cap, path, allow_negative, negative_hint)
        return cap
    raw = _read_mat(path, version)
    if tofgrid_path is not None:
        tpath = Path(tofgrid_path)
        if not tpath.is_file():
            raise FileNotFoundError(f"no tofgrid file at {tpath}")
        with open(tpath, "rb") as f:
            version_73 = f.read(19) == b"MATLAB 7.3 MAT-file"
        extra = _read_mat(tpath, "7.3" if version_73 else "5")
        if "tofgrid" not in extra:
            raise DatasetError(f"{tofgrid_path}: no 'tofgrid' field (found {sorted(extra)[:8]})")
        raw["tofgrid"] = extra["tofgrid"]
    given = set()
    for key, value in (("width", width), ("bin_resolution", bin_resolution)):
        if key not in raw and value is not None:
            raw[key] = np.array([[float(value)]])
            given.add(key)
    cap = LabCapture(fmt, raw, version, str(path))
    check_mat_fields(cap, path, allow_negative, given, negative_hint)
    return cap


def _read_mat(path: Path, version: str) -> dict:
    if version == "5":
        from scipy.io import loadmat

        try:
            raw = loadmat(str(path), squeeze_me=False, mat_dtype=False)
        except Exception as exc:
            raise DatasetError(f"{path}: cannot read the MAT v5 file: {' '.join(str(exc).split())}") from None
        return {k: v for k, v in raw.items() if not k.startswith("__")}
    return _read_hdf5_fields(path, None, transpose=True)


def _read_hdf5_fields(path: Path, names, transpose: bool) -> dict:
    """Datasets at the file's root (``names``: only those; ``transpose``: reverse the axes, MAT v7.3 → MATLAB
    order). Groups and references (MATLAB structs, cells) are skipped."""
    import h5py

    out = {}
    with open_hdf5(path) as f:
        for key in f.keys():
            obj = f[key]
            if not isinstance(obj, h5py.Dataset) or (names is not None and key not in names):
                continue
            if obj.shape is None:
                continue
            value = obj[()]
            if isinstance(value, np.ndarray) and transpose:
                value = value.T
            out[key] = np.asarray(value)
    return out


# -------------------------------------------------------------------------------------------------------------
# writing


def write_lab_capture(capture: LabCapture, path: str | Path, mat_version: str | None = None) -> Path:
    """Write ``capture`` in its format (``raw`` unchanged) to ``path``; written to ``<path>.partial`` and renamed.

    Args:
        mat_version: "5" (scipy.io.savemat) or "7.3" (HDF5 behind MATLAB's header, h5py) for ``.mat`` formats;
            default the capture's own, else "5". MAT v5 cannot hold arrays over 2 GiB: use "7.3".
    Raises:
        ValueError: an unknown format or MAT version; OSError: the write failed (nothing is left behind).
    """
    path = Path(path)
    if capture.format not in FORMATS:
        raise ValueError(f"unknown lab format {capture.format!r} (one of {', '.join(FORMATS)})")
    version = mat_version or capture.mat_version or "5"
    if capture.format in MAT_FORMATS and version not in ("5", "7.3"):
        raise ValueError(f"MAT version must be '5' or '7.3', got {version!r}")
    tmp = path.with_name(path.name + ".partial")
    try:
        if capture.format == "znlos":
            _write_hdf5(tmp, capture.raw, transpose=False, matlab=False)
        elif version == "5":
            from scipy.io import savemat
            savemat(str(tmp), capture.raw, format="5", do_compression=False, oned_as="column")
        else:
            _write_hdf5(tmp, capture.raw, transpose=True, matlab=True)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _write_hdf5(path: Path, fields: dict, transpose: bool, matlab: bool) -> None:
    import h5py

    with h5py.File(path, "w", userblock_size=MAT73_HEADER if matlab else 0) as f:
        for key, value in fields.items():
            arr = np.asarray(value)
            if arr.dtype.kind in "US":
                f[key] = str(arr.reshape(-1)[0]) if arr.size else ""
                continue
            if matlab and arr.ndim < 2:
                arr = arr.reshape(1, -1) if arr.ndim == 1 else arr.reshape(1, 1)
            ds = f.create_dataset(key, data=arr.T if transpose else arr)
            if matlab:
                ds.attrs["MATLAB_class"] = np.bytes_(_MATLAB_CLASS.get(arr.dtype, b"double"))
    if matlab:
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%a %b %d %H:%M:%S %Y")
        text = f"MATLAB 7.3 MAT-file, Platform: datagen, Created on: {stamp} HDF5 schema 1.00 .".encode()
        header = text.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02" + b"IM"
        header = header.ljust(MAT73_HEADER, b"\0")
        with open(path, "r+b") as f:
            f.write(header)


def capture_kind(result) -> tuple[str, str]:
    """(kind, description) of a capture or result: kind "zones" (a multi-zone flood), "confocal", "exhaustive" or
    "single" (one laser spot, one FoV); the description names its grid, e.g. "a confocal scan of 8 x 8 points"."""
    attrs = getattr(result, "attrs", None) or {}
    lead = tuple(np.shape(result.envelope)[:-1])
    grid = " x ".join(str(n) for n in lead)
    if "multizone" in attrs:
        return "zones", f"a multi-zone result of {grid} zones (a flood)"
    kind = (attrs.get("capture") or {}).get("type")
    if kind in ("confocal", "exhaustive"):
        return kind, f"an {kind} scan of {grid} points" if kind == "exhaustive" else f"a confocal scan of {grid} points"
    return "single", f"a single-spot transient{f' ({grid})' if lead else ''}"


def refuse_flood(result, fmt: str) -> None:
    """Raise :class:`DatasetError` when ``result`` is a multi-zone flood (:func:`capture_kind` "zones"): its
    transients are zones lit by a whole flood, and the capture formats (LCT, f-k, ZNLOS, tal) hold one laser point
    per transient. docs/multizone.md."""
    if capture_kind(result)[0] == "zones":
        zones = " x ".join(str(n) for n in np.shape(result.envelope)[:-1])
        raise DatasetError(f"a multi-zone result ({zones} zones lit by a flood) has no single laser point per "
                           f"transient, which {fmt} files hold; keep it as a datagen store (docs/multizone.md)")


def capture_from_result(result, fmt: str, *, source: str = "datagen") -> LabCapture:
    """A datagen result (or dataset sample, :func:`datagen.dataset.export.sample_result`) as a lab capture.

    LCT / f-k: confocal scans on a square N × N grid of equal pitch in both directions; ``rect_data`` / ``meas``
    (N, N, T) float64 is the envelope (LCT: anti-transposed into the release's order,
    :func:`~datagen.io.orientation.scan_to_lct`; f-k: as datagen orders it), ``bin_resolution`` the bin width
    (s), ``width`` = pitch·(N−1)/2 (m, the release's ``linspace(−width, width, N)``), and ``tofgrid`` (ps, ordered
    as the transients) = the counted wall legs − t_start, so that the public reader's shift puts the light at
    the wall at bin 0 (omitted when zero everywhere). ZNLOS: data (1, T, 1, ny, nx) confocal or (1, T, 1, ny, nx, ly,
    lx), deltaT and t0 as optical path (m); the time axis must count both wall legs, as ZNLOS's does.

    Raises:
        DatasetError: a capture the format cannot hold (named: type, grid, legs, bins; a multi-zone flood).
    """
    refuse_flood(result, fmt)
    env = np.asarray(result.envelope, dtype=np.float64)
    edges = np.asarray(result.time_edges, dtype=np.float64)
    widths = np.diff(edges)
    if not np.allclose(widths, widths[0], rtol=1e-9, atol=0):
        raise DatasetError(f"{fmt} needs uniform time bins; the result's time_edges are not uniform")
    attrs = getattr(result, "attrs", {}) or {}
    cap = attrs.get("capture") or {}
    conf = attrs.get("config") or {}
    ctype = cap.get("type", "single")
    laser_leg, sensor_leg = bool(conf.get("count_laser_leg", False)), bool(conf.get("count_sensor_leg", True))
    if result.sensor_points is None or result.laser_points is None:
        raise DatasetError("the result has no capture grids (laser_points / sensor_points); re-simulate it")
    sensor = np.asarray(result.sensor_points, dtype=np.float64)
    meta = {"capture": cap, "config": conf}
    if fmt in MAT_FORMATS:
        if ctype != "confocal" or env.ndim != 3:
            raise DatasetError(f"{fmt} files hold confocal scans (ny, nx, T); the result's capture is {ctype!r} "
                               f"with envelope {env.shape}")
        ny, nx = env.shape[:2]
        pts = sensor.reshape(ny, nx, 3)
        pitch = square_pitch(pts, fmt)
        legs = np.zeros((ny, nx))
        emitter, sensor_pos = cap.get("emitter_position"), cap.get("sensor_position")
        if laser_leg:
            legs += np.linalg.norm(pts - np.asarray(emitter, float), axis=-1)
        if sensor_leg:
            legs += np.linalg.norm(pts - np.asarray(sensor_pos, float), axis=-1)
        tof_ps = (legs / SPEED_OF_LIGHT - edges[0]) * 1e12
        to_file = scan_to_lct if fmt == "lct-mat" else np.ascontiguousarray
        env, tof_ps = to_file(env), to_file(tof_ps)
        raw = {MAT_FORMATS[fmt]: env, "width": np.array([[lct_half_width(pitch, nx)]]),
               "bin_resolution": np.array([[float(widths[0])]])}
        if np.any(tof_ps != 0):
            raw["tofgrid"] = tof_ps
        meta["wall"] = {"center": pts.reshape(-1, 3).mean(0).tolist(),
                        "normal": np.asarray(result.wall_normal, float).tolist()}
        return LabCapture(fmt, raw, "5", source, meta)
    if fmt != "znlos":
        raise ValueError(f"unknown lab format {fmt!r} (one of {', '.join(FORMATS)})")
    if not (laser_leg and sensor_leg):
        raise DatasetError(f"ZNLOS time axes count both wall legs; the result counts laser leg {laser_leg}, sensor "
                           f"leg {sensor_leg}: re-simulate with count_laser_leg and count_sensor_leg true, or export "
                           "lct-mat (its tofgrid carries per-point offsets)")
    laser = np.asarray(result.laser_points, dtype=np.float64)
    if ctype == "exhaustive":
        data = env.transpose(4, 2, 3, 0, 1)[None, :, None]          # (1, T, 1, sy, sx, ly, lx)
        lgrid = laser
    else:
        e3 = env.reshape(-1, env.shape[-1]) if env.ndim == 1 else env
        data = np.moveaxis(e3, -1, 0)[None, :, None]                 # (1, T, 1, sy, sx)
        lgrid = sensor.reshape(e3.shape[:2] + (3,)) if ctype == "confocal" else laser.reshape(1, 1, 3)
        if ctype == "single":
            data = data[..., None, None]
        sensor = sensor.reshape(e3.shape[:2] + (3,))
    normal = np.asarray(result.wall_normal, dtype=np.float64)
    raw = {
        "data": np.ascontiguousarray(data),
        "deltaT": np.float64(widths[0] * SPEED_OF_LIGHT), "t0": np.float64(edges[0] * SPEED_OF_LIGHT),
        "cameraPosition": np.asarray(cap["sensor_position"], float), "laserPosition": np.asarray(
            cap["emitter_position"], float),
        "cameraGridPositions": sensor.transpose(2, 0, 1).copy(),
        "cameraGridNormals": np.broadcast_to(normal[:, None, None], (3,) + sensor.shape[:2]).copy(),
        "cameraGridPoints": np.array(sensor.shape[1::-1], dtype=np.float64),
        "laserGridPositions": lgrid.transpose(2, 0, 1).copy(),
        "laserGridNormals": np.broadcast_to(normal[:, None, None], (3,) + lgrid.shape[:2]).copy(),
        "laserGridPoints": np.array(lgrid.shape[1::-1], dtype=np.float64),
        "isConfocal": np.int64(ctype == "confocal"), "t": np.int64(env.shape[-1]),
    }
    return LabCapture("znlos", raw, None, source, meta)


# -------------------------------------------------------------------------------------------------------------
# datagen's store of an imported capture


def write_capture_store(capture: LabCapture, path: str | Path) -> Path:
    """Keep an imported capture as a datagen result store (:func:`datagen.io.write_result`: envelope, counts,
    time_edges, grids, attrs) plus ``time_offsets`` (ny, nx) float64 s when the file has per-point offsets.

    Returns:
        the ``.zarr`` path written.
    """
    import warnings

    import zarr

    from .store import write_result

    out = write_result(capture.to_result(), path)
    offsets = capture.time_offsets()
    if offsets is not None:
        root = zarr.open_group(str(out), mode="a")
        root.create_array("time_offsets", data=np.asarray(offsets, dtype=np.float64), overwrite=True)
        with warnings.catch_warnings():     # consolidated metadata is a zarr-python v3 extension, as store.py
            warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
            zarr.consolidate_metadata(str(out))
    return out


def read_capture_store(path: str | Path):
    """(Result, time_offsets (ny, nx) s or None) of a store written by :func:`write_capture_store` (or any
    result store: offsets from its counted legs are not computed here, None).

    Raises:
        FileNotFoundError: no result store at ``path``.
    """
    import zarr

    from .store import RESULT_NAME, read_result

    result = read_result(path)
    store = Path(path) / RESULT_NAME if (Path(path) / RESULT_NAME).exists() else Path(path)
    root = zarr.open_group(str(store), mode="r")
    offsets = root["time_offsets"][...] if "time_offsets" in root.array_keys() else None
    return result, offsets
