"""Light transport: primary and secondary path weights and times, summed into the envelope L(t).

The estimated quantity is the transient path integral of DESIGN.md §2. For one laser spot x_l with Φ photons
per pulse, primary (three-bounce) light detected by a sensor imaging the FoV region F of the relay wall is

    L_p(t) = q·∫_S dA_x ∫_F dA_y  Φ f_l cosθ_l cosθ_x,in /|x−x_l|² V(x_l,x)
                               · f_x cosθ_x,out cosθ_y,in /|y−x|² V(x,y)
                               · f_y cosθ_y,out · A_ap cosθ_ap /|x_s−y|² V(y,x_s) · e^{−μ·path} h(t − τ).

How the paper's factors (Scholes & Leach 2024, Eqs. 1, 6, 8) map to this, per leg:

- **A1** (laser spot → lookin, Γ_1 α_1 B_1 / R_j²): lookins are sampled by *direction* ω_j at the spot with
  pdf p(ω_j), and a point reached through solid angle dω has dA = R² dω / cosθ, so the paper's 1/R_j² cancels:
  the flux a lookin carries is W_j = Φ·f_l(ω_e, ω_j)·cosθ_l / (N·p(ω_j)) photons (f_l = Γ_1/π for a
  Lambertian relay wall, B_1 = cos φ is our cosθ_l; α_1 is replaced by the exact 1/(N·p)).
- **A2** (lookin → observed point, Γ_j α_j B_j / (R_k^o)²): the camera pixel of solid angle Ω = 2π/(l·p)
  carries W_j·f_j(ω_in, ω_k)·cosθ_k·Ω photons to the observed point; again the 1/R² cancels against the
  pixel's area on the surface, and α_j is replaced by Ω.
- **A3/A4** (FoV point → sensor, Γ β B / (R^s)² and the aperture term π f²/f_no²): a point on the relay
  wall that receives F photons sends F·f_y(ω_in, ω_s)·cosθ_y,out·A_ap·cosθ_ap/|x_s−y|² of them into the
  aperture of area A_ap = π r_ap² (the paper's (f/f_no)² aperture term with r_ap = f/(2 f_no)); β is unity.
- **Secondary** (Eq. 8, A^1 A^2 A^3): paths x_l → y' → x_j → y → sensor, with y' the observed points of
  lookin j lit by the laser (a real shadow ray to the spot). The laser irradiance at y' is
  E' = Φ f_l cosθ_l cosθ_y',in / r² · V (an area quantity: here the 1/r² is genuine), y' reflects radiance
  L' = f_y' E' toward x_j, which receives L' cosθ_j Ω through the pixel. x_j now acts as an *area* sample:
  its area measure is dA_j = R_j² / (N·p(ω_j)·cosθ_j,l). The lookin then scatters with f_j(ω_k', ω_k)
  exactly like the primary. Each factor is therefore the same as for the primary; only the sampling differs.
- C_atm = e^{−μ R} per leg: one factor e^{−μ·(total physical path)}; q is the PDE (quantum efficiency).

Estimators: ``full`` secondary sums every (k', k) pair: O(Ñ²) per lookin. ``optimized`` keeps, for each
lookin and FoV point k, only the ``top_k`` strongest k' (the paper's optimized scheme, §4: top_k = 1). It is
*biased low by design*: it keeps the secondary's timing and drops most of its energy. Primary and full
secondary are consistent: they converge to the path integral as N and l×p grow (tests compare against an
independent area quadrature).
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from typing import Callable, Literal, Protocol

import multiprocessing as mp
import numpy as np
import scipy.fft

from .brdf import SIN_THETA, MaterialTable
from .raycast import RayCaster
from .sampling import Lookins, ObservedPoints, observe, sample_lookins, stratified_grid
from .scene import Scene, SceneError
from .units import SPEED_OF_LIGHT

SecondaryMode = Literal["none", "optimized", "full", "exact"]

FOV_PLANE_TOL = 10.0
"""A hit lies on the FoV plane when within this many ray offsets of it (hit points are float64 rebuilt
from float32 barycentrics, accurate to a few offsets)."""


@dataclass(frozen=True)
class Capture:
    """Resolved capture geometry (all float64, metres): laser points, sensor grid, sensor device.

    Attributes:
        kind: "single" | "confocal" | "exhaustive" (DESIGN.md §8, tal's scan types).
        convention: "aperture" (detected photons per pulse) or "point_radiance" (tal / mitransient).
        spots: (L, 3) laser points; spot_normals: (L, 3) relay-wall normals there (facing the hidden side);
        spot_objects: (L,) object ids; laser_shape: (lx, ly) grid of the laser points (L = lx·ly).
        emitter: (3,); emitter_legs: (L,) |spot − emitter|.
        sensor: (3,) sensor position; aperture_area: m²; aperture_normal: unit vector toward the grid centre.
        fov_center, fov_u, fov_v, fov_normal: the sensor grid's frame on the relay wall; fov_size: (w, h);
        fov_pixels: (nx, ny) sensor points (cell centres) / pixel regions (cells).
        photons: Φ, photons per pulse (1 for point radiance: per unit power at the spot).
        legacy_single_pixel: the scene used the paper's one-pixel ``sensor.fov`` (envelope shape (T,)).
    """

    kind: str
    convention: str
    spots: np.ndarray
    spot_normals: np.ndarray
    spot_objects: np.ndarray
    laser_shape: tuple[int, int]
    emitter: np.ndarray
    emitter_legs: np.ndarray
    sensor: np.ndarray
    aperture_area: float
    aperture_normal: np.ndarray
    fov_center: np.ndarray
    fov_u: np.ndarray
    fov_v: np.ndarray
    fov_normal: np.ndarray
    fov_size: tuple[float, float]
    fov_pixels: tuple[int, int]
    photons: float
    legacy_single_pixel: bool = False

    # -- the first laser point, for single-spot callers (figures, planner) --------------------------------
    @property
    def spot(self) -> np.ndarray:
        return self.spots[0]

    @property
    def spot_normal(self) -> np.ndarray:
        return self.spot_normals[0]

    @property
    def spot_object(self) -> int:
        return int(self.spot_objects[0])

    @property
    def emitter_leg(self) -> float:
        return float(self.emitter_legs[0])

    @property
    def n_pixels(self) -> int:
        """Sensor points (or pixel regions) S."""
        return self.fov_pixels[0] * self.fov_pixels[1]

    @property
    def n_lasers(self) -> int:
        return len(self.spots)

    @property
    def n_channels(self) -> int:
        """Output channels: S (single, confocal) or L·S (exhaustive)."""
        return self.n_lasers * self.n_pixels if self.kind == "exhaustive" else self.n_pixels

    def channel(self, laser: int, pixel: np.ndarray) -> np.ndarray:
        """Output channel of sensor pixel(s) ``pixel`` lit from laser point ``laser`` (−1: not recorded)."""
        pixel = np.asarray(pixel)
        if self.kind == "exhaustive":
            return np.where(pixel >= 0, laser * self.n_pixels + pixel, -1)
        if self.kind == "confocal":
            return np.where(pixel == laser, pixel, -1)
        return pixel

    def channel_shape(self) -> tuple[int, ...]:
        """Leading shape of the envelope: () legacy single pixel, (ny, nx), or (ly, lx, ny, nx) exhaustive."""
        if self.legacy_single_pixel:
            return ()
        nx, ny = self.fov_pixels
        if self.kind == "exhaustive":
            lx, ly = self.laser_shape
            return (ly, lx, ny, nx)
        return (ny, nx)

    def sensor_points(self) -> np.ndarray:
        """(ny, nx, 3) sensor points: cell centres of the sensor grid."""
        nx, ny = self.fov_pixels
        return _grid_points(self.fov_center, self.fov_size, self.fov_pixels, self.fov_u, self.fov_v).reshape(ny, nx, 3)

    def fov_pixel(self, points: np.ndarray, tol: float) -> np.ndarray:
        """Sensor pixel index (row-major over (v, u)) of each point, −1 outside the FoV. (..., 3) → (...,)."""
        rel = points - self.fov_center
        a = (rel @ self.fov_u) / self.fov_size[0] + 0.5
        b = (rel @ self.fov_v) / self.fov_size[1] + 0.5
        inside = (np.abs(rel @ self.fov_normal) <= tol) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        nx, ny = self.fov_pixels
        ix = np.clip((np.nan_to_num(a) * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip((np.nan_to_num(b) * ny).astype(np.int64), 0, ny - 1)
        return np.where(inside, iy * nx + ix, -1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _on_surface(caster: RayCaster, point: np.ndarray, direction: np.ndarray, tol: float) -> bool:
    """True when a surface passes within ``tol`` of ``point`` along ``direction`` (a short probe ray)."""
    probe = caster.intersect((point - 2 * tol * direction)[None], direction[None])
    return bool(probe.hit[0] and probe.distance[0] <= 4 * tol)


def _wall_frame(caster: RayCaster, sensor: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, ...]:
    """(u, v, n) of the relay wall around ``center`` as the sensor sees it (n facing the sensor)."""
    hit_c = caster.intersect(sensor[None], _unit(center - sensor)[None])
    normal = hit_c.normals[0] if hit_c.hit[0] else _unit(sensor - center)
    u = np.cross(normal, np.array([0.0, 0.0, 1.0]))
    u = _unit(np.cross(normal, np.array([0.0, 1.0, 0.0]))) if np.linalg.norm(u) < 1e-9 else _unit(u)
    return u, np.cross(u, normal), normal


def _grid_points(center, size, points, u, v) -> np.ndarray:
    """(ny·nx, 3) cell centres of an nx×ny grid of size (w, h) around ``center`` in the (u, v) frame."""
    nx, ny = points
    a = ((np.arange(nx) + 0.5) / nx - 0.5) * size[0]
    b = ((np.arange(ny) + 0.5) / ny - 0.5) * size[1]
    return (np.asarray(center, float) + b[:, None, None] * v + a[None, :, None] * u).reshape(-1, 3)


def _resolve_spot(caster: RayCaster, names: list[str], emitter: np.ndarray, spot: np.ndarray, where: str,
                  field: str) -> tuple[np.ndarray, int, float]:
    """Normal, object id and emitter leg of a laser point; SceneError when it is off every surface."""
    leg = float(np.linalg.norm(spot - emitter))
    if leg == 0:
        raise SceneError(f"{where}{field} equals laser.emitter {spot.tolist()}")
    hits = caster.intersect(emitter[None], _unit(spot - emitter)[None])
    tol = FOV_PLANE_TOL * caster.offset
    if not hits.hit[0] or hits.distance[0] < leg - tol:
        if hits.hit[0] and _on_surface(caster, spot, _unit(spot - emitter), tol):
            raise SceneError(f"{where}{field} {spot.tolist()} is hidden from the emitter: the beam hits "
                             f"object {names[hits.object_id[0]]!r} at "
                             f"{np.round(hits.points[0], 4).tolist()} first")
        raise SceneError(f"{where}{field} {spot.tolist()} is off every surface (no surface there along "
                         f"the beam from the emitter {emitter.tolist()})")
    if hits.distance[0] > leg + tol:
        raise SceneError(f"{where}{field} {spot.tolist()} is off every surface (the beam from the emitter "
                         f"first hits {np.round(hits.points[0], 4).tolist()})")
    return hits.normals[0], int(hits.object_id[0]), leg


def resolve_capture(scene: Scene, caster: RayCaster) -> Capture:
    """Find the laser points' surfaces and normals, set up the sensor grid, check the sensor sees it.

    Raises:
        SceneError: a laser point off every surface or hidden from the emitter; the sensor grid sees no
            surface from the sensor.
    """
    where = f"{scene.source}: " if scene.source else ""
    emitter = np.asarray(scene.laser.emitter, dtype=np.float64)
    sensor = np.asarray(scene.sensor.position, dtype=np.float64)
    cap = scene.capture
    kind = cap.type if cap else "single"
    convention = cap.convention if cap else "aperture"
    if cap is not None and cap.type == "confocal":
        grid, grid_field = cap.laser_grid, "capture.laser_grid"
    elif cap is not None and cap.sensor_grid is not None:
        grid, grid_field = cap.sensor_grid, "capture.sensor_grid"
    else:
        fov = scene.sensor.fov
        grid, grid_field = fov, "sensor.fov"
    center = np.asarray(grid.center, dtype=np.float64)
    size = tuple(float(x) for x in grid.size)
    pixels = tuple(grid.pixels) if grid_field == "sensor.fov" else tuple(grid.points)
    if convention == "aperture" and min(size) <= 0:
        raise SceneError(f"{where}{grid_field}.size must be > 0 for the aperture convention (pixel regions), "
                         f"got {list(size)}")
    u, v, normal = _wall_frame(caster, sensor, center)
    if cap is None or cap.type == "single":
        spots = np.asarray(scene.laser.spot, dtype=np.float64)[None]
        laser_shape, fields = (1, 1), ["laser.spot"]
    else:
        lg = cap.laser_grid
        lu, lv, _ = _wall_frame(caster, sensor, np.asarray(lg.center, float))
        spots = _grid_points(lg.center, lg.size, lg.points, lu, lv)
        laser_shape = tuple(lg.points)
        fields = [f"capture.laser_grid point {i}" for i in range(len(spots))]
    names = [o.name for o in scene.objects]
    resolved = [_resolve_spot(caster, names, emitter, p, where, f) for p, f in zip(spots, fields)]
    if float(np.dot(normal, resolved[0][0])) < 0:
        raise SceneError(f"{where}sensor.position {sensor.tolist()} is behind the relay wall: it sees the back of "
                         f"the wall at {grid_field} while the laser lights the other side")
    photons = 1.0 if convention == "point_radiance" else scene.laser.photons
    capture = Capture(kind, convention, spots, np.array([r[0] for r in resolved]),
                      np.array([r[1] for r in resolved], dtype=np.int64), laser_shape, emitter,
                      np.array([r[2] for r in resolved]), sensor, scene.sensor.aperture_area,
                      _unit(center - sensor), center, u, v, normal, size, pixels, photons,
                      legacy_single_pixel=(cap is None and pixels == (1, 1)))
    # Probe the sensor grid from the sensor: some of it must be a surface the sensor sees.
    tol = FOV_PLANE_TOL * caster.offset
    g = (np.arange(9) + 0.5) / 9 - 0.5
    gu, gv = np.meshgrid(g * size[0], g * size[1])
    targets = np.concatenate([center + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * v,
                              capture.sensor_points().reshape(-1, 3)])
    probe = caster.intersect(np.broadcast_to(sensor, targets.shape), _unit(targets - sensor))
    on_wall = probe.hit & (np.abs(_dot(np.nan_to_num(probe.points) - center, normal)) <= tol)
    if not on_wall.any():
        raise SceneError(f"{where}{grid_field} (center {center.tolist()}, size {list(size)}) sees no surface "
                         f"from the sensor at {sensor.tolist()}")
    return capture


@dataclass(frozen=True)
class TransportSettings:
    """Sampling and transport options (see :class:`datagen.simulate.SimulationConfig` for the user side).

    Attributes:
        lookins: (n_u, n_v) lookin grid; pixels: (l, p) camera resolution.
        lookin_pdf: "cosine" or "uniform" hemisphere sampling at the spot.
        jitter: stratified jitter (True) or cell centres (False).
        secondary: "none" | "optimized" | "full" | "exact"; top_k: kept k' per (lookin, FoV point) when
            optimized.
        sensor_sampling: "camera" (the paper: FoV points are the lookin cameras' observed points) or
            "connect" (next-event connection from each lookin to ``connect_samples`` stratified points per
            sensor pixel region, or to each sensor point for point radiance).
        connect_samples: (n_u, n_v) stratified points per pixel region for ``connect``.
        attenuation: μ in 1/m (0 = none).
        pde: q, detection efficiency applied to every detected photon.
        count_laser_leg / count_sensor_leg: include emitter→spot / FoV→sensor in the time of flight.
        shadow_spot: shadow rays from observed points to the laser spot (which points the laser lights).
        shadow_sensor: shadow rays from FoV points to the sensor.
        first_bounce: add the direct laser spot → sensor return when the spot lies in a sensor pixel.
        brdf_angles: evaluate every BRDF in full (default False: Lambertian materials take f = ρ/π with no
            angle work, identical values).
        dark_middle: add the secondary paths whose middle vertex the laser does not light (next-event
            connections from the lookins' observed points in laser shadow; :meth:`Transport._secondary_dark`)
            to the full and exact secondaries. Off reproduces the paper's estimator, which misses them; the
            optimized (top-K) secondary, an approximation by design, never adds them.
        spot_blockers: every face that can cross a laser point → observed point segment (the effect planner's
            pair test), or None (unknown: every laser shadow ray is cast). Segments that miss the bounding
            spheres of these faces (grouped by object) are unoccluded without a ray.
        sensor_blockers: the same for FoV point → sensor segments (the planner's sensor-pyramid test).
        conv_refine: the exact secondary bins its time profiles this many times finer than the envelope's
            fine grid before convolving (its only approximation; error ~ (step/feature width)²).
        batch: lookins per random stream and unit of work of ``workers`` (each is processed in slices of
            ``CACHE_RAYS`` camera rays).
        workers: processes sharing the lookin batches (results do not depend on it).
    """

    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    secondary: SecondaryMode = "full"
    top_k: int = 1
    sensor_sampling: Literal["camera", "connect"] = "camera"
    connect_samples: tuple[int, int] = (4, 4)
    attenuation: float = 0.0
    pde: float = 1.0
    count_laser_leg: bool = False
    count_sensor_leg: bool = True
    shadow_spot: bool = True
    shadow_sensor: bool = True
    first_bounce: bool = False
    brdf_angles: bool = False
    dark_middle: bool = True
    spot_blockers: tuple[int, ...] | None = None
    sensor_blockers: tuple[int, ...] | None = None
    conv_refine: int = 1
    batch: int = 32
    workers: int = 1


class Counters:
    """Mixin for dataclasses of int counters: ``add`` sums another run's counters into this one."""

    def add(self, other: "Counters") -> None:
        for k, v in vars(other).items():
            setattr(self, k, getattr(self, k) + v)


@dataclass
class TransportStats(Counters):
    """Counters from a transport run (recorded in the result attributes)."""

    lookins_cast: int = 0
    lookins_hit: int = 0
    observed_points: int = 0
    fov_points: int = 0
    lit_points: int = 0
    shadow_rays: int = 0
    dark_points: int = 0
    secondary_pairs: int = 0


class Sink(Protocol):
    """Where transport sends path impulses (e.g. :class:`datagen.irf.EnvelopeAccumulator`)."""

    def add(self, times: np.ndarray, weights: np.ndarray, component: np.ndarray) -> None: ...


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


@dataclass
class _Lit:
    """Hit observed points of a batch (flat: index into the batch's B·P pixels; hb: lookin) with their
    laser-spot geometry: y, n_y (facing the lookin), r and unit w (spot → y), cos_l (at the spot), cos_in (at
    y, on the lookin's side), and lit (the spot lights y on that side: both cosines > 0 and, with
    ``shadow_spot``, an unoccluded ray)."""

    flat: np.ndarray
    hb: np.ndarray
    y: np.ndarray
    n_y: np.ndarray
    r: np.ndarray
    w: np.ndarray
    cos_l: np.ndarray
    cos_in: np.ndarray
    lit: np.ndarray


@dataclass
class _Out:
    """Sensor-side impulses of a batch of lookins: one row per (lookin, FoV point or sensor target).

    b: lookin index in the batch; direction: unit ω_k from the lookin; cos: cosθ_k at the lookin;
    weight: detected photons per unit radiant intensity of the lookin toward ω_k (geometry, far-side
    BRDF and sensor collection; excludes the lookin's own BRDF and cos); time: seconds from the lookin to
    detection; phys: metres of physical path (for attenuation); channel: output channel.
    """

    b: np.ndarray
    direction: np.ndarray
    weight: np.ndarray
    time: np.ndarray
    phys: np.ndarray
    channel: np.ndarray


class _ConvGrid:
    """Time profiles of the exact secondary, summed on a grid of step ``step`` aligned to the sink's grid.

    Holds ``(n_channels, n_nodes)`` float64 node weights; node n sits at ``t0 + n·step``. Impulses beyond
    the grid are kept as a total per channel and sent as one impulse past the window by :meth:`flush`.
    """

    def __init__(self, t0: float, step: float, n_nodes: int, n_channels: int):
        self.t0, self.step, self.n_nodes = t0, step, n_nodes
        self.nodes = np.zeros((n_channels, n_nodes))
        self.beyond = np.zeros(n_channels)

    def empty_like(self) -> "_ConvGrid":
        return _ConvGrid(self.t0, self.step, self.n_nodes, len(self.nodes))

    def merge(self, other: "_ConvGrid") -> None:
        self.nodes += other.nodes
        self.beyond += other.beyond

    def add_block(self, channel: int, start: int, values: np.ndarray) -> None:
        """Add node weights ``values`` to ``channel`` from node ``start`` on (clipped; clipped mass → beyond)."""
        lo, hi = max(start, 0), min(start + len(values), self.n_nodes)
        if hi > lo:
            self.nodes[channel, lo:hi] += values[lo - start:hi - start]
        self.beyond[channel] += values.sum() - (values[lo - start:hi - start].sum() if hi > lo else 0.0)

    def add_impulses(self, times: np.ndarray, weights: np.ndarray, channel: np.ndarray) -> None:
        """Linear (cloud-in-cell) splat of impulses onto the nodes."""
        x = (times - self.t0) / self.step
        inside = (x >= 0) & (x <= self.n_nodes - 1)
        if not inside.all():
            np.add.at(self.beyond, channel[~inside], weights[~inside])
        x, w, c = x[inside], weights[inside], channel[inside]
        i = np.minimum(np.floor(x).astype(np.int64), self.n_nodes - 2)
        wr = w * (x - i)
        flat = self.nodes.reshape(-1)
        idx = c * self.n_nodes + i
        flat += np.bincount(idx, w - wr, minlength=flat.size) + np.bincount(idx + 1, wr, minlength=flat.size)

    def flush(self, sink: Sink, component_offset: int, t_beyond: float) -> None:
        ch, n = np.nonzero(self.nodes)
        if len(ch):
            sink.add(self.t0 + n * self.step, self.nodes[ch, n], component_offset + ch)
        far = np.flatnonzero(self.beyond > 0)
        if len(far):
            sink.add(np.full(len(far), t_beyond), self.beyond[far], component_offset + far)


def _cic_rows(x: np.ndarray, w: np.ndarray, row: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Cloud-in-cell splat of positions ``x`` (in nodes) into per-row local windows.

    Returns (start (n_rows,) int64 first node of each row's window, dense (n_rows, width) weights).
    """
    i = np.floor(x).astype(np.int64)
    start = np.zeros(n_rows, dtype=np.int64)
    width = 1
    if len(i):
        if np.all(row[1:] >= row[:-1]):                # already grouped (the usual case): no sort
            rs, io = row, i
        else:
            order = np.argsort(row, kind="stable")
            rs, io = row[order], i[order]
        first = np.flatnonzero(np.r_[True, rs[1:] != rs[:-1]])
        start[rs[first]] = np.minimum.reduceat(io, first)
        width = int((np.maximum.reduceat(io, first) + 2 - start[rs[first]]).max())
    dense = np.zeros(n_rows * width)
    local = row * width + (i - start[row])
    wr = w * (x - i)
    dense += np.bincount(local, w - wr, minlength=dense.size) + np.bincount(local + 1, wr, minlength=dense.size)
    return start, dense.reshape(n_rows, width)


CACHE_RAYS = 1 << 15
"""Camera rays processed together inside a batch: ~30k rays keep the slice's (rays, 3) float64 arrays within
a 2 MiB L2 cache (measured on the demo room at 45×45×60×60: 12 % less CPU than slices of 32 lookins)."""

CONV_REFINE_MAX = 1024
"""Largest automatic refinement of the exact secondary's profile grid (for IRFs much narrower than a bin)."""

_CONV_DENSE_MAX = 1 << 22
"""Cap on rows × nodes of the exact secondary's dense profile buffers (32 MiB of float64)."""

_WORKER: dict = {}


def _worker_init(transport: "Transport") -> None:
    transport.caster = RayCaster(transport.scene)          # a fresh BVH per process
    _WORKER["transport"] = transport


def _worker_batch(args):
    return _WORKER["transport"]._run_batch(*args)


class Transport:
    """Runs the lookin estimator over a scene and sends impulses to a sink.

    Component ids sent to the sink: ``component * n_channels + channel`` where component indexes
    ``scene.component_names()`` for primary paths (by the object the lookin hit), then
    ``len(scene.component_names())`` for secondary paths and, when ``first_bounce`` is on, one more for the
    direct laser-spot return (:attr:`component_names`).
    """

    def __init__(self, scene: Scene, settings: TransportSettings, caster: RayCaster | None = None):
        self.scene = scene
        self.settings = settings
        self.caster = caster or RayCaster(scene)
        self.capture = resolve_capture(scene, self.caster)
        self.materials: MaterialTable = scene.materials
        # f = ρ/π per object for Lambertian materials, NaN for the others (evaluated in full by _brdf)
        self._lambert_f = np.where(self.materials.lambertian, self.materials.albedo / np.pi, np.nan)
        self._angular_g = self.materials.kind == SIN_THETA        # g(ω) ≠ 1 in the separable split
        self.object_component = scene.object_component()
        self.n_primary = len(scene.component_names())
        self.stats = TransportStats()
        self.configure(settings)

    def configure(self, settings: TransportSettings) -> None:
        """Replace the settings (e.g. after the effect planner); point radiance forces ``connect``."""
        if self.capture.convention == "point_radiance" and settings.sensor_sampling != "connect":
            settings = replace(settings, sensor_sampling="connect")
        self.settings = settings
        self.component_names = self.scene.component_names() + ["secondary"] + (
            ["first_bounce"] if settings.first_bounce else [])
        self._spot_spheres = self._blocker_spheres(settings.spot_blockers)
        self._sensor_spheres = self._blocker_spheres(settings.sensor_blockers)

    # -- per-leg physics (written once, used by every estimator) -----------------------------------------

    def _spot_emission(self, directions: np.ndarray, laser: int = 0) -> np.ndarray:
        """f_l(ω_e, ω)·cosθ_l at laser point ``laser`` for outgoing unit directions ω (..., 3) → (...,).

        The beam arrives from the emitter, ω_e = unit(emitter − spot); radiant intensity per photon of the
        pulse is f_l·cosθ_l (DESIGN.md §2).
        """
        c = self.capture
        spot, normal = c.spots[laser], c.spot_normals[laser]
        w_e = _unit(c.emitter - spot)
        n = np.broadcast_to(normal, directions.shape)
        cos = np.maximum(_dot(n, directions), 0.0)
        obj = c.spot_objects[laser]
        if self.materials.lambertian[obj] and not self.settings.brdf_angles:
            return self.materials.albedo[obj] / np.pi * cos
        f = self.materials.evaluate(np.full(directions.shape[:-1], obj), n,
                                    np.broadcast_to(w_e, directions.shape), directions)
        return f * cos

    def _sensor_collection(self, points: np.ndarray, normals: np.ndarray, object_id: np.ndarray,
                           w_in: np.ndarray, sign_in: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """What a photon landing at a FoV point becomes at the sensor, and the FoV→sensor distance.

        Aperture convention: the detected fraction q·f_y(ω_in, ω_s)·cosθ_y,out·A_ap·cosθ_ap/d²·V(y, x_s)
        (paper A3 and aperture term). Point radiance: f_y(ω_in, ω_s), the radiance toward the sensor per
        unit irradiance. (n,) each. ω_in is ``sign_in · w_in`` (see :meth:`_brdf`).
        """
        c = self.capture
        to_sensor = c.sensor - points
        d = np.linalg.norm(to_sensor, axis=-1)
        w_s = to_sensor / d[..., None]
        f = self._brdf(object_id, normals, w_in, w_s, sign_in)
        if c.convention == "point_radiance":
            return f, d
        cos_out = np.maximum(_dot(normals, w_s), 0.0)
        cos_ap = np.maximum(-_dot(w_s, c.aperture_normal), 0.0)
        out = self.settings.pde * f * cos_out * c.aperture_area * cos_ap / d ** 2
        if self.settings.shadow_sensor:
            idx = np.flatnonzero(out > 0)
            idx = idx[self._may_be_blocked(c.sensor, -w_s[idx], d[idx], self._sensor_spheres)]
            if len(idx):
                self.stats.shadow_rays += len(idx)
                out[idx[~self.caster.visible(points[idx], normals[idx], c.sensor, None)]] = 0.0
        return out, d

    def _attenuation(self, path: np.ndarray) -> np.ndarray | float:
        mu = self.settings.attenuation
        return np.exp(-mu * path) if mu > 0 else 1.0

    def _brdf(self, obj: np.ndarray, normals: np.ndarray, w_in: np.ndarray, w_out: np.ndarray,
              sign_in: float = 1.0, sign_out: float = 1.0) -> np.ndarray:
        """f(sign_in·ω_in, sign_out·ω_out) for directions known to lie above the surface.

        Unless ``brdf_angles`` is set, Lambertian materials take f = ρ/π without any angle work and only the
        other materials are evaluated in full (the values are identical: callers only pass directions above
        the surface). The signs flip a direction without materialising the negated array.
        """
        if self.settings.brdf_angles:
            return self.materials.evaluate(obj, normals, sign_in * w_in, sign_out * w_out)
        shape = np.broadcast_shapes(np.shape(obj), normals.shape[:-1], w_in.shape[:-1], w_out.shape[:-1])
        obj_b = np.broadcast_to(obj, shape)
        f = self._lambert_f[obj_b]
        sel = np.isnan(f)
        if sel.any():
            full = lambda a: np.broadcast_to(a, shape + (3,))[sel]
            f[sel] = self.materials.evaluate(obj_b[sel], full(normals), sign_in * full(w_in), sign_out * full(w_out))
        return f

    # -- estimator ---------------------------------------------------------------------------------------

    def lookins(self, rng: np.random.Generator | None, laser: int = 0) -> Lookins:
        s, c = self.settings, self.capture
        return sample_lookins(self.caster, c.spots[laser], c.spot_normals[laser], s.lookins, s.lookin_pdf, rng)

    def needs_camera(self) -> bool:
        return self.settings.sensor_sampling == "camera" or self.settings.secondary != "none"

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Sample lookins and observed points and send every primary (and secondary) impulse to ``sink``.

        Work is split into fixed batches of ``settings.batch`` lookins, each with its own random stream
        (from ``rng``) and its own partial sums, merged in batch order: the result is bit-identical whatever
        ``settings.workers``. With ``workers > 1`` and a sink that can ``spawn`` partial accumulators
        (:class:`~datagen.irf.EnvelopeAccumulator`), batches run in worker processes.
        """
        s, c = self.settings, self.capture
        conv = self._conv_grid(sink) if s.secondary == "exact" else None
        root = np.random.SeedSequence(int(rng.integers(0, 2 ** 63)))
        tasks = []
        for laser in range(c.n_lasers):
            look_rng = np.random.default_rng(root.spawn(1)[0]) if s.jitter else None
            look = self.lookins(look_rng, laser)
            self.stats.lookins_cast += look.n_rays
            idx = np.flatnonzero(look.hit)
            self.stats.lookins_hit += len(idx)
            for start in range(0, len(idx), s.batch):
                sel = idx[start:start + s.batch]
                tasks.append((laser, look.n_rays, look.directions[sel], look.pdf[sel], look.points[sel],
                              look.normals[sel], look.object_id[sel], look.distance[sel],
                              root.spawn(1)[0] if s.jitter else None))
        spawn = getattr(sink, "spawn", None)
        parallel = s.workers > 1 and spawn is not None and len(tasks) > 1
        results = self._map(tasks, spawn, conv, parallel, sink)
        for n_done, (partial, partial_conv, stats) in results:
            if partial is not None:
                sink.merge(partial)
            if partial_conv is not None:
                conv.merge(partial_conv)
            self.stats.add(stats)
            if progress is not None:
                progress(n_done)
        if s.first_bounce:
            self._first_bounce(sink)
        if conv is not None:
            conv.flush(sink, self.n_primary * c.n_channels, sink_far_time(sink))
        if progress is not None and not tasks:
            progress(0)

    def _map(self, tasks, spawn, conv, parallel, sink):
        """Yield (lookins done, partial sink, partial conv grid, stats) per batch, in batch order."""
        if not parallel:
            for task in tasks:
                part = spawn() if spawn is not None else None
                stats = TransportStats()
                part_conv = conv.empty_like() if conv is not None else None
                self._batch(task, part if part is not None else sink, part_conv, stats)
                yield len(task[2]), (part, part_conv, stats)
            return
        ctx = mp.get_context("fork")
        with ProcessPoolExecutor(self.settings.workers, mp_context=ctx, initializer=_worker_init,
                                 initargs=(self,)) as pool:
            futures = [pool.submit(_worker_batch, (task, spawn(), conv.empty_like() if conv else None))
                       for task in tasks]
            for task, fut in zip(tasks, futures):
                part, part_conv, stats = fut.result()
                yield len(task[2]), (part, part_conv, stats)

    def _run_batch(self, task, part, part_conv):
        stats = TransportStats()
        self._batch(task, part, part_conv, stats)
        return part, part_conv, stats

    def _conv_grid(self, sink: Sink) -> _ConvGrid:
        """Exact-secondary profile grid aligned to the sink's fine grid, ``conv_refine`` times finer."""
        k = max(1, int(self.settings.conv_refine))
        irf = getattr(sink, "irf", None)
        if irf is not None and irf.sigma > 0 and hasattr(sink, "fine_step"):
            # a narrow IRF (σ below 4 grid steps) would show the profiles' binning: refine to ≤ σ/4
            k = max(k, min(CONV_REFINE_MAX, int(np.ceil(4.0 * sink.fine_step / irf.sigma))))
        if hasattr(sink, "fine_step"):
            step = sink.fine_step / k
            t0 = float(sink.fine_times[0])
            n = (sink.n_fine - 1) * k + 1
        else:
            raise SceneError("secondary 'exact' needs an EnvelopeAccumulator sink")
        return _ConvGrid(t0, step, n, self.capture.n_channels)

    def _batch(self, task, sink: Sink, conv: _ConvGrid | None, stats: TransportStats) -> None:
        """One batch of lookins (one random stream), in cache-sized slices of ``CACHE_RAYS`` camera rays."""
        (laser, n_rays, directions, pdf, x, n_x, obj_x, r_lx, seed) = task
        saved, self.stats = self.stats, stats
        try:
            rng = np.random.default_rng(seed) if seed is not None else None
            # the dark-middle connections draw from their own stream, so switching them on or off (full vs
            # optimized secondary) leaves the cameras' jitter, hence the primary, unchanged
            dark_rng = np.random.default_rng(np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key + (1,))) \
                if seed is not None else None
            step = max(1, CACHE_RAYS // (self.settings.pixels[0] * self.settings.pixels[1]))
            for start in range(0, len(x), step):
                sl = slice(start, start + step)
                self._lookin_slice(laser, n_rays, directions[sl], pdf[sl], x[sl], n_x[sl], obj_x[sl], r_lx[sl],
                                   rng, dark_rng, sink, conv)
        finally:
            self.stats = saved

    def _lookin_slice(self, laser, n_rays, directions, pdf, x, n_x, obj_x, r_lx, rng, dark_rng, sink,
                      conv) -> None:
        c, s, stats = self.capture, self.settings, self.stats
        spot = c.spots[laser]
        w_to_spot = (spot - x) / r_lx[:, None]
        cos_x_l = np.maximum(_dot(n_x, w_to_spot), 0.0)
        flux = c.photons * self._spot_emission(directions, laser) / (n_rays * pdf)   # W_j, photons
        obs = observe(self.caster, x, n_x, s.pixels, rng) if self.needs_camera() else None
        if obs is not None:
            stats.observed_points += int(obs.hit.sum())
        out = self._camera_out(obs, laser) if s.sensor_sampling == "camera" else \
            self._connect_out(x, n_x, laser, rng)
        stats.fov_points += len(out.b)
        laser_t = (c.emitter_legs[laser] if s.count_laser_leg else 0.0) / SPEED_OF_LIGHT
        if len(out.b):
            b = out.b
            f = self._brdf(obj_x[b], n_x[b], w_to_spot[b], out.direction)
            cos_k = np.maximum(_dot(n_x[b], out.direction), 0.0)
            weight = flux[b] * f * cos_k * out.weight * self._attenuation(
                c.emitter_legs[laser] + r_lx[b] + out.phys)
            comp = self.object_component[obj_x[b]] * c.n_channels + out.channel
            sink.add(laser_t + r_lx[b] / SPEED_OF_LIGHT + out.time, weight, comp)
        if s.secondary != "none" and len(out.b):
            light = self._spot_light(obs, laser)
            self._secondary(laser, n_rays, pdf, x, n_x, obj_x, r_lx, cos_x_l, obs, light, out, sink, conv)
            if s.dark_middle and s.secondary != "optimized":     # the paper's top-K approximation stays as is
                self._secondary_dark(laser, flux, x, n_x, obj_x, r_lx, w_to_spot, obs, light, sink, dark_rng)

    # -- sensor side -------------------------------------------------------------------------------------

    def _camera_out(self, obs: ObservedPoints, laser: int) -> _Out:
        """FoV points among the observed points (the paper's final bounce through the camera pixels)."""
        c, s = self.capture, self.settings
        tol = FOV_PLANE_TOL * self.caster.offset
        obj = obs.object_id.ravel()
        fov_ids = self._fov_objects()
        flat = np.flatnonzero(obj == fov_ids[0] if len(fov_ids) == 1 else np.isin(obj, fov_ids))   # pre-filter
        pts = np.take(obs.points.reshape(-1, 3), flat, axis=0)
        n_y = np.take(obs.normals.reshape(-1, 3), flat, axis=0)
        ch = c.channel(laser, c.fov_pixel(pts, tol))
        keep = np.flatnonzero((ch >= 0) & (_dot(n_y, c.sensor - pts) > 0))
        flat, ch, y, n_y = flat[keep], ch[keep], pts[keep], n_y[keep]
        direction = np.take(obs.directions.reshape(-1, 3), flat, axis=0)
        collect, d_ys = self._sensor_collection(y, n_y, obj[flat], direction, -1.0)
        r = obs.distance.ravel()[flat]
        time = (r + (d_ys if s.count_sensor_leg else 0.0)) / SPEED_OF_LIGHT
        # per unit radiant intensity toward ω_k the pixel carries Ω photons to y (the caller applies f·cos)
        return _Out(flat // obs.hit.shape[1], direction, obs.solid_angle * collect, time, r + d_ys, ch)

    def _connect_out(self, x: np.ndarray, n_x: np.ndarray, laser: int, rng, jitter: np.ndarray | None = None
                     ) -> _Out:
        """Next-event connections from each lookin to sensor points (point radiance) or to stratified area
        samples of each sensor pixel region (aperture), with shadow rays (the FoV side of transient path
        tracers; DESIGN.md §2 with dA_y explicit).

        ``jitter`` (B, 2) in [0, 1)², aperture only: instead of one stratified ``connect_samples`` grid shared
        by the batch, row b connects to the single point at ``jitter[b]`` inside each pixel region (density
        1/A_pixel; unbiased for uniform jitter, and uncorrelated across rows)."""
        c, s = self.capture, self.settings
        nx, ny = c.fov_pixels
        if c.convention == "point_radiance":
            targets = c.sensor_points().reshape(1, -1, 3)                     # (1, S, 3)
            pix = np.arange(c.n_pixels)[None]
            area = 1.0
        elif jitter is not None:
            iy, ix = np.divmod(np.arange(c.n_pixels), nx)
            a = ((ix[None] + jitter[:, :1]) / nx - 0.5) * c.fov_size[0]          # (B, S)
            bb = ((iy[None] + jitter[:, 1:]) / ny - 0.5) * c.fov_size[1]
            targets = c.fov_center + a[..., None] * c.fov_u + bb[..., None] * c.fov_v      # (B, S, 3)
            pix = np.arange(c.n_pixels)[None]
            area = c.fov_size[0] * c.fov_size[1] / c.n_pixels
        else:
            mu, mv = s.connect_samples
            uv = stratified_grid(mu, mv, rng, count=c.n_pixels)               # (S, M, 2)
            iy, ix = np.divmod(np.arange(c.n_pixels), nx)
            a = ((ix[:, None] + uv[..., 0]) / nx - 0.5) * c.fov_size[0]
            bb = ((iy[:, None] + uv[..., 1]) / ny - 0.5) * c.fov_size[1]
            targets = (c.fov_center + a[..., None] * c.fov_u + bb[..., None] * c.fov_v).reshape(1, -1, 3)
            pix = np.repeat(np.arange(c.n_pixels), mu * mv)[None]
            area = c.fov_size[0] * c.fov_size[1] / (c.n_pixels * mu * mv)
        ch = c.channel(laser, pix)
        keep = ch[0] >= 0
        targets, pix, ch = targets[:, keep], pix[:, keep], ch[:, keep]
        to_y = targets - x[:, None, :]                                      # (B, S, 3)
        r = np.linalg.norm(to_y, axis=-1)
        w = to_y / np.maximum(r, 1e-300)[..., None]
        cos_x = _dot(n_x[:, None, :], w)
        n_y = np.broadcast_to(c.fov_normal, to_y.shape)
        cos_y = -_dot(n_y, w)
        ok = (cos_x > 0) & (cos_y > 0)
        bi, si = np.nonzero(ok)
        row = bi if len(targets) > 1 else np.zeros_like(bi)
        vis = self.caster.visible(x[bi], n_x[bi], targets[row, si], c.fov_normal)
        self.stats.shadow_rays += len(bi)
        bi, si, row = bi[vis], si[vis], row[vis]
        y = targets[row, si]
        wk = w[bi, si]
        obj_y = np.full(len(bi), self._wall_object())
        collect, d_ys = self._sensor_collection(y, n_y[bi, si], obj_y, -wk)
        rr = r[bi, si]
        # photons landing on dA_y per unit radiant intensity toward ω_k: cosθ_y dA_y / r²
        weight = cos_y[bi, si] * area / rr ** 2 * collect
        time = (rr + (d_ys if s.count_sensor_leg else 0.0)) / SPEED_OF_LIGHT
        return _Out(bi, wk, weight, time, rr + d_ys, ch[0, si])

    def _fov_objects(self) -> np.ndarray:
        """Ids of the objects with a face in the sensor grid's plane (only they can hold FoV points)."""
        if not hasattr(self, "_fov_ids"):
            c, rc = self.capture, self.caster
            tol = FOV_PLANE_TOL * rc.offset
            tri = rc.vertices[rc.faces]
            in_plane = np.abs((tri - c.fov_center) @ c.fov_normal).max(axis=1) <= tol
            self._fov_ids = np.unique(rc.face_object[in_plane])
        return self._fov_ids

    def _wall_object(self) -> int:
        """Object id of the relay wall under the sensor grid centre."""
        if not hasattr(self, "_wall_id"):
            c = self.capture
            h = self.caster.intersect((c.fov_center + 2 * FOV_PLANE_TOL * self.caster.offset * c.fov_normal)[None],
                                      (-c.fov_normal)[None])
            self._wall_id = int(h.object_id[0]) if h.hit[0] else int(c.spot_objects[0])
        return self._wall_id

    def _first_bounce(self, sink: Sink) -> None:
        """Direct return of each laser spot lying inside a sensor pixel region (aperture convention)."""
        c, s = self.capture, self.settings
        if c.convention != "aperture":
            return
        tol = FOV_PLANE_TOL * self.caster.offset
        comp = (self.n_primary + 1) * c.n_channels
        for laser in range(c.n_lasers):
            spot = c.spots[laser]
            rel = spot - c.fov_center
            margin = min(c.fov_size[0] / 2 - abs(rel @ c.fov_u), c.fov_size[1] / 2 - abs(rel @ c.fov_v))
            if margin <= 1e-9 * max(c.fov_size):        # on the FoV's edge (or outside): not imaged
                continue
            pix = c.fov_pixel(spot[None], tol)
            ch = c.channel(laser, pix)
            if ch[0] < 0:
                continue
            w_s = _unit(c.sensor - spot)
            d = float(np.linalg.norm(c.sensor - spot))
            emit = self._spot_emission(w_s[None], laser)
            cos_ap = max(-float(_dot(w_s, c.aperture_normal)), 0.0)
            vis = self.caster.visible(spot[None], c.spot_normals[laser][None], c.sensor, None)
            weight = c.photons * s.pde * emit * c.aperture_area * cos_ap / d ** 2 * vis
            weight = weight * self._attenuation(np.array([c.emitter_legs[laser] + d]))
            t = ((c.emitter_legs[laser] if s.count_laser_leg else 0.0) + (d if s.count_sensor_leg else 0.0))
            sink.add(np.array([t / SPEED_OF_LIGHT]), weight, np.array([comp + ch[0]]))

    # -- secondary ---------------------------------------------------------------------------------------

    def _spot_light(self, obs: ObservedPoints, laser: int) -> "_Lit":
        """Which observed points the laser spot lights on the side facing their lookin (one shadow ray each
        where ``shadow_spot``), with the spot → point geometry; shared by both secondary estimators."""
        c, s = self.capture, self.settings
        spot, spot_n = c.spots[laser], c.spot_normals[laser]
        flat = np.flatnonzero(obs.hit)
        y = np.take(obs.points.reshape(-1, 3), flat, axis=0)
        n_y = np.take(obs.normals.reshape(-1, 3), flat, axis=0)          # facing the lookin
        w = y - spot
        r = np.sqrt(_dot(w, w))
        w /= np.maximum(r, 1e-300)[:, None]
        cos_l = w @ spot_n
        cos_in = -_dot(n_y, w)
        lit = (cos_l > 0) & (cos_in > 0)
        if s.shadow_spot and lit.any():
            idx = np.flatnonzero(lit)
            idx = idx[self._may_be_blocked(spot, w[idx], r[idx], self._spot_spheres)]
            self.stats.shadow_rays += len(idx)
            lit[idx] = self.caster.visible(y[idx], n_y[idx], spot, spot_n)
        return _Lit(flat, flat // obs.hit.shape[1], y, n_y, r, w, cos_l, cos_in, lit)

    def _blocker_spheres(self, blockers: tuple[int, ...] | None) -> np.ndarray | None:
        """(G, 4) bounding spheres (centre, radius; metres) of the faces ``blockers`` grouped by object, padded
        by 10 surface offsets; None when the blockers are unknown."""
        if blockers is None:
            return None
        faces = np.asarray(blockers, dtype=np.int64)
        spheres = []
        for obj in np.unique(self.caster.face_object[faces]):
            mine = faces[self.caster.face_object[faces] == obj]
            pts = self.caster.vertices[self.caster.faces[mine]].reshape(-1, 3)
            centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            radius = float(np.max(np.linalg.norm(pts - centre, axis=1))) + 10 * self.caster.offset
            spheres.append([*centre, radius])
        return np.array(spheres).reshape(-1, 4)

    def _may_be_blocked(self, origin: np.ndarray, w: np.ndarray, r: np.ndarray,
                        spheres: np.ndarray | None) -> np.ndarray:
        """(n,) bool: the segment from ``origin`` (3,) along unit directions w (n, 3) over lengths r (n,) may meet
        one of the blockers' bounding ``spheres`` (inside its cone from the origin and not wholly before it);
        the others need no shadow ray. All True when ``spheres`` is None (blockers unknown)."""
        if spheres is None:
            return np.ones(len(w), dtype=bool)
        out = np.zeros(len(w), dtype=bool)
        for cx, cy, cz, radius in spheres:
            to_c = np.array([cx, cy, cz]) - origin
            dist = float(np.linalg.norm(to_c))
            if dist <= radius:                                      # the origin is inside the sphere
                return np.ones(len(w), dtype=bool)
            cos_cone = np.sqrt(1.0 - (radius / dist) ** 2)
            out |= (w @ (to_c / dist) >= cos_cone - 1e-12) & (r >= dist - radius)
        return out

    def _secondary(self, laser, n_rays, pdf, x, n_x, obj_x, r_lx, cos_x_l, obs, light: "_Lit", out: _Out, sink,
                   conv) -> None:
        c, s = self.capture, self.settings
        # area measure of each lookin as a second hidden vertex: dA_j = R_j² / (N p_j cosθ_j,l)
        with np.errstate(divide="ignore", invalid="ignore"):
            area = np.where(cos_x_l > 0, r_lx ** 2 / (n_rays * pdf * cos_x_l), 0.0)
        # laser-lit observed points y' of lookins with an area
        cand = np.flatnonzero(light.lit & (area[light.hb] > 0))
        self.stats.lit_points += len(cand)
        if len(cand) == 0:
            return
        lb, flat = light.hb[cand], light.flat[cand]
        n_yp, obj_yp = light.n_y[cand], obs.object_id.ravel()[flat]
        w_l = light.w[cand]
        r_l = light.r[cand]
        irradiance = c.photons * self._spot_emission(w_l, laser) * light.cos_in[cand] / r_l ** 2
        in_dir = np.take(obs.directions.reshape(-1, 3), flat, axis=0)
        radiance = irradiance * self._brdf(obj_yp, n_yp, w_l, in_dir, -1.0, -1.0)     # toward the lookin
        in_w = radiance * obs.local_z.ravel()[flat] * (obs.solid_angle * area[lb])   # photons arriving at the lookin
        in_path = r_l + obs.distance.ravel()[flat]
        laser_t = (c.emitter_legs[laser] if s.count_laser_leg else 0.0) / SPEED_OF_LIGHT
        if s.attenuation > 0:
            in_w = in_w * self._attenuation(c.emitter_legs[laser] + in_path)
        cos_out = np.maximum(_dot(n_x[out.b], out.direction), 0.0)
        out_w = cos_out * out.weight * self._attenuation(out.phys)
        out_t = laser_t + out.time
        if s.secondary == "exact":
            self._secondary_exact(x, n_x, obj_x, lb, in_w, in_path / SPEED_OF_LIGHT, in_dir, out, out_w, out_t,
                                  conv)
            return
        sec_comp = self.n_primary * c.n_channels
        for j in range(len(x)):
            a = np.flatnonzero(lb == j)
            b = np.flatnonzero(out.b == j)
            if len(a) == 0 or len(b) == 0:
                continue
            f = self._brdf(np.full((len(a), len(b)), obj_x[j]), n_x[j], in_dir[a][:, None, :],
                           out.direction[b][None])
            pair = in_w[a, None] * f * out_w[None, b]
            t_pair = in_path[a, None] / SPEED_OF_LIGHT + out_t[None, b]
            chan = np.broadcast_to(out.channel[b][None, :], pair.shape)
            if s.secondary == "optimized" and s.top_k < len(a):
                keep = np.argpartition(-pair, s.top_k - 1, axis=0)[:s.top_k]   # (K, n_fov)
                pair = np.take_along_axis(pair, keep, axis=0)
                t_pair = np.take_along_axis(np.broadcast_to(t_pair, (len(a), len(b))), keep, axis=0)
                chan = chan[:s.top_k]
            self.stats.secondary_pairs += pair.size
            sink.add(t_pair.ravel(), pair.ravel(), (sec_comp + chan).ravel())

    def _secondary_dark(self, laser, flux, x, n_x, obj_x, r_lx, w_to_spot, obs: ObservedPoints, light: "_Lit",
                        sink, rng) -> None:
        """Secondary paths whose middle vertex the laser does not light (DESIGN.md §2's path integral;
        docs/accuracy.md, "dark middle vertices").

        The lookin secondary (:meth:`_secondary`) puts the middle vertex of spot → y' → x → FoV on a lookin
        x, i.e. on a point the laser spot lights; paths whose middle vertex lies in a laser shadow (behind
        the box, on the side of the pillar turned away from the spot) have no lookin and are missed (6.9 % of
        the demo room's secondary). They are sampled here the other way round: lookin x_j (lit, first
        hidden vertex) → observed point z of its camera that the spot does *not* light on the side facing
        x_j (shadowed or facing away) → a next-event connection from z to the FoV (one uniformly jittered
        point per sensor pixel region, or every sensor point, with a shadow ray). The two sets split the
        paths by whether the middle vertex is lit, so together they count every path once.

        Weight: Φ_z = W_j f_x cosθ_x Ω photons reach z through pixel k (W_j the lookin's photons, Ω the pixel
        solid angle); z radiates Φ_z f_z cosθ_z,out per sr toward y, times the connection weight
        cosθ_y dA_y / r² · collection(y) (:meth:`_connect_out`). Time: spot → x_j → z → y [→ sensor].
        """
        c, s = self.capture, self.settings
        # not lit on the side facing x_j, and in front of the spot's plane (the relay wall cannot reflect to it)
        dark = np.flatnonzero(~light.lit & (light.cos_l > 1e-12))
        if len(dark) == 0:
            return
        z, n_z = light.y[dark], light.n_y[dark]
        self.stats.dark_points += len(dark)
        jitter = rng.random((len(dark), 2)) if rng is not None else np.full((len(dark), 2), 0.5)
        out = self._connect_out(z, n_z, laser, rng, jitter)
        if len(out.b) == 0:
            return
        j, flat = light.hb[dark[out.b]], light.flat[dark[out.b]]
        d_in = np.take(obs.directions.reshape(-1, 3), flat, axis=0)                 # x_j → z
        phi = flux[j] * self._brdf(obj_x[j], n_x[j], w_to_spot[j], d_in) * obs.local_z.ravel()[flat] * obs.solid_angle
        f_z = self._brdf(obs.object_id.ravel()[flat], n_z[out.b], d_in, out.direction, -1.0)
        cos_z = np.maximum(_dot(n_z[out.b], out.direction), 0.0)
        path = r_lx[j] + obs.distance.ravel()[flat]
        weight = phi * f_z * cos_z * out.weight * self._attenuation(c.emitter_legs[laser] + path + out.phys)
        laser_t = (c.emitter_legs[laser] if s.count_laser_leg else 0.0) / SPEED_OF_LIGHT
        self.stats.secondary_pairs += len(out.b)
        sink.add(laser_t + path / SPEED_OF_LIGHT + out.time, weight, self.n_primary * c.n_channels + out.channel)

    def _separable_factor(self, obj_x: np.ndarray, n_x: np.ndarray, rows: np.ndarray, w: np.ndarray) -> np.ndarray:
        """g(ω) of the separable BRDF split at lookins ``rows`` (indices into the batch's obj_x, n_x) for
        directions w (n, 3) above them; 1 for Lambertian and Phong lookins, so only the others are evaluated."""
        g = np.ones(len(rows))
        sel = np.flatnonzero(self._angular_g[obj_x][rows])
        if len(sel):
            r = rows[sel]
            g[sel] = self.materials.separable_factor_above(obj_x[r], n_x[r], w[sel])
        return g

    def _secondary_exact(self, x, n_x, obj_x, lb, in_w, in_t, in_dir, out: _Out, out_w, out_t,
                         conv: _ConvGrid) -> None:
        """Exact secondary at O(N·l·p) cost (DESIGN.md §3): with the split f = c·g(ω_in)·g(ω_out) + lobe, the
        sum over pairs (k', k) at each lookin is c × (incoming profile weighted by g) ⊛ (outgoing profile
        weighted by g): one FFT convolution per lookin and channel. Lobes (Phong) are summed pairwise.
        Profiles are binned on ``conv``'s grid (cloud-in-cell), its only approximation."""
        B = len(x)
        if B > 1:
            t_all = np.concatenate([in_t, out_t])
            span = (t_all.max() - t_all.min()) / conv.step if len(t_all) else 0.0
            if B * span > _CONV_DENSE_MAX:                 # bound the dense profile buffers: split the batch
                half = B // 2
                for sel in (np.arange(half), np.arange(half, B)):
                    mi, mo = np.isin(lb, sel), np.isin(out.b, sel)
                    remap = np.full(B, -1)
                    remap[sel] = np.arange(len(sel))
                    sub = _Out(remap[out.b[mo]], out.direction[mo], out.weight[mo], out.time[mo], out.phys[mo],
                               out.channel[mo])
                    self._secondary_exact(x[sel], n_x[sel], obj_x[sel], remap[lb[mi]], in_w[mi], in_t[mi],
                                          in_dir[mi], sub, out_w[mo], out_t[mo], conv)
                return
        scale = self.materials.separable_scale(obj_x)                                  # (B,)
        g_in = self._separable_factor(obj_x, n_x, lb, in_dir)
        g_out = self._separable_factor(obj_x, n_x, out.b, out.direction)
        step = conv.step
        # incoming profiles, one row per lookin, on nodes n·step (time from the spot)
        a_start, a_dense = _cic_rows(in_t / step, in_w * g_in, lb, B)
        # outgoing profiles per (lookin, channel) on nodes t0 + n·step
        pairs, pair_row = np.unique(out.b * conv.nodes.shape[0] + out.channel, return_inverse=True)
        b_start, b_dense = _cic_rows((out_t - conv.t0) / step, out_w * g_out, pair_row, len(pairs))
        p_lookin, p_channel = np.divmod(pairs, conv.nodes.shape[0])
        has_in = np.bincount(lb, minlength=B) > 0
        use = has_in[p_lookin]
        n = scipy.fft.next_fast_len(a_dense.shape[1] + b_dense.shape[1] - 1, real=True)
        fa = scipy.fft.rfft(a_dense, n, axis=1)
        fb = scipy.fft.rfft(b_dense[use], n, axis=1)
        prod = scipy.fft.irfft(fa[p_lookin[use]] * fb, n, axis=1)
        length = a_dense.shape[1] + b_dense.shape[1] - 1
        for row, (j, ch, bs) in enumerate(zip(p_lookin[use], p_channel[use], b_start[use])):
            vals = prod[row, :length] * scale[j]
            np.maximum(vals, 0.0, out=vals)                       # FFT round-off below zero
            conv.add_block(int(ch), int(a_start[j] + bs), vals)
        self.stats.secondary_pairs += int(np.bincount(lb, minlength=B) @ np.bincount(out.b, minlength=B))
        lobe = self.materials.has_lobe(obj_x)
        for j in np.flatnonzero(lobe):
            a = np.flatnonzero(lb == j)
            b = np.flatnonzero(out.b == j)
            if len(a) == 0 or len(b) == 0:
                continue
            f = self.materials.lobe(np.full((len(a), len(b)), obj_x[j]), n_x[j], in_dir[a][:, None, :],
                                    out.direction[b][None])
            pair = in_w[a, None] * f * out_w[None, b]
            t_pair = in_t[a, None] + out_t[None, b]
            chan = np.broadcast_to(out.channel[b][None, :], pair.shape)
            conv.add_impulses(t_pair.ravel(), pair.ravel(), chan.ravel())


def sink_far_time(sink: Sink) -> float:
    """A time beyond every window of ``sink`` (for mass that must be counted as outside)."""
    axis = getattr(sink, "axis", None)
    return float(axis.t_stop + 1.0) if axis is not None else 1e9
