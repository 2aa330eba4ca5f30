"""Scene model: labelled triangle meshes with materials, the laser and the sensor; YAML loading; builders.

World frame right-handed, z up, metres (DESIGN.md §1). A scene is a list of :class:`SceneObject` (a mesh with
a semantic ``label`` — wall, floor, ceiling, relay_wall, pillar, box, mesh… — an ``instance_id`` and a
:class:`~datagen.brdf.Material`), a :class:`Laser` (emitter position and laser spot on the relay wall) and a
:class:`Sensor` (position, collection aperture, field of view on the relay wall).

Scenes load from YAML with :func:`load_scene` (validated by pydantic; an error names the file, the field and
the value) or are built in Python from the builder functions :func:`l_room`, :func:`pillar`, :func:`box`,
:func:`quad` and :func:`import_mesh`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .brdf import Material, MaterialTable
from .units import parse_energy, parse_length, photons_per_pulse

ROOM_LABELS = ("wall", "floor", "ceiling", "relay_wall")
"""Labels of the extended surfaces; lookins on them form the paper's 'walls, roof and floor' component."""

Vec3 = tuple[float, float, float]


class SceneError(ValueError):
    """A scene is invalid; the message names the file (when there is one), the field and the value."""


def check_finite(v: Vec3) -> Vec3:
    """Pydantic validator body: every coordinate finite (names no field; pydantic adds it)."""
    if not np.all(np.isfinite(v)):
        raise ValueError(f"must be finite, got {list(v)}")
    return v


def check_counts(v: tuple[int, int], what: str) -> tuple[int, int]:
    """Pydantic validator body: both grid counts >= 1 (``what`` names them in the message)."""
    if min(v) < 1:
        raise ValueError(f"{what} must be >= 1, got {list(v)}")
    return v


@dataclass(frozen=True)
class SceneObject:
    """One labelled mesh.

    Attributes:
        name: unique name, used for the object's envelope component.
        label: semantic class (wall, floor, ceiling, relay_wall, pillar, box, mesh, …).
        material: its BRDF and albedo.
        vertices: (V, 3) float64 metres.
        faces: (F, 3) int64 vertex indices.
    """

    name: str
    label: str
    material: Material
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if bad.size:
            raise SceneError(f"object {self.name!r}: vertex {bad[0]} is not finite: {vertices[bad[0]].tolist()}")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise SceneError(f"object {self.name!r}: face index out of range 0..{len(vertices) - 1}")
        if len(faces) == 0:
            raise SceneError(f"object {self.name!r} has no faces")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)


class Laser(BaseModel):
    """Pulsed laser: emitter position, laser spot on the relay wall, photons per pulse.

    Photons per pulse Φ come from ``photons_per_pulse`` directly or from ``pulse_energy`` (J, or "1nJ")
    and ``wavelength`` (m, or "532nm") as E·λ/(h·c).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    emitter: Vec3 = (0.0, 0.0, 1.0)
    spot: Vec3
    photons_per_pulse: float | None = Field(None, gt=0, allow_inf_nan=False)
    pulse_energy: float | None = Field(None, gt=0, allow_inf_nan=False)
    wavelength: float = Field(532e-9, gt=0)

    @field_validator("pulse_energy", mode="before")
    @classmethod
    def _energy(cls, v: Any) -> Any:
        return None if v is None else parse_energy(v)

    @field_validator("wavelength", mode="before")
    @classmethod
    def _wavelength(cls, v: Any) -> Any:
        return parse_length(v)

    @field_validator("emitter", "spot")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @model_validator(mode="after")
    def _one_source(self) -> "Laser":
        if self.photons_per_pulse is not None and self.pulse_energy is not None:
            raise ValueError("give photons_per_pulse or pulse_energy, not both")
        return self

    @property
    def photons(self) -> float:
        """Φ, photons per pulse (1.0 when neither photons_per_pulse nor pulse_energy is given)."""
        if self.photons_per_pulse is not None:
            return self.photons_per_pulse
        if self.pulse_energy is not None:
            return photons_per_pulse(self.pulse_energy, self.wavelength)
        return 1.0


class FieldOfView(BaseModel):
    """The rectangle of the relay wall the sensor images: centre, size (width, height) in metres.

    ``width`` runs along the wall's horizontal tangent (n × z normalised), ``height`` along the wall's
    in-plane up direction. ``pixels`` (nx, ny) splits it into a sensor array; (1, 1) is the paper's single
    pixel.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    center: Vec3
    size: tuple[float, float]
    pixels: tuple[int, int] = (1, 1)

    @field_validator("center")
    @classmethod
    def _finite_center(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @field_validator("size")
    @classmethod
    def _positive(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) > 0):
            raise ValueError(f"both sizes must be positive, got {list(v)}")
        return v

    @field_validator("pixels")
    @classmethod
    def _pixels(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "pixel counts")


