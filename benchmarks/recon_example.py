"""A method to score on a benchmark suite, as a template (docs/benchmark.md): LCT on a confocal suite's test split.

    python benchmarks/recon_example.py suites/wall-meshes-v1 pred.npz [--variant clean|low-photon]
    datagen suite score wall-meshes-v1 pred.npz

Reads the test split's scans with ``datagen.NLOSDataset`` (``envelope`` for the clean variant, ``counts`` for the
low-photon one), reconstructs each with :func:`datagen.analysis.lct.lct_volume` and writes ``pred.npz`` with
``depth`` (N, H, W) metres on the wall-view grid: replace ``reconstruct`` by your method.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from datagen.analysis.lct import depth_from_volume, lct_volume  # noqa: E402
from datagen.dataset import NLOSDataset  # noqa: E402
from datagen.dataset.suite import suite_of_dataset  # noqa: E402
from datagen.units import SPEED_OF_LIGHT  # noqa: E402


def reconstruct(scan: np.ndarray, bin_width: float, scan_size: float) -> np.ndarray:
    """(H, W) depth (m) of a confocal scan (H, W, T) of a square of side ``scan_size`` m, bins of ``bin_width`` s."""
    depths = (np.arange(scan.shape[-1]) + 0.5) * SPEED_OF_LIGHT * bin_width / 2
    return depth_from_volume(lct_volume(scan, bin_width, scan_size / 2), depths)[0]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("suite_dir", type=Path)
    p.add_argument("pred", type=Path)
    p.add_argument("--variant", default="clean")
    a = p.parse_args()
    suite, _ = suite_of_dataset(a.suite_dir)
    field = suite.spec.variants[a.variant].input
    ds = NLOSDataset(a.suite_dir, split=suite.spec.test_split, fields=[field])
    bin_width = float(ds.time_edges[1] - ds.time_edges[0])
    depth = []
    for i in range(len(ds)):
        size = ds.params(i)["room"]["sensor"]["scan"]["laser_grid"]["size"][0]    # the scanned square's side (m)
        depth.append(reconstruct(ds.read(i)[field], bin_width, size))
    np.savez(a.pred, depth=np.asarray(depth, np.float32), index=np.arange(len(ds)))
    print(f"wrote {a.pred}: depth {np.shape(depth)} for {suite.name} ({a.variant})")


if __name__ == "__main__":
    main()
