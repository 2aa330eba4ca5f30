"""Scale of a dataset's bookkeeping (issue 30): card, ``datagen verify``, ``--resume`` planning, loader start-up
and the Dask path's per-task overhead, at 10³, 10⁴ and 10⁵ samples. Plain script::

    python benchmarks/bench_scale.py                          # 10³ (real), 10⁴ and 10⁵ (synthetic), Dask
    python benchmarks/bench_scale.py --sizes 1000 --dask-tasks 0   # quick look
    python benchmarks/bench_scale.py --json scale.json        # also write the figures as JSON

The samples cost ~nothing: ``configs/datasets/smoke.yaml`` cut to a single-pixel capture of 32 bins, 256 hidden
samples, 4×4 depth labels, 4³ voxels, two object slots, no components, tolerance 50 % and a 0.05 s cost cap
(≈ 0.04 CPU-s and ≈ 1 KiB of arrays per sample, 17 fields). Sizes up to ``--real-max`` (1000) are built for
real (``build_dataset``, in process); above it the build is the same ``build_dataset`` call (real shards written
by ``write_shard``, done markers, card, consolidation) with ``make_sample`` replaced by a lookup of
``--distinct`` (64) real samples (sample i gets real sample i mod 64): only the simulation is skipped, every
byte on disk is written by the store's own code. For every size the script reports:

* build: wall time and the time spent writing shards (the done markers' ``shard_seconds.write``);
* card: ``finish_card`` (reads every done marker) + writing the root ``zarr.json`` + consolidation, and the
  card's size;
* verify: ``verify_dataset`` in process and ``python -m datagen.cli verify`` (a fresh process, imports included);
* resume planning: ``build_dataset(..., resume=True)`` on the complete set, then with 1 % of the shards removed
  (marker and files), split into its stages (reading the markers, ``repair_store``'s hashing, the card);
* loader: ``NLOSDataset(path)`` construction and the first ``__getitem__`` (median of 3, imports done before);
* files and bytes on disk;
* sha256 throughput (one thread): the per-byte cost of verify and resume.

Then the Dask path: a ``LocalCluster`` of ``--dask-workers`` (2) single-threaded processes runs
``--dask-tasks`` (400) shard tasks through the build's own engine (:func:`datagen.dataset.dask_engine.run_dask`,
with the real config and marker-sized results) whose work is nothing, then the same number sleeping
``--dask-work`` s (0.05): the seconds per task beyond the work.

Timings depend on the machine's load (the documented figures: docs/datasets.md, "Scale").
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

from datagen.dataset import build as build_mod  # noqa: E402
from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config, make_sample  # noqa: E402
from datagen.dataset.config import config_from_json  # noqa: E402
from datagen.dataset.integrity import verify_dataset  # noqa: E402
from datagen.dataset.store import (consolidate, finish_card, marker_path, plan_shards, read_card,  # noqa: E402
                                   shard_file, zarr_module)


def tiny_config(samples: int, shard_size: int):
    """The smoke config cut to near-free samples (module doc), one ``train`` split of ``samples``."""
    j = load_dataset_config(ROOT / "configs/datasets/smoke.yaml").to_json()
    j.update(name="scale", shard_size=shard_size, splits={"train": {"count": samples}}, tolerance=0.5,
             cost_cap=0.05, labels={"max_objects": 2, "depth_map": [4, 4], "voxels": 4})
    j["simulation"]["time"] = {"t_start": "15ns", "bin_width": "1600ps", "n_bins": 32}
    j["simulation"]["estimator"]["samples"] = 256
    j["store"]["components"] = False
    return config_from_json(j)


class Timers:
    """Cumulative seconds and calls of wrapped functions of :mod:`datagen.dataset.build`."""

    def __init__(self):
        self.seconds, self.calls = defaultdict(float), defaultdict(int)

    @contextlib.contextmanager
    def wrap(self, module, *names):
        saved = {n: getattr(module, n) for n in names}

        def timed(name, fn):
            def inner(*a, **k):
                t = time.perf_counter()
                try:
                    return fn(*a, **k)
                finally:
                    self.seconds[name] += time.perf_counter() - t
                    self.calls[name] += 1
            return inner

        for n, fn in saved.items():
            setattr(module, n, timed(n, fn))
        try:
            yield self
        finally:
            for n, fn in saved.items():
                setattr(module, n, fn)


@contextlib.contextmanager
def synthetic_samples(config, distinct: int):
    """``build.make_sample`` replaced by a lookup of ``distinct`` real samples of ``config`` (module doc)."""
    real = [make_sample(config, "train", i) for i in range(distinct)]
    saved = build_mod.make_sample
    build_mod.make_sample = lambda cfg, split, i: real[i % distinct]
    try:
        yield
    finally:
        build_mod.make_sample = saved


def disk_usage(root: Path) -> tuple[int, int]:
    files = size = 0
    for dirpath, _, names in os.walk(root):
        for n in names:
            files += 1
            size += os.path.getsize(os.path.join(dirpath, n))
    return files, size


def timed(fn, repeat: int = 1) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def card_write(root: Path, config) -> float:
    """Seconds of the build's card step on a complete store: finish_card, root zarr.json, consolidation."""
    t = time.perf_counter()
    card = finish_card(root, read_card(root), config)
    zarr_module().open_group(str(root), mode="r+").update_attributes(card)
    consolidate(root)
    return time.perf_counter() - t


