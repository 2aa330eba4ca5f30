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
Each is imported from its module on first use (``import datagen.scene`` loads no mesh code, Embree or numba).
Every other name (input bounds, YAML helpers, BRDF tables, separating planes, ...) is imported from its module;
:class:`~datagen.errors.SceneError` from :mod:`datagen.errors` (or ``datagen.SceneError``).

Modules (they import each other directly, never through this package):

- :mod:`~datagen.scene.parts`: :class:`SceneObject`, :class:`Laser`, :class:`FieldOfView`, :class:`Sensor`,
  :class:`WallGrid`, :class:`CaptureSpec`, ``ROOM_LABELS``, and the input bounds (``MAX_EXTENT``,
  ``RESERVED_NAMES``, :func:`check_object_name`, ...);
- :mod:`~datagen.scene.model`: the :class:`Scene` dataclass (checks and coincident faces on construction);
- :mod:`~datagen.scene.coincident`: coplanar overlapping faces rejected or de-duplicated;
- :mod:`~datagen.scene.static_faces`: that check's verdict on the objects that do not move, kept across a sequence's
  instants;
- :mod:`~datagen.scene.builders`: meshes and objects built in Python;
- :mod:`~datagen.scene.load`: the scene-file schema and :func:`load_scene`;
- :mod:`~datagen.scene.yamlfile`: bounded YAML reading (:func:`read_yaml`, :func:`parse_yaml`) and one-line
  validation messages, shared by every config reader and light (no meshes, no kernels);
- :mod:`~datagen.scene.materials`: BRDFs (:class:`Material`, :class:`MaterialTable`);
- :mod:`~datagen.scene.raycast`: :class:`RayCaster`, :class:`Hits`;
- :mod:`~datagen.scene.capture`: :class:`Capture`, :func:`resolve_capture`, ``FOV_PLANE_TOL``, ``FOV_EDGE_REL``;
- :mod:`~datagen.scene.separation`: separating-plane tests between triangles and convex hulls (planner,
  quadrature).
- :mod:`~datagen.scene.brdf_kernel`: each BRDF formula once, as numba device functions every kernel calls;
- :mod:`~datagen.scene.motion`: moving objects' poses over time (keyframes, velocity, walk) and a capture's
  frames (:class:`~datagen.scene.motion.FrameSpec`; docs/motion.md);
- :mod:`~datagen.scene.flood`: flood illumination and multi-zone sensors, the scene-stage part (docs/multizone.md).
"""
from ..lazy import lazy_attributes

_LAZY = {"box": "builders", "import_mesh": "builders", "l_room": "builders", "pillar": "builders", "quad": "builders",
         "resolve_capture": "capture", "load_scene": "load", "scene_from_dict": "load", "Material": "materials",
         "Scene": "model", "CaptureSpec": "parts", "FieldOfView": "parts", "Laser": "parts", "SceneObject": "parts",
         "Sensor": "parts", "WallGrid": "parts", "RayCaster": "raycast"}
"""The exported names, each imported from its module on first use (``import datagen.scene`` stays light)."""

__getattr__ = lazy_attributes(__name__, _LAZY)

__all__ = [
    # the scene and its parts
    "Scene", "SceneObject", "Material", "Laser", "Sensor", "FieldOfView", "CaptureSpec", "WallGrid",
    # scene files and builders
    "load_scene", "scene_from_dict", "l_room", "pillar", "box", "quad", "import_mesh",
    # rays and the capture
    "RayCaster", "resolve_capture",
]
