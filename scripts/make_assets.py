"""Generate the small hidden-object mesh library shipped in ``assets/meshes/`` (no download).

Two folders, one binary PLY per mesh, every mesh in the same canonical frame so a room distribution can place it
(``objects.mesh`` in ``configs/rooms/*.yaml``, docs/rooms.md):

- ``assets/meshes/alphanumeric/``: the 26 capital letters and the 10 digits, extruded from the glyph outlines
  of the DejaVu Sans Bold font that matplotlib ships (``matplotlib.textpath.TextPath`` → polygons, holes by the
  even-odd rule → ``shapely`` polygons simplified to ``SIMPLIFY`` of the glyph height → triangulated and extruded
  by ``trimesh.creation.extrude_polygon`` to a depth of ``DEPTH`` of the glyph height): the alphanumerics of the
  NLOS literature (Mu et al. 2022; LFE's test sets);
- ``assets/meshes/primitives/``: a few trimesh primitives (sphere, cylinder, cone, capsule, torus, box).

Canonical frame (metres, right-handed, z up): the bounding box is centred on the origin and its longest side is
1; a glyph stands upright in the y-z plane (glyph x → +y, glyph up → +z) and is extruded along x, so with yaw 0
it faces a relay wall of normal ±x. ``assets/meshes/manifest.json`` lists every file with its triangle count,
bounding box, whether it is watertight and its sha256.

Run from the repository root (needs ``shapely`` and ``mapbox-earcut``: ``pip install -e ".[assets]"``)::

    python scripts/make_assets.py [--out assets/meshes]

The output is deterministic (same files, same hashes) for the same library versions.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import string
from pathlib import Path

import numpy as np

DEPTH = 0.2
"""Extrusion depth of a glyph, as a fraction of the glyph height before normalisation."""

SIMPLIFY = 0.008
"""Douglas–Peucker tolerance of the glyph outlines, as a fraction of the font size (keeps files small: a few
hundred triangles per glyph; the outline moves by at most this much)."""

FONT = {"family": "DejaVu Sans", "weight": "bold"}
"""matplotlib's bundled font (always present with matplotlib)."""


def glyph_mesh(char: str):
    """Watertight trimesh of ``char`` extruded from its font outline, in the canonical frame (module doc)."""
    import trimesh
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath
    from shapely.geometry import Polygon

    path = TextPath((0.0, 0.0), char, size=1.0, prop=FontProperties(**FONT))
    rings = [Polygon(p) for p in path.to_polygons(closed_only=True) if len(p) >= 3]
    shape = rings[0]
    for ring in rings[1:]:           # even-odd fill: holes are rings inside rings
        shape = shape.symmetric_difference(ring)
    shape = shape.simplify(SIMPLIFY, preserve_topology=True)
    parts = list(shape.geoms) if hasattr(shape, "geoms") else [shape]
    height = shape.bounds[3] - shape.bounds[1]
    mesh = trimesh.util.concatenate([trimesh.creation.extrude_polygon(p, DEPTH * height) for p in parts])
    # glyph (x, y, extrusion z) → world (extrusion, x, y), a cyclic permutation (a proper rotation: the
    # winding, and so the outward normals, are kept): upright in the y-z plane, facing ±x
    mesh.vertices = mesh.vertices[:, [2, 0, 1]]
    return normalised(mesh)


def primitive_meshes() -> dict:
    """name → trimesh of each primitive, in the canonical frame."""
    import trimesh

    return {
        "sphere": trimesh.creation.icosphere(subdivisions=2),
        "cylinder": trimesh.creation.cylinder(radius=0.5, height=1.0, sections=24),
        "cone": trimesh.creation.cone(radius=0.5, height=1.0, sections=24),
        "capsule": trimesh.creation.capsule(radius=0.3, height=0.8, count=[12, 12]),
        "torus": trimesh.creation.torus(major_radius=0.35, minor_radius=0.12, major_sections=24, minor_sections=12),
        "box": trimesh.creation.box(extents=(0.5, 0.8, 1.0)),
    }


def normalised(mesh):
    """``mesh`` translated so its bounding box is centred on the origin and scaled so its longest side is 1."""
    lo, hi = mesh.bounds
    mesh.vertices = (mesh.vertices - 0.5 * (lo + hi)) / float(np.max(hi - lo))
    return mesh


def write(mesh, path: Path) -> dict:
    """Write ``mesh`` as binary PLY (float32 vertices) and return its manifest entry."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
    lo, hi = mesh.bounds
    return {"file": path.name, "triangles": int(len(mesh.faces)), "watertight": bool(mesh.is_watertight),
            "extents": [round(float(v), 6) for v in hi - lo],
            "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("assets/meshes"), help="output folder")
    args = parser.parse_args()
    manifest: dict[str, list] = {"alphanumeric": [], "primitives": []}
    for char in string.ascii_uppercase + string.digits:
        manifest["alphanumeric"].append(write(glyph_mesh(char), args.out / "alphanumeric" / f"{char}.ply"))
    for name, mesh in primitive_meshes().items():
        manifest["primitives"].append(write(normalised(mesh), args.out / "primitives" / f"{name}.ply"))
    (args.out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    sizes = sum(p.stat().st_size for p in args.out.rglob("*.ply"))
    n = sum(len(v) for v in manifest.values())
    tris = sum(e["triangles"] for v in manifest.values() for e in v)
    print(f"wrote {n} meshes ({tris} triangles, {sizes / 1024:.0f} KiB) to {args.out}")


if __name__ == "__main__":
    main()
