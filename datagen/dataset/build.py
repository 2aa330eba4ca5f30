"""Dataset builds: sharded Zarr v3 stores written shard by shard, locally or on Dask (docs/physics.md §7).

The layout of a dataset on disk, its lock, its card and its verification are :mod:`datagen.dataset.store`'s.

A shard is the unit of work: :func:`write_shard` computes its samples with
:func:`datagen.dataset.make_sample` and writes each array's whole shard in one call, then the marker. A build
skips shards that have a marker (resume), runs the rest on an engine (in process, a local process pool
recycled every ``max_tasks_per_child`` shards, a Dask ``LocalCluster`` or a Dask scheduler address), retries
failed shards and reports the ones that still fail, keeping every finished shard.
"""
from __future__ import annotations

import json
import os
import socket
import threading
import time
import traceback
from collections import Counter, deque
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .config import (STREAMS, DatasetConfig, Sample, config_from_json, load_dataset_config, make_sample,
                     split_key)
from ..scene import SceneError
from .store import (DONE_DIR, FORMAT, FORMAT_VERSION, LOCK_NAME, BuildLock, ShardTask, code_version, consolidate,
                    create_arrays, file_sha256, finish_card, marker_path, plan_shards, read_card, read_marker,
                    shard_file, write_json_atomic, zarr_module)

DEFAULT_RETRIES = 2
DEFAULT_TASKS_PER_CHILD = 4
"""Shards a local worker process computes before it is replaced (bounds leaked memory per worker)."""
IN_FLIGHT_PER_WORKER = 2
"""Shards queued per local worker: keeps the pool busy without holding every task's future at once."""


class BuildError(RuntimeError):
    """Some shards still failed after their retries; ``failures`` maps (split, shard) → reason."""

    def __init__(self, message: str, failures: dict[tuple[str, int], str]):
        super().__init__(message)
        self.failures = failures


# ---------------------------------------------------------------------------------------------------------
# The shard task


_CONFIG_CACHE: dict[str, DatasetConfig] = {}

_SAMPLE_DONE: Callable[[], None] | None = None
"""Called after each computed sample (progress bar): set in process, or by :func:`_init_pool_worker`."""


def _init_pool_worker(queue) -> None:
    """Pool worker initializer: report every computed sample on ``queue`` (a multiprocessing queue)."""
    global _SAMPLE_DONE
    _SAMPLE_DONE = lambda: queue.put(1)  # noqa: E731


def _config_of(config_json: dict) -> DatasetConfig:
    key = json.dumps(config_json, sort_keys=True)
    if key not in _CONFIG_CACHE:
        _CONFIG_CACHE.clear()
        _CONFIG_CACHE[key] = config_from_json(config_json)
    return _CONFIG_CACHE[key]


def _check_and_stack(samples: list[Sample], arrays: dict, task: ShardTask) -> dict[str, np.ndarray]:
    """Stack each field over the shard's samples after checking field set, shapes, dtypes and component names
    against the dataset's arrays (SceneError naming the sample and the field)."""
    for k, s in enumerate(samples):
        where = f"sample ({task.split}, {task.start + k})"
        if set(s.arrays) != set(arrays):
            raise SceneError(f"{where} has fields {sorted(s.arrays)}, the dataset stores {sorted(arrays)}")
        for name, arr in arrays.items():
            value = s.arrays[name]
            if value.shape != arr.shape[1:]:
                raise SceneError(f"{where}: {name} has shape {value.shape}, the dataset's is {arr.shape[1:]} "
                                 "(every sample must have the same shape)")
            if name != "params" and value.dtype != arr.dtype:
                raise SceneError(f"{where}: {name} has dtype {value.dtype}, the dataset's is {arr.dtype}")
        if "components" in arrays and s.component_names != list(arrays["components"].attrs["component_names"]):
            raise SceneError(f"{where}: components {s.component_names} differ from the dataset's "
                             f"{list(arrays['components'].attrs['component_names'])}")
    return {name: np.stack([s.arrays[name] for s in samples]) for name in arrays}


