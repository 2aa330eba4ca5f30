"""Dataset builds: sharded Zarr v3 stores written shard by shard, locally or on Dask (docs/physics.md §7).

The layout of a dataset on disk, its lock and its card are :mod:`datagen.dataset.store`'s; what its files must
be, its verification and its repair :mod:`datagen.dataset.integrity`'s; the Dask engine
:mod:`datagen.dataset.dask_engine`'s; workers that die with the build :mod:`datagen.dataset.workers`'.

A build checks everything before it writes anything (options, config, the output directory, with ``--resume``
the stored config and mesh assets, the size of every mesh asset, a probe sample, the shard memory, the
scheduler), so a refused command leaves no stub behind; the cheap checks come before the probe sample, which
may take minutes. The card pins the mesh assets (:func:`datagen.dataset.assets.asset_record`), so a resume
never mixes samples drawn from two asset lists. A shard is the unit of work: :func:`write_shard` computes its
samples with :func:`datagen.dataset.make_sample` and writes each array's whole shard in one call, then the
marker. A build skips shards that have an intact marker (resume; damaged or missing shards are rebuilt), runs
the rest on an engine (in process, a local process pool recycled every ``max_tasks_per_child`` shards, a Dask
``LocalCluster`` or a Dask scheduler address), retries failed shards and reports the ones that still fail,
keeping every finished shard; a full disk stops it at once, resumably.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import sys
import threading
import time
import traceback
from collections import Counter, deque
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .assets import asset_record, config_asset_entries
from .config import DatasetConfig, Sample, config_from_json, load_dataset_config, make_sample
from .probe import probe_notice
from ..errors import DatasetError
from ..units import format_duration
from .dask_engine import (FATAL_ERRNOS, WORKER_TIMEOUT_S, StoreWriteError, check_worker_timeout, connect_dask,
                          fatal_error, named_write_errors, run_dask)
from .integrity import remove_shard_files, repair_store
from .store import (DONE_DIR, LOCK_NAME, BuildLock, ShardTask, card_layout, check_dataset_dir, check_same_assets,
                    check_same_config, consolidate, file_sha256, finish_card, initialize_card, marker_path,
                    plan_shards, read_card, read_marker, shard_file, write_json_atomic, zarr_module)
from .workers import BUILD_PID_ENV, check_build_options, init_worker

DEFAULT_RETRIES = 2
DEFAULT_TASKS_PER_CHILD = 4
"""Shards a local worker process computes before it is replaced (bounds leaked memory per worker)."""
IN_FLIGHT_PER_WORKER = 2
"""Shards queued per local worker: keeps the pool busy without holding every task's future at once."""

SHARD_BUFFER_COPIES = 3
"""Copies of a shard's data a worker holds while writing it (the samples, their stacked arrays, the encoded
chunks): the shard-size term of the build's memory estimate."""


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


def _init_pool_worker(queue, build_pid: int) -> None:
    """Pool worker initializer: die with the build (:func:`datagen.dataset.workers.init_worker`) and report
    every computed sample on ``queue`` (a multiprocessing queue, or None)."""
    global _SAMPLE_DONE
    init_worker(build_pid)
    if queue is not None:
        _SAMPLE_DONE = lambda: queue.put(1)  # noqa: E731


def _config_of(config_json: dict) -> DatasetConfig:
    key = json.dumps(config_json, sort_keys=True)
    if key not in _CONFIG_CACHE:
        _CONFIG_CACHE.clear()
        _CONFIG_CACHE[key] = config_from_json(config_json)
    return _CONFIG_CACHE[key]


def _check_and_stack(samples: list[Sample], arrays: dict, task: ShardTask) -> dict[str, np.ndarray]:
    """Stack each field over the shard's samples after checking field set, shapes, dtypes and component names
    against the dataset's arrays (DatasetError naming the sample and the field)."""
    for k, s in enumerate(samples):
        where = f"sample ({task.split}, {task.start + k})"
        if set(s.arrays) != set(arrays):
            raise DatasetError(f"{where} has fields {sorted(s.arrays)}, the dataset stores {sorted(arrays)}")
        for name, arr in arrays.items():
            value = s.arrays[name]
            if value.shape != arr.shape[1:]:
                raise DatasetError(f"{where}: {name} has shape {value.shape}, the dataset's is {arr.shape[1:]} "
                                 "(every sample must have the same shape)")
            if name != "params" and value.dtype != arr.dtype:
                raise DatasetError(f"{where}: {name} has dtype {value.dtype}, the dataset's is {arr.dtype}")
        if "components" in arrays and s.component_names != list(arrays["components"].attrs["component_names"]):
            raise DatasetError(f"{where}: components {s.component_names} differ from the dataset's "
                             f"{list(arrays['components'].attrs['component_names'])}")
    return {name: np.stack([s.arrays[name] for s in samples]) for name in arrays}


