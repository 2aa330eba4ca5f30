"""Scene builders: meshes and :class:`~datagen.scene.parts.SceneObject` s built in Python.

:func:`quad_mesh`, :func:`box_mesh` and :func:`mask_mesh` (a binary mask's filled cells as a planar cut-out) return
bare (vertices, faces) arrays; :func:`l_room` (corridor with an L-bend room behind the relay wall), :func:`pillar`,
:func:`box`, :func:`quad`, :func:`mask_cutout` (a mask written as text rows) and :func:`import_mesh` (any mesh file
trimesh reads) return labelled objects. The YAML object specs of :mod:`datagen.scene.load` call them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from .materials import Material
from .parts import ROOM_LABELS, SceneError, SceneObject, Vec3, check_sizes
from ..vectors import matmul

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
    vertices = matmul(corners * np.asarray(size, dtype=np.float64), _rotation_z(rotation_deg).T) + np.asarray(center)
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
    """Floor-to-ceiling cuboid pillar with footprint ``size_xy`` at ``center_xy``, rotated about z.

    Raises:
        SceneError: a size or the height not finite and > 0 (:func:`~datagen.scene.parts.check_sizes`).
    """
    check_sizes([*size_xy, height], f"pillar {name!r}: size and height")
    v, f = box_mesh((center_xy[0], center_xy[1], height / 2), (size_xy[0], size_xy[1], height), rotation_deg)
    return SceneObject(name, label, material or Material(), v, f)


def box(name: str, center: Vec3, size: Vec3, rotation_deg: float = 0.0, material: Material | None = None,
        label: str = "box") -> SceneObject:
    """Cuboid box of ``size`` (dx, dy, dz) centred at ``center``, rotated about z.

    Raises:
        SceneError: a size not finite and > 0 (:func:`~datagen.scene.parts.check_sizes`).
    """
    check_sizes(size, f"box {name!r}: size")
    return SceneObject(name, label, material or Material(), *box_mesh(center, size, rotation_deg))


PERSON_PARTS = (   # (centre x, y, z; size x, y, z) for a 1 m tall figure facing +x, feet on z = 0
    (0.0, -0.06, 0.24, 0.16, 0.11, 0.48), (0.0, 0.06, 0.24, 0.16, 0.11, 0.48),        # legs
    (0.0, 0.0, 0.64, 0.17, 0.30, 0.34),                                                # torso
    (0.0, -0.18, 0.62, 0.08, 0.07, 0.32), (0.0, 0.18, 0.62, 0.08, 0.07, 0.32),        # arms
    (0.0, 0.0, 0.90, 0.13, 0.11, 0.20))                                                # neck and head
"""A person's blocks in units of its height H (legs to 0.48 H, torso 0.47–0.81 H, head to 1.0 H; arms beside the
torso): each overlaps the next by about 1 cm at 1.75 m, so that no two faces of the figure are coplanar."""


def person(name: str, center_xy: tuple[float, float], height: float, rotation_deg: float = 0.0,
           material: Material | None = None, label: str = "person") -> SceneObject:
    """A standing person of ``height`` m as six closed blocks (legs, torso, arms, head: :data:`PERSON_PARTS`), feet
    on the floor z = 0 at ``center_xy`` (m), facing +x turned by ``rotation_deg`` about z; 72 triangles. Its
    bounding box is 0.17 H deep, 0.43 H wide and H tall (0.30 × 0.75 × 1.75 m at 1.75 m).

    Raises:
        SceneError: a height not finite and > 0.
    """
    check_sizes((height,), f"person {name!r}: height")
    turn = _rotation_z(rotation_deg)
    parts = []
    for cx, cy, cz, sx, sy, sz in PERSON_PARTS:
        v, f = box_mesh((cx * height, cy * height, cz * height), (sx * height, sy * height, sz * height))
        parts.append((matmul(v, turn.T) + np.array([center_xy[0], center_xy[1], 0.0]), f))
    return SceneObject(name, label, material or Material(), *_merge(parts))


def quad(name: str, corner: Vec3, edge_u: Vec3, edge_v: Vec3, material: Material | None = None,
         label: str = "mesh") -> SceneObject:
    """A single rectangle corner, corner+u, corner+u+v, corner+v (two triangles)."""
    return SceneObject(name, label, material or Material(), *quad_mesh(corner, edge_u, edge_v))


def import_mesh(name: str, path: str | Path, scale: float = 1.0, left_handed: bool = False,
                rotation_deg: float = 0.0, translate: Vec3 = (0.0, 0.0, 0.0), material: Material | None = None,
                label: str = "mesh") -> SceneObject:
    """Load OBJ/PLY/STL/GLB (anything trimesh reads) as one object.

    Coordinates are multiplied by ``scale`` (e.g. 0.01 for centimetres), then, if ``left_handed``, y is
    flipped (Unreal's left-handed x-forward/y-right/z-up frame → ours, docs/physics.md §1; face winding is reversed
    to keep orientation), then rotated about z and translated.

    Raises:
        SceneError: the file is missing, unreadable (binary garbage, truncated, unknown format: the message
            names the file and trimesh's reason in one line) or holds no triangles.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
        vertices = np.asarray(loaded.vertices, dtype=np.float64) * scale
        faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types (and ImportErrors) for bad files
        reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
        raise SceneError(f"cannot read mesh file {path}: {reason}") from None
    if len(faces) == 0:
        raise SceneError(f"mesh file {path} holds no triangles (empty, truncated, or not a valid "
                         f"{path.suffix.lstrip('.').upper() or 'mesh'} file)")
    if left_handed:
        vertices = vertices * np.array([1.0, -1.0, 1.0])
        faces = faces[:, ::-1]
    vertices = matmul(vertices, _rotation_z(rotation_deg).T) + np.asarray(translate, dtype=np.float64)
    return SceneObject(name, label, material or Material(), vertices, faces)


MASK_SYMBOLS = {"#": True, ".": False}
"""Characters of a mask row in a scene file: "#" filled, "." empty."""


MASK_PERPENDICULAR = 1e-5
"""|û·v̂| up to which a mask's u and v count as perpendicular: directions written with six decimals in a scene file
are perpendicular to about 1e-6."""


def mask_mesh(mask: np.ndarray, pitch: float, center: Vec3, u: Vec3 = (1.0, 0.0, 0.0),
              v: Vec3 = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """A planar cut-out: the filled cells of a binary mask as a triangle mesh in scene coordinates.

    Cell (iy, ix) of the (ny, nx) mask is the square of side ``pitch`` centred at
    center + (ix − (nx − 1)/2)·pitch·û + (iy − (ny − 1)/2)·pitch·v̂ (û, v̂ the unit vectors of ``u`` and ``v``): row 0
    is the lowest, as a confocal scan's rows and ``imshow(..., origin="lower")`` (docs/capture_io.md,
    "Orientation"), so the front view of a reconstruction (ny, nx), thresholded, is the object its scan saw once
    ``center`` is the scan's centre moved ``depth`` along the wall normal. Each run of filled cells along a row is
    one rectangle (two triangles); neighbouring rectangles share their edges exactly (no cracks).

    Args:
        mask: (ny, nx) bool (or 0/1); pitch: cell side in m (> 0); center: (3,) m, the mask's centre;
        u, v: (3,) directions of the columns and rows (need not be unit; they must be perpendicular).
    Returns:
        (vertices (4·R, 3) float64 m, faces (2·R, 3) int64) with R the runs; the faces' normal is û × v̂.
    Raises:
        SceneError: a mask that is not 2-D or has no filled cell, a pitch that is not finite and > 0, u or v zero or
            not perpendicular (|û·v̂| > :data:`MASK_PERPENDICULAR`; within it v is made exactly perpendicular).
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.size == 0:
        raise SceneError(f"mask: expected a (ny, nx) array of cells, got shape {m.shape}")
    m = m.astype(bool)
    if not m.any():
        raise SceneError(f"mask: none of its {m.shape[0]} x {m.shape[1]} cells is filled")
    check_sizes([pitch], "mask pitch")
    uu, vv = (np.asarray(a, dtype=np.float64) for a in (u, v))
    nu, nv = np.linalg.norm(uu), np.linalg.norm(vv)
    if not (nu > 0 and nv > 0):
        raise SceneError(f"mask: u {list(u)} and v {list(v)} must be non-zero directions")
    uu, vv = uu / nu, vv / nv
    if abs(float(uu @ vv)) > MASK_PERPENDICULAR:
        raise SceneError(f"mask: u {list(u)} and v {list(v)} must be perpendicular (u·v = {float(uu @ vv):.3g})")
    vv = vv - (uu @ vv) * uu                               # exactly perpendicular: a planar, rectangular grid
    vv /= np.linalg.norm(vv)
    ny, nx = m.shape
    padded = np.zeros((ny, nx + 2), dtype=np.int8)
    padded[:, 1:-1] = m
    change = np.diff(padded, axis=1)                       # +1 where a run starts, −1 one past where it ends
    rows, starts = np.nonzero(change == 1)
    _, stops = np.nonzero(change == -1)                    # same row order (row-major), one stop per start
    a0 = (starts - (nx - 1) / 2 - 0.5) * pitch             # the runs' left and right edges along û
    a1 = (stops - (nx - 1) / 2 - 0.5) * pitch
    b0 = (rows - (ny - 1) / 2 - 0.5) * pitch               # their lower and upper edges along v̂
    b1 = b0 + pitch
    corners = np.stack([np.stack([a0, b0], -1), np.stack([a1, b0], -1), np.stack([a1, b1], -1),
                        np.stack([a0, b1], -1)], axis=1)   # (R, 4, 2): counter-clockwise about û × v̂
    vertices = (np.asarray(center, dtype=np.float64) + corners[..., :1] * uu + corners[..., 1:] * vv).reshape(-1, 3)
    base = 4 * np.arange(len(rows))[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3).astype(np.int64)
    return vertices, faces


def mask_cutout(name: str, rows: list[str], pitch: float, center: Vec3, u: Vec3 = (1.0, 0.0, 0.0),
                v: Vec3 = (0.0, 0.0, 1.0), material: Material | None = None, label: str = "mesh") -> SceneObject:
    """A planar cut-out written as text rows (a scene file's ``mask`` builder): ``rows`` top row first (as the
    picture reads, highest v̂ first), "#" filled and "." empty (:data:`MASK_SYMBOLS`); :func:`mask_mesh` builds it.

    Raises:
        SceneError: rows of different lengths, another character (the row and column are named), or what
            :func:`mask_mesh` refuses.
    """
    if not rows or len({len(r) for r in rows}) != 1:
        raise SceneError(f"mask {name!r}: rows must be equally long strings, got lengths "
                         f"{sorted({len(r) for r in rows})}")
    for i, row in enumerate(rows):
        bad = [c for c in row if c not in MASK_SYMBOLS]
        if bad:
            raise SceneError(f"mask {name!r}: rows.{i} column {row.index(bad[0])}: {bad[0]!r} is neither '#' (filled) "
                             "nor '.' (empty)")
    mask = np.array([[MASK_SYMBOLS[c] for c in row] for row in rows[::-1]], dtype=bool)
    try:
        vertices, faces = mask_mesh(mask, pitch, center, u, v)
    except SceneError as exc:
        raise SceneError(f"mask {name!r}: {str(exc).removeprefix('mask: ')}") from None
    return SceneObject(name, label, material or Material(), vertices, faces)
