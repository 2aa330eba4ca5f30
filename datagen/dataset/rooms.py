"""Procedural rooms: a YAML distribution over L-bend rooms, hidden objects, materials and capture geometry.

A :class:`RoomDistribution` (loaded from ``configs/rooms/*.yaml`` by :func:`load_room_distribution`) describes
ranges for every parameter of the scene family built by :func:`datagen.scene.l_room` (corridor along +x
ending at the relay wall x = ``relay_x`` facing −x, an L-bend room on the ``bend_side`` over the corridor's
last ``room.depth`` metres; or, with ``family: wall``, the relay wall alone), floor-to-ceiling pillars, boxes and
meshes from asset files (:mod:`datagen.dataset.assets`), per-class materials, the emitter and sensor positions, the
laser spot and the sensor's field of view (FoV) on the relay wall, or a scanned capture (``capture.scan``,
:mod:`datagen.dataset.scan`). Loading validates every field
(pydantic; errors name the file, the dotted field and the value) and checks up front that every room the
distribution can make can hold its objects and capture (:func:`check_feasible`). Rooms are drawn from it by
:func:`datagen.dataset.sampler.sample_room`.

World frame right-handed, z up, metres; yaw in degrees about +z (counter-clockwise seen from above).
"""
from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, ValidationError, field_validator, model_validator

from ..errors import ConfigError
from ..scene import Laser, Material
from ..scene.brdf_kernel import BRDF_KINDS
from ..scene.materials import LOBE_WIDTH_MAX
from ..scene.load import format_validation_error, read_yaml
from ..scene.motion import FrameSpec
from ..scene.parts import check_counts
from ..units import parse_energy, parse_length
from .assets import asset_files, resolve_assets
from .ranges import CountRange, Fraction, Model, NonNegative, Positive, Range, Signed, Unit
from .scan import ScanDist, scan_fits
from ..vectors import norm

OBJECT_CLASSES = ("box", "pillar", "mesh")
"""Hidden-object classes; the index is the class code of the labels (0 box, 1 pillar, 2 mesh)."""

MATERIAL_CLASSES = ("relay_wall", "wall", "floor", "ceiling", "pillar", "box", "mesh")
"""Classes with their own material distribution (scene labels of :func:`datagen.scene.l_room` + objects)."""

UNIFORMS_PER_MATERIAL = 4
"""Uniform draws per material (kind, albedo, specular, exponent or lobe width), fixed whatever the kind: changing
one class's distribution leaves every other draw of the materials stream where it was."""

PACKING_LIMIT = 0.5
"""Largest share of a region's floor that the inflated footprints of the maximum object count may cover.
Random sequential placement of rectangles jams near 55 % coverage; above ~50 % rejection sampling stalls."""


# ---------------------------------------------------------------------------------------------------------
# Distribution schema


class CorridorDist(Model):
    """Corridor from its open (or closed) end to the relay wall, along +x."""

    length: Positive = Range(min=8.0, max=8.0)
    width: Positive = Range(min=2.1, max=2.1)
    closed_end: bool = False


class RoomDist(Model):
    """The L-bend room: ``depth`` along x (its opening on the corridor), ``length`` sideways (m)."""

    depth: Positive = Range(min=3.0, max=3.0)
    length: Positive = Range(min=4.0, max=4.0)
    bend_side: tuple[Literal[1, -1], ...] = (1,)

    @field_validator("bend_side", mode="before")
    @classmethod
    def _choices(cls, v: Any) -> Any:
        if v in ("either", "both"):
            return (1, -1)
        return (v,) if isinstance(v, int) and not isinstance(v, bool) else v

    @field_validator("bend_side")
    @classmethod
    def _nonempty(cls, v: tuple) -> tuple:
        if not v:
            raise ValueError("give at least one bend side (1, -1 or [1, -1])")
        return v


