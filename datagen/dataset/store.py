"""Dataset store: the on-disk layout of a dataset, its build lock, its card and its verification (docs/physics.md §7).

Layout of a dataset at ``PATH`` (a Zarr v3 group):

``PATH/zarr.json``
    root attributes = the dataset card (:func:`read_card`): config (room and detector inlined), code
    version, library versions, stream ids and split keys, per-split field shapes, per-sample timing
    statistics, every shard's per-array sha256, build runs; consolidated metadata once the build completes.
``PATH/<split>/``
    one group per split: ``time_edges`` (T+1,) float64 s, and one array per field with the sample axis
    first, inner chunk = one sample, shard = ``shard_size`` samples (zarr's sharding codec, zstd inside).
``PATH/_done/<split>/<shard>.json``
    done marker of a shard, written (atomically) after all its arrays: sample range, per-array sha256 of the
    shard file's bytes, per-sample timings, worker host/pid.
``PATH/_build.lock``
    held (``flock``) while a build runs; a second build into the same path is refused; the kernel drops the
    lock when its process dies, so a killed build never blocks ``--resume``.

Shards are computed and written by :mod:`datagen.dataset.build` (one write per array, then the done marker);
this module plans them (:func:`plan_shards`), writes the card and creates the arrays (:func:`initialize_card`,
:func:`create_arrays`), names shard files and markers, fills the card from the markers (:func:`finish_card`) and
compares a card with the config and the mesh assets of a resume (:func:`check_same_config`,
:func:`check_same_assets`). What the files must be, and the checks of ``datagen verify``, the repairs of
``--resume`` and the loader's checks, are :mod:`datagen.dataset.integrity`'s.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import subprocess
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout

from ..errors import DatasetError
from .assets import asset_changes
from .config import STREAMS, DatasetConfig, Sample, location_free_json, split_key
from .legacy import canonical_json

FORMAT = "datagen-dataset"
FORMAT_VERSION = 1
LOCK_NAME = "_build.lock"
DONE_DIR = "_done"

UNITS = {"envelope": "expected detected photons per laser pulse per bin",
         "envelope_error": "estimated relative L2 error of the envelope (bins above 1 % of its peak; 0.01 = 1 %)",
         "components": "expected detected photons per laser pulse per bin, per component",
         "counts": "SPAD detections over the exposure (int64)",
         "time_edges": "s", "depth": "m", "object_center": "m", "object_size": "m", "object_yaw": "rad",
         "occupancy_origin": "m", "occupancy_pitch": "m", "params": "JSON", "wall_depth": "m"}


MISSED_LISTED = 1000
"""Samples that missed the tolerance listed by name in the card (all are counted)."""


class BuildLockedError(RuntimeError):
    """Another build holds the dataset's lock."""


@dataclass(frozen=True)
class ShardTask:
    """Samples [start, stop) of ``split``: shard number ``shard``."""

    split: str
    shard: int
    start: int
    stop: int

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def label(self) -> str:
        return f"{self.split}/{self.shard:06d}"


def plan_shards(config: DatasetConfig) -> list[ShardTask]:
    """Every shard of every split, in split order."""
    tasks = []
    for split, spec in config.splits.items():
        for shard, start in enumerate(range(0, spec.count, config.shard_size)):
            tasks.append(ShardTask(split, shard, start, min(start + config.shard_size, spec.count)))
    return tasks


# ---------------------------------------------------------------------------------------------------------
# Paths, hashes, markers


def shard_key(shard: int, ndim: int) -> str:
    """Zarr v3 default chunk key ('/' separator) of shard ``shard`` of an array with ``ndim`` dimensions."""
    return "/".join(["c", str(shard)] + ["0"] * (ndim - 1))


def shard_file(root: str | Path, split: str, name: str, shard: int, ndim: int) -> Path:
    """File holding shard ``shard`` of array ``<split>/<name>`` (``ndim`` dims including the sample axis)."""
    return Path(root) / split / name / shard_key(shard, ndim)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def marker_path(root: str | Path, split: str, shard: int) -> Path:
    return Path(root) / DONE_DIR / split / f"{shard:06d}.json"


