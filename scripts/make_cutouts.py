"""Write the planar cut-outs of the Stanford LCT release's kind to ``assets/meshes/cutouts/`` (no download).

One binary PLY per cut-out of :func:`datagen.dataset.cutouts.cutout_library`: the 36 shipped glyphs' faces, five signs
(the release's exit sign among them), dot charts and bar charts, each a flat sheet of zero thickness in the glyphs'
asset frame (facing ±x, upright along z; docs/datasets.md, "The LCT release's kind of set-up"). Sheets are not
watertight, so they are not in ``assets/meshes/manifest.json`` (whose entries are closed meshes); the files'
sha256 are in ``assets/meshes/cutouts/manifest.json``.

Run from the repository root::

    PYTHONPATH=$PWD python scripts/make_cutouts.py [--out assets/meshes/cutouts]

The output is deterministic (same files, same hashes) for the same numpy and trimesh versions.
"""
from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np
import trimesh

from datagen.dataset.cutouts import cutout_library, cutout_mesh


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="assets/meshes/cutouts", help="output folder (default %(default)s)")
    parser.add_argument("--glyphs", default="assets/meshes/alphanumeric", help="the shipped glyph meshes")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = []
    for name, mask in cutout_library(args.glyphs).items():
        vertices, faces = cutout_mesh(mask)
        mesh = trimesh.Trimesh(vertices.astype(np.float32), faces, process=True)   # shared corners merged
        path = out / f"{name}.ply"
        path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
        manifest.append({"file": path.name, "triangles": int(len(mesh.faces)), "cells": list(mask.shape),
                         "sha256": hashlib.sha256(path.read_bytes()).hexdigest()})
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"wrote {len(manifest)} cut-outs to {out} ({sum(p.stat().st_size for p in out.glob('*.ply'))} bytes)")


if __name__ == "__main__":
    main()
