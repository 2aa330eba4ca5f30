"""Capture geometry: where the laser points and the sensor grid lie on the relay wall (scene stage).

:func:`resolve_capture` turns a scene's ``laser``, ``sensor`` and ``capture`` blocks into a :class:`Capture`
(laser points with their relay-wall normals, the sensor grid's frame, aperture, photons per pulse), checking
with the ray caster that each laser point lies on a surface the emitter sees and that the sensor sees its
grid. Every estimator, the effect planner and the figures read the capture from here; the scan types and
conventions are those of tal (docs/physics.md §8).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..vectors import dot, matmul, norm, unit
from .model import Scene
from .parts import SceneError
from .raycast import RayCaster

FOV_PLANE_TOL = 10.0
"""A hit lies on the FoV plane when within this many ray offsets of it (hit points are float64 rebuilt
from float32 barycentrics, accurate to a few offsets)."""

FOV_EDGE_REL = 1e-9
"""A laser point within this fraction of the FoV size of the FoV's edge is on the boundary, which counts as
outside (the demo room's spot lies exactly on its FoV's top edge; float rounding of the in-plane
coordinates is ~1e-16 relative)."""


@dataclass(frozen=True)
class Capture:
    """Resolved capture geometry (all float64, metres): laser points, sensor grid, sensor device.

    Attributes:
        kind: "single" | "confocal" | "exhaustive" (docs/physics.md §8, tal's scan types).
        convention: "aperture" (detected photons per pulse) or "point_radiance" (tal / mitransient).
        spots: (L, 3) laser points; spot_normals: (L, 3) relay-wall normals there (facing the hidden side);
        spot_objects: (L,) object ids; laser_shape: (lx, ly) grid of the laser points (L = lx·ly).
        emitter: (3,); emitter_legs: (L,) |spot − emitter|.
        sensor: (3,) sensor position; aperture_area: m²; aperture_normal: unit vector toward the grid centre
        (the staring aperture of single-spot and exhaustive captures; a confocal scan's aperture follows the
        laser, :meth:`aperture_normals`).
        fov_center, fov_u, fov_v, fov_normal: the sensor grid's frame on the relay wall; fov_size: (w, h);
        fov_pixels: (nx, ny) sensor points (cell centres) / pixel regions (cells).
        photons: Φ, photons per pulse (1 for point radiance: per unit power at the spot).
        legacy_single_pixel: the scene used the paper's one-pixel ``sensor.fov`` (envelope shape (T,)).
        pixel_size: (w, h) m, a confocal scan's detector field of view at each scan point (``capture.detector_fov``):
            pixel region i is the w × h rectangle centred on sensor point i, and neighbouring regions may overlap;
            None: each pixel region is its cell of the grid (:attr:`region_size`).
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
    pixel_size: tuple[float, float] | None = None

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
    def region_size(self) -> tuple[float, float]:
        """(w, h) m of each pixel region: :attr:`pixel_size`, or the grid's cell (fov_size / fov_pixels)."""
        if self.pixel_size is not None:
            return self.pixel_size
        return (self.fov_size[0] / self.fov_pixels[0], self.fov_size[1] / self.fov_pixels[1])

    @property
    def fov_extent(self) -> tuple[float, float]:
        """(w, h) m of the rectangle that holds every pixel region: the grid's ``fov_size``, widened by the overhang of
        regions larger than their cells (:attr:`pixel_size`)."""
        if self.pixel_size is None:
            return self.fov_size
        return tuple(max(s, s - s / n + r) for s, n, r in zip(self.fov_size, self.fov_pixels, self.pixel_size))

    def pixel_area(self, parts: int = 1) -> float:
        """The area (m²) of one pixel region divided into ``parts`` equal cells."""
        if self.pixel_size is None:
            return self.fov_size[0] * self.fov_size[1] / (self.n_pixels * parts)
        return self.pixel_size[0] * self.pixel_size[1] / parts

    def pixel_density(self) -> float:
        """1 / the area of one pixel region (1/m²): the density of a point drawn uniformly in it."""
        if self.pixel_size is None:
            return self.n_pixels / (self.fov_size[0] * self.fov_size[1])
        return 1.0 / (self.pixel_size[0] * self.pixel_size[1])

    def region_offsets(self, uv: np.ndarray) -> np.ndarray:
        """Positions (..., 2) in [0, 1]² inside a pixel region ((0.5, 0.5): its centre) as offsets from the pixel's
        index in sensor-grid units (what :meth:`fov_points` and the compiled FoV kernels take): ``uv`` itself for
        regions that are their cells, else 0.5 + (uv − 0.5) · region / cell, which may reach into the neighbours'
        cells (:attr:`pixel_size`)."""
        if self.pixel_size is None:
            return uv
        scale = np.asarray(self.pixel_size) * np.asarray(self.fov_pixels) / np.asarray(self.fov_size)
        return 0.5 + (np.asarray(uv, dtype=np.float64) - 0.5) * scale

    def region_points(self, ix: np.ndarray, iy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """World points (..., 3) inside pixel regions: pixel (ix, iy) and the position (a, b) in [0, 1]² inside its
        region ((0.5, 0.5): its centre, the sensor point), broadcast together: :meth:`fov_points` of
        (ix + a, iy + b) with (a, b) mapped by :meth:`region_offsets`."""
        if self.pixel_size is None:
            return self.fov_points(ix + a, iy + b)
        a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
        off = self.region_offsets(np.stack([a, b], axis=-1))
        return self.fov_points(ix + off[..., 0], iy + off[..., 1])

    def points_channel(self, laser: int | np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
        """Output channel (int64, (...,)) that wall points (..., 3) lit from laser point(s) ``laser`` (an index, or
        one per point) are recorded in; −1: in no recorded pixel region. Without :attr:`pixel_size`,
        ``channel(laser, fov_pixel(points, tol))``; with it (confocal), laser point l records the points within
        ``tol`` of the wall's plane inside its own region (overlapping regions: a point may count for several laser
        points, each in its own scan)."""
        if self.pixel_size is None:
            return self.channel(laser, self.fov_pixel(points, tol))
        laser = np.broadcast_to(np.asarray(laser, dtype=np.int64), np.shape(points)[:-1])
        ok = laser < self.n_pixels
        iy, ix = np.divmod(np.where(ok, laser, 0), self.fov_pixels[0])
        rel = np.asarray(points, dtype=np.float64) - self.fov_points(ix + 0.5, iy + 0.5)
        inside = (ok & (np.abs(matmul(rel, self.fov_normal)) <= tol)
                  & (np.abs(matmul(rel, self.fov_u)) <= 0.5 * self.pixel_size[0])
                  & (np.abs(matmul(rel, self.fov_v)) <= 0.5 * self.pixel_size[1]))
        return np.where(inside, laser, -1)

    def fov_distance(self, points: np.ndarray) -> np.ndarray:
        """The distance of points (..., 3) to the nearest point of the FoV rectangle (every pixel region,
        :attr:`fov_extent`), m: (...,) float64, a lower bound of any path's length from a point to a FoV point or
        sensor point."""
        rel = np.asarray(points, dtype=np.float64) - self.fov_center
        w, h = self.fov_extent
        a = np.clip(matmul(rel, self.fov_u), -0.5 * w, 0.5 * w)
        b = np.clip(matmul(rel, self.fov_v), -0.5 * h, 0.5 * h)
        return np.linalg.norm(rel - a[..., None] * self.fov_u - b[..., None] * self.fov_v, axis=-1)

    def fov_sensor_distance(self) -> float:
        """The shortest distance from the sensor position to the FoV rectangle, m: the shortest FoV → sensor leg of
        any path."""
        return float(self.fov_distance(np.asarray(self.sensor, dtype=np.float64)))

    @property
    def n_lasers(self) -> int:
        return len(self.spots)

    @property
    def n_channels(self) -> int:
        """Output channels: S (single, confocal) or L·S (exhaustive)."""
        return self.n_lasers * self.n_pixels if self.kind == "exhaustive" else self.n_pixels

    def channel(self, laser: int | np.ndarray, pixel: np.ndarray) -> np.ndarray:
        """Output channel (int64, pixel's shape) of sensor pixel(s) ``pixel`` lit from laser point(s) ``laser`` (an
        index, or one per pixel; −1: not recorded)."""
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

    def fov_points(self, cu: np.ndarray, cv: np.ndarray) -> np.ndarray:
        """World points (..., 3) of sensor-grid coordinates: ``cu`` in [0, nx] and ``cv`` in [0, ny] are a pixel
        index plus the position inside that pixel (0.5: its centre), broadcast together."""
        nx, ny = self.fov_pixels
        a = (cu / nx - 0.5) * self.fov_size[0]
        b = (cv / ny - 0.5) * self.fov_size[1]
        return self.fov_center + a[..., None] * self.fov_u + b[..., None] * self.fov_v

    def fov_margin(self, points: np.ndarray) -> np.ndarray:
        """In-plane distance (m) of points (..., 3) inside the sensor grid's rectangle edges: > 0 inside,
        < 0 outside (the off-plane distance is not included)."""
        rel = points - self.fov_center
        return np.minimum(0.5 * self.fov_size[0] - np.abs(matmul(rel, self.fov_u)),
                          0.5 * self.fov_size[1] - np.abs(matmul(rel, self.fov_v)))

    def spots_inside_fov(self) -> np.ndarray:
        """(L,) bool: whether each laser point lies strictly inside the sensor grid's rectangle (a point on its edge,
        within ``FOV_EDGE_REL`` of the FoV size, counts as outside)."""
        return self.fov_margin(self.spots) > FOV_EDGE_REL * max(self.fov_size)

    def aperture_normals(self, points: np.ndarray) -> np.ndarray:
        """Unit aperture normal(s) (pointing from the sensor into the scene) seen by FoV points (n, 3): (3,) or (n, 3).

        Single-spot and exhaustive captures stare: one normal toward the sensor grid's centre
        (``aperture_normal``; a SPAD array behind one lens, or a sensor point). A confocal scan steers the
        detector's line of sight with the laser through the same galvo mirrors, so while laser point p is
        scanned the aperture faces p: each point gets the normal toward the centre of the pixel region holding it
        (its laser point; cos θ_ap = 1 at p), and laser point p's envelope equals the single-spot capture of p
        (docs/scans.md, docs/physics.md §2). Points outside the grid take the nearest edge pixel's normal (their
        channel is not recorded).
        """
        if self.kind != "confocal":
            return self.aperture_normal
        rel = np.asarray(points, dtype=np.float64) - self.fov_center
        nx, ny = self.fov_pixels
        ix = np.clip(np.floor((matmul(rel, self.fov_u) / self.fov_size[0] + 0.5) * nx), 0, nx - 1).astype(np.int64)
        iy = np.clip(np.floor((matmul(rel, self.fov_v) / self.fov_size[1] + 0.5) * ny), 0, ny - 1).astype(np.int64)
        return self._pixel_aperture_normals[iy, ix]

    @cached_property
    def _pixel_aperture_normals(self) -> np.ndarray:
        """(ny, nx, 3) unit directions from the sensor to each pixel region's centre (a confocal scan's aperture
        normals, :meth:`aperture_normals`), computed once."""
        nx, ny = self.fov_pixels
        iy, ix = np.meshgrid(np.arange(ny, dtype=np.float64), np.arange(nx, dtype=np.float64), indexing="ij")
        return unit(self.fov_points(ix + 0.5, iy + 0.5) - self.sensor)

    def fov_pixel(self, points: np.ndarray, tol: float) -> np.ndarray:
        """Sensor pixel index (row-major over (v, u)) of each point, −1 outside the FoV. (..., 3) → (...,)."""
        rel = points - self.fov_center
        a = (matmul(rel, self.fov_u)) / self.fov_size[0] + 0.5
        b = (matmul(rel, self.fov_v)) / self.fov_size[1] + 0.5
        inside = (np.abs(matmul(rel, self.fov_normal)) <= tol) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        nx, ny = self.fov_pixels
        ix = np.minimum((np.where(inside, a, 0.0) * nx).astype(np.int64), nx - 1)    # inside: a, b in [0, 1]
        iy = np.minimum((np.where(inside, b, 0.0) * ny).astype(np.int64), ny - 1)
        return np.where(inside, iy * nx + ix, -1)



def _on_surface(caster: RayCaster, point: np.ndarray, direction: np.ndarray, tol: float) -> bool:
    """True when a surface passes within ``tol`` of ``point`` along ``direction`` (a short probe ray)."""
    probe = caster.intersect((point - 2 * tol * direction)[None], direction[None])
    return bool(probe.hit[0] and probe.distance[0] <= 4 * tol)


def _wall_frame(caster: RayCaster, sensor: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, ...]:
    """(u, v, n) of the relay wall around ``center`` as the sensor sees it (n facing the sensor)."""
    hit_c = caster.intersect(sensor[None], unit(center - sensor)[None])
    normal = hit_c.normals[0] if hit_c.hit[0] else unit(sensor - center)
    u = np.cross(normal, np.array([0.0, 0.0, 1.0]))
    u = unit(np.cross(normal, np.array([0.0, 1.0, 0.0]))) if norm(u) < 1e-9 else unit(u)
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
    leg = float(norm(spot - emitter))
    if leg == 0:
        raise SceneError(f"{where}{field} equals laser.emitter {spot.tolist()}")
    hits = caster.intersect(emitter[None], unit(spot - emitter)[None])
    tol = FOV_PLANE_TOL * caster.offset
    if not hits.hit[0] or hits.distance[0] < leg - tol:
        if hits.hit[0] and _on_surface(caster, spot, unit(spot - emitter), tol):
            raise SceneError(f"{where}{field} {spot.tolist()} is hidden from the emitter: the beam hits "
                             f"object {names[hits.object_id[0]]!r} at "
                             f"{np.round(hits.points[0], 4).tolist()} first")
        raise SceneError(f"{where}{field} {spot.tolist()} is off every surface (no surface there along "
                         f"the beam from the emitter {emitter.tolist()})")
    if hits.distance[0] > leg + tol:
        raise SceneError(f"{where}{field} {spot.tolist()} is off every surface (the beam from the emitter "
                         f"first hits {np.round(hits.points[0], 4).tolist()})")
    return hits.normals[0], int(hits.object_id[0]), leg


def _opposite_sides(scene: Scene, emitter: np.ndarray, sensor: np.ndarray, spot: np.ndarray, spot_normal: np.ndarray,
                    where: str, grid_field: str) -> str:
    """The message for an emitter and a sensor on opposite sides of the relay wall. The one on the other side
    from the rest of the scene (the centroid of the vertices of every object not labelled relay_wall) is named
    as misplaced; both positions are given."""
    rest = [o.vertices for o in scene.objects if o.label != "relay_wall"] or [o.vertices for o in scene.objects]
    bulk = float(np.dot(np.concatenate(rest).mean(axis=0) - spot, spot_normal))   # > 0: the emitter's side
    if bulk < 0:
        return (f"{where}laser.emitter {emitter.tolist()} is behind the relay wall: it lights laser.spot from the "
                f"far side, away from the hidden scene and from sensor.position {sensor.tolist()}")
    return (f"{where}sensor.position {sensor.tolist()} is behind the relay wall: it sees the back of the wall at "
            f"{grid_field}, while laser.emitter {emitter.tolist()} lights the other side")


def _resolve_spots(caster: RayCaster, names: list[str], emitter: np.ndarray, spots: np.ndarray, where: str,
                   field: Callable[[int], str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_resolve_spot` of every laser point as arrays (normals (L, 3), object ids (L,) int64, emitter legs
    (L,) m), with one batch of beams (a scan's thousand points); when the batch finds a point wrong, each point is
    resolved alone (``field(i)`` names point i), which raises that point's message."""
    legs = np.linalg.norm(spots - emitter, axis=1)
    if (legs > 0).all():
        hits = caster.intersect(np.broadcast_to(emitter, spots.shape), unit(spots - emitter))
        tol = FOV_PLANE_TOL * caster.offset
        good = hits.hit & (np.abs(hits.distance - legs) <= tol)
        if good.all():
            return np.array(hits.normals), hits.object_id.astype(np.int64), legs
    resolved = [_resolve_spot(caster, names, emitter, p, where, field(i)) for i, p in enumerate(spots)]
    return (np.array([r[0] for r in resolved]), np.array([r[1] for r in resolved], dtype=np.int64),
            np.array([r[2] for r in resolved]))


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
        laser_shape, field = (1, 1), lambda i: "laser.spot"
    else:
        lg = cap.laser_grid
        lu, lv, _ = _wall_frame(caster, sensor, np.asarray(lg.center, float))
        spots = _grid_points(lg.center, lg.size, lg.points, lu, lv)
        laser_shape = tuple(lg.points)
        field = "capture.laser_grid point {}".format
    names = [o.name for o in scene.objects]
    spot_normals, spot_objects, emitter_legs = _resolve_spots(caster, names, emitter, spots, where, field)
    if float(np.dot(normal, spot_normals[0])) < 0:
        raise SceneError(_opposite_sides(scene, emitter, sensor, spots[0], spot_normals[0], where, grid_field))
    photons = 1.0 if convention == "point_radiance" else scene.laser.photons
    capture = Capture(kind, convention, spots, spot_normals, spot_objects, laser_shape, emitter, emitter_legs,
                      sensor, scene.sensor.aperture_area,
                      unit(center - sensor), center, u, v, normal, size, pixels, photons,
                      legacy_single_pixel=(cap is None or cap.model_fields_set <= {"frames"}) and pixels == (1, 1),
                      pixel_size=cap.detector_fov if cap is not None else None)
    # Probe the sensor grid from the sensor: some of it must be a surface the sensor sees.
    tol = FOV_PLANE_TOL * caster.offset
    g = (np.arange(9) + 0.5) / 9 - 0.5
    gu, gv = np.meshgrid(g * size[0], g * size[1])
    targets = np.concatenate([center + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * v,
                              capture.sensor_points().reshape(-1, 3)])
    probe = caster.intersect(np.broadcast_to(sensor, targets.shape), unit(targets - sensor))
    on_wall = probe.hit & (np.abs(dot(probe.hit_points() - center, normal)) <= tol)
    if not on_wall.any():
        raise SceneError(f"{where}{grid_field} (center {center.tolist()}, size {list(size)}) sees no surface "
                         f"from the sensor at {sensor.tolist()}")
    return capture


