"""Loader throughput in the network layout (issue 30): samples/s of ``NLOSDataset(layout="network")`` through a
``torch.utils.data.DataLoader`` with 2 worker processes. Plain script::

    python benchmarks/bench_loader_network.py data/wall128                  # its train split, (1, 512, 128, 128)
    python benchmarks/bench_loader_network.py data/wall128 --fields envelope --epochs 3

Per epoch it iterates the whole split once in a shuffled order (``batch_size`` 8, ``num_workers`` 2, a fresh
DataLoader each epoch so the workers' start-up counts, as in a training loop without persistent workers) and
reports samples/s and MB/s of the tensors delivered (envelope and counts as float32, ``wall_depth``); the first
epoch also reads the files from disk unless the page cache holds them, so the best of the epochs is the
loader's own rate. A sample's compressed bytes on disk (the shard files' size over the sample count) is printed
too. Nothing else runs in the loop: this is the rate a training step must not exceed to be loader-bound.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from datagen.dataset import NLOSDataset  # noqa: E402


def disk_bytes(path: Path, split: str) -> dict[str, int]:
    """Bytes of each field's shard files of ``split``."""
    out = {}
    for field in sorted(p for p in (path / split).iterdir() if p.is_dir()):
        out[field.name] = sum(f.stat().st_size for f in (field / "c").rglob("*") if f.is_file())
    return out


def epoch(ds, workers: int, batch: int, seed: int) -> tuple[float, int]:
    """(seconds, bytes delivered) of one shuffled pass."""
    loader = torch.utils.data.DataLoader(ds, batch_size=batch, shuffle=True, num_workers=workers,
                                         generator=torch.Generator().manual_seed(seed))
    t0, nbytes = time.perf_counter(), 0
    for item in loader:
        nbytes += sum(v.numel() * v.element_size() for v in item.values() if isinstance(v, torch.Tensor))
    return time.perf_counter() - t0, nbytes


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="train")
    parser.add_argument("--fields", default="envelope,counts,wall_depth")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--epochs", type=int, default=3)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    path = Path(args.data)
    fields = tuple(args.fields.split(","))
    ds = NLOSDataset(path, split=args.split, fields=fields, layout="network", counts_dtype=torch.float32)
    shapes = {k: tuple(v.shape) for k, v in ds[0].items() if isinstance(v, torch.Tensor)}
    sizes = disk_bytes(path, args.split)
    print(f"{path} {args.split}: {len(ds)} samples, {shapes}; on disk per sample: "
          + ", ".join(f"{k} {v / len(ds) / 1e6:.2f} MB" for k, v in sizes.items() if k in fields)
          + f"; {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load "
          + " ".join(f"{x:.1f}" for x in os.getloadavg()))
    rates = []
    for e in range(args.epochs):
        sec, nbytes = epoch(ds, args.workers, args.batch, e)
        rates.append(len(ds) / sec)
        print(f"epoch {e}: {sec:.1f} s, {len(ds) / sec:.1f} samples/s, {nbytes / sec / 1e6:.0f} MB/s delivered "
              f"({args.workers} workers, batch {args.batch})")
    print(f"best: {max(rates):.1f} samples/s")


if __name__ == "__main__":
    main()