def write_shard(root: str, config_json: dict, task: ShardTask) -> dict:
    """Compute the samples of ``task`` and write each array's whole shard in one call, then its done marker.

    Runs in a worker (local process, Dask worker or in process); takes plain data only.

    Returns:
        the marker dict (also written to ``_done/<split>/<shard>.json``).
    Raises:
        SceneError: a sample failed, or its field set / shapes / dtypes differ from the dataset's (the
            message names the sample and the field).
    """
    zarr = zarr_module()
    config = _config_of(config_json)
    t0 = time.perf_counter()
    samples = []
    for i in range(task.start, task.stop):
        samples.append(make_sample(config, task.split, i))
        if _SAMPLE_DONE is not None:
            _SAMPLE_DONE()
    t1 = time.perf_counter()
    group = zarr.open_group(str(Path(root) / task.split), mode="r+")
    with zarr.config.set({"array.write_empty_chunks": True}):   # every shard file exists, even all-zero ones
        arrays = {n: group[n] for n in sorted(group.array_keys()) if n != "time_edges"}
    stacked = _check_and_stack(samples, arrays, task)
    hashes = {}
    for name, arr in arrays.items():   # every check passed: now one write per array
        arr[task.start:task.stop] = stacked[name]
        hashes[name] = file_sha256(shard_file(root, task.split, name, task.shard, arr.ndim))
    marker = {"split": task.split, "shard": task.shard, "start": task.start, "stop": task.stop,
              "sha256": hashes, "seconds": [s.seconds for s in samples],
              "envelope_error": [float(s.arrays["envelope_error"]) for s in samples],
              "shard_seconds": {"compute": t1 - t0, "write": time.perf_counter() - t1},
              "worker": {"host": socket.gethostname(), "pid": os.getpid()},
              "finished": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    write_json_atomic(marker_path(root, task.split, task.shard), marker)
    return marker


# ---------------------------------------------------------------------------------------------------------
# Engines: each yields (task, marker, None) or (task, None, reason) once per task, retrying internally.

Event = tuple[ShardTask, "dict | None", "str | None"]


def _reason(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}"
    cause = exc.__cause__
    if cause is not None and type(cause).__name__ == "_RemoteTraceback":
        text += "\n" + str(cause).strip()
    return text


def _run_in_process(root: str, cfg: dict, tasks: list[ShardTask], retries: int,
                    on_sample: Callable[[], None] | None = None) -> Iterator[Event]:
    global _SAMPLE_DONE
    _SAMPLE_DONE = on_sample
    try:
        yield from _in_process(root, cfg, tasks, retries)
    finally:
        _SAMPLE_DONE = None


def _in_process(root: str, cfg: dict, tasks: list[ShardTask], retries: int) -> Iterator[Event]:
    for task in tasks:
        for attempt in range(retries + 1):
            try:
                yield task, write_shard(root, cfg, task), None
                break
            except Exception as exc:  # noqa: BLE001 - any failure of a shard is reported, not fatal
                if attempt == retries:
                    yield task, None, _reason(exc) + "\n" + traceback.format_exc(limit=-3)


def _run_pool(root: str, cfg: dict, tasks: list[ShardTask], workers: int, retries: int,
              tasks_per_child: int, on_sample: Callable[[], None] | None = None) -> Iterator[Event]:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    import threading

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["datagen.dataset.build"])
    queue = ctx.SimpleQueue() if on_sample is not None else None

    def new_pool():
        return ProcessPoolExecutor(workers, mp_context=ctx, max_tasks_per_child=tasks_per_child,
                                   initializer=_init_pool_worker if queue is not None else None,
                                   initargs=(queue,) if queue is not None else ())

    def relay():   # per-sample progress from the workers
        while queue.get() is not None:
            on_sample()

    relay_thread = threading.Thread(target=relay, daemon=True) if queue is not None else None
    if relay_thread is not None:
        relay_thread.start()

    pending, attempts, running = deque(tasks), Counter(), {}
    pool = new_pool()
    try:
        while pending or running:
            while pending and len(running) < workers * IN_FLIGHT_PER_WORKER:
                task = pending.popleft()
                running[pool.submit(write_shard, root, cfg, task)] = task
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            broken = False
            for fut in done:
                task = running.pop(fut)
                try:
                    yield task, fut.result(), None
                    continue
                except BrokenProcessPool as exc:
                    broken, reason = True, f"worker process died ({exc}); killed or out of memory?"
                except Exception as exc:  # noqa: BLE001
                    reason = _reason(exc)
                attempts[task] += 1
                if attempts[task] > retries:
                    yield task, None, reason
                else:
                    pending.appendleft(task)
            if broken:   # every queued future of a broken pool fails too: requeue them on a fresh pool
                for fut, task in list(running.items()):
                    fut.cancel()
                    pending.appendleft(task)
                running.clear()
                pool.shutdown(wait=False, cancel_futures=True)
                pool = new_pool()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if relay_thread is not None:
            queue.put(None)
            relay_thread.join(timeout=10)


