"""Classical baseline for the confocal wall scans: filtered backprojection → a depth image per sample, written in
the layout of ``datagen score``.

    python -m examples.backprojection_baseline data/wall_baseline    # → data/wall_baseline_bp_val.npz
    datagen score data/wall_baseline_bp_val.npz --dataset data/wall_baseline --split val

For each scan point p (row iy, column ix of the scan grid, docs/scans.md "Axis order") the voxels
p + d·n̂ in front of it (n̂ the relay wall's normal towards the hidden side, d from ``--near`` to ``--far`` at
``--step``) form a (H, W, D) volume; :func:`datagen.analysis.backprojection.backproject` fills it from every
scan point's transient (round trip t = 2·|x − p|/c: the wall configs count neither wall leg), with the sensor
leg's fall-off undone (:func:`~datagen.analysis.backprojection.wall_leg_weights`), and
:func:`~datagen.analysis.backprojection.laplacian_filter` sharpens it (filtered backprojection, Arellano et al.
2017). The depth of pixel (iy, ix) is the d of the filtered volume's maximum along its column: the orthographic
distance from the wall, as the ``wall_depth`` label. It reads the measured (stored, frozen) counts by default
(``--input envelope``: the noise-free envelope). No training; ≈ 0.2 s per 16 × 16 × 256 scan.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import datagen
from datagen.analysis.backprojection import backproject, laplacian_filter, wall_leg_weights

NEAR, FAR, STEP = 0.3, 1.9, 0.02
"""Depths searched by default (m in front of the wall): the wall configs place objects 0.5–1.5 m out
(configs/rooms/wall.yaml), plus their half-depth and margin. The confocal rooms (configs/rooms/confocal.yaml) place
them up to ≈ 3 m from the relay wall: search to ``--far 4.0`` there."""


def scan_geometry(params: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (H, W, 3) m, wall normal (3,) pointing to the hidden side, sensor position (3,) m) of a confocal
    scan sample, from its params (``room.sensor.scan.laser_grid``; grid convention of docs/scans.md)."""
    room = params["room"]
    grid = room["sensor"]["scan"]["laser_grid"]
    nx, ny = grid["points"]
    width, height = grid["size"]
    normal = np.array([-1.0, 0.0, 0.0])          # the relay wall x = relay_x faces −x (the hidden side)
    u, v = np.cross(normal, [0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])
    fx = (np.arange(nx) + 0.5) / nx - 0.5
    fy = (np.arange(ny) + 0.5) / ny - 0.5
    points = (np.asarray(grid["center"], float) + fx[None, :, None] * width * u
              + fy[:, None, None] * height * v)
    return points, normal, np.asarray(room["sensor"]["position"], float)


def depth_image(scan: np.ndarray, time_edges: np.ndarray, params: dict, near: float = NEAR, far: float = FAR,
                step: float = STEP) -> np.ndarray:
    """Filtered-backprojection depth image of one confocal scan.

    Args:
        scan: (H, W, T) counts or envelope (the stored layout).
        time_edges: (T + 1,) s; params: the sample's params (:meth:`datagen.NLOSDataset.params`).
    Returns:
        (H, W) float32 depth in metres in front of the wall (the ``wall_depth`` convention).
    """
    points, normal, sensor = scan_geometry(params)
    depths = np.arange(near + step / 2, far, step)
    voxels = points[:, :, None, :] + depths[None, None, :, None] * normal             # (H, W, D, 3)
    flat = points.reshape(-1, 3)
    volume = backproject(scan.reshape(len(flat), -1), time_edges, flat, voxels,
                         weights=wall_leg_weights(flat, -normal, sensor))
    filtered = laplacian_filter(volume)
    return depths[np.argmax(filtered, axis=-1)].astype(np.float32)


def predict(path: str | Path, split: str, field: str = "counts", limit: int | None = None, near: float = NEAR,
            far: float = FAR) -> dict[str, np.ndarray]:
    """{"depth": (N, H, W) float32 m, "index": (N,) int64} for the first ``limit`` samples of ``split``, searching
    depths ``near`` to ``far`` (m in front of the wall)."""
    ds = datagen.NLOSDataset(path, split=split, fields=(field,))
    n = len(ds) if limit is None else min(limit, len(ds))
    depth = np.stack([depth_image(ds.read(i)[field].astype(np.float64), ds.time_edges, ds.params(i), near, far)
                      for i in range(n)])
    return {"depth": depth, "index": np.arange(n)}


def main(argv=None):
    parser = argparse.ArgumentParser(description="filtered backprojection depth images of a confocal scan split")
    parser.add_argument("data")
    parser.add_argument("--split", default="val")
    parser.add_argument("--input", choices=("counts", "envelope"), default="counts")
    parser.add_argument("--out", default=None, help="predictions .npz (default: DATA_bp_<split>.npz)")
    parser.add_argument("--limit", type=int, default=None, help="only the first N samples")
    parser.add_argument("--near", type=float, default=NEAR, help=f"nearest depth searched, m (default {NEAR})")
    parser.add_argument("--far", type=float, default=FAR,
                        help=f"farthest depth searched, m (default {FAR}; confocal_baseline's rooms: 4.0)")
    args = parser.parse_args(argv)
    if not 0 <= args.near < args.far - STEP:
        parser.error(f"--near {args.near} and --far {args.far}: need 0 <= near < far - {STEP} m (depths searched in "
                     f"{STEP} m steps)")
    t0 = time.perf_counter()
    pred = predict(args.data, args.split, args.input, args.limit, args.near, args.far)
    out = Path(args.out or f"{Path(args.data)}_bp_{args.split}.npz")
    np.savez(out, **pred)
    print(f"{len(pred['index'])} depth images ({time.perf_counter() - t0:.1f} s) -> {out}")
    print(f"score: datagen score {out} --dataset {args.data} --split {args.split}")


if __name__ == "__main__":
    main()
