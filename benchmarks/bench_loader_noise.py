"""Batched SPAD noise (datagen.SPADNoise) against today's per-item re-draw in the loader, and what it costs a
training loop (issue 16). Plain script::

    python benchmarks/bench_loader_noise.py            # builds 192 default-config samples in a temp dir
    python benchmarks/bench_loader_noise.py --quick    # 64 samples, fewer repetitions
    python benchmarks/bench_loader_noise.py --data data/default     # an existing build (its train split)

Measures, in one process with one torch thread, repetitions interleaved, medians reported:

1. noise cost per sample (CPU time, ``time.process_time``): the loader's re-draw, ``NLOSDataset(noise=
   "resample")[i]`` minus ``NLOSDataset(noise="frozen")[i]`` for the counts field (numpy: rates, the pile-up
   tree sampler, the per-item generator), against ``SPADNoise`` on batches of 64 and 256 of the same envelopes;
2. a training loop (the baseline network of ``examples/train_single_pixel.py``, batch 64, AdamW, one torch
   thread) over in-memory data, CPU and wall time per epoch: frozen stored counts against counts drawn per
   batch with ``SPADNoise`` in the loop (the training device, here the CPU). Both read the same tensors, so the
   difference is the noise alone;
3. the same network fed by ``DataLoader(num_workers=2, batch_size=64, persistent_workers=True)``, wall time per
   epoch: frozen counts, today's per-item re-draw (``noise="resample"``), ``SPADNoise`` in the loop, and
   ``SPADNoise`` in the workers (``datagen.dataset.BatchNoise`` as ``collate_fn``).
The machine is shared with other jobs: ratios measured in one run are the result, not the absolute times.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import datagen  # noqa: E402
from datagen.dataset import BatchNoise, build_dataset, load_dataset_config  # noqa: E402
from datagen.dataset.config import SplitSpec  # noqa: E402
from examples.train_single_pixel import Net  # noqa: E402


def build(out: Path, samples: int) -> Path:
    config = load_dataset_config(ROOT / "configs/datasets/default.yaml")
    config = config.model_copy(update={"splits": {"train": SplitSpec(count=samples)}, "shard_size": 32})
    t0 = time.perf_counter()
    build_dataset(config, out, workers=2, progress=False)
    print(f"built {samples} default-config samples in {time.perf_counter() - t0:.0f} s")
    return out


def per_item_cpu(ds, indices) -> float:
    t0 = time.process_time()
    for i in indices:
        ds[i]
    return (time.process_time() - t0) / len(indices)


def batched_cpu(noise, envelopes, batch, gen) -> float:
    t0 = time.process_time()
    for s in range(0, len(envelopes), batch):
        noise(envelopes[s:s + batch], gen)
    return (time.process_time() - t0) / len(envelopes)


def epoch_time(net, opt, x_source, n, batch=64) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one epoch."""
    c0, t0 = time.process_time(), time.perf_counter()
    for s in range(0, n, batch):
        x = x_source(s, min(s + batch, n))
        loss = net(x).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return time.process_time() - c0, time.perf_counter() - t0


