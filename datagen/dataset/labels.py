"""Ground-truth labels of a sampled room for reconstruction networks: fixed shapes whatever the room.

:func:`scene_labels` turns a :class:`~datagen.dataset.sampler.SampledRoom` into numpy arrays, deterministically (no
randomness):

- the hidden-object list as arrays padded to ``max_objects`` with a count;
- a depth map and a normal map of the hidden scene seen from the relay wall by an equal-area hemispherical
  camera at the FoV centre (the same camera model as the paper's lookin cameras, Scholes & Leach 2024 §3.1,
  implemented by :func:`datagen.sampling.square_to_hemisphere`);
- an occupancy voxel grid over a box that is fixed for the whole distribution, so grids align across
  samples (mesh objects: their exact inside when closed, their surface voxels when open);
- for scanned captures (or on request), the networks' orthographic wall-view images of the hidden objects:
  depth, normal, albedo and per-object masks on the scan grid (:mod:`datagen.dataset.wall_view`).
"""
from __future__ import annotations

import numpy as np
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from ..sampling import square_to_hemisphere
from ..sampling.surfaces import subdivide_with_vertices
from ..errors import ConfigError
from ..scene import RayCaster
from ..scene.brdf_kernel import BRDF_KINDS
from ..scene.parts import check_counts
from .obb import points_in_box, yaw_matrix
from .rooms import OBJECT_CLASSES, LabelRegion
from .sampler import SampledRoom
from .wall_view import view_rectangle, wall_frame, wall_view_labels
from ..vectors import matmul

MAX_OBJECTS = 1024
"""Most ``labels.max_objects``: the per-object arrays and the components (max_objects + 3 slots × channels × bins)
of one sample are allocated before the build's memory check (the rooms hold a handful)."""

MAX_LABEL_BYTES = 1 << 30
"""Most bytes of one sample's occupancy grid (V³ uint8) and depth/normal maps (H·W·4 float64): 1 GiB, so a
hostile ``voxels`` (at most 1024) or ``depth_map`` fails here, naming the field, rather than in a numpy
allocation."""

PAD_INT = -1
"""Padding of integer per-object arrays (class, BRDF kind) beyond ``object_count``; float arrays pad with 0."""


class LabelSpec(BaseModel):
    """What :func:`scene_labels` computes.

    Attributes:
        max_objects: length of the padded per-object arrays.
        depth_map: (H, W) pixels of the hemispherical depth/normal camera.
        voxels: V, occupancy voxels along the longest side of the label region (grid (V, V, V), cubic
            voxels of pitch = longest side / V starting at the region's min corner).
        occupancy_region: fixed box (origin, size) m for the grid; None: the room's
            ``params["label_region"]`` (the distribution's :meth:`~datagen.dataset.rooms.RoomDistribution.label_box`).
        wall_view: the orthographic wall-view labels (:func:`datagen.dataset.wall_view.wall_view_labels`):
            "scan" (default) on the scan grid when the capture scans, none otherwise; (H, W) at that resolution
            over the scan rectangle (or the FoV of a single-spot capture); "none": never.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_objects: int = Field(8, ge=0, le=MAX_OBJECTS)
    depth_map: tuple[int, int] = (64, 64)
    voxels: int = Field(32, ge=1)
    occupancy_region: LabelRegion | None = None
    wall_view: Literal["scan", "none"] | tuple[int, int] = "scan"

    @field_validator("depth_map")
    @classmethod
    def _pixels(cls, v: tuple[int, int]) -> tuple[int, int]:
        check_counts(v, "both pixel counts")
        if 32 * v[0] * v[1] > MAX_LABEL_BYTES:     # depth + normals, float64
            raise ValueError(f"{v[0]}x{v[1]} pixels need {32 * v[0] * v[1] / 2**30:.4g} GiB per sample, more than "
                             f"{MAX_LABEL_BYTES / 2**30:g} GiB")
        return v

    @field_validator("voxels")
    @classmethod
    def _voxels(cls, v: int) -> int:
        if v ** 3 > MAX_LABEL_BYTES:
            raise ValueError(f"{v}³ voxels need {v ** 3 / 2**30:.4g} GiB per sample, more than "
                             f"{MAX_LABEL_BYTES / 2**30:g} GiB")
        return v

    @field_validator("wall_view")
    @classmethod
    def _wall_view(cls, v):
        return v if isinstance(v, str) else check_counts(v, "both wall_view pixel counts")

    def wall_pixels(self, params: dict) -> tuple[int, int] | None:
        """(H, W) of the wall-view labels of a room with ``params``, or None when it has none."""
        if self.wall_view == "none":
            return None
        if self.wall_view == "scan":
            scan = (params.get("sensor") or {}).get("scan")
            return None if scan is None else tuple(scan["laser_grid"]["points"][::-1])
        return tuple(self.wall_view)


def label_shapes(spec: LabelSpec, wall_pixels: tuple[int, int] | None = None
                 ) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Shape and dtype of every array :func:`scene_labels` returns under ``spec`` (for preallocating stores);
    ``wall_pixels`` (H, W) adds the wall-view labels (:meth:`LabelSpec.wall_pixels` of the rooms)."""
    k, (h, w), v = spec.max_objects, spec.depth_map, spec.voxels
    i4, f4 = np.dtype(np.int32), np.dtype(np.float32)
    out = {"object_count": ((), i4), "object_class": ((k,), i4), "object_center": ((k, 3), f4),
           "object_size": ((k, 3), f4), "object_yaw": ((k,), f4), "object_albedo": ((k,), f4),
           "object_brdf": ((k,), i4), "depth": ((h, w), f4), "normal": ((h, w, 3), f4),
           "occupancy": ((v, v, v), np.dtype(np.uint8)), "occupancy_origin": ((3,), f4),
           "occupancy_pitch": ((), f4)}
    if wall_pixels is not None:
        hh, ww = wall_pixels
        out.update({"wall_depth": ((hh, ww), f4), "wall_normal": ((hh, ww, 3), f4), "wall_albedo": ((hh, ww), f4),
                    "wall_mask": ((k, hh, ww), np.dtype(np.uint8))})
    return out