class Sensor(BaseModel):
    """SPAD sensor: position, circular collection aperture (radius, m), field of view on the relay wall.

    The aperture faces the FoV centre; its area πr² enters the envelope (DESIGN.md §2, A_ap). ``fov`` may be
    omitted when the scene has a ``capture`` block with a sensor or laser grid.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: Vec3 = (0.0, 0.0, 1.0)
    aperture_radius: float = Field(0.02, gt=0)
    fov: FieldOfView | None = None

    @field_validator("aperture_radius", mode="before")
    @classmethod
    def _radius(cls, v: Any) -> Any:
        return parse_length(v)

    @field_validator("position")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @property
    def aperture_area(self) -> float:
        return float(np.pi * self.aperture_radius ** 2)


class WallGrid(BaseModel):
    """A grid of nx×ny points on the relay wall: cell centres of a w×h rectangle around ``center``.

    Point (iy, ix) sits at center + ((ix+½)/nx − ½)·w·u + ((iy+½)/ny − ½)·h·v with u the wall's horizontal
    tangent (n × z normalised) and v = u × n, as for :class:`FieldOfView`.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    center: Vec3
    size: tuple[float, float]
    points: tuple[int, int] = (1, 1)

    @field_validator("size")
    @classmethod
    def _nonnegative(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) >= 0):
            raise ValueError(f"both sizes must be >= 0, got {list(v)}")
        return v

    @field_validator("points")
    @classmethod
    def _points(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "point counts")


