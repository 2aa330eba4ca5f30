"""Mesh assets as hidden objects: asset folders, reading meshes, and placing one in a room.

A room distribution's ``objects.mesh`` class (:class:`datagen.dataset.rooms.MeshObjectDist`) lists asset folders
or files (OBJ, PLY, STL, GLB/GLTF, OFF: anything trimesh reads; e.g. a ShapeNet export or the library
``scripts/make_assets.py`` writes to ``assets/meshes/``). :func:`resolve_assets` turns those entries into
absolute paths when a distribution is loaded, :func:`asset_files` lists the meshes they hold (sorted, so an
asset index means the same file on every worker), :func:`load_asset` reads one into its *normalised* frame
(bounding box centred on the origin, longest side 1) and :func:`place_asset` gives the world vertices and the
oriented bounding box of a scaled, tilted and yawed copy.

Size and identity of the assets. :func:`mesh_triangles` reads a mesh file's triangle count from its header (or
counts its face records) without loading it; :func:`load_asset` and dataset builds refuse a file with more than
:data:`MAX_ASSET_TRIANGLES` before any heavy work. :func:`asset_record` lists a dataset's asset files by
location-free name with their sha256 and triangle count: the card pins it at build time, and ``build --resume``
and ``datagen verify`` compare it with the files on disk (:func:`asset_changes`; docs/reliability.md, "Builds").

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

from ..errors import ConfigError
from .obb import yaw_matrix
from ..vectors import matmul

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
"""File suffixes listed from an asset folder (lower case; trimesh reads each)."""

MAX_ASSET_TRIANGLES = 100_000
"""Most triangles a mesh asset may have. Each triangle of a hidden mesh is at least one quadrature sub-triangle,
so a sample's time grows linearly with them: one sample of ``configs/datasets/wall_smoke.yaml`` (16 × 16 scan)
with an icosphere asset took 1.5 s at 5 120 triangles and 88–112 s at 81 920 (measured, 2 shared cores), so 2
million would take some 45 minutes per sample (extrapolated), and reading such a file with trimesh alone takes
2.5 s and 1.1 GB. Decimate larger meshes first (e.g. Open3D's ``simplify_quadric_decimation``): the quadrature's
few centimetres of resolution (``quadrature_edge``) do not see finer detail."""


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


class AssetNotFoundError(ConfigError):
    """A mesh asset folder or file that a room names exists nowhere (:func:`resolve_assets`): the one config
    problem a store copied from the machine that built it has by nature
    (:func:`datagen.dataset.integrity.asset_problems` notes it; every other ConfigError stays an error)."""


def resolve_assets(entries: list[str], base: Path | None, where: str) -> list[str]:
    """Absolute paths of asset folders or files: each entry relative to ``base`` (the room file's folder) first,
    then to the working directory.

    Raises:
        AssetNotFoundError: an entry exists in neither place (``where``: the field, e.g. "rooms.yaml:
            objects.mesh.assets").
    """
    out = []
    for entry in entries:
        path = Path(entry).expanduser()
        candidates = [path] if path.is_absolute() else ([base / path] if base is not None else []) + [path]
        found = next((p for p in candidates if p.exists()), None)
        if found is None:
            looked = ", ".join(str(p) for p in dict.fromkeys(candidates))
            raise AssetNotFoundError(f"{where}: asset folder or file not found: {entry!r} (looked at {looked})")
        out.append(str(found.resolve()))
    return out


@lru_cache(maxsize=64)
def asset_files(entries: tuple[str, ...]) -> tuple[str, ...]:
    """Mesh files of resolved asset entries: a folder gives every file below it with a suffix in
    :data:`MESH_SUFFIXES`, sorted by path; a file gives itself. Order: entries in order.

    Raises:
        ConfigError: an entry is missing, or the entries hold no mesh file.
    """
    files: list[str] = []
    for entry in entries:
        path = Path(entry)
        if path.is_dir():
            files += sorted(str(p) for p in path.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        elif path.is_file():
            files.append(str(path))
        else:
            raise ConfigError(f"objects.mesh.assets: {entry} does not exist")
    if not files:
        raise ConfigError(f"objects.mesh.assets: no mesh file ({', '.join(MESH_SUFFIXES)}) in {list(entries)}")
    return tuple(files)


def refresh_assets() -> None:
    """Forget the per-process caches of :func:`asset_files` and :func:`load_asset`, so files added, removed or
    changed since they were filled are seen (a build calls it first: it pins the files it draws from)."""
    asset_files.cache_clear()
    load_asset.cache_clear()


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


def _file_sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _count_token(path: Path, token: bytes, at_start: bytes | None = None) -> int:
    """Occurrences of ``token`` in the file (read in 1 MiB blocks; bounded memory), plus one if the file starts
    with ``at_start``."""
    count, tail = 0, b""
    with open(path, "rb") as fh:
        first = True
        while block := fh.read(1 << 20):
            if first and at_start is not None and block.startswith(at_start):
                count += 1
            first = False
            data = tail + block
            count += data.count(token)     # the carried tail is shorter than a token: nothing counted twice
            tail = data[-(len(token) - 1):] if len(token) > 1 else b""
    return count


def _gltf_triangles(doc: dict) -> int:
    """Triangles of every triangle-list primitive of a glTF document (indices' count / 3, else positions')."""
    accessors = doc.get("accessors") or []
    total = 0
    for mesh in doc.get("meshes") or []:
        for prim in mesh.get("primitives") or []:
            if prim.get("mode", 4) != 4:
                continue
            index = prim["indices"] if prim.get("indices") is not None else prim["attributes"]["POSITION"]
            total += int(accessors[index]["count"]) // 3
    return total


def mesh_triangles(path: str | Path) -> int | None:
    """Triangle count of a mesh file read without loading its geometry: the header of binary STL (its count),
    PLY (``element face``) and OFF, the JSON of GLB / glTF (its triangle primitives), and a count of the face
    records of OBJ and ASCII STL (one pass over the file in blocks). A PLY, OFF or OBJ polygon counts as one
    (a lower bound of its triangles).

    Returns:
        the count, or None when the file cannot be read this way (trimesh then reads it, or names the error).
    """
    import json
    import struct

    path = Path(path)
    suffix = path.suffix.lower()
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(84)
        if suffix == ".stl":
            if len(head) == 84:
                n = struct.unpack("<I", head[80:84])[0]
                if size == 84 + 50 * n:
                    return int(n)
            return _count_token(path, b"endfacet")
        if suffix == ".obj":
            return _count_token(path, b"\nf ", at_start=b"f ")
        if suffix in (".ply", ".off"):
            with open(path, "rb") as fh:
                lines = [fh.readline(4096) for _ in range(200)]    # headers are short; comments count too
            words = [line.split(b"#")[0].split() for line in lines]
            if suffix == ".ply":
                for w in words:
                    if w[:2] == [b"element", b"face"] and len(w) == 3:
                        return int(w[2])
                    if w[:1] == [b"end_header"]:
                        return None
                return None
            numbers = [x for w in words for x in w if not x.isalpha() and x not in (b"OFF", b"COFF", b"NOFF")]
            return int(numbers[1]) if len(numbers) >= 2 else None
        if suffix == ".glb":
            magic, _, _, length, kind = struct.unpack("<4sIII4s", head[:20])
            if magic != b"glTF" or kind != b"JSON":
                return None
            with open(path, "rb") as fh:
                fh.seek(20)
                return _gltf_triangles(json.loads(fh.read(length)))
        if suffix == ".gltf":
            return _gltf_triangles(json.loads(path.read_bytes()))
    except (OSError, ValueError, KeyError, IndexError, TypeError, struct.error):
        return None
    return None


def check_asset_size(path: str | Path) -> int | None:
    """Refuse a mesh asset with more than :data:`MAX_ASSET_TRIANGLES` triangles (:func:`mesh_triangles`, no
    geometry is loaded). Returns its triangle count (None: not countable without loading).

    Raises:
        ConfigError: naming the file, its triangle count and the limit.
    """
    n = mesh_triangles(path)
    if n is not None and n > MAX_ASSET_TRIANGLES:
        raise ConfigError(f"mesh asset {path}: {n} triangles, more than the {MAX_ASSET_TRIANGLES} a hidden mesh may "
                         f"have (datagen.dataset.assets.MAX_ASSET_TRIANGLES: a sample's time grows with them); "
                         f"decimate it, e.g. with Open3D's simplify_quadric_decimation")
    return n


def asset_record(entry_groups: list[tuple[str, ...]], refuse_large: bool = True) -> list[dict]:
    """What a dataset's card pins of its mesh assets: one ``{"file", "sha256", "triangles"}`` per file of the
    resolved entries in ``entry_groups`` (one tuple of asset folders / files per room distribution), with
    ``file`` the location-free :func:`asset_name`, sorted by it (``triangles``: :func:`mesh_triangles`, None when
    not countable from the header). Files are listed afresh (the caches are refreshed: :func:`refresh_assets`);
    with ``refuse_large`` every file's size is checked (:func:`check_asset_size`) before any is hashed.

    Raises:
        ConfigError: an entry is missing or holds no mesh; a file has more than :data:`MAX_ASSET_TRIANGLES`
            triangles (naming it, its count and the limit).
    """
    refresh_assets()
    named: dict[str, str] = {}
    for entries in entry_groups:
        for file in asset_files(tuple(entries)):
            named.setdefault(asset_name(tuple(entries), file), file)
    count = check_asset_size if refuse_large else mesh_triangles
    sizes = {name: count(file) for name, file in named.items()}     # every file, before any hash
    return [{"file": name, "sha256": _file_sha256(Path(named[name])), "triangles": sizes[name]}
            for name in sorted(named)]


def current_asset_record(entry_groups: list[tuple[str, ...]]) -> list[dict]:
    """:func:`asset_record` of the files on disk now, large ones included, with the entries that no longer exist
    left out (their recorded files then show as removed in :func:`asset_changes`): what ``datagen verify``
    compares with the card."""
    kept = [k for entries in entry_groups if (k := tuple(e for e in entries if Path(e).exists()))]
    return asset_record(kept, refuse_large=False) if kept else []


def asset_changes(recorded: list[dict], current: list[dict], entry_groups: list[tuple[str, ...]]) -> list[str]:
    """The differences between a card's asset list and the files now, one line each, in name order:
    ``<asset folder>: <name> was added`` / ``was removed`` / ``changed (sha256 <old> → <new>)``, the folder
    being the resolved entry whose name the file's name starts with."""
    folders = {Path(e).name: e for entries in entry_groups for e in entries}
    old = {r["file"]: r["sha256"] for r in recorded}
    new = {r["file"]: r["sha256"] for r in current}
    lines = []
    for name in sorted(set(old) | set(new)):
        where = folders.get(name.split("/")[0], "objects.mesh.assets")
        if name not in old:
            lines.append(f"{where}: {name} was added")
        elif name not in new:
            lines.append(f"{where}: {name} was removed")
        elif old[name] != new[name]:
            lines.append(f"{where}: {name} changed (sha256 {old[name][:12]}… → {new[name][:12]}…)")
    return lines


@lru_cache(maxsize=512)
def load_asset(path: str) -> Asset:
    """Read a mesh file with trimesh into its normalised frame (cached per process).

    Raises:
        ConfigError: the file cannot be read, holds no triangles, has zero extent, or has more than
            :data:`MAX_ASSET_TRIANGLES` triangles (read from its header first: nothing is loaded then); the message
            names it.
    """
    import trimesh

    check_asset_size(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files  # noqa: BLE001
        raise ConfigError(f"mesh asset {path}: cannot read it: {' '.join(str(exc).split())}") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise ConfigError(f"mesh asset {path}: holds no triangles")
    if not np.isfinite(vertices).all():
        raise ConfigError(f"mesh asset {path}: has non-finite vertex coordinates")
    lo, hi = vertices.min(0), vertices.max(0)
    extent = float(np.max(hi - lo))
    if extent <= 0:
        raise ConfigError(f"mesh asset {path}: all vertices coincide (zero extent)")
    m = np.eye(4)
    m[:3, :3] /= extent
    m[:3, 3] = -0.5 * (lo + hi) / extent
    watertight = bool(trimesh.Trimesh(vertices, faces, process=False).is_watertight)
    return Asset(path, matmul(vertices, m[:3, :3].T) + m[:3, 3], faces, m, watertight)


def tilt_matrix(tilt_deg: float, axis_deg: float) -> np.ndarray:
    """(3, 3) rotation by ``tilt_deg`` about the horizontal unit axis (cos a, sin a, 0), a = ``axis_deg``
    (Rodrigues' formula)."""
    a, t = math.radians(axis_deg), math.radians(tilt_deg)
    k = np.array([math.cos(a), math.sin(a), 0.0])
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * kx + matmul((1 - math.cos(t)) * kx, kx)


def asset_box(asset: Asset, size: float, tilt_deg: float, axis_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Oriented-bounding-box size (3,) m and the centre offset c (3,) of the scaled, tilted asset in its yaw
    frame (module doc)."""
    local = matmul(size * asset.vertices, tilt_matrix(tilt_deg, axis_deg).T)
    lo, hi = local.min(0), local.max(0)
    return hi - lo, 0.5 * (lo + hi)


def place_asset(asset: Asset, size: float, tilt_deg: float, axis_deg: float, center, yaw_deg: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (V, 3) float64 of the placed asset and its (4, 4) file → world transform (module doc)."""
    _, offset = asset_box(asset, size, tilt_deg, axis_deg)
    linear = matmul(yaw_matrix(yaw_deg), size * tilt_matrix(tilt_deg, axis_deg))
    shift = np.asarray(center, float) - matmul(yaw_matrix(yaw_deg), offset)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, shift
    world = matmul(m, asset.file_to_normalised)
    return matmul(asset.vertices, linear.T) + shift, world


def config_asset_entries(config) -> list[tuple[str, ...]]:
    """The resolved asset entries (folders or files) of every split's room distribution of a
    :class:`datagen.dataset.DatasetConfig` that draws meshes (``objects.mesh.count.max > 0``), one tuple per
    distinct list, in split order: the input of :func:`asset_record`.

    Raises:
        ConfigError: a split's room distribution cannot be loaded (e.g. an asset folder is gone; names it).
    """
    groups: list[tuple[str, ...]] = []
    for split in config.splits:
        mesh = config.room_distribution(split).objects.mesh
        if mesh.count.max > 0 and tuple(mesh.assets) not in groups:
            groups.append(tuple(mesh.assets))
    return groups