class PointDist(Model):
    """Emitter or sensor position in the corridor.

    ``standoff``: fraction of the corridor length between the relay wall and the point (x = relay_x −
    standoff·length); ``lateral``: y as a fraction of the usable half-width (−1..1); ``height``: z in m.
    """

    standoff: Fraction = Range(min=0.75, max=0.75)
    lateral: Signed = Range(min=0.0, max=0.0)
    height: Positive = Range(min=1.0, max=1.0)

    @field_validator("standoff")
    @classmethod
    def _inside(cls, v: Range) -> Range:
        if v.max >= 1.0:
            raise ValueError(f"max must be < 1 (the point must stay inside the corridor), got {v.max}")
        return v


class SpotDist(Model):
    """Laser spot on the relay wall's corridor end: y = lateral·(w/2 − edge_margin), z = height (m)."""

    lateral: Signed = Range(min=0.0, max=0.0)
    height: Positive = Range(min=2.5, max=2.5)


class FovDist(Model):
    """FoV rectangle on the relay wall's corridor end: size ranges (m), pixels fixed; its centre is uniform
    over the positions that keep it ``edge_margin`` inside the corridor end."""

    width: Positive = Range(min=2.0, max=2.0)
    height: Positive = Range(min=2.0, max=2.0)
    pixels: tuple[int, int] = (1, 1)

    @field_validator("pixels")
    @classmethod
    def _pixels(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "pixel counts")


class CaptureDist(Model):
    """Emitter, sensor (``null``: co-located with the emitter), laser spot, FoV, aperture, pulse; ``scan``
    (:class:`~datagen.dataset.scan.ScanDist`) replaces the single spot and FoV by a scanned capture."""

    emitter: PointDist = PointDist()
    sensor: PointDist | None = None
    spot: SpotDist = SpotDist()
    fov: FovDist = FovDist()
    scan: ScanDist | None = None
    edge_margin: float = Field(0.05, ge=0.0, description="m kept between spot/FoV/emitter and the walls")
    aperture_radius: float = Field(0.02, gt=0.0)
    photons_per_pulse: float | None = Field(None, gt=0)
    pulse_energy: float | None = Field(None, gt=0)
    wavelength: float = Field(532e-9, gt=0)

    @field_validator("aperture_radius", "wavelength", mode="before")
    @classmethod
    def _length(cls, v: Any) -> Any:
        return parse_length(v)

    @field_validator("pulse_energy", mode="before")
    @classmethod
    def _energy(cls, v: Any) -> Any:
        return None if v is None else parse_energy(v)

    @model_validator(mode="after")
    def _laser(self) -> "CaptureDist":
        Laser(spot=(0.0, 0.0, 0.0), **self.laser_settings())   # same rules as scene files
        return self

    def laser_settings(self) -> dict:
        return {"photons_per_pulse": self.photons_per_pulse, "pulse_energy": self.pulse_energy,
                "wavelength": self.wavelength}


class RoomRegion(Model):
    """Placement in the L-room proper: relative ``weight`` and the object's bottom height above the floor."""

    weight: float = Field(1.0, ge=0.0)
    elevation: NonNegative = Range(min=0.0, max=0.0)


class CorridorEndRegion(Model):
    """Placement in the corridor end: between ``min_depth`` and ``depth`` m from the relay wall (like the demo's
    shelf box, or a hidden object in front of a bare wall)."""

    weight: float = Field(0.0, ge=0.0)
    elevation: NonNegative = Range(min=0.0, max=0.0)
    depth: float = Field(1.0, gt=0.0)
    min_depth: float = Field(0.0, ge=0.0)

    @model_validator(mode="after")
    def _depths(self) -> "CorridorEndRegion":
        if self.min_depth >= self.depth:
            raise ValueError(f"min_depth ({self.min_depth}) must be < depth ({self.depth})")
        return self


class Placement(Model):
    room: RoomRegion = RoomRegion()
    corridor_end: CorridorEndRegion = CorridorEndRegion()

    @model_validator(mode="after")
    def _some_weight(self) -> "Placement":
        if self.room.weight + self.corridor_end.weight <= 0:
            raise ValueError("room.weight + corridor_end.weight must be > 0")
        return self

    def regions(self) -> list[tuple[str, RoomRegion | CorridorEndRegion]]:
        return [(n, r) for n, r in (("room", self.room), ("corridor_end", self.corridor_end)) if r.weight > 0]


