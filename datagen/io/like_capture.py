"""Simulate the capture a store holds: ``datagen simulate SCENE.yaml --like STORE`` (docs/capture_io.md,
"Simulating a capture").

A confocal capture store (an imported lab file, ``datagen import-capture``, or a datagen result) fixes what a
simulation of it must reproduce; :func:`capture_template` reads that into a :class:`CaptureTemplate`: the scan grid
(shape and pitch, in datagen's orientation, :mod:`datagen.io.orientation`), the bins (width, count, start), time zero
(the per-point offsets its time axis holds beyond the hidden round trip: an LCT ``tofgrid``, a datagen result's
counted wall legs, or none, as in the Stanford LCT release's rectified files) and, for a datagen result, its detector.

:func:`scene_like` replaces the scene's confocal grid by the capture's (same points per side and pitch, about the
centre the scene's ``capture.laser_grid`` gives on its relay wall, columns along the wall's u and rows up its v as in
every datagen scan); :func:`like_overrides` replaces the time axis: the scene is simulated on the hidden round-trip
axis (neither wall leg counted) over every round trip the capture's bins hold; :func:`to_capture_axis` then puts each
point's transient on the capture's own bins (shifted by its offset, exact for binned data,
:func:`datagen.spad.rates.rebin_envelope`) and redraws its counts there. What cannot be reconciled is refused in one
line naming the file, the field and the value: a scene without a confocal capture, a store that is not a confocal scan
on a regular grid, non-uniform bins.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError
from ..scene.parts import CaptureSpec, SceneError, WallGrid

__all__ = ["CaptureTemplate", "capture_template", "scene_like", "like_overrides", "to_capture_axis",
           "write_time_offsets", "merge_detector",
           "DETECTOR_FROM_TIME_AXIS", "EXPOSURE_FIELDS"]

DETECTOR_FROM_TIME_AXIS = ("bin_width", "bin_widths", "t_start")
"""Fields of a stored detector that follow the simulated time axis (never copied from a store)."""

GRID_RTOL = 1e-6
"""Relative spread of a scan's pitches below which it counts as a regular grid (float32 round-off of stored points)."""