def _run_dask(root: str, cfg: dict, tasks: list[ShardTask], scheduler: str, workers: int | None,
              retries: int) -> Iterator[Event]:
    import logging
    import uuid

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        run = uuid.uuid4().hex[:8]
        futures = {client.submit(write_shard, root, cfg, task, key=f"datagen-shard-{task.split}-{task.shard}-{run}",
                                 retries=retries, pure=False): task for task in tasks}
        for fut in as_completed(futures):
            task = futures[fut]
            if fut.status == "finished":
                yield task, fut.result(), None
            else:
                exc = fut.exception()
                tb = "".join(traceback.format_tb(fut.traceback()))[-2000:] if fut.traceback() else ""
                yield task, None, f"{type(exc).__name__}: {exc}\n{tb}"
            fut.release()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# ---------------------------------------------------------------------------------------------------------
# Card


def _initialize(root: Path, config: DatasetConfig) -> dict:
    """Compute a probe sample (its shapes fix the dataset's), write the card, create every array."""
    from ..simulation import library_versions

    card = {"format": FORMAT, "format_version": FORMAT_VERSION, "name": config.name, "status": "incomplete",
            "config": config.to_json(), "config_sha256": config.fingerprint(), "code_version": code_version(),
            "versions": library_versions(), "streams": STREAMS,
            "seed_rule": "SeedSequence(seed, spawn_key=(split_key, index, stream)), split_key = CRC-32 of the "
                         "split name; loader noise: SeedSequence(seed, spawn_key=(split_key, epoch, index, 4))",
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"), "runs": []}
    group = zarr_module().open_group(str(root), mode="a", zarr_format=3)
    group.update_attributes(card)
    non_empty = [s for s, spec in config.splits.items() if spec.count > 0]
    splits = {}
    if non_empty:
        probe = make_sample(config, non_empty[0], 0)
        splits = create_arrays(root, config, probe)
        card["time_edges"] = {"t_start": float(probe.time_edges[0]), "n_bins": len(probe.time_edges) - 1,
                              "bin_width": float(probe.time_edges[1] - probe.time_edges[0])}
    for split in config.splits:
        sim = config.simulation_config(split)
        splits.setdefault(split, {"count": 0, "split_key": split_key(split), "n_shards": 0, "fields": {}})
        splits[split]["detector"] = sim.detector_config().model_dump(mode="json")
    card["splits"] = splits
    group.update_attributes(card)
    return card


# ---------------------------------------------------------------------------------------------------------
# Build


@dataclass
class BuildReport:
    """What a build did: shards computed now / skipped (already done), samples, wall time, engine."""

    path: Path
    shards_built: int
    shards_skipped: int
    samples_built: int
    seconds: float
    engine: str
    card: dict = field(default_factory=dict)

    @property
    def samples_per_second(self) -> float:
        return self.samples_built / self.seconds if self.seconds > 0 else float("nan")


def _config_diff(a, b, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _config_diff(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def build_dataset(config: DatasetConfig | str | Path, out: str | Path, workers: int | None = None,
                  scheduler: str | None = None, resume: bool = False, retries: int = DEFAULT_RETRIES,
                  max_tasks_per_child: int = DEFAULT_TASKS_PER_CHILD, progress: bool = True,
                  on_shard: Callable[[dict], None] | None = None) -> BuildReport:
    """Build (or resume) the dataset of ``config`` into ``out``.

    Args:
        config: a resolved :class:`DatasetConfig` or a YAML path.
        out: dataset directory (a Zarr v3 group).
        workers: local worker processes (default: CPU count; 0: compute in this process) or Dask LocalCluster
            workers.
        scheduler: None (local processes), "local" (Dask LocalCluster) or a Dask scheduler address
            ("tcp://host:8786"; the workers must see ``out`` at the same path).
        resume: continue a build whose store exists: shards with a done marker are skipped.
        retries: extra attempts of a failed shard.
        max_tasks_per_child: shards per local worker process before it is replaced.
        progress: tqdm bar in samples (rate and ETA).
        on_shard: called with each finished shard's marker (in this process).
    Returns:
        :class:`BuildReport`.
    Raises:
        SceneError: invalid config, or ``--resume`` with a different config than the stored one.
        FileExistsError: ``out`` holds a dataset (or other files) and ``resume`` is False.
        BuildLockedError: another build is writing ``out``.
        BuildError: shards still failing after retries (finished shards are kept; resume later).
    """
    if not isinstance(config, DatasetConfig):
        config = load_dataset_config(config)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    cfg_json = config.to_json()
    t_start = time.perf_counter()
    engine = ("dask:" + scheduler) if scheduler else ("in-process" if workers == 0 else "processes")
    with BuildLock(root):
        exists = (root / "zarr.json").exists()
        if exists and not resume:
            raise FileExistsError(f"{root} already holds a dataset; pass --resume to continue it, or choose "
                                  "another --out")
        if not exists:
            others = [p.name for p in root.iterdir() if p.name not in (LOCK_NAME, DONE_DIR)]
            if others:
                raise FileExistsError(f"{root} exists and is not empty ({', '.join(sorted(others)[:5])}); "
                                      "choose another --out")
            # a fresh build: stale markers from an earlier, removed store must not count
            if (root / DONE_DIR).exists():
                import shutil
                shutil.rmtree(root / DONE_DIR)
            card = _initialize(root, config)
        else:
            card = read_card(root)
            if card.get("config_sha256") != config.fingerprint():
                diff = _config_diff(card.get("config", {}), cfg_json)
                raise SceneError(f"{root} was built from a different config (differs in: {', '.join(diff)}); "
                                 "resume with the same config or build into another --out")
            if "splits" not in card:   # killed while creating the arrays
                card = _initialize(root, config)

        tasks = plan_shards(config)
        todo = [t for t in tasks if read_marker(root, t.split, t.shard) is None]
        skipped = len(tasks) - len(todo)
        total = sum(t.size for t in tasks)
        bar = None
        if progress:
            from tqdm.auto import tqdm
            bar = tqdm(total=total, initial=total - sum(t.size for t in todo), unit="sample",
                       desc=f"build {config.name}", smoothing=0.05, dynamic_ncols=True)
        done_before = total - sum(t.size for t in todo)
        progress_lock = threading.Lock()
        computed = [0]   # samples computed so far in this run (retried ones included), for the bar

        def on_sample():
            with progress_lock:
                computed[0] += 1
                if bar is not None:
                    bar.update(1)

        if not todo:
            events: Iterator[Event] = iter(())
        elif scheduler:   # the bar moves shard by shard
            events = _run_dask(str(root), cfg_json, todo, scheduler, workers, retries)
            on_sample = None
        elif workers == 0:
            events = _run_in_process(str(root), cfg_json, todo, retries, on_sample if bar is not None else None)
        else:
            n = min(workers or os.cpu_count() or 1, len(todo))
            events = _run_pool(str(root), cfg_json, todo, n, retries, max_tasks_per_child,
                               on_sample if bar is not None else None)
        failures: dict[tuple[str, int], str] = {}
        built = samples = 0
        try:
            for task, marker, reason in events:
                if marker is not None:
                    built += 1
                    samples += task.size
                    if on_shard is not None:
                        on_shard(marker)
                else:
                    failures[(task.split, task.shard)] = reason or "unknown error"
                if bar is not None:
                    with progress_lock:
                        if on_sample is None and marker is not None:   # shard-level progress (Dask)
                            bar.update(task.size)
                        elif marker is None:   # a failed shard's samples do not count (retries may overshoot
                            bar.n = done_before + samples   # briefly; the bar is exact again at the end)
                            bar.refresh()
        finally:
            if bar is not None:
                with progress_lock:
                    bar.n = done_before + samples
                bar.close()
        seconds = time.perf_counter() - t_start
        card = finish_card(root, card, config)
        card.setdefault("runs", []).append({
            "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"), "engine": engine,
            "workers": workers, "shards_built": built, "shards_failed": len(failures), "samples": samples,
            "wall_s": seconds, "samples_per_s": samples / seconds if seconds > 0 else None,
            "host": socket.gethostname()})
        group = zarr_module().open_group(str(root), mode="r+")
        group.update_attributes(card)
        if card["status"] == "complete":
            consolidate(root)
    if failures:
        lines = [f"  {split}/{shard:06d}: {reason.splitlines()[0]}"
                 for (split, shard), reason in sorted(failures.items())]
        raise BuildError(f"{len(failures)} shard(s) failed after {retries} retries (finished shards are kept; "
                         f"fix the cause and run again with --resume):\n" + "\n".join(lines), failures)
    return BuildReport(root, built, skipped, samples, seconds, engine, card)