def camera_frame(room: SampledRoom, caster: RayCaster) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position and frame (u, v, n) of the depth camera: the FoV centre (a scanned capture: the centre of its
    laser grid); n the relay-wall normal facing the sensor, u = n × z (the FoV width axis), v = u × n (the FoV
    height axis), as in the transport's capture (:func:`datagen.dataset.wall_view.wall_frame`).

    Returns four (3,) float64 arrays: centre, u, v, n.
    """
    fov = room.scene.sensor.fov
    center = np.asarray(fov.center if fov is not None else view_rectangle(room.params)[0], dtype=np.float64)
    u, v, n = wall_frame(caster, np.asarray(room.scene.sensor.position, dtype=np.float64), center)
    return center, u, v, n


def camera_directions(pixels: tuple[int, int], u: np.ndarray, v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(H, W, 3) float64 world directions of the equal-area hemispherical camera's pixel centres.

    Pixel (i, j) is the cell centre ((j + ½)/W, (i + ½)/H) of the unit square mapped by the concentric
    equal-area map (:func:`~datagen.sampling.square_to_hemisphere`, "uniform"): its local (x, y, z) is
    x·u + y·v + z·n. Column j grows along u, row i along v (upward on a vertical wall: plot with
    ``origin="lower"``); each pixel covers 2π/(H·W) sr.
    """
    h, w = pixels
    sv, su = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
    local, _ = square_to_hemisphere(su, sv, "uniform")
    return local[..., :1] * u + local[..., 1:2] * v + local[..., 2:3] * n