@dataclass(frozen=True)
class CaptureTemplate:
    """What a simulation of a stored confocal capture must reproduce.

    Attributes:
        source: the store's path (for messages and the result's ``like`` record).
        points: (ny, nx, 3) float64 scan points in m, datagen's order (row up the wall, column along u).
        pitch: (between rows, between columns) in m.
        time_edges: (T+1,) float64 s, uniform.
        offsets: (ny, nx) float64 s each transient's time axis holds beyond the hidden round trip, or None (0).
        detector: the store's detector record (a datagen result's ``attrs["detector"]``) without the time-axis fields
            (:data:`DETECTOR_FROM_TIME_AXIS`), or None (an imported lab file records none).
    """

    source: str
    points: np.ndarray
    pitch: tuple[float, float]
    time_edges: np.ndarray
    offsets: np.ndarray | None
    detector: dict | None

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) scan points."""
        return tuple(int(n) for n in self.points.shape[:2])

    @property
    def bin_width(self) -> float:
        """s."""
        return float(self.time_edges[1] - self.time_edges[0])

    def hidden_window(self) -> tuple[float, float]:
        """(first, last) hidden round trip in s that any point's bins hold: the capture's edges less the largest and
        the smallest offset."""
        off = np.zeros(1) if self.offsets is None else self.offsets
        return float(self.time_edges[0] - off.max()), float(self.time_edges[-1] - off.min())

    def describe(self) -> str:
        """One line: grid, pitch, bins and time zero."""
        ny, nx = self.shape
        dy, dx = self.pitch
        pitch = f"{dx * 1e3:.4g} mm" if np.isclose(dx, dy, rtol=GRID_RTOL) else f"{dy * 1e3:.4g} x {dx * 1e3:.4g} mm"
        zero = ("time zero at the scanned point (no per-point offsets)" if self.offsets is None else
                f"per-point time offsets {self.offsets.min() * 1e9:.4g}..{self.offsets.max() * 1e9:.4g} ns")
        return (f"{ny} x {nx} points of pitch {pitch}, {len(self.time_edges) - 1} bins of "
                f"{self.bin_width * 1e12:.4g} ps from {self.time_edges[0] * 1e9:.4g} ns, {zero}")


def _pitch(points: np.ndarray, axis: int, source: str) -> float:
    d = np.linalg.norm(np.diff(points, axis=axis), axis=-1)
    pitch = float(d.mean())
    if not (pitch > 0 and np.allclose(d, pitch, rtol=GRID_RTOL)):
        name = "rows" if axis == 0 else "columns"
        raise DatasetError(f"{source}: laser_points: not a regular grid (the spacing between {name} runs from "
                           f"{float(d.min()):.6g} m to {float(d.max()):.6g} m); --like needs one pitch per axis")
    return pitch


def capture_template(result, offsets: np.ndarray | None, source: str) -> CaptureTemplate:
    """The :class:`CaptureTemplate` of a stored capture.

    Args:
        result: a :class:`~datagen.simulation.Result` read from the store (:func:`datagen.io.read_result`, or
            :func:`~datagen.io.lab_formats.read_capture_store`); offsets: its per-point time offsets in s ((ny, nx),
            or None: time zero at the scanned point); source: the store's path, for messages.
    Raises:
        DatasetError: one line naming ``source``, the field and the value: not a confocal scan (ny, nx, T) with
            ny, nx ≥ 2, no laser_points, points off a regular grid, non-uniform bins, offsets of another shape or
            not finite.
    """
    attrs = getattr(result, "attrs", None) or {}
    ctype = (attrs.get("capture") or {}).get("type")
    env = np.asarray(result.envelope)
    if "multizone" in attrs or ctype != "confocal" or env.ndim != 3 or min(env.shape[:2]) < 2:
        raise DatasetError(f"{source}: capture.type: {ctype!r} with envelope {env.shape}; --like simulates a "
                           "confocal scan of at least 2 x 2 points (ny, nx, T)")
    if result.laser_points is None:
        raise DatasetError(f"{source}: laser_points: none stored, so the scan has no grid to simulate (import the "
                           "capture again)")
    points = np.asarray(result.laser_points, dtype=np.float64).reshape(env.shape[:2] + (3,))
    pitch = (_pitch(points, 0, source), _pitch(points, 1, source))
    edges = np.asarray(result.time_edges, dtype=np.float64)
    widths = np.diff(edges)
    if not (widths[0] > 0 and np.allclose(widths, widths[0], rtol=1e-9, atol=0)):
        raise DatasetError(f"{source}: time_edges: the bins are not uniform ({widths.min() * 1e12:.6g} to "
                           f"{widths.max() * 1e12:.6g} ps); --like simulates uniform bins")
    off = None
    if offsets is not None:
        off = np.asarray(offsets, dtype=np.float64)
        if off.shape != env.shape[:2] or not np.isfinite(off).all():
            raise DatasetError(f"{source}: time_offsets: expected finite values of shape {env.shape[:2]}, got "
                               f"shape {off.shape}")
        if not off.any():
            off = None
    det = attrs.get("detector")
    detector = ({k: v for k, v in det.items() if k not in DETECTOR_FROM_TIME_AXIS and v is not None}
                if isinstance(det, dict) and "lab_capture" not in attrs else None)
    return CaptureTemplate(str(source), points, pitch, edges, off, detector)


GRID_SAME = 1e-6
"""m: a scene's scan size within 1 µm of the capture's is the capture's (a scene file written with four decimals
of the capture's pitch is not "replaced")."""


