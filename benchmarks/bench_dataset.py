"""Benchmark of dataset builds, their accuracy and the loader (issues 4 and 12). Plain script::

    python benchmarks/bench_dataset.py                       # every measurement
    python benchmarks/bench_dataset.py --quick               # 16-sample build, 8 accuracy checks, no big build
    python benchmarks/bench_dataset.py --big-config smoke    # the 1000-sample build on the smoke config

Reports
* build throughput (samples/s) of ``configs/datasets/default.yaml`` cut to ``--samples`` (40) train samples,
  ``--workers`` (2) local worker processes, and the distribution of the samples' stored ``envelope_error``
  (median, p95, max; samples that missed the tolerance);
* accuracy (``--honesty`` 24 samples of the default config's ``val`` split, which no test uses): each sample as
  the build stores it (``make_sample``) against ``datagen.converged_reference`` of its own scene and simulation
  config (``datagen.sample_setup``; rel_tol 3e-3, cached under ``--cache-dir``): the actual relative L2 error,
  the stored estimate, their ratio; checks median actual ≤ 1 %, worst ≤ 2 %, actual ≤ 2 × estimate for every
  sample (the reference's own error, ≤ 0.3 %, is included in "actual");
* loader throughput (samples/s) of ``NLOSDataset`` on that store with ``DataLoader(num_workers=2,
  batch_size=64, shuffle=True, persistent_workers=True)``, frozen and re-drawn noise, after a warm-up epoch;
  plus the time of one ``__getitem__`` in the main process;
* peak resident memory (RSS summed over the build process and all its children, sampled every 0.1 s) of a
  ``--big`` (1000) sample build of ``--big-config`` (default or smoke).
Timings depend on the machine's load: run it on an otherwise idle machine.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

from datagen.dataset import build_dataset  # noqa: E402
from datagen.dataset import load_dataset_config  # noqa: E402
from datagen.dataset.config import SplitSpec  # noqa: E402

CONFIGS = {"default": ROOT / "configs/datasets/default.yaml", "smoke": ROOT / "configs/datasets/smoke.yaml"}


def config_with(name: str, samples: int, shard_size: int | None = None):
    config = load_dataset_config(CONFIGS[name])
    update = {"splits": {"train": SplitSpec(count=samples)}}
    if shard_size:
        update["shard_size"] = shard_size
    return config.model_copy(update=update)


class PeakRSS:
    """Peak of the summed RSS of this process and all its descendants, sampled in a thread."""

    def __init__(self, interval: float = 0.1):
        self.interval, self.peak, self._stop = interval, 0, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        me = psutil.Process()
        while not self._stop.is_set():
            total = 0
            for proc in [me] + me.children(recursive=True):
                try:
                    total += proc.memory_info().rss
                except psutil.Error:
                    pass
            self.peak = max(self.peak, total)
            time.sleep(self.interval)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def tree_cpu_seconds() -> float:
    """User + system CPU seconds of this process and its live children (load-independent work measure)."""
    total = 0.0
    me = psutil.Process()
    for proc in [me] + me.children(recursive=True):
        try:
            t = proc.cpu_times()
            total += t.user + t.system
        except psutil.Error:
            pass
    return total


def bench_build(tmp: Path, samples: int, workers: int) -> tuple[Path, float]:
    out = tmp / "default_build"
    config = config_with("default", samples, shard_size=max(1, samples // (2 * workers)))
    report = build_dataset(config, out, workers=workers, progress=False)
    timing = report.card["timing"]["per_sample_s"]
    print(f"build  default config, {samples} samples, {workers} workers, shard size {config.shard_size}: "
          f"{report.samples_per_second:.2f} samples/s ({report.seconds:.1f} s wall incl. pool start-up; "
          f"per sample {timing['mean']:.3f} s mean, {timing['p95']:.3f} s p95 in a worker)")
    print(f"build  without the pool start-up: {workers} workers / "
          f"{timing['mean']:.3f} s per sample = {workers / timing['mean']:.2f} samples/s")
    acc = report.card["accuracy"]
    e = acc["envelope_error"]
    print(f"build  envelope_error (estimated relative L2) at tolerance {acc['tolerance']:.2%}: median "
          f"{e['median']:.3%}, p95 {e['p95']:.3%}, max {e['max']:.3%}; {acc['n_missed']} of {e['n']} samples missed")
    # load-independent view: CPU seconds of one sample in this process (the build is one thread per sample)
    from datagen.dataset import make_sample
    make_sample(config, "train", 0)
    cpu0 = time.process_time()
    for i in range(1, 9):
        make_sample(config, "train", i)
    cpu = (time.process_time() - cpu0) / 8
    print(f"build  {cpu:.3f} CPU-s per default sample in one process: {workers / cpu:.1f} samples/s expected on "
          f"{workers} idle cores")
    return out, report.samples_per_second


def bench_accuracy(n: int, cache: Path, split: str = "val") -> dict:
    """Stored envelope and envelope_error of ``n`` samples of ``split`` against converged references."""
    import numpy as np

    import datagen
    from datagen.analysis import relative_l2
    from datagen.dataset import make_sample

    config = load_dataset_config(CONFIGS["default"])
    rows = []
    print(f"\naccuracy: {n} samples of the default config's {split!r} split (no test uses them) against "
          f"converged_reference(rel_tol=3e-3); tolerance {config.tolerance:.2%}")
    print("| sample | replicas | stored estimate | actual rel L2 | actual / estimate | reference error |")
    print("|---|---:|---:|---:|---:|---:|")
    for i in range(n):
        sample = make_sample(config, split, i)
        estimate = float(sample.arrays["envelope_error"])
        replicas = json.loads(str(sample.arrays["params"][()]))["accuracy"]["replicas"]
        scene, sim = datagen.sample_setup(config, split, i)
        ref = datagen.converged_reference(scene, sim, rel_tol=3e-3, cache_dir=cache)
        actual = relative_l2(sample.arrays["envelope"].astype(np.float64), ref.envelope)
        rows.append((i, replicas, estimate, actual, ref.error_estimate["rel_l2"]))
        print(f"| {split}[{i}] | {replicas} | {estimate:.3%} | {actual:.3%} | {actual / estimate:.2f} | "
              f"{ref.error_estimate['rel_l2']:.3%} |", flush=True)
    est = np.array([r[2] for r in rows])
    act = np.array([r[3] for r in rows])
    ratio = act / est
    checks = {"median actual <= 1 %": float(np.median(act)) <= 0.01, "worst actual <= 2 %": float(act.max()) <= 0.02,
              "actual <= 2 x estimate for every sample": bool((ratio <= 2.0).all())}
    print(f"accuracy: median actual {np.median(act):.3%}, worst {act.max():.3%}; estimate median {np.median(est):.3%}; "
          f"actual/estimate median {np.median(ratio):.2f}, max {ratio.max():.2f}")
    for name, ok in checks.items():
        print(f"accuracy check {name}: {'PASS' if ok else 'FAIL'}")
    return {"rows": rows, "checks": checks}


def bench_loader(path: Path, epochs: int = 5) -> dict:
    import torch
    from torch.utils.data import DataLoader

    from datagen.dataset import NLOSDataset

    results = {}
    ds = NLOSDataset(path, split="train")
    ds[0]
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < 1.0:
        ds[n % len(ds)]
        n += 1
    per_item = (time.perf_counter() - t0) / n
    sample_bytes = sum(t.numel() * t.element_size() for t in ds[0].values())
    print(f"loader one __getitem__ in the main process: {per_item * 1e6:.0f} µs "
          f"({len(ds.fields)} fields, {sample_bytes / 1024:.1f} KiB per sample)")
    for noise in ("frozen", "resample"):
        ds = NLOSDataset(path, split="train", noise=noise)
        # a few thousand items per epoch, like a real training set: repeat the stored samples
        # (re-drawn noise is far slower: a smaller epoch)
        items = max(4096 if noise == "frozen" else 256, len(ds))
        index = torch.utils.data.Subset(ds, [i % len(ds) for i in range(items)])
        loader = DataLoader(index, batch_size=64, shuffle=True, num_workers=2, persistent_workers=True)
        for _ in loader:   # warm-up epoch: worker start-up, shard indexes
            pass
        cpu0, t0, seen = tree_cpu_seconds(), time.perf_counter(), 0
        for epoch in range(epochs if noise == "frozen" else 1):
            for batch in loader:
                seen += batch["envelope"].shape[0]
        rate = seen / (time.perf_counter() - t0)
        per_cpu = seen / (tree_cpu_seconds() - cpu0)
        results[noise] = rate
        print(f"loader DataLoader(num_workers=2, batch 64, shuffle) noise={noise}: {rate:.0f} samples/s "
              f"({per_cpu:.0f} samples per CPU-second of the main process and its workers together)")
        del loader
    return results


def bench_memory(tmp: Path, samples: int, workers: int, name: str) -> float:
    out = tmp / f"{name}_big"
    config = config_with(name, samples)
    before = psutil.Process().memory_info().rss
    with PeakRSS() as rss:
        report = build_dataset(config, out, workers=workers, progress=False)
    print(f"memory {samples}-sample build of the {name} config, {workers} workers: peak RSS of the process tree "
          f"{rss.peak / 2**20:.0f} MiB, of which this driver process held {before / 2**20:.0f} MiB before the "
          f"build ({report.samples_per_second:.2f} samples/s, {report.seconds:.0f} s)")
    return rss.peak


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--big", type=int, default=1000)
    parser.add_argument("--big-config", choices=sorted(CONFIGS), default="default")
    parser.add_argument("--skip-big", action="store_true")
    parser.add_argument("--honesty", type=int, default=24, help="val samples checked against converged references")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="reference cache (default $DATAGEN_CACHE or ~/.cache/datagen, /references)")
    parser.add_argument("--quick", action="store_true", help="16-sample build, 8 accuracy checks, no big build")
    args = parser.parse_args()
    if args.quick:
        args.samples, args.honesty, args.skip_big = 16, 8, True
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.1f}")
    tmp = Path(tempfile.mkdtemp(prefix="bench_dataset_"))
    try:
        path, _ = bench_build(tmp, args.samples, args.workers)
        bench_loader(path)
        if args.honesty:
            from datagen.cli.bench import default_cache_dir
            bench_accuracy(args.honesty, args.cache_dir or default_cache_dir())
        if not args.skip_big:
            bench_memory(tmp, args.big, args.workers, args.big_config)
            if args.big_config == "default":
                print(f"\nthroughput of the default config at its tolerance on {args.workers} workers: the "
                      f"{args.big}-sample build above is the figure to quote (target >= 10 samples/s; the "
                      f"{args.samples}-sample build carries the pool start-up)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