def write_shard(root: str, config_json: dict, task: ShardTask) -> dict:
    """Compute the samples of ``task`` and write each array's whole shard in one call, then its done marker.

    Runs in a worker (local process, Dask worker or in process); takes plain data only.

    Returns:
        the marker dict (also written to ``_done/<split>/<shard>.json``).
    Raises:
        DatasetError: a sample failed, or its field set / shapes / dtypes differ from the dataset's (the
            message names the sample and the field).
        StoreWriteError: the disk is full, over quota or read-only (names the shard and the dataset).
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
    # a shard rewritten after a kill or a repair starts from nothing: zarr would otherwise read (and trip on) a
    # truncated or damaged file before overwriting it
    remove_shard_files(root, task, {name: (arr.shape[1:], None) for name, arr in arrays.items()})
    hashes = {}
    try:
        for name, arr in arrays.items():   # every check passed: now one write per array
            arr[task.start:task.stop] = stacked[name]
            hashes[name] = file_sha256(shard_file(root, task.split, name, task.shard, arr.ndim))
        marker = {"split": task.split, "shard": task.shard, "start": task.start, "stop": task.stop,
                  "sha256": hashes, "seconds": [s.seconds for s in samples],
                  "envelope_error": [float(s.arrays["envelope_error"]) for s in samples],
                  **({"orders": [s.orders for s in samples]} if any(s.orders for s in samples) else {}),
                  "shard_seconds": {"compute": t1 - t0, "write": time.perf_counter() - t1},
                  "worker": {"host": socket.gethostname(), "pid": os.getpid()},
                  "finished": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        write_json_atomic(marker_path(root, task.split, task.shard), marker)
    except OSError as exc:
        if exc.errno in FATAL_ERRNOS:
            raise StoreWriteError(exc.errno, f"{os.strerror(exc.errno)} while writing shard {task.label} of "
                                  f"{root}") from None
        raise
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
                if fatal_error(exc):
                    raise
                if attempt == retries:
                    yield task, None, _reason(exc) + "\n" + traceback.format_exc(limit=-3)


def _run_pool(root: str, cfg: dict, tasks: list[ShardTask], workers: int, retries: int,
              tasks_per_child: int, on_sample: Callable[[], None] | None = None) -> Iterator[Event]:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    import threading

    ctx = multiprocessing.get_context("forkserver")
    # the fork server dies with this process (its preload module sets the parent-death signal), the workers
    # with the fork server and with this process (their initializer): datagen.dataset.workers
    os.environ[BUILD_PID_ENV] = str(os.getpid())
    ctx.set_forkserver_preload(["datagen.dataset.forkserver_preload", "datagen.dataset.build"])
    queue = ctx.SimpleQueue() if on_sample is not None else None

    def new_pool():
        return ProcessPoolExecutor(workers, mp_context=ctx, max_tasks_per_child=tasks_per_child,
                                   initializer=_init_pool_worker, initargs=(queue, os.getpid()))

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
                    if fatal_error(exc):
                        raise
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


# ---------------------------------------------------------------------------------------------------------
# Probe


def _first_split(config: DatasetConfig) -> str:
    """The first split with samples (the probe's); ValueError when every split has count 0 (a YAML config is
    refused when it loads, one cut with ``model_copy`` here)."""
    split = next((s for s, spec in config.splits.items() if spec.count > 0), None)
    if split is None:
        raise ValueError(f"{config.name}: every split has count 0 ({', '.join(config.splits)}): nothing to build")
    return split


PROJECTION_NOTE_S = 60.0
"""A build whose projection (probe time × samples ÷ processes) exceeds this many seconds says so after the probe."""


def _probe(config: DatasetConfig, progress: bool = False, processes: int = 1, project: bool = True) -> Sample:
    """Sample 0 of the first non-empty split: its shapes fix the dataset's (computed before any write).

    With ``progress``, one line on stderr says the probe runs (it may take minutes) and its tolerance loop reports
    each round (and the transport's bar). With or without it, a new build (``project``) projected beyond
    :data:`PROJECTION_NOTE_S` says how long on ``processes``, and a probe that missed its tolerance says so in one
    line (:func:`probe_notice`), before the build spends."""
    split = _first_split(config)
    if progress:
        print(f"build {config.name}: probe sample ({split}, 0) first: its arrays fix the dataset's shapes",
              file=sys.stderr)
    t0 = time.perf_counter()
    probe = make_sample(config, split, 0, progress=True) if progress else make_sample(config, split, 0)
    seconds = time.perf_counter() - t0
    total = sum(spec.count for spec in config.splits.values())
    projected = seconds * total / max(processes, 1)
    if project and projected > PROJECTION_NOTE_S:          # a long build says so, --quiet or not
        print(f"build {config.name}: the probe took {seconds:.3g} s; {total} samples project to about "
              f"{format_duration(projected)} on {processes} process{'es' if processes > 1 else ''} (samples differ: "
              "the bar's ETA follows the build)", file=sys.stderr)
    line = probe_notice(config, split, probe) if project else None
    if line is not None:
        print(line, file=sys.stderr)
    return probe


def check_shard_memory(config: DatasetConfig, probe: Sample, processes: int) -> None:
    """Refuse a shard size whose buffers (:data:`SHARD_BUFFER_COPIES` × shard_size × one sample's bytes, per
    process) exceed the available memory.

    Raises:
        ResourceError: naming shard_size, its value and both figures in GiB.
    """
    from ..simulation.budget import check_memory
    per_sample = sum(len(str(a[()])) if a.dtype == object else a.nbytes for a in probe.arrays.values())
    check_memory(SHARD_BUFFER_COPIES * config.shard_size * per_sample * max(1, processes), "shard_size",
                 f"{config.shard_size} ({per_sample / 2**20:.3g} MiB per sample, {max(1, processes)} process(es))",
                 f"{config.name}: ")


# ---------------------------------------------------------------------------------------------------------
# Build


@dataclass
class BuildReport:
    """What a build did: shards computed now / skipped (already done), samples, wall time, engine, and what
    ``--resume`` repaired first (one line each: metadata rewritten, damaged shards rebuilt)."""

    path: Path
    shards_built: int
    shards_skipped: int
    samples_built: int
    seconds: float
    engine: str
    card: dict = field(default_factory=dict)
    repairs: list[str] = field(default_factory=list)

    @property
    def samples_per_second(self) -> float:
        return self.samples_built / self.seconds if self.seconds > 0 else float("nan")


def build_dataset(config: DatasetConfig | str | Path, out: str | Path, workers: int | None = None,
                  scheduler: str | None = None, resume: bool = False, retries: int = DEFAULT_RETRIES,
                  max_tasks_per_child: int = DEFAULT_TASKS_PER_CHILD, progress: bool = True,
                  on_shard: Callable[[dict], None] | None = None, worker_timeout: float = WORKER_TIMEOUT_S
                  ) -> BuildReport:
    """Build (or resume) the dataset of ``config`` into ``out``.

    Everything is checked before anything is written: the options, the config, ``out`` (not a file, not under
    one, not a foreign or existing dataset without ``resume``), a probe sample (sample 0 of the first non-empty
    split, which also fixes the arrays' shapes), the memory the shards need, and the Dask scheduler. Before the
    probe (which may take minutes), every mesh asset's triangle count is read from its header and refused above
    :data:`datagen.dataset.assets.MAX_ASSET_TRIANGLES`, and a resume compares the stored config and the pinned
    mesh assets (:func:`datagen.dataset.store.check_same_config`, :func:`~datagen.dataset.store.check_same_assets`).
    A resumed build first repairs the store (:func:`datagen.dataset.integrity.repair_store`): metadata that
    differs from what the card implies is rewritten, and every done shard whose files are missing or whose
    bytes differ from its marker's sha256 is rebuilt, bit-identical to an uninterrupted build.

    Args:
        config: a resolved :class:`DatasetConfig` or a YAML path.
        out: dataset directory (a Zarr v3 group).
        workers: local worker processes (default: CPU count; 0: compute in this process) or Dask LocalCluster
            workers.
        scheduler: None (local processes), "local" (Dask LocalCluster) or a Dask scheduler address
            ("tcp://host:8786"; the workers must see ``out`` at the same path: docs/datasets.md, "Running on a
            cluster").
        resume: continue a build whose store exists: intact shards with a done marker are skipped.
        retries: extra attempts of a failed shard (>= 0).
        max_tasks_per_child: shards per local worker process before it is replaced (>= 1).
        progress: tqdm bar in samples (rate and ETA).
        on_shard: called with each finished shard's marker (in this process).
        worker_timeout: seconds (> 0) a scheduler address may have no worker, at the start (the count is
            printed on stderr) or mid-build, before the build gives up.
    Returns:
        :class:`BuildReport`.
    Raises:
        ValueError: an invalid option (naming it), or every split has count 0; DatasetError: invalid config or
            probe sample, a mesh asset over :data:`~datagen.dataset.assets.MAX_ASSET_TRIANGLES` triangles, or
            ``--resume`` with a different config or other mesh assets than the stored ones; ResourceError: the
            shards need more memory than available; SchedulerError: the scheduler cannot be reached, has
            no worker for ``worker_timeout`` s or is lost mid-build.
        FileExistsError / PermissionError: ``out`` is a file, under one, not writable, holds a dataset (and
            ``resume`` is False) or other files.
        BuildLockedError: another build is writing ``out``.
        StoreWriteError: the disk filled up (or is read-only); finished shards are kept, resume later.
        BuildError: shards still failing after retries (finished shards are kept; resume later).
    """
    check_build_options(workers, scheduler, retries, max_tasks_per_child)
    check_worker_timeout(worker_timeout)
    if not isinstance(config, DatasetConfig):
        config = load_dataset_config(config)
    _first_split(config)
    root = Path(out)
    check_dataset_dir(root, resume)
    if resume and (root / LOCK_NAME).exists():   # a build writing it now (its card perhaps not yet written)
        BuildLock(root).acquire().release()
    stored = read_card(root) if resume and (root / "zarr.json").exists() else None
    if stored is not None:
        check_same_config(root, stored, config)   # first: no asset is read and no sample computed for a wrong one
    entries = config_asset_entries(config)
    assets = asset_record(entries)     # every mesh's size from its header, then its sha256: before the probe
    if stored is not None:
        check_same_assets(root, stored, assets, entries)
    processes = 1 if workers == 0 or scheduler else (workers or os.cpu_count() or 1)
    probe = _probe(config, progress, processes, project=stored is None)
    check_shard_memory(config, probe, processes)
    dask = connect_dask(scheduler, workers, worker_timeout) if scheduler else None
    try:
        return _build(config, root, probe, (assets, entries), dask, workers, scheduler, resume, retries,
                      max_tasks_per_child, progress, on_shard)
    finally:
        if dask is not None:
            dask.close()   # the client, and the LocalCluster it started


def _open_store(root: Path, config: DatasetConfig, probe: Sample, pinned: tuple[list[dict], list[tuple[str, ...]]],
                resume: bool) -> tuple[dict, list[str]]:
    """Under the lock: initialise a fresh store (removing what it wrote if that fails), or read and check an
    existing one (``check_same_config``, ``check_same_assets``; the layout is refreshed from the probe, and a
    card without pinned assets gets the ``pinned`` ones, with a note). Returns the card and the repairs."""
    assets, entries = pinned
    exists = (root / "zarr.json").exists()
    if exists and not resume:
        raise FileExistsError(f"{root} already holds a dataset; pass --resume to continue it, or choose "
                              "another --out")
    if not exists:
        others = [p.name for p in root.iterdir() if p.name not in (LOCK_NAME, DONE_DIR)]
        if others:
            raise FileExistsError(f"{root} exists and is not empty ({', '.join(sorted(others)[:5])}); "
                                  "choose another --out")
        try:
            if (root / DONE_DIR).exists():   # stale markers from an earlier, removed store must not count
                shutil.rmtree(root / DONE_DIR)
            return initialize_card(root, config, probe, assets), []
        except BaseException:
            for path in root.iterdir():      # a failed initialisation leaves nothing behind
                if path.name != LOCK_NAME:
                    shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)
            raise
    card = read_card(root)
    check_same_config(root, card, config)
    check_same_assets(root, card, assets, entries)
    if "splits" not in card or "time_edges" not in card:   # killed while creating the arrays
        return initialize_card(root, config, probe, assets), ["card: initialisation completed (it was interrupted)"]
    repairs = []
    if "assets" not in card:   # built before the card pinned its assets: pin the current ones from now on
        card["assets"] = assets
        zarr_module().open_group(str(root), mode="r+").update_attributes({"assets": assets})
        if assets:
            repairs.append(f"card: pinned the {len(assets)} mesh asset files found now (name, sha256); the card "
                           "had no asset list (built before datagen recorded it), so the shards built before "
                           "were not checked against it")
    layout = card_layout(config, probe)
    changed = [k for k, v in layout.items() if card.get(k) != v]
    if changed:   # edited or damaged card: the config and the probe are the truth
        card.update(layout)
        zarr_module().open_group(str(root), mode="r+").update_attributes(card)
        repairs.append(f"card: {', '.join(changed)} rewritten from the config and the probe sample")
    return card, repairs


def _build(config: DatasetConfig, root: Path, probe: Sample, pinned: tuple[list[dict], list[tuple[str, ...]]],
           dask, workers: int | None, scheduler: str | None, resume: bool, retries: int, max_tasks_per_child: int,
           progress: bool, on_shard: Callable[[dict], None] | None) -> BuildReport:
    cfg_json = config.to_json()
    t_start = time.perf_counter()
    engine = ("dask:" + scheduler) if scheduler else ("in-process" if workers == 0 else "processes")
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    try:
        with BuildLock(root):
            with named_write_errors(f"{'opening' if resume else 'creating'} the dataset store {root}", "free space, "
                                    "then run again" + (" with --resume (its shards are kept)" if resume else "")):
                card, repairs = _open_store(root, config, probe, pinned, resume)
                repairs += repair_store(root, card, config)
            report = _run(config, root, card, cfg_json, dask, workers, scheduler, retries, max_tasks_per_child,
                          progress, on_shard, engine, t_start)
            report.repairs = repairs
            return report
    except BaseException:
        if created and not (root / "zarr.json").exists():
            shutil.rmtree(root, ignore_errors=True)   # nothing of a dataset was written: leave no stub
        raise


def _run(config, root, card, cfg_json, dask, workers, scheduler, retries, max_tasks_per_child, progress,
         on_shard, engine, t_start) -> BuildReport:
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

    def count_sample():
        with progress_lock:
            computed[0] += 1
            if bar is not None:
                bar.update(1)

    on_sample = count_sample if bar is not None else None   # None: shard-level progress (Dask) or no bar
    if not todo:
        events: Iterator[Event] = iter(())
    elif scheduler:   # the bar moves shard by shard
        events = run_dask(write_shard, str(root), cfg_json, todo, dask, retries)
        on_sample = None
    elif workers == 0:
        events = _run_in_process(str(root), cfg_json, todo, retries, on_sample)
    else:
        n = min(workers or os.cpu_count() or 1, len(todo))
        events = _run_pool(str(root), cfg_json, todo, n, retries, max_tasks_per_child,
                           on_sample)
    failures: dict[tuple[str, int], str] = {}
    built = samples = 0
    fatal = None
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
    except OSError as exc:
        fatal = exc if exc.errno in FATAL_ERRNOS else None
        if fatal is None:
            raise
    finally:
        if bar is not None:
            with progress_lock:
                bar.n = done_before + samples
            bar.close()
    seconds = time.perf_counter() - t_start
    try:
        card = finish_card(root, card, config)
        card.setdefault("runs", []).append({
            "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"), "engine": engine,
            "workers": workers, "shards_built": built, "shards_failed": len(failures), "samples": samples,
            "wall_s": seconds, "samples_per_s": samples / seconds if seconds > 0 else None,
            "host": socket.gethostname()})
        zarr_module().open_group(str(root), mode="r+").update_attributes(card)   # written atomically by zarr
        if card["status"] == "complete":
            consolidate(root)
    except OSError as exc:
        if fatal is None and exc.errno not in FATAL_ERRNOS:
            raise
        fatal = fatal or exc
    if fatal is not None:
        what = fatal.strerror if isinstance(fatal, StoreWriteError) else \
            f"{os.strerror(fatal.errno)} while writing the dataset {root}"
        raise StoreWriteError(fatal.errno, f"{what}; the {built} shard(s) finished in this run are kept: free "
                              "space, then run again with --resume") from None
    if failures:
        lines = [f"  {split}/{shard:06d}: {reason.splitlines()[0]}"
                 for (split, shard), reason in sorted(failures.items())]
        raise BuildError(f"{len(failures)} shard(s) failed after {retries} retries (finished shards are kept; "
                         f"fix the cause and run again with --resume):\n" + "\n".join(lines), failures)
    return BuildReport(root, built, skipped, samples, seconds, engine, card)
