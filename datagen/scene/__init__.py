"""Scene stage: what is in the world, where the laser and the sensor are, and rays through it.

In: a scene YAML file (:func:`load_scene`; scene_library/demo_room.yaml) or builder calls in Python
(:func:`l_room`, :func:`pillar`, :func:`box`, :func:`quad`, :func:`import_mesh`). Out: a :class:`Scene` —
``objects`` (:class:`SceneObject`: ``label``, :class:`Material`, vertices (V, 3) float64 m, faces (F, 3)
int64), the :class:`Laser` (emitter, spot), the :class:`Sensor` (position, aperture, :class:`FieldOfView`),
an optional :class:`CaptureSpec` (scan over :class:`WallGrid` s) and the YAML's ``simulation`` defaults —
then, for the transport stage, a :class:`RayCaster` (Embree first hits as :class:`Hits`, shadow rays) and
the resolved :class:`Capture` (laser points (L, 3), sensor grid frame, aperture; :func:`resolve_capture`).
Every invalid input raises :class:`SceneError` naming the file, the field and the value. World frame
right-handed, z up, metres (docs/physics.md §1).

Exported here, what users call: :class:`Scene` and its parts (:class:`SceneObject`, :class:`Material`,
:class:`Laser`, :class:`Sensor`, :class:`FieldOfView`, :class:`CaptureSpec`, :class:`WallGrid`), scene files
(:func:`load_scene`, :func:`scene_from_dict`), the builders, :class:`RayCaster` and :func:`resolve_capture`.
Every other name (input bounds, YAML helpers, BRDF tables, separating planes, ...) is imported from its module;
:class:`~datagen.errors.SceneError` from :mod:`datagen.errors` (or ``datagen.SceneError``).

Modules (they import each other directly, never through this package):

- :mod:`~datagen.scene.parts`: :class:`SceneObject`, :class:`Laser`, :class:`FieldOfView`, :class:`Sensor`,
  :class:`WallGrid`, :class:`CaptureSpec`, ``ROOM_LABELS``, and the input bounds (``MAX_EXTENT``,
  ``RESERVED_NAMES``, :func:`check_object_name`, ...);
- :mod:`~datagen.scene.model`: the :class:`Scene` dataclass (checks and coincident faces on construction);
- :mod:`~datagen.scene.coincident`: coplanar overlapping faces rejected or de-duplicated;
- :mod:`~datagen.scene.builders`: meshes and objects built in Python;
- :mod:`~datagen.scene.load`: the scene-file schema and :func:`load_scene`, :func:`read_yaml`, :func:`parse_yaml`;
- :mod:`~datagen.scene.materials`: BRDFs (:class:`Material`, :class:`MaterialTable`);
- :mod:`~datagen.scene.raycast`: :class:`RayCaster`, :class:`Hits`;
- :mod:`~datagen.scene.capture`: :class:`Capture`, :func:`resolve_capture`, ``FOV_PLANE_TOL``, ``FOV_EDGE_REL``;
- :mod:`~datagen.scene.separation`: separating-plane tests between triangles and convex hulls (planner,
  quadrature).
"""
from .builders import box, import_mesh, l_room, pillar, quad
from .capture import resolve_capture
from .load import load_scene, scene_from_dict
from .materials import Material
from .model import Scene
from .parts import CaptureSpec, FieldOfView, Laser, SceneObject, Sensor, WallGrid
from .raycast import RayCaster

__all__ = [
    # the scene and its parts
    "Scene", "SceneObject", "Material", "Laser", "Sensor", "FieldOfView", "CaptureSpec", "WallGrid",
    # scene files and builders
    "load_scene", "scene_from_dict", "l_room", "pillar", "box", "quad", "import_mesh",
    # rays and the capture
    "RayCaster", "resolve_capture",
]
