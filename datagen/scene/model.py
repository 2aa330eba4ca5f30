"""Scene model: the :class:`Scene` every stage reads — labelled meshes, the laser, the sensor, the capture.

World frame right-handed, z up, metres (docs/physics.md §1). A scene is a list of
:class:`~datagen.scene.parts.SceneObject` (a mesh with a unique ``name``, a semantic ``label`` — wall, floor,
ceiling, relay_wall, pillar, box, mesh… — and a :class:`~datagen.scene.materials.Material`), a
:class:`~datagen.scene.parts.Laser` (emitter position and laser spot on the relay wall), a
:class:`~datagen.scene.parts.Sensor` (position, collection aperture, field of view on the relay wall) and an
optional :class:`~datagen.scene.parts.CaptureSpec`. Construction checks the scene and resolves coincident faces
(:mod:`datagen.scene.coincident`).

Scenes load from YAML with :func:`datagen.scene.load.load_scene` or are built in Python from the builder
functions of :mod:`datagen.scene.builders`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from .coincident import resolve_coincident_faces
from .materials import MaterialTable
from .parts import ROOM_LABELS, CaptureSpec, Laser, SceneError, SceneObject, Sensor


@dataclass
class Scene:
    """A complete scene.

    Attributes:
        objects: the meshes; object ids index this list.
        laser, sensor: the capture geometry.
        name: scene name; ``source``: file it came from (or None).
        defaults: the YAML's ``simulation`` block (time axis, IRF, detector…), merged under CLI options.
        notes: what construction changed (duplicate faces removed, see
            :func:`datagen.scene.coincident.resolve_coincident_faces`) and objects of zero area.
        summed_primary: one primary component, "primary", for every object (:meth:`component_names`) instead of
            the room and each hidden object (set by :meth:`with_summed_primary`).

    Raises:
        SceneError: repeated object names (ignoring case), no objects, no FoV, or coincident faces with different materials
            (:func:`datagen.scene.coincident.resolve_coincident_faces`).
    """

    objects: list[SceneObject]
    laser: Laser
    sensor: Sensor
    name: str = "scene"
    source: str | None = None
    defaults: dict = field(default_factory=dict)
    capture: CaptureSpec | None = None
    summed_primary: bool = False
    notes: list[str] = field(default_factory=list, init=False)

    def __post_init__(self):
        names = [o.name.lower() for o in self.objects]   # case-insensitive: component files on macOS/Windows
        dup = {o.name for o in self.objects if names.count(o.name.lower()) > 1}
        if dup:
            raise SceneError(f"{self._where()}object names must be unique (ignoring case); repeated: {sorted(dup)}")
        if not self.objects:
            raise SceneError(f"{self._where()}a scene needs at least one object")
        cap = self.capture
        needs_fov = cap is None or (cap.type == "single" and cap.sensor_grid is None) or (
            cap.type == "exhaustive" and cap.sensor_grid is None)
        if needs_fov and self.sensor.fov is None:
            raise SceneError(f"{self._where()}sensor.fov is required unless capture gives a sensor_grid "
                             f"(or is confocal)")
        self.objects, self.notes = resolve_coincident_faces(self.objects, self.laser, self.sensor, self._where())
        for o in self.objects:
            tri = o.vertices[o.faces]
            if not np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).any():
                self.notes.append(f"object {o.name!r} has zero area (every triangle degenerate): it reflects no "
                                  "light and its component is zero")

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
        """Primary components: 'room' (walls/floor/ceiling/relay wall) then each other object by name; only
        'primary' when :attr:`summed_primary`."""
        if self.summed_primary:
            return ["primary"]
        return ["room"] + [o.name for o in self.objects if o.label not in ROOM_LABELS]

    def object_component(self) -> np.ndarray:
        """(n_objects,) int64: the primary component index of each object (see :meth:`component_names`)."""
        if self.summed_primary:
            return np.zeros(len(self.objects), dtype=np.int64)
        names = self.component_names()
        return np.array([0 if o.label in ROOM_LABELS else names.index(o.name) for o in self.objects])

    def with_summed_primary(self) -> "Scene":
        """This scene with one primary component (:attr:`summed_primary`): a shallow copy sharing the objects,
        capture and notes (construction's checks are not repeated)."""
        out = copy.copy(self)
        out.summed_primary = True
        return out

    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounding box of all objects and the laser/sensor positions."""
        pts = np.concatenate([self.vertices, [self.laser.emitter, self.laser.spot, self.sensor.position]])
        return np.stack([pts.min(axis=0), pts.max(axis=0)])
