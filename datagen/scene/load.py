"""Scene files: the YAML schema of a scene and its loading into a :class:`~datagen.scene.model.Scene`.

:func:`load_scene` reads a scene YAML (see scene_library/demo_room.yaml), validates it with pydantic
(:class:`SceneFile`; an error names the file, the field and the value, :func:`format_validation_error`) and
builds its objects with the builders of :mod:`datagen.scene.builders` (one spec per ``builder``: l_room,
pillar, box, quad, mesh). :func:`read_yaml` / :func:`parse_yaml` are the shared, bounded readers of YAML inputs
(scene files, room distributions, dataset configs, detector presets, tal configs): size and alias expansion are
capped so a hostile file fails in one short line instead of filling memory; :func:`check_output_dir` refuses an
output directory that cannot be created before any work.
"""
from __future__ import annotations

import os
import reprlib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import DatagenError
from .builders import box, import_mesh, l_room, pillar, quad
from .materials import Material
from .model import Scene
from .parts import MAX_EXTENT, CaptureSpec, Laser, SceneError, SceneObject, Sensor, Vec3


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")


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


MAX_SHOWN = 80
"""Characters of an offending value an error message shows (a 1e6-element list stays one short line)."""

MAX_PROBLEMS = 5
"""Validation problems listed in one error message (the count of the others follows)."""


def short_repr(value: Any, limit: int = MAX_SHOWN) -> str:
    """``repr(value)`` cut to ``limit`` characters (``…`` marks a cut), on one line."""
    shorter = reprlib.Repr()
    shorter.maxlist = shorter.maxtuple = shorter.maxdict = 8
    shorter.maxstring = shorter.maxother = limit
    text = " ".join(shorter.repr(value).split())
    return text if len(text) <= limit else text[:limit - 1] + "…"


def format_validation_error(exc: ValidationError, source: str | None = None, head: str | None = None) -> str:
    """One line: ``file: head.field.path: message (got value)`` per problem (at most :data:`MAX_PROBLEMS`,
    values cut by :func:`short_repr`), joined by "; "."""
    lines = []
    errors = exc.errors()
    for err in errors[:MAX_PROBLEMS]:
        loc = ".".join(([head] if head else []) + [str(p) for p in err["loc"]])
        value = err.get("input")
        shown = "" if isinstance(value, dict) else f" (got {short_repr(value)})"
        msg = " ".join(str(err["msg"]).split()).removeprefix("Value error, ")[:300]
        lines.append(f"{source + ': ' if source else ''}{loc + ': ' if loc else ''}{msg}{shown}")
    if len(errors) > MAX_PROBLEMS:
        lines.append(f"and {len(errors) - MAX_PROBLEMS} more problem(s)")
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
    if "multizone" in data:
        raise SceneError(f"{source or 'scene'}: this is a multi-zone scene (it has a multizone block): simulate it "
                         "with `datagen simulate SCENE.yaml --out DIR`, or load it with "
                         "datagen.scene.flood.load_multizone_scene (docs/multizone.md)")
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


MAX_YAML_BYTES = 8 << 20
"""Largest YAML input read, bytes (8 MiB): scenes, configs and presets are a few kB; meshes live in their own
files."""

MAX_YAML_VALUES = 1_000_000
"""Largest number of values a YAML document may expand to, an alias counting its anchor's values again at
every use: bounds the memory and time an alias bomb ("billion laughs") can take; real inputs hold hundreds."""


def read_yaml(path: Path, what: str, error: type[DatagenError] = SceneError) -> Any:
    """Parsed content of the YAML file ``path`` (a ``what``: "scene file", "tal config", ...), bounded in size
    (:data:`MAX_YAML_BYTES`) and in alias expansion (:data:`MAX_YAML_VALUES`). ``error`` is the class raised: a
    scene's :class:`SceneError`, a config reader's :class:`~datagen.errors.ConfigError` (docs/reliability.md).

    Raises:
        ``error`` (SceneError by default): the file does not exist ("<what> not found: <path>"), is too large,
            is not UTF-8 text, is not valid YAML or expands beyond the bound (each names the file, in one line).
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} not found: {path}")
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise error(f"{path}: {size} bytes is too large for a {what} (at most {MAX_YAML_BYTES} bytes)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file (byte {exc.start}): is it really a {what}?") from None
    return parse_yaml(text, str(path), error)


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A YAML mapping holds the same key twice (raised by :class:`UniqueKeyLoader`)."""


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that holds the same key twice at any depth (plain PyYAML keeps
    the last one silently: a second top-level ``simulation:`` would replace the first). Keys merged in by
    ``<<: *anchor`` may be overridden, as YAML's merge key intends; only keys written in the mapping itself
    count."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:   # an unhashable key: the base class reports it
                    continue
                if first is not key_node:
                    raise DuplicateKeyError(
                        None, None, f"duplicate key {short_repr(key)} on lines {first.start_mark.line + 1} "
                        f"and {key_node.start_mark.line + 1} (the second would silently replace the first)")
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, source: str, error: type[DatagenError] = SceneError) -> Any:
    """Parse YAML ``text`` with :class:`UniqueKeyLoader` (the safe loader, refusing duplicate keys), then refuse
    documents that expand to more than :data:`MAX_YAML_VALUES` values (aliases counted at every use, recursive
    aliases included). ``error`` is the class raised (as in :func:`read_yaml`).

    Raises:
        ``error`` (SceneError by default): invalid YAML, a key repeated in one mapping ("<source>: duplicate
            key 'simulation' on lines 12 and 30 ...") or too large an expansion; one short line naming ``source``.
    """
    if len(text) > MAX_YAML_BYTES:
        raise error(f"{source}: {len(text)} characters is too large (at most {MAX_YAML_BYTES})")
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)   # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise error(f"{source}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise error(f"{source}: not valid YAML: {' '.join(str(exc).split())[:300]}") from None
    except RecursionError:
        raise error(f"{source}: YAML nested too deeply") from None
    count, stack = 0, [data]
    while stack:
        value = stack.pop()
        count += 1
        if count > MAX_YAML_VALUES:
            raise error(f"{source}: the YAML expands to more than {MAX_YAML_VALUES} values (its aliases "
                        "repeat their anchors' content): not a datagen input")
        if isinstance(value, dict):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, (list, tuple)):
            stack.extend(value)
    return data


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