def scene_like(scene, template: CaptureTemplate) -> tuple[object, list[str]]:
    """``scene`` with its confocal grid replaced by the capture's: ``template.shape`` points at its pitch, centred
    where the scene's ``capture.laser_grid`` is (its wall frame gives the columns' and rows' directions).

    Returns:
        (a shallow copy of the :class:`~datagen.scene.Scene` with the new ``capture``, notes: one line per value of
        the scene's grid that was replaced).
    Raises:
        SceneError: the scene has no confocal capture (one line naming its file, ``capture.type`` and the value).
    """
    where = f"{scene.source}: " if scene.source else ""
    cap = scene.capture
    ctype = cap.type if cap is not None else None
    if ctype != "confocal":
        raise SceneError(f"{where}capture.type: {ctype!r}; --like {template.source} is a confocal scan: give the "
                         "scene a confocal capture whose laser_grid centre lies on its relay wall (capture: {type: "
                         "confocal, laser_grid: {center: [x, y, z], size: [w, h]}}); --like sets its points and size")
    ny, nx = template.shape
    dy, dx = template.pitch
    old = cap.laser_grid
    grid = WallGrid(center=old.center, size=(dx * nx, dy * ny), points=(nx, ny))
    notes = []
    if tuple(old.points) != (nx, ny) or not np.allclose(old.size, grid.size, rtol=0.0, atol=GRID_SAME):
        notes.append(f"{where}capture.laser_grid: {old.points[0]} x {old.points[1]} points over "
                     f"{old.size[0]:.4g} x {old.size[1]:.4g} m replaced by the capture's {nx} x {ny} over "
                     f"{grid.size[0]:.4g} x {grid.size[1]:.4g} m (cells of the pitch, centred as the capture's points)")
    new_cap = CaptureSpec(type="confocal", convention=cap.convention, laser_grid=grid, detector_fov=cap.detector_fov)
    return dataclasses.replace(scene, capture=new_cap), notes


def like_overrides(template: CaptureTemplate, scene_defaults: dict | None = None,
                   detector: dict | None = None, irf: dict | None = None) -> dict:
    """Simulation overrides for a simulation of ``template``: the hidden round-trip time axis (neither wall leg
    counted) at the capture's bin width over :meth:`CaptureTemplate.hidden_window` (from 0 at the earliest, on the
    capture's bin grid when it has no offsets), and the detector: the scene's block, updated by the store's detector
    (a datagen result) and then by ``detector`` (e.g. ``--detector FILE``); ``irf`` replaces the scene's IRF.

    Returns:
        a mapping for :func:`datagen.simulation.resolve_config`'s ``overrides``.
    """
    dt = template.bin_width
    lo, hi = template.hidden_window()
    if lo < 0:                                   # no light comes back before it left: start at 0, on lo's grid
        lo += np.ceil(-lo / dt - 1e-9) * dt
    n_bins = max(1, int(np.ceil((hi - lo) / dt - 1e-9)))
    out = {"time": {"t_start": float(lo), "bin_width": dt, "n_bins": n_bins},
           "count_laser_leg": False, "count_sensor_leg": False}
    det = merge_detector((scene_defaults or {}).get("detector"), template.detector, detector)
    if det:
        out["detector"] = det
    if irf:
        out["irf"] = dict(irf)
    return out


EXPOSURE_FIELDS = ("exposure", "n_cycles")
"""A detector's exposure is one of these (:class:`datagen.spad.DetectorConfig`): a later block giving one replaces
both of an earlier block's."""


def merge_detector(*blocks: dict | None) -> dict:
    """Detector blocks merged left to right (None skipped); a block that gives ``exposure`` or ``n_cycles`` replaces
    the exposure of those before it (:data:`EXPOSURE_FIELDS`)."""
    out: dict = {}
    for block in blocks:
        block = dict(block or {})
        if set(EXPOSURE_FIELDS) & set(block):
            for key in EXPOSURE_FIELDS:
                out.pop(key, None)
        out.update(block)
    return out


