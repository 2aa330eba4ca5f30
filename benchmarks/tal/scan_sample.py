"""tal reads a datagen dataset sample and its backprojection finds the hidden mesh (issue 13).

Runs in datagen's environment and calls ``tal_side.py`` in the tal venv of ``setup_env.sh`` (as compare.py does)::

    python benchmarks/tal/scan_sample.py [--venv /opt/venvs/tal-bench] [--samples 4]

1. Builds a small dataset from ``configs/datasets/wall.yaml`` with one hidden mesh before the wall (the shipped box
   primitive, upright, facing the wall; ``--letters`` uses the alphanumerics instead), a confocal 32 × 32 scan of the
   2 m wall and 512 bins of 32 ps (out/scan_sample/dataset).
2. ``datagen export-tal DATASET --split test --index i --out sample_i.hdf5`` for each sample.
3. ``tal.io.read_capture`` loads each file (``tal_side.py read``) and tal's ``bp`` / ``fbp`` reconstruct it over the
   box in front of the wall (``tal_side.py bp-box``: coarse 4 cm volume, then a 1 m cube of 2 cm voxels around its
   maximum, half-maximum centroid), after ``tal.reconstruct.compensate_laser_cos_dsqr`` (for datagen's aperture
   convention with a co-located sensor it undoes the wall → sensor leg's cos/d²; the confocal aperture follows the
   laser, so there is no cos θ_ap left).
4. The distance of each centroid to the sample's labelled position: the centroid of the hidden object's visible
   surface in the wall-view labels (scan point + n · wall_depth over its mask). Results: out/scan_sample/results.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))    # this checkout's datagen (the export-tal subprocess runs from ROOT too)

from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config  # noqa: E402


def tal_side(args: list[str], venv: Path) -> dict:
    proc = subprocess.run([str(venv / "bin" / "python"), str(HERE / "tal_side.py")] + [str(a) for a in args],
                          capture_output=True, text=True, env={**os.environ, "HOME": str(HERE / "out" / "tal-home")})
    if proc.returncode != 0:
        raise SystemExit(f"tal_side {args[0]} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--venv", type=Path, default=Path(os.environ.get("TAL_BENCH_VENV", "/opt/venvs/tal-bench")))
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--letters", action="store_true", help="alphanumerics instead of the box primitive")
    a = p.parse_args()
    out = HERE / "out" / "scan_sample"
    (HERE / "out" / "tal-home").mkdir(parents=True, exist_ok=True)
    assets = ROOT / "assets" / "meshes" / ("alphanumeric" if a.letters else "primitives/box.ply")
    config = load_dataset_config({
        **load_dataset_config(ROOT / "configs" / "datasets" / "wall.yaml").to_json(),
        "name": "tal_scan_sample", "shard_size": a.samples, "splits": {"test": {"count": a.samples}},
        "room_overrides": {"capture": {"scan": {"points": [32, 32]}}, "objects": {"mesh": {
            "assets": [str(assets)], "yaw_deg": 0.0, "tilt_deg": 0.0, "size": {"min": 0.4, "max": 0.6}}}}})
    dataset = out / f"dataset_{'letters' if a.letters else 'box'}_{a.samples}"
    if not (dataset / "zarr.json").exists():
        build_dataset(config, dataset, workers=0, progress=False)
    ds = NLOSDataset(dataset, split="test", fields=["wall_depth", "wall_mask"])
    rows = []
    for i in range(a.samples):
        path = out / f"sample_{i}.hdf5"
        subprocess.run([sys.executable, "-m", "datagen.cli", "export-tal", str(dataset), "--split", "test", "--index",
                        str(i), "--out", str(path)], check=True, capture_output=True, cwd=ROOT)
        read = tal_side(["read", path], a.venv)
        params = ds.params(i)
        grid = params["room"]["sensor"]["scan"]["laser_grid"]
        x0 = params["room"]["room"]["relay_x"]
        labels = ds.read(i)
        # scan points (iy, ix): centre + ((ix+½)/32 − ½)·w·(+y) + ((iy+½)/32 − ½)·h·(+z); normal −x
        a_ = ((np.arange(32) + 0.5) / 32 - 0.5) * grid["size"][0]
        b_ = ((np.arange(32) + 0.5) / 32 - 0.5) * grid["size"][1]
        pts = np.array(grid["center"]) + b_[:, None, None] * [0, 0, 1.0] + a_[None, :, None] * [0, 1.0, 0]
        mask = labels["wall_mask"][0] > 0
        target = (pts + labels["wall_depth"][..., None] * np.array([-1.0, 0.0, 0.0]))[mask].mean(0)
        row = {"index": i, "asset": Path(params["objects"][0]["asset"]).name, "target_xyz": target.tolist(),
               "tal_read": {"is_confocal": read.get("is_confocal")}}
        bp = tal_side(["bp-box", path, "--lo", x0 - 1.6, -1.0, 0.05, "--hi", x0 - 0.45, 1.0, 2.05], a.venv)
        for name in ("bp", "fbp"):
            found = np.array(bp[name]["half_max_centroid_xyz"])
            row[name] = {"xyz": found.tolist(), "distance_m": float(np.linalg.norm(found - target)),
                         "seconds": bp[name]["seconds"]}
        print(f"sample {i} ({row['asset']}, tal read it: confocal {read.get('is_confocal')}): "
              f"bp {row['bp']['distance_m'] * 100:.1f} cm, fbp {row['fbp']['distance_m'] * 100:.1f} cm "
              f"from the labelled surface {np.round(target, 3).tolist()}", flush=True)
        rows.append(row)
    (out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
