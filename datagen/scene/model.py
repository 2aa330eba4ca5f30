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

from typing import Any

import numpy as np

from .coincident import resolve_coincident_faces
from .materials import MaterialTable
from .motion import posed_vertices
from .parts import ROOM_LABELS, CaptureSpec, Laser, SceneError, SceneObject, Sensor
from .static_faces import StaticFaces

ROOM_MARGIN = 1e-6
"""Metres a moving object may stand past the room's bounding box (its faces may touch the walls and floor)."""


ROOM_CHECK_CHUNK = 256
"""Instants whose posed vertices are checked against the room at once (bounds the (instants, V, 3) arrays)."""


@dataclass(frozen=True)
class Moving:
    """A moving object's motion (:mod:`datagen.scene.motion`), its vertices (V, 3) m as built, and the scene-file
    field that gave it (``objects.2.motion``, for errors)."""

    motion: Any
    vertices: np.ndarray
    field: str = "motion"


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
        moving: the moving objects by name (:class:`Moving`; set by :meth:`with_motion`); the objects stand at
            their pose at the sequence's start (:meth:`at` gives another instant).

    Raises:
        SceneError: repeated object names (ignoring case), no objects, no FoV, or coincident faces with different
            materials (:func:`datagen.scene.coincident.resolve_coincident_faces`).
    """

    objects: list[SceneObject]
    laser: Laser
    sensor: Sensor
    name: str = "scene"
    source: str | None = None
    defaults: dict = field(default_factory=dict)
    capture: CaptureSpec | None = None
    summed_primary: bool = False
    moving: dict[str, Moving] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list, init=False)
    _static: StaticFaces | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self._check()

    def _check(self, static: StaticFaces | None = None) -> None:
        """Construction's checks (class doc, Raises); ``static``: the coincident-face verdict on the objects that
        do not move, from an earlier instant (:meth:`at`)."""
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
        self.objects, self.notes = resolve_coincident_faces(self.objects, self.laser, self.sensor, self._where(),
                                                            static)
        tri = np.concatenate([o.vertices[o.faces] for o in self.objects])
        twice_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        starts = np.cumsum([0] + [len(o.faces) for o in self.objects[:-1]])
        for o, area in zip(self.objects, np.maximum.reduceat(twice_area, starts)):
            if not area > 0:
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

    # --- moving objects (docs/motion.md) ---------------------------------------------------------------------

    def with_motion(self, moving: dict[str, Moving]) -> "Scene":
        """This scene with the objects named in ``moving`` moving, posed at the sequence's start (``frames.start``
        of the capture, else 0 s).

        Raises:
            SceneError: a name that is no object of the scene, or a motion that takes an object out of the room
                (the bounding box of the walls, floor, ceiling and relay wall, when the scene has walls, a floor or a
                ceiling) at a frame's start or end, naming the field, the time and the coordinate.
        """
        unknown = sorted(set(moving) - {o.name for o in self.objects})
        if unknown:
            raise SceneError(f"{self._where()}moving objects not in the scene: {unknown}")
        out = copy.copy(self)
        out.moving = dict(moving)
        out._check_room()
        return out.at(out.frame_times()[0]) if moving else out

    def frame_times(self) -> np.ndarray:
        """(n,) float64 s: the starts of the capture's frames (``capture.frames``), or [0] without frames."""
        frames = self.capture.frames if self.capture is not None else None
        return frames.times() if frames is not None else np.zeros(1)

    def at(self, t: float) -> "Scene":
        """The scene at time ``t`` s: every moving object at its pose then, the rest unchanged (a new
        :class:`Scene`; construction's checks run again, every moving object's against everything; the pairs of
        objects that do not move, once found clean, are not tested again:
        :class:`~datagen.scene.static_faces.StaticFaces`). Without moving objects, this scene."""
        if not self.moving:
            return self
        if self._static is None or self._static.moving != set(self.moving):
            self._static = StaticFaces(self.moving)
        out = copy.copy(self)
        out.objects = [SceneObject(o.name, o.label, o.material, posed_vertices(self.moving[o.name].motion,
                                                                              self.moving[o.name].vertices, t), o.faces)
                       if o.name in self.moving else o for o in self.objects]
        out._check(self._static)
        return out

    def _check_room(self) -> None:
        room = [o.vertices for o in self.objects if o.label in ROOM_LABELS]
        if not self.moving or not any(o.label in ("wall", "floor", "ceiling") for o in self.objects):
            return                                  # no room around the objects (a bare relay wall)
        pts = np.concatenate(room)
        lo, hi = pts.min(axis=0) - ROOM_MARGIN, pts.max(axis=0) + ROOM_MARGIN
        frames = self.capture.frames if self.capture is not None else None
        times = (np.concatenate([frames.times(), frames.times() + frames.exposure]) if frames is not None
                 else np.zeros(1))
        times = np.sort(times)
        for name, m in self.moving.items():
            for k0 in range(0, len(times), ROOM_CHECK_CHUNK):       # the posed vertices' exact extents
                posed = posed_vertices(m.motion, m.vertices, times[k0:k0 + ROOM_CHECK_CHUNK])
                low, high = posed.min(axis=1), posed.max(axis=1)
                out = (low < lo) | (high > hi)
                if out.any():
                    k, axis = np.argwhere(out)[0]
                    value = low[k, axis] if low[k, axis] < lo[axis] else high[k, axis]
                    raise SceneError(
                        f"{self._where()}{m.field}: object {name!r} leaves the room at t = {times[k0 + k]:g} s "
                        f"({'xyz'[axis]} reaches {value:.3f} m, the room spans {lo[axis] + ROOM_MARGIN:.3f}.."
                        f"{hi[axis] - ROOM_MARGIN:.3f} m): slow it, move its start or shorten the sequence")