def remove_shards(root: Path, config, fraction: float, seed: int = 0) -> int:
    """Delete the done marker and every file of ``fraction`` of the shards (at least one)."""
    tasks = plan_shards(config)
    chosen = random.Random(seed).sample(tasks, max(1, round(fraction * len(tasks))))
    card = read_card(root)
    fields = card["splits"]["train"]["fields"]
    for task in chosen:
        marker_path(root, task.split, task.shard).unlink()
        for name, spec in fields.items():
            shard_file(root, task.split, name, task.shard, 1 + len(spec["shape"])).unlink()
    return len(chosen)


def resume_run(config, out: Path, synthetic: bool, distinct: int) -> dict:
    timers = Timers()
    ctx = synthetic_samples(config, distinct) if synthetic else contextlib.nullcontext()
    with ctx, timers.wrap(build_mod, "repair_store", "read_marker", "finish_card", "consolidate", "write_shard",
                          "read_card"):
        t = time.perf_counter()
        report = build_dataset(config, out, workers=0, resume=True, progress=False)
        wall = time.perf_counter() - t
    return {"wall_s": wall, "shards_built": report.shards_built, **{f"{k}_s": v for k, v in timers.seconds.items()}}


def measure(n: int, args, tmp: Path) -> dict:
    config = tiny_config(n, args.shard_size)
    out = tmp / f"scale_{n}"
    synthetic = n > args.real_max
    row: dict = {"samples": n, "shard_size": args.shard_size, "shards": len(plan_shards(config)),
                 "synthetic": synthetic}
    timers = Timers()
    ctx = synthetic_samples(config, args.distinct) if synthetic else contextlib.nullcontext()
    with ctx, timers.wrap(build_mod, "write_shard"):
        t = time.perf_counter()
        build_dataset(config, out, workers=0, progress=False)
        row["build_s"] = time.perf_counter() - t
    row["write_shard_s"] = timers.seconds["write_shard"]
    row["shard_write_only_s"] = sum(json.loads(marker_path(out, task.split, task.shard).read_text())
                                    ["shard_seconds"]["write"] for task in plan_shards(config))
    row["files"], row["bytes"] = disk_usage(out)
    row["card_bytes"] = (out / "zarr.json").stat().st_size
    row["card_s"] = card_write(out, config)
    row["verify_s"] = timed(lambda: verify_dataset(out))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "datagen.cli", "verify", str(out)], env=env, capture_output=True,
                          text=True)
    row["verify_cli_s"] = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"verify failed on {out}:\n{proc.stderr[-2000:]}")
    NLOSDataset(out)                     # imports and first-use set-up outside the timings
    row["loader_init_s"] = timed(lambda: NLOSDataset(out), repeat=3)
    fresh = [NLOSDataset(out) for _ in range(3)]   # the first item of a new dataset object opens its shards
    row["loader_first_item_s"] = statistics.median(timed(lambda ds=ds: ds[n - 1]) for ds in fresh)
    row["resume_complete"] = resume_run(config, out, True, args.distinct)
    row["removed_shards"] = remove_shards(out, config, 0.01)
    row["resume_1pct"] = resume_run(config, out, True, args.distinct)
    row["resume_1pct"]["shard_write_s"] = row["resume_1pct"].pop("write_shard_s", 0.0)
    if not args.keep:
        shutil.rmtree(out)
    return row


# ---------------------------------------------------------------------------------------------------------
# Dask


def trivial_shard(root, cfg, task, marker, work_s=0.0):
    """A shard task whose work is ``work_s`` seconds of sleep, returning a marker-sized dict."""
    if work_s:
        time.sleep(work_s)
    return dict(marker, shard=task.shard, start=task.start, stop=task.stop)