def occupancy_grid(objects: list[dict], origin: np.ndarray, pitch: float, voxels: int,
                   meshes: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> np.ndarray:
    """(V, V, V) uint8: 1 where a voxel centre origin + pitch·(i+½, j+½, k+½) lies in an object.

    Only the voxels inside each object's axis-aligned bounds are tested. Boxes and pillars: exact
    point-in-oriented-box. Objects of class "mesh" whose name is in ``meshes`` (name → world (vertices (V, 3),
    faces (F, 3))): a closed (watertight) mesh marks the voxel centres inside it (trimesh's ray-parity test), an
    open one the voxels its surface passes through (points no farther apart than pitch / 2 on every face).
    """
    grid = np.zeros((voxels,) * 3, dtype=np.uint8)
    for obj in objects:
        half = matmul(np.abs(yaw_matrix(obj["yaw_deg"])), np.asarray(obj["size"], float) / 2)   # AABB half extents
        c = np.asarray(obj["center"], float)
        lo = np.clip(np.floor((c - half - origin) / pitch - 0.5).astype(int), 0, voxels)
        hi = np.clip(np.ceil((c + half - origin) / pitch + 0.5).astype(int), 0, voxels)
        if np.any(hi <= lo):
            continue
        mesh = (meshes or {}).get(obj.get("name")) if obj.get("class") == "mesh" else None
        if mesh is not None and not _mesh_inside(grid, mesh, origin, pitch, lo, hi):
            continue
        axes = [origin[a] + pitch * (np.arange(lo[a], hi[a]) + 0.5) for a in range(3)]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        if mesh is not None:
            import trimesh
            inside = trimesh.Trimesh(*mesh, process=False).contains(pts.reshape(-1, 3)).reshape(pts.shape[:3])
        else:
            inside = points_in_box(pts.reshape(-1, 3), obj).reshape(pts.shape[:3])
        grid[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] |= inside.astype(np.uint8)
    return grid


def _mesh_inside(grid: np.ndarray, mesh: tuple[np.ndarray, np.ndarray], origin: np.ndarray, pitch: float,
                 lo: np.ndarray, hi: np.ndarray) -> bool:
    """True for a closed mesh (the caller tests voxel centres inside it); for an open mesh, marks the voxels its
    surface passes through in ``grid`` and returns False."""
    import trimesh

    vertices, faces = mesh
    if trimesh.Trimesh(vertices, faces, process=False).is_watertight:
        return True
    points, _, _, _ = subdivide_with_vertices(vertices[faces], pitch / 2)
    idx = np.floor((points - origin) / pitch).astype(np.int64)
    idx = idx[np.all((idx >= lo) & (idx < hi), axis=1)]
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = 1
    return False


def scene_labels(room: SampledRoom, spec: LabelSpec) -> dict[str, np.ndarray]:
    """Ground-truth arrays of ``room`` (shapes/dtypes of :func:`label_shapes`, whatever the room).

    Returns:
        object_count: int32 (); object_class: int32 (K,) 0 box / 1 pillar, −1 pad;
        object_center, object_size: float32 (K, 3) m (box centre; a pillar's size z is the ceiling height);
        object_yaw: float32 (K,) rad about +z; object_albedo: float32 (K,); object_brdf: int32 (K,) index
        in :data:`datagen.scene.materials.BRDF_KINDS` (0 lambertian, 1 sin_theta, 2 phong, 3 retroreflective), −1 pad;
        float pads are 0.
        depth: float32 (H, W) m, distance along each pixel ray from the camera at the FoV centre (see
        :func:`camera_directions`) to the first surface (walls, floor, ceiling and objects), 0 where the
        ray escapes (the open corridor end); rays start ε = offset/cos θ along their line (RayCaster
        offset, 1e-5 × scene size; ≤ 32 offsets at 64×64), so surfaces nearer than ε are not seen;
        normal: float32 (H, W, 3) unit world normals facing the camera, 0 where no hit.
        occupancy: uint8 (V, V, V) (:func:`occupancy_grid`), axes (x, y, z);
        occupancy_origin: float32 (3,) m, min corner; occupancy_pitch: float32 () m.
    Raises:
        ConfigError: more hidden objects than ``spec.max_objects``, or no occupancy region.
    """
    objects = room.objects
    k = spec.max_objects
    if len(objects) > k:
        raise ConfigError(f"labels.max_objects: the room has {len(objects)} hidden objects, more than "
                         f"max_objects = {k}; raise it to at least the distribution's maximum object count")
    out = {"object_count": np.array(len(objects), dtype=np.int32),
           "object_class": np.full(k, PAD_INT, dtype=np.int32),
           "object_center": np.zeros((k, 3), dtype=np.float32),
           "object_size": np.zeros((k, 3), dtype=np.float32),
           "object_yaw": np.zeros(k, dtype=np.float32),
           "object_albedo": np.zeros(k, dtype=np.float32),
           "object_brdf": np.full(k, PAD_INT, dtype=np.int32)}
    for i, obj in enumerate(objects):
        out["object_class"][i] = OBJECT_CLASSES.index(obj["class"])
        out["object_center"][i] = obj["center"]
        out["object_size"][i] = obj["size"]
        out["object_yaw"][i] = np.deg2rad(obj["yaw_deg"])
        out["object_albedo"][i] = obj["material"]["albedo"]
        out["object_brdf"][i] = BRDF_KINDS.index(obj["material"]["kind"])

    caster = RayCaster(room.scene)
    center, u, v, n = camera_frame(room, caster)
    directions = camera_directions(spec.depth_map, u, v, n)
    # Each ray starts on its own line from the FoV centre, stepped off the relay wall to a height of
    # caster.offset (ε = offset / cos θ along the ray), so depth is the distance from the centre itself.
    step = caster.offset / matmul(directions, n)
    hits = caster.intersect(center + step[..., None] * directions, directions)
    distance = np.linalg.norm(np.nan_to_num(hits.points) - center, axis=-1)
    out["depth"] = np.where(hits.hit, distance, 0.0).astype(np.float32)
    out["normal"] = hits.normals.astype(np.float32)

    if spec.occupancy_region is not None:
        origin, size = np.array(spec.occupancy_region.origin, float), np.array(spec.occupancy_region.size, float)
    elif "label_region" in room.params:
        origin = np.asarray(room.params["label_region"]["origin"], float)
        size = np.asarray(room.params["label_region"]["size"], float)
    else:
        raise ConfigError("labels.occupancy_region: not given and the room's params hold no label_region")
    pitch = float(np.max(size)) / spec.voxels
    meshes = {o.name: (o.vertices, o.faces) for o in room.scene.objects if o.label == "mesh"}
    out["occupancy"] = occupancy_grid(objects, origin, pitch, spec.voxels, meshes)
    out["occupancy_origin"] = origin.astype(np.float32)
    out["occupancy_pitch"] = np.array(pitch, dtype=np.float32)
    wall_pixels = spec.wall_pixels(room.params)
    if wall_pixels is not None:
        out.update(wall_view_labels(room, caster, wall_pixels, k))
    return out