def write_json_atomic(path: Path, data: dict) -> None:
    """Write ``data`` as JSON to ``path`` (creating its directory) via a temporary file and a rename, so a reader
    never sees a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True))
    os.replace(tmp, path)


def read_marker(root: str | Path, split: str, shard: int) -> dict | None:
    path = marker_path(root, split, shard)
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def check_dataset_dir(root: Path, resume: bool) -> None:
    """Refuse, before any work, a dataset directory that cannot be written or would be clobbered: ``root`` is
    a file or lies under one, its nearest existing parent is not writable, it holds a dataset and ``resume``
    is False, or it holds other files.

    Raises:
        FileExistsError / PermissionError: naming the path and what to do instead.
    """
    from ..scene.load import check_output_dir
    check_output_dir(root, "--out")
    if not root.exists():
        return
    if (root / "zarr.json").exists():
        if not resume:
            raise FileExistsError(f"{root} already holds a dataset; pass --resume to continue it, or choose "
                                  "another --out")
        return
    others = [p.name for p in root.iterdir() if p.name not in (LOCK_NAME, DONE_DIR)]
    if others:
        raise FileExistsError(f"{root} exists and is not empty ({', '.join(sorted(others)[:5])}); "
                              "choose another --out")


# ---------------------------------------------------------------------------------------------------------
# Lock


class BuildLock:
    """Exclusive lock on ``<root>/_build.lock`` (the ``filelock`` package: an ``flock`` on Linux) holding the owner's
    host, pid and start time.

    The kernel releases the lock when the owner dies (even by SIGKILL), so there are no stale locks on local
    filesystems; the recorded pid only makes the refusal message useful. The owner removes the file before it
    unlocks (``filelock`` itself is told to keep it), and ``filelock`` retries a lock taken on a removed file, so
    two builds never hold it at once.

    Raises (``acquire``):
        BuildLockedError: another process holds it; the message names its host, pid and start time.
    """

    def __init__(self, root: str | Path):
        self.path = Path(root) / LOCK_NAME
        self._lock = FileLock(self.path, timeout=0, thread_local=False, preserve_lock_file=True,
                              on_acquired=self._record_owner)

    def acquire(self) -> "BuildLock":
        try:
            self._lock.acquire()
        except Timeout:
            raise BuildLockedError(f"{self.path.parent} is being built by another process ({self._holder()}); "
                                   "wait for it to finish, or stop it first") from None
        return self

    @staticmethod
    def _record_owner(fd: int) -> None:
        """Write host, pid and start time into the lock file just locked (``fd``)."""
        info = {"host": socket.gethostname(), "pid": os.getpid(),
                "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)

    def _holder(self) -> str:
        try:
            info = json.loads(self.path.read_text())
            return f"pid {info['pid']} on {info['host']}, started {info['started']}"
        except (OSError, ValueError, KeyError):
            return "holder unknown"

    def release(self) -> None:
        if self._lock.is_locked:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)                # while still held (see the class doc)
            self._lock.release(force=True)

    def __enter__(self) -> "BuildLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


# ---------------------------------------------------------------------------------------------------------
# Store creation


def zarr_module():
    """The ``zarr`` module, imported on first use rather than when this module is imported."""
    import zarr
    return zarr


def consolidate(root: Path) -> None:
    """Consolidate the store's metadata (once, at the end). ``_done/`` and the lock file are not Zarr nodes."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
        warnings.filterwarnings("ignore", message="Object at .* is not recognized", category=UserWarning)
        zarr_module().consolidate_metadata(str(root))


def probe_fields(probe: Sample) -> dict[str, tuple[tuple[int, ...], str]]:
    """Per-sample shape and dtype of every field of ``probe`` as the card records them: dtype ``"str"`` for
    ``params``, else the numpy dtype string (``"<f4"``)."""
    return {name: (tuple(value.shape), "str" if name == "params" else value.dtype.str)
            for name, value in probe.arrays.items()}