def measure_dask(args) -> dict:
    import functools

    from datagen.dataset.dask_engine import connect_dask, run_dask

    config = tiny_config(args.dask_tasks * args.shard_size, args.shard_size)
    tasks = plan_shards(config)
    marker = {"sha256": {f"field{k}": "0" * 64 for k in range(17)},
              "seconds": [{"room": 0.01, "simulate": 0.03, "labels": 0.001, "total": 0.04}] * args.shard_size,
              "envelope_error": [0.1] * args.shard_size, "shard_seconds": {"compute": 1.0, "write": 0.01},
              "worker": {"host": "h", "pid": 1}, "finished": "2026-01-01T00:00:00+00:00"}
    cfg = config.to_json()
    out: dict = {"workers": args.dask_workers, "tasks": len(tasks), "config_json_bytes": len(json.dumps(cfg)),
                 "marker_json_bytes": len(json.dumps(marker))}
    t = time.perf_counter()
    conn = connect_dask("local", args.dask_workers)
    out["cluster_start_s"] = time.perf_counter() - t
    try:
        for work in (0.0, 0.0, args.dask_work):   # the first pass warms the workers up (imports, cloudpickle)
            fn = functools.partial(trivial_shard, marker=marker, work_s=work)
            t = time.perf_counter()
            n = sum(1 for _, m, reason in run_dask(fn, "/nonexistent", cfg, tasks, conn, 0) if m is not None)
            wall = time.perf_counter() - t
            if n != len(tasks):
                raise SystemExit(f"dask: {len(tasks) - n} trivial tasks failed")
            out[f"wall_s_work_{work:g}"] = wall
        busy = len(tasks) * args.dask_work / args.dask_workers
        out["overhead_per_task_s_no_work"] = out["wall_s_work_0"] * args.dask_workers / len(tasks)
        out["overhead_per_task_s_with_work"] = (out[f"wall_s_work_{args.dask_work:g}"] - busy) * \
            args.dask_workers / len(tasks)
    finally:
        conn.close()
    return out


def hash_rate(megabytes: int = 64) -> float:
    """sha256 throughput of this machine in bytes/s (one thread, in memory): verify's and resume's per-byte cost."""
    import hashlib
    data = os.urandom(megabytes << 20)
    t = time.perf_counter()
    hashlib.sha256(data).hexdigest()
    return len(data) / (time.perf_counter() - t)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="1000,10000,100000", help="comma-separated sample counts")
    p.add_argument("--shard-size", type=int, default=64)
    p.add_argument("--real-max", type=int, default=1000, help="largest size built with real samples")
    p.add_argument("--distinct", type=int, default=64, help="real samples the synthetic sizes cycle through")
    p.add_argument("--dask-workers", type=int, default=2)
    p.add_argument("--dask-tasks", type=int, default=400, help="0: skip the Dask measurement")
    p.add_argument("--dask-work", type=float, default=0.05, help="seconds of work per task in the second pass")
    p.add_argument("--dir", default=None, help="scratch directory (default: a temporary one)")
    p.add_argument("--keep", action="store_true", help="keep the datasets")
    p.add_argument("--json", default=None, help="write every figure to this JSON file")
    args = p.parse_args()
    print(f"{platform.node()}: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}", flush=True)
    tmp = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="bench_scale_"))
    tmp.mkdir(parents=True, exist_ok=True)
    results: dict = {"rows": [], "sha256_bytes_per_s": hash_rate()}
    print(f"sha256: {results['sha256_bytes_per_s'] / 2**20:.0f} MiB/s (one thread)", flush=True)
    try:
        for n in (int(s) for s in args.sizes.split(",")):
            row = measure(n, args, tmp)
            results["rows"].append(row)
            rc, r1 = row["resume_complete"], row["resume_1pct"]
            print(f"{n:>7} samples, {row['shards']} shards of {row['shard_size']}"
                  f"{' (synthetic)' if row['synthetic'] else ''}: build {row['build_s']:.1f} s (shard writes "
                  f"{row['shard_write_only_s']:.1f} s), {row['files']} files, {row['bytes'] / 2**20:.1f} MiB, card "
                  f"{row['card_bytes'] / 2**10:.0f} KiB written in {row['card_s']:.2f} s\n"
                  f"         verify {row['verify_s']:.2f} s (CLI {row['verify_cli_s']:.2f} s); resume complete "
                  f"{rc['wall_s']:.2f} s (repair/hash {rc.get('repair_store_s', 0):.2f}, markers "
                  f"{rc.get('read_marker_s', 0):.2f}, card {rc.get('finish_card_s', 0) + rc.get('consolidate_s', 0):.2f});"
                  f" 1 % missing ({row['removed_shards']} shards) {r1['wall_s']:.2f} s (rebuilding them "
                  f"{r1['shard_write_s']:.2f}); loader init {row['loader_init_s'] * 1e3:.0f} ms, first item "
                  f"{row['loader_first_item_s'] * 1e3:.1f} ms", flush=True)
        if args.dask_tasks:
            d = measure_dask(args)
            results["dask"] = d
            print(f"dask LocalCluster {d['workers']} workers (start {d['cluster_start_s']:.1f} s), {d['tasks']} tasks "
                  f"(config {d['config_json_bytes']} B, marker {d['marker_json_bytes']} B): no work "
                  f"{d['wall_s_work_0']:.2f} s wall = {d['overhead_per_task_s_no_work'] * 1e3:.1f} ms per task per "
                  f"worker; {args.dask_work:g} s of work each: {d['overhead_per_task_s_with_work'] * 1e3:.1f} ms "
                  "per task beyond the work", flush=True)
    finally:
        if not args.dir and not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
