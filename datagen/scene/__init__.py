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

Modules (they import each other directly, never through this package):

- :mod:`~datagen.scene.parts`: :class:`SceneError`, :class:`SceneObject`, :class:`Laser`,
  :class:`FieldOfView`, :class:`Sensor`, :class:`WallGrid`, :class:`CaptureSpec`, ``ROOM_LABELS``, and the
  input bounds (``MAX_EXTENT``, ``RESERVED_NAMES``, :func:`check_object_name`, ...);
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
from .builders import box, box_mesh, import_mesh, l_room, pillar, quad, quad_mesh
from .separation import CHUNK_ELEMENTS, hull_planes, may_meet, outward_planes
from .capture import FOV_EDGE_REL, FOV_PLANE_TOL, Capture, resolve_capture
from .coincident import (COPLANAR_TOL_REL, Coincidence, duplicate_faces, find_coincident_faces,
                         resolve_coincident_faces)
from .load import (MAX_YAML_BYTES, MAX_YAML_VALUES, ObjectSpec, SceneFile, check_output_dir, format_validation_error,
                   load_scene, parse_yaml, read_yaml, scene_from_dict, short_repr)
from .materials import BRDF_KINDS, LAMBERTIAN, PHONG, SIN_THETA, Material, MaterialTable, tangent_frame
from .model import Scene
from .parts import (MAX_APERTURE_RADIUS, MAX_EXTENT, RESERVED_NAMES, ROOM_LABELS, WAVELENGTH_RANGE, CaptureSpec,
                    FieldOfView, Laser, SceneError, SceneObject, Sensor, Vec3, WallGrid, check_counts, check_finite,
                    check_object_name, check_sizes)
from .raycast import RAY_OFFSET_REL, Hits, RayCaster

__all__ = [
    # parts
    "ROOM_LABELS", "Vec3", "SceneError", "check_finite", "check_counts", "SceneObject", "Laser", "FieldOfView",
    "Sensor", "WallGrid", "CaptureSpec", "MAX_EXTENT", "MAX_APERTURE_RADIUS", "WAVELENGTH_RANGE", "RESERVED_NAMES",
    "check_object_name", "check_sizes",
    # model
    "Scene",
    # coincident faces
    "COPLANAR_TOL_REL", "Coincidence", "find_coincident_faces", "resolve_coincident_faces", "duplicate_faces",
    # builders
    "quad_mesh", "box_mesh", "l_room", "pillar", "box", "quad", "import_mesh",
    # scene files
    "SceneFile", "ObjectSpec", "format_validation_error", "scene_from_dict", "load_scene", "read_yaml", "parse_yaml",
    "short_repr", "check_output_dir", "MAX_YAML_BYTES", "MAX_YAML_VALUES",
    # materials
    "BRDF_KINDS", "LAMBERTIAN", "SIN_THETA", "PHONG", "Material", "MaterialTable", "tangent_frame",
    # ray casting
    "RAY_OFFSET_REL", "Hits", "RayCaster",
    # capture geometry
    "FOV_EDGE_REL", "FOV_PLANE_TOL", "Capture", "resolve_capture",
    # separating planes (planner, quadrature)
    "CHUNK_ELEMENTS", "hull_planes", "may_meet", "outward_planes",
]