def main():
    parser = argparse.ArgumentParser(description="SPADNoise vs per-item re-draw; training loop overhead")
    parser.add_argument("--data", help="existing dataset (train split); default: build one in a temp dir")
    parser.add_argument("--samples", type=int, default=192)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="64 samples, 3 repetitions")
    args = parser.parse_args()
    if args.quick:
        args.samples, args.reps = 64, 3
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.data) if args.data else build(Path(tmp) / "ds", args.samples)
        frozen = datagen.NLOSDataset(path, fields=("counts",))
        resample = datagen.NLOSDataset(path, fields=("counts",), noise="resample")
        n = min(len(frozen), args.samples)
        envelopes = torch.stack([datagen.NLOSDataset(path, fields=("envelope",))[i]["envelope"] for i in range(n)])
        counts = torch.stack([frozen[i]["counts"] for i in range(n)]).double()
        noise = resample.spad_noise()
        gen = torch.Generator().manual_seed(0)
        times = {"loader re-draw (per item)": [], "SPADNoise, batch 64": [], "SPADNoise, batch 256": []}
        for rep in range(args.reps):
            idx = range(n)
            times["loader re-draw (per item)"].append(per_item_cpu(resample, idx) - per_item_cpu(frozen, idx))
            times["SPADNoise, batch 64"].append(batched_cpu(noise, envelopes, 64, gen))
            times["SPADNoise, batch 256"].append(batched_cpu(noise, envelopes, 256, gen))
        base = statistics.median(times["loader re-draw (per item)"])
        print(f"\nnoise cost per sample (CPU time, 1 thread, {envelopes.shape[-1]} bins, {n} samples, "
              f"median of {args.reps})")
        print(f"{'':30s} {'us/sample':>10s} {'cheaper than re-draw':>21s}")
        for name, values in times.items():
            med = statistics.median(values)
            print(f"{name:30s} {med * 1e6:10.1f} {base / med:20.1f}x")

        net = Net(1, envelopes.shape[-1], 4)
        opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
        scale = torch.log1p(counts).mean()

        def frozen_x(a, b):
            return (torch.log1p(counts[a:b]) / scale).float()[:, None]

        def batched_x(a, b):
            return (torch.log1p(noise(envelopes[a:b], gen)) / scale).float()[:, None]

        loop = {"frozen counts": [], "SPADNoise per batch": []}
        epoch_time(net, opt, frozen_x, n)      # warm-up
        for rep in range(2 * args.reps):
            loop["frozen counts"].append(epoch_time(net, opt, frozen_x, n))
            loop["SPADNoise per batch"].append(epoch_time(net, opt, batched_x, n))
        ref_cpu = statistics.median(c for c, _ in loop["frozen counts"])
        ref_wall = statistics.median(w for _, w in loop["frozen counts"])
        print(f"\ntraining loop, {sum(p.numel() for p in net.parameters()) / 1e3:.0f} k-parameter baseline CNN "
              f"(examples/train_single_pixel.py), batch 64, {n} samples per epoch, 1 thread, median of "
              f"{2 * args.reps} epochs")
        print(f"{'':30s} {'CPU s/epoch':>12s} {'vs frozen':>10s} {'wall s/epoch':>13s} {'vs frozen':>10s}")
        for name, values in loop.items():
            cpu, wall = statistics.median(c for c, _ in values), statistics.median(w for _, w in values)
            print(f"{name:30s} {cpu:12.3f} {cpu / ref_cpu - 1:+9.1%} {wall:13.3f} {wall / ref_wall - 1:+9.1%}")
        def loader_epoch(loader, make_x) -> float:
            t0 = time.perf_counter()
            for _ in range(2):
                for batch in loader:
                    loss = net(make_x(batch)).square().mean()
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
            return (time.perf_counter() - t0) / 2

        def dl(ds, **kw):
            return torch.utils.data.DataLoader(ds, batch_size=64, shuffle=True, num_workers=2,
                                               persistent_workers=True, **kw)

        env_ds = datagen.NLOSDataset(path, fields=("envelope",))
        modes = {
            "frozen counts": (dl(frozen), lambda b: (torch.log1p(b["counts"].double()) / scale).float()[:, None]),
            "per-item re-draw (workers)": (dl(resample),
                                           lambda b: (torch.log1p(b["counts"].double()) / scale).float()[:, None]),
            "SPADNoise in the loop": (dl(env_ds), lambda b: (torch.log1p(noise(b["envelope"], gen)) / scale)
                                      .float()[:, None]),
            "SPADNoise in the workers": (dl(env_ds, collate_fn=BatchNoise(noise, seed=1)),
                                         lambda b: (torch.log1p(b["counts"]) / scale).float()[:, None]),
        }
        walls = {name: [] for name in modes}
        for name, (loader, make_x) in modes.items():
            loader_epoch(loader, make_x)       # start the workers, warm up
        for rep in range(args.reps):
            for name, (loader, make_x) in modes.items():
                walls[name].append(loader_epoch(loader, make_x))
        ref = statistics.median(walls["frozen counts"])
        print(f"\nthe same loop fed by DataLoader(num_workers=2, batch_size=64), wall time per epoch, median of "
              f"{args.reps}")
        print(f"{'':30s} {'wall s/epoch':>13s} {'vs frozen':>10s}")
        for name, values in walls.items():
            med = statistics.median(values)
            print(f"{name:30s} {med:13.3f} {med / ref - 1:+9.1%}")
        print("\n(machine shared with other jobs: compare the ratios, not the absolute times)")


if __name__ == "__main__":
    main()
