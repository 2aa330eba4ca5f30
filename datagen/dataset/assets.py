"""Mesh assets as hidden objects: asset folders, reading meshes, and placing one in a room.

A room distribution's ``objects.mesh`` class (:class:`datagen.dataset.rooms.MeshObjectDist`) lists asset folders
or files (OBJ, PLY, STL, GLB/GLTF, OFF: anything trimesh reads; e.g. a ShapeNet export or the library
``scripts/make_assets.py`` writes to ``assets/meshes/``). :func:`resolve_assets` turns those entries into
absolute paths when a distribution is loaded, :func:`asset_files` lists the meshes they hold (sorted, so an
asset index means the same file on every worker), :func:`load_asset` reads one into its *normalised* frame
(bounding box centred on the origin, longest side 1) and :func:`place_asset` gives the world vertices and the
oriented bounding box of a scaled, tilted and yawed copy.

Transform of a placed asset (metres, right-handed, z up): file coordinates p → world
``R_z(yaw) · (s · R_tilt · N(p) − c) + center``, with N the normalisation, s the drawn size (the longest side of
the normalised bounding box), R_tilt a rotation by ``tilt_deg`` about the horizontal axis at azimuth
``tilt_axis_deg`` (measured from +x, counter-clockwise seen from above) and c the centre of the tilted mesh's
bounding box in the yaw frame, so the object's oriented bounding box (``center``, ``size``, ``yaw_deg``: what the
room sampler tests for overlaps, the laser beams and the sensor's view) is tight around the mesh.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..scene import SceneError
from .obb import yaw_matrix

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
"""File suffixes listed from an asset folder (lower case; trimesh reads each)."""


@dataclass(frozen=True)
class Asset:
    """A mesh in its normalised frame.

    Attributes:
        path: the file (absolute).
        vertices: (V, 3) float64, bounding box centred on the origin, longest side 1.
        faces: (F, 3) int64.
        file_to_normalised: (4, 4) float64 affine map from the file's coordinates to ``vertices``.
        watertight: whether the mesh is closed (occupancy labels test points against it exactly then).
    """

    path: str
    vertices: np.ndarray
    faces: np.ndarray
    file_to_normalised: np.ndarray
    watertight: bool


def resolve_assets(entries: list[str], base: Path | None, where: str) -> list[str]:
    """Absolute paths of asset folders or files: each entry relative to ``base`` (the room file's folder) first,
    then to the working directory.

    Raises:
        SceneError: an entry exists in neither place (``where``: the field, e.g. "rooms.yaml: objects.mesh.assets").
    """
    out = []
    for entry in entries:
        path = Path(entry).expanduser()
        candidates = [path] if path.is_absolute() else ([base / path] if base is not None else []) + [path]
        found = next((p for p in candidates if p.exists()), None)
        if found is None:
            looked = ", ".join(str(p) for p in dict.fromkeys(candidates))
            raise SceneError(f"{where}: asset folder or file not found: {entry!r} (looked at {looked})")
        out.append(str(found.resolve()))
    return out


@lru_cache(maxsize=64)
def asset_files(entries: tuple[str, ...]) -> tuple[str, ...]:
    """Mesh files of resolved asset entries: a folder gives every file below it with a suffix in
    :data:`MESH_SUFFIXES`, sorted by path; a file gives itself. Order: entries in order.

    Raises:
        SceneError: an entry is missing, or the entries hold no mesh file.
    """
    files: list[str] = []
    for entry in entries:
        path = Path(entry)
        if path.is_dir():
            files += sorted(str(p) for p in path.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        elif path.is_file():
            files.append(str(path))
        else:
            raise SceneError(f"objects.mesh.assets: {entry} does not exist")
    if not files:
        raise SceneError(f"objects.mesh.assets: no mesh file ({', '.join(MESH_SUFFIXES)}) in {list(entries)}")
    return tuple(files)


def asset_name(entries: tuple[str, ...], file: str) -> str:
    """Location-free name of an asset file: its path from the folder that holds its entry, e.g. ``meshes/A.ply``
    for the entry ``/any/checkout/assets/meshes`` (a file entry: its own name). Pure string arithmetic on resolved
    paths (no file access), so a recorded name means the same on every machine."""
    path = Path(file)
    for entry in entries:
        root = Path(entry)
        if path == root:
            return root.name
        if root in path.parents:
            return str(path.relative_to(root.parent))
    return path.name


def asset_digest(files: tuple[str, ...]) -> list[dict]:
    """[{file, sha256}] of every asset file (recorded in the dataset card: a changed asset changes samples)."""
    return [{"file": f, "sha256": hashlib.sha256(Path(f).read_bytes()).hexdigest()} for f in files]


@lru_cache(maxsize=512)
def load_asset(path: str) -> Asset:
    """Read a mesh file with trimesh into its normalised frame (cached per process).

    Raises:
        SceneError: the file cannot be read, holds no triangles, or has zero extent (the message names it).
    """
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files  # noqa: BLE001
        raise SceneError(f"mesh asset {path}: cannot read it: {' '.join(str(exc).split())}") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise SceneError(f"mesh asset {path}: holds no triangles")
    if not np.isfinite(vertices).all():
        raise SceneError(f"mesh asset {path}: has non-finite vertex coordinates")
    lo, hi = vertices.min(0), vertices.max(0)
    extent = float(np.max(hi - lo))
    if extent <= 0:
        raise SceneError(f"mesh asset {path}: all vertices coincide (zero extent)")
    m = np.eye(4)
    m[:3, :3] /= extent
    m[:3, 3] = -0.5 * (lo + hi) / extent
    watertight = bool(trimesh.Trimesh(vertices, faces, process=False).is_watertight)
    return Asset(path, vertices @ m[:3, :3].T + m[:3, 3], faces, m, watertight)


def tilt_matrix(tilt_deg: float, axis_deg: float) -> np.ndarray:
    """(3, 3) rotation by ``tilt_deg`` about the horizontal unit axis (cos a, sin a, 0), a = ``axis_deg``
    (Rodrigues' formula)."""
    a, t = math.radians(axis_deg), math.radians(tilt_deg)
    k = np.array([math.cos(a), math.sin(a), 0.0])
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * kx + (1 - math.cos(t)) * kx @ kx


def asset_box(asset: Asset, size: float, tilt_deg: float, axis_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Oriented-bounding-box size (3,) m and the centre offset c (3,) of the scaled, tilted asset in its yaw
    frame (module doc)."""
    local = size * asset.vertices @ tilt_matrix(tilt_deg, axis_deg).T
    lo, hi = local.min(0), local.max(0)
    return hi - lo, 0.5 * (lo + hi)


def place_asset(asset: Asset, size: float, tilt_deg: float, axis_deg: float, center, yaw_deg: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (V, 3) float64 of the placed asset and its (4, 4) file → world transform (module doc)."""
    _, offset = asset_box(asset, size, tilt_deg, axis_deg)
    linear = yaw_matrix(yaw_deg) @ (size * tilt_matrix(tilt_deg, axis_deg))
    shift = np.asarray(center, float) - yaw_matrix(yaw_deg) @ offset
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, shift
    world = m @ asset.file_to_normalised
    return asset.vertices @ linear.T + shift, world