def numeric_codecs(compression: str, level: int, shuffle: str = "byte") -> list | None:
    """Zarr v3 compressors of every numeric inner chunk for ``store.compression`` ("lz4", "blosc-zstd", "zstd",
    "none"), ``store.compression_level`` (Blosc levels capped at 9) and ``store.shuffle`` ("byte" or "bit", Blosc
    only). The loader's fast path (:mod:`datagen.dataset.shard_reader`) decodes each of them."""
    from zarr.codecs import BloscCodec, ZstdCodec
    blosc_shuffle = {"byte": "shuffle", "bit": "bitshuffle"}[shuffle]
    if compression in ("lz4", "blosc-zstd"):
        return [BloscCodec(cname=compression.removeprefix("blosc-"), clevel=min(level, 9), shuffle=blosc_shuffle)]
    return {"zstd": [ZstdCodec(level=level)], "none": None}[compression]


def create_arrays(root, config: DatasetConfig, fields: dict[str, tuple[tuple[int, ...], str]],
                  time_edges: np.ndarray, component_names: list[str],
                  axes: dict[str, list[str]] | None = None) -> dict:
    """Create every split group and array: ``fields`` (name → (sample shape, dtype), :func:`probe_fields`),
    ``time_edges`` (T+1,) s, ``component_names`` (attribute of ``components``), ``axes`` (field → axis names). ``root`` is the dataset
    directory or an open zarr group (the expected metadata of :mod:`datagen.dataset.integrity` is built in
    memory with the same calls). Returns the card's ``splits`` entry."""
    zarr = zarr_module()
    from zarr.codecs import ZstdCodec

    numeric = numeric_codecs(config.store.compression, config.store.compression_level, config.store.shuffle)
    group = zarr.open_group(str(root), mode="a", zarr_format=3) if isinstance(root, (str, Path)) else root
    for split, spec in config.splits.items():
        g = group.create_group(split, overwrite=True, attributes={"count": spec.count, "split_key": split_key(split),
                                                  "shard_size": config.shard_size,
                                                  "room_overrides": spec.room_overrides})
        g.create_array("time_edges", data=np.asarray(time_edges, dtype=np.float64), attributes={"units": "s"})
        for name, (shape, dtype) in fields.items():
            is_str = dtype == "str"
            shape = tuple(shape)
            attrs = {"units": UNITS[name]} if name in UNITS else {}
            if name == "components":
                attrs["component_names"] = list(component_names)
            if axes and name in axes:               # axis order of scans and wall views (docs/datasets.md)
                attrs["axes"] = list(axes[name])
            g.create_array(name, shape=(spec.count,) + shape, chunks=(1,) + shape,
                           shards=(config.shard_size,) + shape, dtype=str if is_str else np.dtype(dtype),
                           fill_value="" if is_str else 0, compressors=[ZstdCodec(level=3)] if is_str else numeric,
                           config={"write_empty_chunks": True}, attributes=attrs)
    return split_entries(config, fields, axes)