class CaptureSpec(BaseModel):
    """Scan pattern over the relay wall (the tal capture types) and the sensor convention.

    - ``single``: one laser spot (``laser.spot``) and a sensor grid (``sensor_grid``, or ``sensor.fov``).
    - ``confocal``: the laser visits each point of ``laser_grid`` and the sensor looks at that same point.
    - ``exhaustive``: every laser point of ``laser_grid`` × every sensor point of ``sensor_grid``.

    Conventions: ``aperture`` (default): each sensor point is the centre of a pixel region (cell of the grid)
    imaged through the aperture; the envelope is expected detected photons per pulse per bin (DESIGN.md §2).
    ``point_radiance`` (tal / mitransient): radiance leaving the wall point toward ``sensor.position`` per
    unit power delivered to the laser spot, per bin, in 1/(m²·sr); no PDE, aperture or sensor visibility.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: Literal["single", "confocal", "exhaustive"] = "single"
    convention: Literal["aperture", "point_radiance"] = "aperture"
    laser_grid: WallGrid | None = None
    sensor_grid: WallGrid | None = None

    @model_validator(mode="after")
    def _grids(self) -> "CaptureSpec":
        if self.type in ("confocal", "exhaustive") and self.laser_grid is None:
            raise ValueError(f"capture type {self.type!r} needs a laser_grid")
        if self.type == "confocal" and self.sensor_grid is not None:
            raise ValueError("confocal captures use laser_grid for the sensor points too; drop sensor_grid")
        if self.type == "single" and self.laser_grid is not None:
            raise ValueError("single captures use laser.spot; laser_grid needs type confocal or exhaustive")
        return self


@dataclass
class Scene:
    """A complete scene.

    Attributes:
        objects: the meshes; object ids index this list.
        laser, sensor: the capture geometry.
        name: scene name; ``source``: file it came from (or None).
        defaults: the YAML's ``simulation`` block (time axis, IRF, detector…), merged under CLI options.
        notes: what construction changed (duplicate faces removed, see :func:`datagen.coincident.resolve_coincident_faces`).

    Raises:
        SceneError: repeated object names, no objects, no FoV, or coincident faces with different materials
            (:func:`datagen.coincident.resolve_coincident_faces`).
    """

    objects: list[SceneObject]
    laser: Laser
    sensor: Sensor
    name: str = "scene"
    source: str | None = None
    defaults: dict = field(default_factory=dict)
    capture: CaptureSpec | None = None
    notes: list[str] = field(default_factory=list, init=False)

    def __post_init__(self):
        names = [o.name for o in self.objects]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise SceneError(f"{self._where()}object names must be unique; repeated: {sorted(dup)}")
        if not self.objects:
            raise SceneError(f"{self._where()}a scene needs at least one object")
        cap = self.capture
        needs_fov = cap is None or (cap.type == "single" and cap.sensor_grid is None) or (
            cap.type == "exhaustive" and cap.sensor_grid is None)
        if needs_fov and self.sensor.fov is None:
            raise SceneError(f"{self._where()}sensor.fov is required unless capture gives a sensor_grid "
                             f"(or is confocal)")
        from .coincident import resolve_coincident_faces       # imports this module's types
        self.objects, self.notes = resolve_coincident_faces(self.objects, self.laser, self.sensor, self._where())

    def _where(self) -> str:
        return f"{self.source}: " if self.source else ""

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) float64 vertices of all objects, concatenated."""
        return np.concatenate([o.vertices for o in self.objects])

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 faces of all objects, indexing :attr:`vertices`."""
        offsets = np.cumsum([0] + [len(o.vertices) for o in self.objects[:-1]])
        return np.concatenate([o.faces + off for o, off in zip(self.objects, offsets)])

    @property
    def face_object(self) -> np.ndarray:
        """(F,) int64 object id of every face."""
        return np.concatenate([np.full(len(o.faces), i, dtype=np.int64) for i, o in enumerate(self.objects)])

    @property
    def materials(self) -> MaterialTable:
        return MaterialTable([o.material for o in self.objects])

    @property
    def labels(self) -> list[str]:
        return [o.label for o in self.objects]

    def component_names(self) -> list[str]:
        """Primary components: 'room' (walls/floor/ceiling/relay wall) then each other object by name."""
        return ["room"] + [o.name for o in self.objects if o.label not in ROOM_LABELS]

    def object_component(self) -> np.ndarray:
        """(n_objects,) int64: the primary component index of each object (see :meth:`component_names`)."""
        names = self.component_names()
        return np.array([0 if o.label in ROOM_LABELS else names.index(o.name) for o in self.objects])

    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounding box of all objects and the laser/sensor positions."""
        pts = np.concatenate([self.vertices, [self.laser.emitter, self.laser.spot, self.sensor.position]])
        return np.stack([pts.min(axis=0), pts.max(axis=0)])


# ---------------------------------------------------------------------------------------------------------
# Builders. Each returns (vertices, faces); normals are not needed (the ray caster orients them).