class Size3(Model):
    x: Positive
    y: Positive
    z: Positive = Range(min=1.0, max=1.0)


class ObjectDist(Model):
    """One hidden-object class: count, size (m; a pillar's z is the ceiling), yaw (deg), placement."""

    count: CountRange = CountRange()
    size: Size3 = Size3(x=Range(min=0.5, max=0.5), y=Range(min=0.5, max=0.5), z=Range(min=0.5, max=0.5))
    cube: bool = Field(False, description="box: one edge length drawn from size.x for all three axes")
    yaw_deg: Range = Range(min=0.0, max=0.0)
    placement: Placement = Placement()


class MeshObjectDist(Model):
    """Hidden meshes drawn from asset files (:mod:`datagen.dataset.assets`): ``assets`` folders or files
    (relative to the room file, then the working directory; resolved to absolute paths on loading), one file
    drawn uniformly per object; ``size`` the longest side of its bounding box (m; the mesh is scaled
    uniformly); ``yaw_deg`` about +z; ``tilt_deg`` about a horizontal axis of uniform azimuth (0: upright);
    ``placement`` and ``elevation`` (bottom height) as for boxes."""

    count: CountRange = CountRange()
    assets: list[str] = Field(default_factory=list)
    size: Positive = Range(min=0.5, max=0.5)
    yaw_deg: Range = Range(min=0.0, max=0.0)
    tilt_deg: Range = Range(min=0.0, max=0.0)
    placement: Placement = Placement()

    @field_validator("tilt_deg")
    @classmethod
    def _tilt(cls, v: Range) -> Range:
        if v.min < 0 or v.max > 180:
            raise ValueError(f"tilt must lie in [0, 180] degrees, got [{v.min}, {v.max}]")
        return v

    @model_validator(mode="after")
    def _assets(self) -> "MeshObjectDist":
        if self.count.max > 0 and not self.assets:
            raise ValueError("give assets (folders or mesh files) when count.max > 0")
        return self


class ObjectsDist(Model):
    min_gap: float = Field(0.05, ge=0.0, description="m of clearance around every object")
    max_tries: int = Field(200, ge=1, description="placement attempts per object before a layout restarts")
    max_layouts: int = Field(20, ge=1, description="layout restarts before sample_room gives up")
    box: ObjectDist = ObjectDist()
    pillar: ObjectDist = ObjectDist()
    mesh: MeshObjectDist = MeshObjectDist()


class MaterialDist(Model):
    """Per-class materials: albedo range, BRDF kind mixture weights (absent kinds weigh 0), lobe ranges.

    ``exponent`` (Phong) and ``lobe_width`` (retroreflective) are drawn log-uniformly (lobe sharpness spans decades);
    ``specular`` is the lobe's fraction k_s of both; ``axis`` is the sin θ reference. The ``retroreflective`` kind
    (road signs, safety apparel, bicycle reflectors; docs/rooms.md) weighs 0 unless a config gives it a weight, and
    a kind's draw uses the same four uniforms whatever the kinds: configs without it draw what they drew before.
    """

    albedo: Unit = Range(min=1.0, max=1.0)
    kinds: dict[Literal["lambertian", "sin_theta", "phong", "retroreflective"], float] = {"lambertian": 1.0}
    specular: Unit = Range(min=0.5, max=0.5)
    exponent: Positive = Range(min=50.0, max=50.0)
    lobe_width: Positive = Range(min=0.01, max=0.05)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    @field_validator("kinds")
    @classmethod
    def _weights(cls, v: dict) -> dict:
        bad = {k: w for k, w in v.items() if not (math.isfinite(w) and w >= 0)}
        if bad:
            raise ValueError(f"weights must be finite and >= 0, got {bad}")
        if sum(v.values()) <= 0:
            raise ValueError(f"at least one kind needs a positive weight, got {v}")
        return v

    @field_validator("lobe_width")
    @classmethod
    def _width(cls, v: Range) -> Range:
        if v.max > LOBE_WIDTH_MAX:
            raise ValueError(f"max must be <= {LOBE_WIDTH_MAX} (GGX α), got {v.max}")
        return v

    @field_validator("axis")
    @classmethod
    def _axis(cls, v: tuple) -> tuple:
        if not np.all(np.isfinite(v)) or norm(v) == 0:
            raise ValueError(f"must be a finite non-zero vector, got {list(v)}")
        return v

    def draw(self, u: np.ndarray) -> Material:
        """Material at uniforms ``u`` (4,) float64 in [0, 1): kind by inverse CDF, then albedo, k_s, n or α."""
        weights = np.array([self.kinds.get(k, 0.0) for k in BRDF_KINDS], dtype=np.float64)
        cdf = np.cumsum(weights) / weights.sum()
        kind = BRDF_KINDS[min(int(np.searchsorted(cdf, u[0], side="right")), len(BRDF_KINDS) - 1)]
        albedo = self.albedo.draw(u[1])
        if kind == "phong":
            return Material(kind=kind, albedo=albedo, specular=self.specular.draw(u[2]),
                            exponent=self.exponent.draw_log(u[3]))
        if kind == "retroreflective":
            return Material(kind=kind, albedo=albedo, specular=self.specular.draw(u[2]),
                            lobe_width=self.lobe_width.draw_log(u[3]))
        if kind == "sin_theta":
            return Material(kind=kind, albedo=albedo, axis=self.axis)
        return Material(kind=kind, albedo=albedo)


