"""Scene files: the YAML schema of a scene and its loading into a :class:`~datagen.scene.model.Scene`.

:func:`load_scene` reads a scene YAML (see scene_library/demo_room.yaml), validates it with pydantic
(:class:`SceneFile`; an error names the file, the field and the value, :func:`format_validation_error`) and
builds its objects with the builders of :mod:`datagen.scene.builders` (one spec per ``builder``: l_room,
pillar, box, person, quad, mesh, mask). :func:`read_yaml` / :func:`parse_yaml` are the shared, bounded readers of YAML inputs
(scene files, room distributions, dataset configs, detector presets, tal configs): size and alias expansion are
capped so a hostile file fails in one short line instead of filling memory; :func:`check_output_dir` refuses an
output directory that cannot be created before any work.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import DatagenError
from .yamlfile import (MAX_PROBLEMS, MAX_SHOWN, MAX_YAML_BYTES, MAX_YAML_VALUES, DuplicateKeyError,  # noqa: F401
                       UniqueKeyLoader, format_validation_error, parse_yaml, read_yaml, short_repr)
from .builders import box, import_mesh, l_room, mask_cutout, person, pillar, quad
from .materials import Material
from .model import Moving, Scene
from .motion import Motion
from .parts import MAX_EXTENT, CaptureSpec, Laser, SceneError, SceneObject, Sensor, Vec3


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")


class _Movable(_Spec):
    """A hidden object's spec: it may move (``motion``, :mod:`datagen.scene.motion`)."""

    motion: Motion | None = None


class LRoomSpec(_Spec):
    builder: Literal["l_room"]
    relay_x: float = Field(6.0, ge=-MAX_EXTENT, le=MAX_EXTENT)
    corridor_start: float = Field(-2.0, ge=-MAX_EXTENT, le=MAX_EXTENT)
    corridor_width: float = Field(2.1, gt=0, le=MAX_EXTENT)
    room_depth: float = Field(3.0, gt=0, le=MAX_EXTENT)
    room_length: float = Field(4.0, gt=0, le=MAX_EXTENT)
    height: float = Field(3.0, gt=0, le=MAX_EXTENT)
    bend_side: Literal[1, -1] = 1
    closed_corridor_end: bool = False
    materials: dict[Literal["wall", "floor", "ceiling", "relay_wall"], Material] = {}

    def build(self) -> list[SceneObject]:
        kwargs = self.model_dump(exclude={"builder", "materials"})
        return l_room(**kwargs, materials=dict(self.materials))


class PillarSpec(_Movable):
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


class BoxSpec(_Movable):
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


class PersonSpec(_Movable):
    """A standing person (:func:`~datagen.scene.builders.person`): feet at ``center`` (x, y) on the floor."""

    builder: Literal["person"]
    name: str = "person"
    label: str = "person"
    center: tuple[float, float]
    height: float = Field(1.75, gt=0, le=3.0)
    rotation_deg: float = 0.0
    material: Material = Material()

    def build(self) -> list[SceneObject]:
        return [person(self.name, self.center, self.height, self.rotation_deg, self.material, self.label)]


class QuadSpec(_Movable):
    builder: Literal["quad"]
    name: str
    label: str = "mesh"
    corner: Vec3
    edge_u: Vec3
    edge_v: Vec3
    material: Material = Material()

    def build(self) -> list[SceneObject]:
        return [quad(self.name, self.corner, self.edge_u, self.edge_v, self.material, self.label)]


class MeshSpec(_Movable):
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


class MaskSpec(_Movable):
    """A planar cut-out drawn as text (:func:`~datagen.scene.builders.mask_cutout`): ``rows`` top first, "#" filled,
    "." empty, cells of side ``pitch`` m centred on ``center``, columns along ``u`` and rows up ``v``."""

    builder: Literal["mask"]
    name: str
    label: str = "mesh"
    rows: list[str] = Field(min_length=1, max_length=4096)
    pitch: float = Field(gt=0, le=MAX_EXTENT)
    center: Vec3
    u: Vec3 = (1.0, 0.0, 0.0)
    v: Vec3 = (0.0, 0.0, 1.0)
    material: Material = Material()

    def build(self) -> list[SceneObject]:
        return [mask_cutout(self.name, self.rows, self.pitch, self.center, self.u, self.v, self.material, self.label)]


ObjectSpec = Annotated[Union[LRoomSpec, PillarSpec, BoxSpec, PersonSpec, QuadSpec, MeshSpec, MaskSpec],
                       Field(discriminator="builder")]


class SceneFile(_Spec):
    """Schema of a scene YAML file (see scene_library/demo_room.yaml)."""

    name: str = "scene"
    objects: list[ObjectSpec]
    laser: Laser
    sensor: Sensor
    capture: CaptureSpec | None = None
    simulation: dict = {}


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
    if "multizone" in data:
        raise SceneError(f"{source or 'scene'}: this is a multi-zone scene (it has a multizone block): simulate it "
                         "with `datagen simulate SCENE.yaml --out DIR`, or load it with "
                         "datagen.scene.flood.load_multizone_scene (docs/multizone.md)")
    try:
        spec = SceneFile.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, source)) from None
    objects: list[SceneObject] = []
    moving: dict[str, Moving] = {}
    for i, obj in enumerate(spec.objects):
        try:
            built = obj.build(base) if isinstance(obj, MeshSpec) else obj.build()
        except SceneError as exc:
            raise SceneError(f"{source + ': ' if source else ''}objects.{i}: {exc}") from None
        objects.extend(built)
        if getattr(obj, "motion", None) is not None:
            moving[built[0].name] = Moving(obj.motion, built[0].vertices, f"objects.{i}.motion")
    scene = Scene(objects, spec.laser, spec.sensor, spec.name, source, spec.simulation, spec.capture)
    return scene.with_motion(moving) if moving else scene


def load_scene(path: str | Path) -> Scene:
    """Load and validate a scene YAML file.

    Raises:
        SceneError: missing file, YAML syntax error, or invalid content (message names file, field, value).
    """
    path = Path(path)
    return scene_from_dict(read_yaml(path, "scene file"), str(path), path.parent)


def check_output_dir(path: str | Path, option: str = "--out") -> None:
    """Refuse, before any work, an output directory that is a file, lies under a file, or whose nearest
    existing parent is not writable (shared by ``simulate --out`` and dataset builds).

    Raises:
        FileExistsError / PermissionError: naming ``option`` and the path.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{option} {path} is a file, not a directory: choose another {option}")
    parent = path
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise FileExistsError(f"{option} {path}: cannot create it, {parent} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"{option} {path}: {parent} is not writable")