def to_capture_axis(result, template: CaptureTemplate, rng: np.random.Generator):
    """A simulated result (of :func:`scene_like` and :func:`like_overrides`) on the capture's bins.

    Without offsets the simulated axis is the capture's (it is returned with its ``like`` record). With offsets, each
    point's envelope and components are rebinned onto the capture's edges less its offset (exact for binned data)
    and its counts redrawn there with the result's detector (:func:`datagen.spad.sample_histogram`); the result's
    time axis is then the capture's, and ``attrs["like"]["time_offsets"]`` says the store must keep them.

    Args:
        result: :class:`~datagen.simulation.Result` (ny, nx, n) on the hidden axis; rng: the noise stream.
    Returns:
        a :class:`~datagen.simulation.Result` (ny, nx, T) on ``template.time_edges``.
    Raises:
        DatasetError: the result's grid differs from the capture's (shape, or pitch beyond 1e-6 relative).
    """
    from .. import spad

    env = np.asarray(result.envelope)
    pts = np.asarray(result.laser_points, dtype=np.float64).reshape(env.shape[:2] + (3,))
    pitch = (_pitch(pts, 0, "the simulation"), _pitch(pts, 1, "the simulation"))
    if env.shape[:2] != template.shape or not np.allclose(pitch, template.pitch, rtol=GRID_RTOL):
        raise DatasetError(f"the simulation's grid {env.shape[:2]} of pitch {pitch} m differs from {template.source}'s "
                           f"{template.shape} of pitch {template.pitch} m")
    record = {"source": template.source, "grid": list(template.shape), "pitch_m": list(template.pitch),
              "bin_width_s": template.bin_width, "t_start_s": float(template.time_edges[0]),
              "n_bins": len(template.time_edges) - 1, "time_offsets": template.offsets is not None}
    attrs = {**result.attrs, "like": record}
    if template.offsets is None:
        if not np.allclose(result.time_edges, template.time_edges, rtol=0, atol=1e-6 * template.bin_width):
            raise DatasetError(f"the simulation's time axis does not match {template.source}'s bins")
        return dataclasses.replace(result, attrs=attrs)
    edges = template.time_edges
    shift = lambda a: _rebin_points(np.asarray(a, dtype=np.float64), result.time_edges, edges, template.offsets)  # noqa: E731
    envelope = shift(result.envelope)
    components = {k: shift(v) for k, v in result.components.items()}
    det = dict(result.attrs.get("detector") or {})
    det.pop("bin_widths", None)
    config = spad.DetectorConfig.model_validate({**det, "t_start": max(float(edges[0]), 0.0),
                                                 "bin_width": template.bin_width})
    counts = spad.sample_histogram(spad.rates_from_envelope(envelope, config), config, rng)
    return dataclasses.replace(result, time_edges=edges.copy(), envelope=envelope, components=components,
                               counts=counts, attrs=attrs)


def _rebin_points(data: np.ndarray, fine_edges: np.ndarray, edges: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(ny, nx, T): each point's transient on the hidden axis ``fine_edges`` rebinned onto ``edges`` − its offset."""
    from ..spad.rates import rebin_envelope

    flat = data.reshape(-1, data.shape[-1])
    off = offsets.reshape(-1)
    out = np.empty((flat.shape[0], len(edges) - 1))
    values, inverse = np.unique(off, return_inverse=True)
    for k, o in enumerate(values):                  # one rebin per distinct offset
        rows = inverse == k
        out[rows] = rebin_envelope(flat[rows], fine_edges, edges - o)
    return out.reshape(data.shape[:2] + (-1,))


def write_time_offsets(store, offsets: np.ndarray) -> None:
    """Add ``time_offsets`` (ny, nx) float64 s to a written result store (as an imported capture keeps its
    ``tofgrid``, :func:`datagen.io.lab_formats.write_capture_store`), so that readers remove them."""
    import warnings

    import zarr

    root = zarr.open_group(str(store), mode="a")
    root.create_array("time_offsets", data=np.asarray(offsets, dtype=np.float64), overwrite=True)
    with warnings.catch_warnings():     # consolidated metadata is a zarr-python v3 extension, as store.py
        warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
        zarr.consolidate_metadata(str(store))