class MaterialsDist(Model):
    relay_wall: MaterialDist = MaterialDist()
    wall: MaterialDist = MaterialDist()
    floor: MaterialDist = MaterialDist()
    ceiling: MaterialDist = MaterialDist()
    pillar: MaterialDist = MaterialDist()
    box: MaterialDist = MaterialDist()
    mesh: MaterialDist = MaterialDist()


class MotionDist(Model):
    """People walking across the hidden room during a capture sequence (docs/motion.md): ``walkers`` person-sized
    boxes (``size``: x along the way they walk, y across, z tall, m) or, with ``shape: person``, standing figures of
    :func:`~datagen.scene.builders.person` (``size.z`` their height, their width and depth its proportions), each walking a straight line between two
    points drawn uniformly on the L-bend room's floor (inset by the walker's half-diagonal, so that it never leaves
    the room) at ``speed`` m/s, back and forth until the sequence ends; ``frames``: the capture's frames
    (:class:`~datagen.scene.motion.FrameSpec`: count, rate, exposure); ``change_split``: each frame's change is
    simulated with 1/N of the sampling. Drawn from the sample's "motion" stream."""

    walkers: CountRange = CountRange()
    shape: Literal["box", "person"] = "box"
    size: Size3 = Size3(x=Range(min=0.25, max=0.35), y=Range(min=0.4, max=0.5), z=Range(min=1.6, max=1.9))
    speed: Positive = Range(min=0.5, max=2.0)
    frames: FrameSpec | None = None
    change_split: int = Field(128, ge=1, le=4096, description="a frame's change takes 1/N of the sampling "
                              "(datagen.simulation.sequence.simulate_sequence)")

    @model_validator(mode="after")
    def _frames(self) -> "MotionDist":
        if self.walkers.max > 0 and self.frames is None:
            raise ValueError("walkers need frames (count, rate, exposure): a sequence to walk in")
        return self


class LabelRegion(Model):
    """Axis-aligned box (origin = min corner, size) in metres, e.g. for the occupancy grid."""

    origin: tuple[float, float, float]
    size: tuple[float, float, float]

    @field_validator("size")
    @classmethod
    def _positive(cls, v: tuple) -> tuple:
        if min(v) <= 0:
            raise ValueError(f"sizes must be > 0, got {list(v)}")
        return v