def quad_mesh(corner: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rectangle (parallelogram) corner, corner+u, corner+u+v, corner+v as two triangles."""
    corner, edge_u, edge_v = (np.asarray(a, dtype=np.float64) for a in (corner, edge_u, edge_v))
    vertices = np.stack([corner, corner + edge_u, corner + edge_u + edge_v, corner + edge_v])
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _rotation_z(angle_deg: float) -> np.ndarray:
    a = np.deg2rad(angle_deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def box_mesh(center: Vec3, size: Vec3, rotation_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Closed cuboid (12 triangles) of ``size`` (dx, dy, dz) m centred at ``center``, rotated about z."""
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    vertices = corners * np.asarray(size, dtype=np.float64) @ _rotation_z(rotation_deg).T + np.asarray(center)
    # vertex index = 4*ix + 2*iy + iz
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return vertices, faces


def l_room(relay_x: float = 6.0, corridor_start: float = -2.0, corridor_width: float = 2.1,
           room_depth: float = 3.0, room_length: float = 4.0, height: float = 3.0,
           bend_side: Literal[1, -1] = 1, closed_corridor_end: bool = False,
           materials: dict[str, Material] | None = None) -> list[SceneObject]:
    """Corridor along +x ending at the relay wall (plane x = ``relay_x``, facing −x) with an L-bend room.

    The corridor spans x ∈ [corridor_start, relay_x], y ∈ [−w/2, w/2], z ∈ [0, height]. The room opens off
    the corridor's ``bend_side`` (+1: +y) over its last ``room_depth`` metres and extends ``room_length``
    metres sideways; it is hidden from the corridor. The relay wall spans the corridor end and the room's
    side. The corridor's far end is open unless ``closed_corridor_end`` (light escapes there).

    Returns objects labelled relay_wall, wall, floor and ceiling (materials per label, Lambertian ρ = 1 by
    default).
    """
    w, s = corridor_width, float(bend_side)
    if min(corridor_width, room_depth, room_length, height) <= 0 or relay_x - corridor_start <= room_depth:
        raise SceneError("l_room: widths, depth, length and height must be > 0 and the corridor longer than "
                         f"the room depth (corridor {relay_x - corridor_start} m, room_depth {room_depth} m)")
    mats = {label: Material() for label in ROOM_LABELS}
    mats.update(materials or {})
    y_in, y_far = -s * w / 2, s * (w / 2 + room_length)   # corridor's inner wall, room's far wall
    y_open = s * w / 2                                      # corridor wall on the bend side
    x_room = relay_x - room_depth
    ez = np.array([0.0, 0.0, height])

    def wall_x(x, y0, y1):
        return quad_mesh([x, y0, 0.0], [0.0, y1 - y0, 0.0], ez)

    def wall_y(y, x0, x1):
        return quad_mesh([x0, y, 0.0], [x1 - x0, 0.0, 0.0], ez)

    def slab(z, x0, x1, y0, y1):
        return quad_mesh([x0, y0, z], [x1 - x0, 0.0, 0.0], [0.0, y1 - y0, 0.0])

    walls = [wall_y(y_in, corridor_start, relay_x), wall_y(y_open, corridor_start, x_room),
             wall_x(x_room, y_open, y_far), wall_y(y_far, x_room, relay_x)]
    if closed_corridor_end:
        walls.append(wall_x(corridor_start, y_in, y_open))
    floor = [slab(0.0, corridor_start, relay_x, min(y_in, y_open), max(y_in, y_open)),
             slab(0.0, x_room, relay_x, min(y_open, y_far), max(y_open, y_far))]
    ceiling = [slab(height, corridor_start, relay_x, min(y_in, y_open), max(y_in, y_open)),
               slab(height, x_room, relay_x, min(y_open, y_far), max(y_open, y_far))]
    relay = wall_x(relay_x, y_in, y_far)
    return [SceneObject("relay_wall", "relay_wall", mats["relay_wall"], *relay),
            SceneObject("walls", "wall", mats["wall"], *_merge(walls)),
            SceneObject("floor", "floor", mats["floor"], *_merge(floor)),
            SceneObject("ceiling", "ceiling", mats["ceiling"], *_merge(ceiling))]


def pillar(name: str, center_xy: tuple[float, float], size_xy: tuple[float, float], height: float,
           rotation_deg: float = 0.0, material: Material | None = None, label: str = "pillar") -> SceneObject:
    """Floor-to-ceiling cuboid pillar with footprint ``size_xy`` at ``center_xy``, rotated about z."""
    v, f = box_mesh((center_xy[0], center_xy[1], height / 2), (size_xy[0], size_xy[1], height), rotation_deg)
    return SceneObject(name, label, material or Material(), v, f)


def box(name: str, center: Vec3, size: Vec3, rotation_deg: float = 0.0, material: Material | None = None,
        label: str = "box") -> SceneObject:
    """Cuboid box of ``size`` (dx, dy, dz) centred at ``center``, rotated about z."""
    return SceneObject(name, label, material or Material(), *box_mesh(center, size, rotation_deg))


def quad(name: str, corner: Vec3, edge_u: Vec3, edge_v: Vec3, material: Material | None = None,
         label: str = "mesh") -> SceneObject:
    """A single rectangle corner, corner+u, corner+u+v, corner+v (two triangles)."""
    return SceneObject(name, label, material or Material(), *quad_mesh(corner, edge_u, edge_v))


def import_mesh(name: str, path: str | Path, scale: float = 1.0, left_handed: bool = False,
                rotation_deg: float = 0.0, translate: Vec3 = (0.0, 0.0, 0.0), material: Material | None = None,
                label: str = "mesh") -> SceneObject:
    """Load OBJ/PLY/STL/GLB (anything trimesh reads) as one object.

    Coordinates are multiplied by ``scale`` (e.g. 0.01 for centimetres), then, if ``left_handed``, y is
    flipped (Unreal's left-handed x-forward/y-right/z-up frame → ours, DESIGN.md §1; face winding is reversed
    to keep orientation), then rotated about z and translated.

    Raises:
        SceneError: the file is missing or holds no triangles.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise SceneError(f"cannot read mesh {path}: {exc}") from exc
    vertices = np.asarray(loaded.vertices, dtype=np.float64) * scale
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if len(faces) == 0:
        raise SceneError(f"mesh {path} holds no triangles")
    if left_handed:
        vertices = vertices * np.array([1.0, -1.0, 1.0])
        faces = faces[:, ::-1]
    vertices = vertices @ _rotation_z(rotation_deg).T + np.asarray(translate, dtype=np.float64)
    return SceneObject(name, label, material or Material(), vertices, faces)


# ---------------------------------------------------------------------------------------------------------
# YAML schema


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")


class LRoomSpec(_Spec):
    builder: Literal["l_room"]
    relay_x: float = 6.0
    corridor_start: float = -2.0
    corridor_width: float = Field(2.1, gt=0)
    room_depth: float = Field(3.0, gt=0)
    room_length: float = Field(4.0, gt=0)
    height: float = Field(3.0, gt=0)
    bend_side: Literal[1, -1] = 1
    closed_corridor_end: bool = False
    materials: dict[Literal["wall", "floor", "ceiling", "relay_wall"], Material] = {}

    def build(self) -> list[SceneObject]:
        kwargs = self.model_dump(exclude={"builder", "materials"})
        return l_room(**kwargs, materials=dict(self.materials))


class PillarSpec(_Spec):
    builder: Literal["pillar"]
    name: str = "pillar"
    label: str = "pillar"
    center: tuple[float, float]
    size: tuple[float, float]
    height: float = Field(gt=0)
    rotation_deg: float = 0.0
    material: Material = Material()

    def build(self) -> list[SceneObject]:
        return [pillar(self.name, self.center, self.size, self.height, self.rotation_deg, self.material, self.label)]


class BoxSpec(_Spec):
    builder: Literal["box"]
    name: str = "box"
    label: str = "box"
    center: Vec3
    size: Vec3
    rotation_deg: float = 0.0
    material: Material = Material()

    @field_validator("size")
    @classmethod
    def _positive(cls, v: Vec3) -> Vec3:
        if min(v) <= 0:
            raise ValueError(f"box sizes must be > 0, got {list(v)}")
        return v

    def build(self) -> list[SceneObject]:
        return [box(self.name, self.center, self.size, self.rotation_deg, self.material, self.label)]


class QuadSpec(_Spec):
    builder: Literal["quad"]
    name: str
    label: str = "mesh"
    corner: Vec3
    edge_u: Vec3
    edge_v: Vec3
    material: Material = Material()

    def build(self) -> list[SceneObject]:
        return [quad(self.name, self.corner, self.edge_u, self.edge_v, self.material, self.label)]


class MeshSpec(_Spec):
    builder: Literal["mesh"]
    name: str
    label: str = "mesh"
    path: str
    scale: float = Field(1.0, gt=0)
    left_handed: bool = False
    rotation_deg: float = 0.0
    translate: Vec3 = (0.0, 0.0, 0.0)
    material: Material = Material()

    def build(self, base: Path | None = None) -> list[SceneObject]:
        path = Path(self.path)
        if base is not None and not path.is_absolute():
            path = base / path
        return [import_mesh(self.name, path, self.scale, self.left_handed, self.rotation_deg, self.translate,
                            self.material, self.label)]


ObjectSpec = Annotated[Union[LRoomSpec, PillarSpec, BoxSpec, QuadSpec, MeshSpec], Field(discriminator="builder")]


class SceneFile(_Spec):
    """Schema of a scene YAML file (see scene_library/demo_room.yaml)."""

    name: str = "scene"
    objects: list[ObjectSpec]
    laser: Laser
    sensor: Sensor
    capture: CaptureSpec | None = None
    simulation: dict = {}


def format_validation_error(exc: ValidationError, source: str | None = None) -> str:
    """One line per problem: ``file: field.path: message (got value)``."""
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"])
        value = err.get("input")
        shown = "" if isinstance(value, dict) else f" (got {value!r})"
        lines.append(f"{source + ': ' if source else ''}{loc}: {err['msg']}{shown}")
    return "; ".join(lines)


def scene_from_dict(data: dict, source: str | None = None, base: Path | None = None) -> Scene:
    """Build a :class:`Scene` from parsed YAML.

    Raises:
        SceneError: schema violations (naming file, field and value) and geometry errors.
    """
    if not isinstance(data, dict):
        raise SceneError(f"{source or 'scene'}: expected a mapping at the top level, got {type(data).__name__}")
    if "objects" not in data and {"geometry", "scan_type"} & set(data):
        raise SceneError(f"{source or 'scene'}: this is a tal render config (it has "
                         f"{', '.join(sorted({'geometry', 'scan_type'} & set(data)))}), not a datagen scene: "
                         "render it with `datagen tal-render CONFIG.yaml --out FILE.hdf5`")
    try:
        spec = SceneFile.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, source)) from None
    objects: list[SceneObject] = []
    for i, obj in enumerate(spec.objects):
        try:
            objects.extend(obj.build(base) if isinstance(obj, MeshSpec) else obj.build())
        except SceneError as exc:
            raise SceneError(f"{source + ': ' if source else ''}objects.{i}: {exc}") from None
    return Scene(objects, spec.laser, spec.sensor, spec.name, source, spec.simulation, spec.capture)


def load_scene(path: str | Path) -> Scene:
    """Load and validate a scene YAML file.

    Raises:
        SceneError: missing file, YAML syntax error, or invalid content (message names file, field, value).
    """
    path = Path(path)
    return scene_from_dict(read_yaml(path, "scene file"), str(path), path.parent)


def read_yaml(path: Path, what: str) -> Any:
    """Parsed content of the YAML file ``path`` (a ``what``: "scene file", "tal config", ...).

    Raises:
        SceneError: the file does not exist ("<what> not found: <path>") or is not valid YAML (names the file
            and the parser's message).
    """
    if not path.is_file():
        raise SceneError(f"{what} not found: {path}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f"{path}: not valid YAML: {exc}".replace("\n", " ")) from None