def split_entries(config: DatasetConfig, fields: dict[str, tuple[tuple[int, ...], str]],
                  axes: dict[str, list[str]] | None = None) -> dict:
    """The card's ``splits`` entry: per split its count, split key, shard count and the per-sample ``fields``
    (shape, dtype ``"str"`` or a numpy dtype string, and the axis names of scans and wall views, ``axes``)."""
    out = {name: {"shape": list(shape), "dtype": "str" if dtype == "str" else np.dtype(dtype).str,
                  **({"axes": list(axes[name])} if axes and name in axes else {})}
           for name, (shape, dtype) in fields.items()}
    return {split: {"count": spec.count, "split_key": split_key(split),
                    "n_shards": -(-spec.count // config.shard_size), "fields": {k: dict(v) for k, v in out.items()}}
            for split, spec in config.splits.items()}


# ---------------------------------------------------------------------------------------------------------
# Card


def code_version() -> str:
    """``git describe --always --dirty --tags`` of the datagen checkout, else the package version."""
    from ..simulation.provenance import library_versions
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--tags"], cwd=here, capture_output=True,
                             text=True, timeout=10)
        if out.returncode == 0 and out.stdout.strip():
            return f"git:{out.stdout.strip()}"
    except (OSError, subprocess.SubprocessError):
        pass
    return f"datagen {library_versions().get('datagen', 'unknown')}"


def _stats(values: list[float]) -> dict:
    if not values:
        return {"n": 0}
    v = np.asarray(values, dtype=np.float64)
    return {"n": int(v.size), "mean": float(v.mean()), "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)), "min": float(v.min()), "max": float(v.max())}


CARD_KEYS = ("config",)
"""Card entries every reader of a dataset needs (:func:`read_card` refuses a card without them; ``splits`` is
filled as the build goes)."""


def read_card(path: str | Path) -> dict:
    """The dataset card (root attributes) of the dataset at ``path``.

    Raises:
        FileNotFoundError: no datagen dataset there. DatasetError (a ValueError): a damaged ``zarr.json``, or a
        card without the :data:`CARD_KEYS` mappings (names the file).
    """
    meta = Path(path) / "zarr.json"
    if not meta.is_file():
        raise FileNotFoundError(f"no datagen dataset at {path} (no zarr.json)")
    try:
        attrs = json.loads(meta.read_bytes()).get("attributes", {})
    except (ValueError, AttributeError) as exc:
        raise DatasetError(f"{meta}: the dataset card is not a JSON object ({type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:120]}): damaged; rebuild the dataset") from None
    if attrs.get("format") != FORMAT:
        raise FileNotFoundError(f"{path} is a Zarr store but not a datagen dataset (no dataset card)")
    missing = [k for k in CARD_KEYS if not isinstance(attrs.get(k), dict)]
    if missing:   # every reader needs it (a build writes it first): one line here, not a KeyError in each
        raise DatasetError(f"{meta}: the dataset card has no {' and no '.join(repr(k) for k in missing)} mapping: "
                           "damaged (edited by hand?); rebuild the dataset, or restore the card")
    return attrs


def finish_card(root: Path, card: dict, config: DatasetConfig) -> dict:
    """Fill the card from every done marker (hashes, timings, the samples' envelope errors against the tolerance:
    median, p95, max and the samples that missed it); mark complete when every shard is done."""
    shards, totals, stages = {}, [], {}
    errors, missed, orders = [], [], []
    done = 0
    tasks = plan_shards(config)
    for task in tasks:
        marker = read_marker(root, task.split, task.shard)
        if marker is None:
            continue
        done += 1
        shards.setdefault(task.split, {})[f"{task.shard:06d}"] = {"start": marker["start"], "stop": marker["stop"],
                                                                 "sha256": marker["sha256"]}
        for s in marker["seconds"]:
            totals.append(s["total"])
            for k, v in s.items():
                stages.setdefault(k, []).append(v)
        orders += marker.get("orders", [])
        for i, err in enumerate(marker.get("envelope_error", [])):
            errors.append(err)
            if not err <= config.tolerance:
                missed.append({"split": task.split, "index": marker["start"] + i, "envelope_error": err})
    card["shards"] = shards
    card["timing"] = {"per_sample_s": _stats(totals),
                      "per_stage_mean_s": {k: float(np.mean(v)) for k, v in stages.items()}}
    card["accuracy"] = {"tolerance": config.tolerance, "time_cap_s": config.cost_cap,
                        "envelope_error": _stats(errors), "n_missed": len(missed),
                        "missed": missed[:MISSED_LISTED]}
    if orders:              # orders: auto or >= 3 (docs/physics.md §2): what was simulated and what was left out
        simulated = sorted({o["simulated"] for o in orders})
        card["orders"] = {"setting": orders[0]["setting"],
                          "simulated": {k: sum(o["simulated"] == k for o in orders) for k in simulated},
                          "residual_share": _stats([o["residual_share"] for o in orders]),
                          "multibounce_share": _stats([o["multibounce_share"] for o in orders])}
    card["status"] = "complete" if done == len(tasks) else "incomplete"
    card["shards_done"], card["shards_total"] = done, len(tasks)
    return card


def _config_diff(a, b, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _config_diff(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def _at(data, dotted: str):
    for key in dotted.split("."):
        data = data.get(key) if isinstance(data, dict) else None
    return data


def _short(value) -> str:
    text = "(absent)" if value is None else json.dumps(value, sort_keys=True)
    return text if len(text) <= 80 else text[:79] + "…"


def check_same_config(root: Path, card: dict, config: DatasetConfig) -> None:
    """Refuse to resume the dataset at ``root`` (its ``card``) with a ``config`` whose fingerprint differs from
    the stored one (compared location-free: :func:`datagen.dataset.config.location_free_json`).

    Raises:
        DatasetError: one line naming the differing fields (dotted paths), the first one's value in the card and
            in ``config``, and what to do.
    """
    if card.get("config_sha256") == config.fingerprint():
        return
    stored, current = location_free_json(card.get("config") or {}), location_free_json(config.to_json())
    if canonical_json(stored) == canonical_json(current):
        return          # the same config, one of them written with the older keys (e.g. time_cap)
    diff = _config_diff(stored, current) or ["config_sha256"]
    first = diff[0]
    more = f", … ({len(diff)} fields)" if len(diff) > 5 else ""
    raise DatasetError(f"{root} was built from a different config (differs in: {', '.join(diff[:5])}{more}): "
                     f"{first} is {_short(_at(stored, first))} in the dataset's card, {_short(_at(current, first))} "
                     "in this config; resume with the same config or build into another --out")


def check_same_assets(root: Path, card: dict, assets: list[dict], asset_entries: list[tuple[str, ...]]) -> None:
    """Refuse to resume the dataset at ``root`` when the mesh ``assets`` on disk
    (:func:`datagen.dataset.assets.asset_record` of ``asset_entries``) differ from those its ``card`` pins. A
    card written before assets were pinned pins none: nothing to compare (the build pins the current ones).

    Raises:
        DatasetError: one line naming the asset folder and the first file added, removed or changed, the number
            of other changes, and what to do.
    """
    recorded = card.get("assets")
    changes = asset_changes(recorded, assets, asset_entries) if recorded is not None else []
    if changes:
        more = f" (+{len(changes) - 1} more changes)" if len(changes) > 1 else ""
        raise DatasetError(f"{root}: the mesh assets differ from those the dataset was built from: {changes[0]}{more}; "
                         "a resume would draw its samples from another asset list: restore the assets the card "
                         "lists (its 'assets': name and sha256 of each file) or build into a new --out")


def card_layout(config: DatasetConfig, probe: Sample) -> dict:
    """The card entries the probe sample fixes.

    Returns:
        {"time_edges": {"t_start" s, "n_bins", "bin_width" s}, "splits": per split its count, split key, shard
        count and fields (:func:`split_entries`) and its detector config as JSON}.
    """
    splits = split_entries(config, probe_fields(probe), probe.axes)
    for split in config.splits:
        splits[split]["detector"] = config.simulation_config(split).detector_config().model_dump(mode="json")
    return {"time_edges": {"t_start": float(probe.time_edges[0]), "n_bins": len(probe.time_edges) - 1,
                           "bin_width": float(probe.time_edges[1] - probe.time_edges[0])},
            "splits": splits}


def initialize_card(root: Path, config: DatasetConfig, probe: Sample, assets: list[dict]) -> dict:
    """Write the card (with the pinned mesh ``assets``, :func:`datagen.dataset.assets.asset_record`) and create
    every array, with the shapes of ``probe`` (sample 0 of the first non-empty split, computed before anything
    was written), in the Zarr group at ``root``.

    Returns:
        The card as written (status "incomplete" until :func:`finish_card`), with :func:`card_layout`'s entries.
    """
    from ..simulation.provenance import library_versions

    card = {"format": FORMAT, "format_version": FORMAT_VERSION, "name": config.name, "status": "incomplete",
            "config": config.to_json(), "config_sha256": config.fingerprint(), "assets": assets,
            "code_version": code_version(),
            "versions": library_versions(), "streams": STREAMS,
            "seed_rule": "SeedSequence(seed, spawn_key=(split_key, index, stream)), split_key = CRC-32 of the "
                         "split name; loader noise: SeedSequence(seed, spawn_key=(split_key, epoch, index, 4))",
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"), "runs": []}
    group = zarr_module().open_group(str(root), mode="a", zarr_format=3)
    group.update_attributes(card)
    create_arrays(root, config, probe_fields(probe), probe.time_edges,
                  config.component_slots(), probe.axes)
    card.update(card_layout(config, probe))
    group.update_attributes(card)
    return card