class RoomDistribution(Model):
    """Distribution over procedural L-bend rooms (see module docstring and docs/rooms.md).

    Fields: ``family`` ("l_room": the corridor and its L-bend room; "wall": the relay wall alone, the corridor
    end's w × ceiling rectangle, with hidden objects in front of it and nothing else, the set-up of LFE and
    NLOST's training data), ``relay_x`` (m, the relay wall plane), ``corridor``, ``room``, ``ceiling`` (height
    range, m), ``capture``, ``objects``, ``materials``, ``motion`` (:class:`MotionDist`: walkers and frames),
    ``label_region`` (fixed occupancy-grid box; ``null``: the
    hull of every room the distribution can make, see :meth:`label_box`) and ``simulation`` (passed to
    :class:`~datagen.scene.Scene` ``defaults``, i.e. a scene file's simulation block).
    """

    name: str = "rooms"
    family: Literal["l_room", "wall"] = "l_room"
    relay_x: float = 6.0
    corridor: CorridorDist = CorridorDist()
    room: RoomDist = RoomDist()
    ceiling: Positive = Range(min=2.85, max=2.85)
    capture: CaptureDist = CaptureDist()
    objects: ObjectsDist = ObjectsDist()
    materials: MaterialsDist = MaterialsDist()
    label_region: LabelRegion | None = None
    motion: MotionDist = MotionDist()
    simulation: dict = {}
    source: str | None = Field(None, exclude=True, description="file it was loaded from (error messages)")

    def with_overrides(self, overrides: dict) -> "RoomDistribution":
        """A copy with ``overrides`` deep-merged in, re-validated and re-checked for feasibility.

        Nested dicts merge key by key, except a ``kinds`` mixture, which is replaced whole (absent kinds
        weigh 0): ``{"materials": {"box": {"kinds": {"phong": 1.0}}}}`` makes every box Phong.

        Raises:
            ConfigError: unknown field or invalid value, naming the dotted field (source "overrides").
        """
        if not isinstance(overrides, dict):
            raise ConfigError(f"overrides: expected a mapping, got {type(overrides).__name__}")
        data = _deep_merge(self.model_dump(mode="json"), overrides)
        where = f"{self.source} + overrides" if self.source else "overrides"
        return load_room_distribution(data, _source=where)

    def label_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Fixed label region (origin (3,), size (3,) float64 m) shared by every sample.

        ``label_region`` when given, else the hull of every placement region the distribution can make:
        x from the relay wall back to the deepest room or corridor-end region, y over both sides the
        room can bend to (corridor half-width + room length), z from the floor to the highest ceiling.
        """
        if self.label_region is not None:
            return np.array(self.label_region.origin, float), np.array(self.label_region.size, float)
        depth = self.room.depth.max if self.family == "l_room" else 0.0
        for cls in (self.objects.box, self.objects.pillar, self.objects.mesh):
            if cls.count.max > 0 and cls.placement.corridor_end.weight > 0:
                depth = max(depth, cls.placement.corridor_end.depth)
        reach = self.corridor.width.max / 2 + (self.room.length.max if self.family == "l_room" else 0.0)
        y_lo = -reach if -1 in self.room.bend_side else -self.corridor.width.max / 2
        y_hi = reach if 1 in self.room.bend_side else self.corridor.width.max / 2
        origin = np.array([self.relay_x - depth, y_lo, 0.0])
        size = np.array([depth, y_hi - y_lo, self.ceiling.max])
        return origin, size


def _deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and key != "kinds":
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def resolve_room_assets(data: dict, base: Path | None, where: str) -> dict:
    """A copy of a room mapping with ``objects.mesh.assets`` resolved to absolute paths (relative entries:
    against ``base``, the room file's folder, then the working directory); other content unchanged.

    Raises:
        ConfigError: an asset folder or file that exists nowhere (naming it and ``where``).
    """
    mesh = ((data.get("objects") or {}) if isinstance(data, dict) else {}).get("mesh")
    if not isinstance(mesh, dict) or not isinstance(mesh.get("assets"), (list, str)):
        return data
    entries = [mesh["assets"]] if isinstance(mesh["assets"], str) else list(mesh["assets"])
    if not all(isinstance(e, str) for e in entries):
        return data      # the schema reports the bad entry
    out = copy.deepcopy(data)
    out["objects"]["mesh"]["assets"] = resolve_assets(entries, base, f"{where}: objects.mesh.assets")
    return out


def without_meshes(room: dict) -> dict:
    """A copy of a room mapping (or of room overrides) without ``objects.mesh``: the room as reading a dataset store
    needs it, with no mesh asset file to find (:meth:`~datagen.dataset.config.DatasetConfig.room_distribution`)."""
    room = copy.deepcopy(room)
    if isinstance(room.get("objects"), dict):
        room["objects"].pop("mesh", None)
    return room


def load_room_distribution(source: str | Path | dict, _source: str | None = None,
                           base_dir: str | Path | None = None) -> RoomDistribution:
    """Load, validate and feasibility-check a room distribution from a YAML file or a parsed dict.

    Mesh asset folders (``objects.mesh.assets``) are resolved against the file's folder (``base_dir`` for a
    dict), then the working directory, and stored as absolute paths.

    Raises:
        ConfigError: missing file, bad YAML, or an invalid/infeasible value; the message names the file,
            the dotted field and the value (e.g. ``configs/rooms/x.yaml: corridor.width: min (3.0) must be
            <= max (2.0)``).
    """
    if isinstance(source, dict):
        data, where = source, _source or "room distribution"
        base = Path(base_dir) if base_dir is not None else None
    else:
        path = Path(source)
        data = read_yaml(path, "room distribution file", ConfigError)
        where, base = str(path), path.parent
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a mapping at the top level, got {type(data).__name__}")
    data = resolve_room_assets({k: v for k, v in data.items() if k != "source"}, base, where)
    try:
        dist = RoomDistribution.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, where)) from None
    dist = dist.model_copy(update={"source": where})
    check_feasible(dist)
    return dist


def _fail(dist: RoomDistribution, field: str, message: str) -> None:
    raise ConfigError(f"{dist.source or 'room distribution'}: {field}: {message}")


def _min_footprint(sx: float, sy: float, yaw: Range) -> tuple[float, float]:
    """Smallest axis-aligned extents (x, y) of an sx×sy footprint over yaws in ``yaw`` (37-point scan)."""
    angles = np.deg2rad(np.linspace(yaw.min, yaw.max, 37))
    c, s = np.abs(np.cos(angles)), np.abs(np.sin(angles))
    ex, ey = c * sx + s * sy, s * sx + c * sy
    best = int(np.argmin(np.maximum(ex, ey)))
    return float(ex[best]), float(ey[best])


def check_feasible(dist: RoomDistribution) -> None:
    """Check up front that every room the distribution can make can hold its objects and capture.

    Checks (with the smallest room, the largest objects): the corridor is longer than the room is deep (L-rooms);
    spot, FoV or scan grids and emitter/sensor fit the corridor end and under the lowest ceiling; each object
    class can be placed (some region with weight > 0 fits its largest footprint at the best yaw and its height
    under the ceiling; a mesh's footprint is its largest size squared; the wall family has no L-room region); the
    maximum object count's inflated footprints cover at most ``PACKING_LIMIT`` of the regions they may use; mesh
    asset entries hold at least one mesh file.

    Raises:
        ConfigError: naming the field, the value and the limit it breaks.
    """
    c, r, cap, obj = dist.corridor, dist.room, dist.capture, dist.objects
    m, gap = cap.edge_margin, obj.min_gap
    if dist.family == "l_room" and r.depth.max >= c.length.min:
        _fail(dist, "room.depth.max", f"{r.depth.max} m must be < corridor.length.min ({c.length.min} m): the "
              "room opens off the corridor's last room.depth metres")
    h_min, w_min = dist.ceiling.min, c.width.min
    for name, point in (("capture.emitter", cap.emitter), ("capture.sensor", cap.sensor)):
        if point is not None and point.height.max > h_min - m:
            _fail(dist, f"{name}.height.max", f"{point.height.max} m is above the lowest ceiling "
                  f"({h_min} m) minus capture.edge_margin ({m} m)")
    if w_min / 2 - m <= 0:
        _fail(dist, "capture.edge_margin", f"{m} m leaves no room in the narrowest corridor ({w_min} m)")
    if cap.scan is not None:
        for field, problem in scan_fits(cap.scan, w_min, h_min, m):
            _fail(dist, field, problem)
    else:
        if cap.spot.height.min < m or cap.spot.height.max > h_min - m:
            _fail(dist, "capture.spot.height", f"[{cap.spot.height.min}, {cap.spot.height.max}] m must lie within "
                  f"[{m}, {h_min - m}] m (edge margin to the lowest ceiling {h_min} m)")
        if cap.fov.width.max > w_min - 2 * m:
            _fail(dist, "capture.fov.width.max", f"{cap.fov.width.max} m does not fit the narrowest corridor end "
                  f"({w_min} m minus 2 × edge_margin {m} m)")
        if cap.fov.height.max > h_min - 2 * m:
            _fail(dist, "capture.fov.height.max", f"{cap.fov.height.max} m does not fit under the lowest ceiling "
                  f"({h_min} m minus 2 × edge_margin {m} m)")
    walk = dist.motion
    if walk.walkers.max > 0:
        if dist.family == "wall":
            _fail(dist, "motion.walkers", "the wall family has no L-bend room to walk in")
        reach = 2 * math.hypot(walk.size.x.max, walk.size.y.max) / 2
        if reach >= min(r.depth.min, r.length.min):
            _fail(dist, "motion.size", f"a walker {reach:.3g} m across (any way it turns) does not fit the smallest "
                  f"room ({r.depth.min} × {r.length.min} m)")
        if walk.size.z.max > h_min:
            _fail(dist, "motion.size.z.max", f"{walk.size.z.max} m is above the lowest ceiling ({h_min} m)")
    if obj.mesh.count.max > 0:
        try:
            asset_files(tuple(obj.mesh.assets))
        except ConfigError as exc:
            _fail(dist, "objects.mesh.assets", str(exc).removeprefix("objects.mesh.assets: "))
    region_area, need = {}, {}
    for cls_name in ("pillar", "box", "mesh"):
        cls = getattr(obj, cls_name)
        if cls.count.max == 0:
            continue
        if cls_name == "mesh":
            sx = sy = sz = cls.size.max
        else:
            sx, sy = cls.size.x.max, (cls.size.x.max if cls.cube else cls.size.y.max)
            sz = cls.size.x.max if cls.cube else cls.size.z.max
        ex, ey = _min_footprint(sx, sy, cls.yaw_deg)
        field = f"objects.{cls_name}"
        for reg_name, reg in cls.placement.regions():
            if reg_name == "room":
                if dist.family == "wall":
                    _fail(dist, f"{field}.placement.room.weight", f"{reg.weight}: the wall family has no L-bend "
                          "room; place objects in corridor_end (in front of the relay wall) only")
                dims = (r.depth.min, r.length.min)
            else:
                dims = (min(reg.depth, c.length.min) - reg.min_depth, w_min)
            if cls_name != "pillar":
                top = reg.elevation.max + sz
                if top > h_min - gap:
                    _fail(dist, f"{field}.placement.{reg_name}.elevation.max",
                          f"a {cls_name} up to {top:.3g} m tall (elevation.max + size) does not fit under the "
                          f"lowest ceiling ({h_min} m) minus objects.min_gap ({gap} m)")
            if ex + 2 * gap > dims[0] or ey + 2 * gap > dims[1]:
                where = ("room.depth.min × room.length.min" if reg_name == "room"
                         else f"{field}.placement.corridor_end.depth − min_depth × corridor.width.min")
                _fail(dist, f"{field}.size", f"the largest {cls_name} footprint ({sx} × {sy} m, best yaw: "
                      f"{ex:.3g} × {ey:.3g} m, + 2 × min_gap {gap} m) does not fit the smallest {reg_name} "
                      f"region ({where} = {dims[0]:.3g} × {dims[1]:.3g} m)")
            region_area[reg_name] = dims[0] * dims[1]
        need[cls_name] = cls.count.max * (sx + gap) * (sy + gap)
    if need:
        area = sum(region_area.values())
        total = sum(need.values())
        if total > PACKING_LIMIT * area:
            _fail(dist, "objects", f"room too small: up to {obj.pillar.count.max} pillars, {obj.box.count.max} "
                  f"boxes and {obj.mesh.count.max} meshes need {total:.3g} m² of floor (largest sizes + min_gap), "
                  f"more than {PACKING_LIMIT:.0%} of the {area:.3g} m² the smallest room offers; lower "
                  "objects.*.count.max or sizes, or enlarge room.depth.min / room.length.min")
