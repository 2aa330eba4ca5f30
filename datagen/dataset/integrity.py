"""Dataset integrity: what a built dataset's files must be, and the checks and repairs that use it
(docs/reliability.md).

The truth is the config recorded in the card plus the per-sample field shapes of the build's probe sample.
From them :func:`expected_metadata` regenerates, in memory and with the same calls as the build
(:func:`datagen.dataset.store.create_arrays`), every split group's and array's ``zarr.json``. Three users:

- :func:`verify_dataset` (``datagen verify``): the card against its config (counts, shard counts, time axis,
  field shapes), every ``zarr.json`` (and the consolidated copy) against the expected one, the time axis
  values, and every shard file's bytes against the card's and the done marker's sha256;
- :func:`repair_store` (``datagen build --resume``): rewrites any ``zarr.json`` that differs, and drops the
  done marker and files of every shard whose bytes no longer match their marker, so the build recomputes it
  (bit-identical: a sample depends only on (config, split, index));
- the loader (:class:`datagen.dataset.NLOSDataset`): :func:`check_split` before reading, and
  :func:`read_shard_index` / :func:`corrupt_chunk` while reading, so damaged data raises
  :class:`DatasetCorruptError` instead of returning garbage.

Every command that reads a dataset (the loader, ``score``, ``inspect``, ``view``, ``export-tal``, ``detect``)
first calls :func:`require_complete`, which refuses an unfinished build with one message naming the missing
shards and ``--resume`` (:class:`DatasetIncompleteError`; docs/reliability.md, "Reading a dataset").
"""
from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .assets import AssetNotFoundError, asset_changes, config_asset_entries, current_asset_record
from .config import DatasetConfig, config_from_json
from .store import (ShardTask, file_sha256, marker_path, plan_shards, read_card, read_marker,
                    shard_file, zarr_module)

REMEDY = "check it with `datagen verify PATH`; `datagen build CONFIG --out PATH --resume` rebuilds what is damaged"

EMPTY_CHUNK = 2**64 - 1
"""Offset and length of an inner chunk absent from a shard index (zarr sharding spec: the fill value)."""

INDEX_ENTRY_BYTES = 16
"""Bytes per inner chunk in a shard index: (offset, nbytes) as little-endian uint64."""


class DatasetCorruptError(DatasetError):
    """A dataset's files disagree with its card (a damaged or missing shard, edited metadata); the message
    names the file and the remedy (:data:`REMEDY`)."""


class DatasetIncompleteError(DatasetError):
    """A dataset whose build has not finished (interrupted, failed shards, or still running); the message
    names the dataset, the shards not built and the remedy (:func:`require_complete`)."""


# ---------------------------------------------------------------------------------------------------------
# What the files must be


def card_fields(card: dict) -> dict[str, tuple[tuple[int, ...], str]]:
    """Per-sample (shape, dtype) of every stored field as the card records them (the build's probe sample)."""
    for info in card.get("splits", {}).values():
        if info.get("fields"):
            return {name: (tuple(spec["shape"]), spec["dtype"]) for name, spec in info["fields"].items()}
    return {}


def card_axes(card: dict) -> dict[str, list[str]]:
    """Axis names of the fields that record them in the card (scans and wall views, docs/datasets.md)."""
    for info in card.get("splits", {}).values():
        if info.get("fields"):
            return {name: spec["axes"] for name, spec in info["fields"].items() if "axes" in spec}
    return {}


@lru_cache(maxsize=8)
def _expected(config_json: str, fields_json: str, n_edges: int, axes_json: str = "{}") -> dict[str, bytes]:
    from .store import create_arrays
    zarr = zarr_module()
    config = config_from_json(json.loads(config_json))
    fields = {name: (tuple(shape), dtype) for name, (shape, dtype) in json.loads(fields_json).items()}
    files: dict = {}
    group = zarr.open_group(zarr.storage.MemoryStore(files), mode="w", zarr_format=3)
    create_arrays(group, config, fields, np.zeros(n_edges), config.component_slots(),
                  json.loads(axes_json))
    return {key: buf.to_bytes() for key, buf in files.items() if key.endswith("zarr.json") and "/" in key}


def expected_metadata(card: dict) -> dict[str, bytes]:
    """``zarr.json`` bytes every split group and array of the dataset must hold, keyed by path relative to the
    dataset (``"train/zarr.json"``, ``"train/envelope/zarr.json"``), regenerated from the card's config and
    fields with the build's own calls (cached per card content).

    Raises:
        DatasetCorruptError: the card has no fields or time axis (a build killed while it initialised).
    """
    fields = card_fields(card)
    if not fields or "time_edges" not in card:
        raise DatasetCorruptError(f"the dataset card records no fields or time axis (initialisation was "
                                  f"interrupted); {REMEDY}")
    return dict(_expected(json.dumps(card["config"], sort_keys=True), json.dumps(fields, sort_keys=True),
                          int(card["time_edges"]["n_bins"]) + 1, json.dumps(card_axes(card), sort_keys=True)))


def _describe(actual: dict, expected: dict) -> str:
    """The keys of a ``zarr.json`` that differ, with both values for the informative ones."""
    keys = [k for k in sorted(set(actual) | set(expected)) if actual.get(k) != expected.get(k)]
    shown = []
    for key in keys[:3]:
        if key in ("shape", "data_type", "fill_value"):
            shown.append(f"{key} {actual.get(key)!r}, expected {expected.get(key)!r}")
        else:
            shown.append(key)
    return "; ".join(shown) + (f" (+{len(keys) - 3} more)" if len(keys) > 3 else "")


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def metadata_problems(root: str | Path, card: dict, splits: list[str] | None = None,
                      names: list[str] | None = None) -> list[str]:
    """Every split group / array ``zarr.json`` (and its consolidated copy in the root ``zarr.json``) that is
    missing, unreadable or differs from :func:`expected_metadata`; restricted to ``splits`` and array
    ``names`` when given. One line per problem, naming the file and what differs."""
    root = Path(root)
    expected = expected_metadata(card)
    consolidated = (_read_json(root / "zarr.json") or {}).get("consolidated_metadata") or {}
    copies = consolidated.get("metadata", {}) if isinstance(consolidated, dict) else {}
    problems = []
    for key, raw in sorted(expected.items()):
        parts = key.split("/")
        if splits is not None and parts[0] not in splits:
            continue
        if names is not None and len(parts) == 3 and parts[1] not in names:
            continue
        want = json.loads(raw)
        path = root / key
        actual = _read_json(path)
        if actual is None:
            problems.append(f"{path}: {'missing' if not path.exists() else 'not valid JSON'}")
        elif actual != want:
            problems.append(f"{path}: differs from what the card implies ({_describe(actual, want)})")
        node = "/".join(parts[:-1])
        # a group's copy holds its own (empty) consolidated block, its zarr.json none (or null: zarr 3.1.3)
        copy = {k: v for k, v in copies.get(node, {}).items() if k != "consolidated_metadata"}
        want_copy = {k: v for k, v in want.items() if k != "consolidated_metadata"}
        if copies and copy != want_copy:
            problems.append(f"{root / 'zarr.json'}: consolidated metadata of {node} "
                            f"{'missing' if not copy else 'differs from what the card implies'}"
                            f"{'' if not copy else f' ({_describe(copy, want_copy)})'}")
    return problems


def card_problems(card: dict, config: DatasetConfig) -> list[str]:
    """The card's own records against its config: config fingerprint, splits, counts, split keys, shard counts,
    the time axis and the field shapes the config implies (labels, component slots, n_bins)."""
    from .config import split_key
    problems = []
    if card.get("config_sha256") != config.fingerprint():
        problems.append("card: config_sha256 does not match the recorded config (the card was edited)")
    tasks = plan_shards(config)
    if card.get("shards_total") != len(tasks):
        problems.append(f"card: shards_total {card.get('shards_total')!r}, the config implies {len(tasks)}")
    if set(card.get("splits", {})) != set(config.splits):
        problems.append(f"card: splits {sorted(card.get('splits', {}))}, the config has {sorted(config.splits)}")
    fields = card_fields(card)
    for split, spec in config.splits.items():
        info = card.get("splits", {}).get(split)
        if info is None:
            continue
        want = {"count": spec.count, "split_key": split_key(split), "n_shards": -(-spec.count // config.shard_size)}
        for key, value in want.items():
            if info.get(key) != value:
                problems.append(f"card: splits.{split}.{key} is {info.get(key)!r}, the config implies {value!r}")
        got = {name: (tuple(s["shape"]), s["dtype"]) for name, s in info.get("fields", {}).items()}
        if got and got != fields:
            problems.append(f"card: splits.{split}.fields differ from the other splits'")
    n_bins = config.simulation_config(next(iter(config.splits))).time.n_bins
    if card.get("time_edges", {}).get("n_bins") not in (None, n_bins):
        problems.append(f"card: time_edges.n_bins is {card['time_edges']['n_bins']!r}, the config implies {n_bins}")
    spec = config.label_spec()
    from .labels import label_shapes          # here: the labels' module loads the scene and sampling stages

    expected = {name: (shape, dt.str) for name, (shape, dt) in label_shapes(spec).items()} if config.store.labels \
        else {}
    motion = config.room_distribution(next(iter(config.splits)), meshes=False).motion
    frames = motion.frames
    if frames is not None and motion.walkers.max > 0:
        from .layout import FRAME_FIELDS       # a capture sequence's labels: one per frame
        expected = {name: ((frames.count, *shape) if name in FRAME_FIELDS else shape, dt)
                    for name, (shape, dt) in expected.items()}
    if config.store.components:
        expected_slots = len(config.component_slots())
        if "components" in fields and fields["components"][0][:1] != (expected_slots,):
            problems.append(f"card: components has shape {list(fields['components'][0])}, the config implies "
                            f"{expected_slots} component slots first")
    for name in ("envelope", "counts", "components"):
        if name in fields and fields[name][0][-1:] != (n_bins,):
            problems.append(f"card: {name} has shape {list(fields[name][0])}, "
                            f"the config implies {n_bins} time bins last")
    for name, (shape, dtype) in expected.items():
        if name in fields and fields[name] != (tuple(shape), dtype):
            problems.append(f"card: {name} is {list(fields[name][0])} {fields[name][1]}, the config implies "
                            f"{list(shape)} {dtype}")
    wanted = {"envelope": config.store.envelope, "counts": config.store.counts, "components": config.store.components,
              "params": config.store.params}
    for name, stored in wanted.items():
        if fields and stored != (name in fields):
            problems.append(f"card: field {name} is {'missing' if stored else 'present'}, the config's store."
                            f"{name} is {stored}")
    return problems


def shard_problems(root: str | Path, task: ShardTask, hashes: dict, fields: dict) -> list[str]:
    """Shard files of ``task`` that are missing, or whose sha256 differs from ``hashes`` (name → hex)."""
    out = []
    for name, (shape, _) in fields.items():
        file = shard_file(root, task.split, name, task.shard, 1 + len(shape))
        expected = hashes.get(name)
        if not file.is_file():
            out.append(f"{name}: shard file missing ({file})")
        elif expected is None:
            out.append(f"{name}: no hash recorded")
        elif file_sha256(file) != expected:
            out.append(f"{name}: sha256 mismatch (corrupted: {file})")
    return out


def _time_axis_problems(root: Path, config: DatasetConfig) -> list[str]:
    problems = []
    for split in config.splits:
        want = config.simulation_config(split).time.edges
        try:
            got = np.asarray(zarr_module().open_array(str(root / split / "time_edges"), mode="r")[...])
        except Exception as exc:  # noqa: BLE001 - any unreadable array is reported, not raised
            problems.append(f"{root / split / 'time_edges'}: unreadable ({type(exc).__name__})")
            continue
        if got.shape != want.shape or not np.array_equal(got, want):
            problems.append(f"{root / split / 'time_edges'}: differs from the config's time axis")
    return problems


def asset_problems(card: dict, config: DatasetConfig, notes: list[str] | None = None) -> list[str]:
    """The mesh asset files now against those the card pins (:func:`datagen.dataset.assets.asset_changes`): one
    line naming the asset folder, the first file added, removed or changed and how many more. A card that pins
    none (built before datagen recorded them) while its config draws meshes, or whose asset folders are not here
    (a store copied from the machine that built it), adds a line to ``notes`` instead.

    Raises:
        ConfigError: the card's room config fails in any other way than an asset folder that exists nowhere
            (:class:`~datagen.dataset.assets.AssetNotFoundError`)."""
    try:
        entries = config_asset_entries(config)
    except AssetNotFoundError as exc:          # the folders the card names (absolute paths of the build) are gone
        if notes is not None:
            notes.append(f"the mesh asset files were not checked: {exc}")
        return []
    recorded = card.get("assets")
    if recorded is None:
        if entries and notes is not None:
            notes.append("the card pins no mesh assets (built before datagen recorded them): the asset files were "
                         "not checked")
        return []
    changes = asset_changes(recorded, current_asset_record(entries), entries)
    if not changes:
        return []
    more = f" (+{len(changes) - 1} more changes)" if len(changes) > 1 else ""
    return [f"mesh assets: {changes[0]} since the build{more}: the samples were drawn from the assets the card lists "
            "(its 'assets': name and sha256 of each file); restore them, or build into a new --out"]


def verify_dataset(path: str | Path, notes: list[str] | None = None, progress: bool = False) -> list[str]:
    """Check a dataset completely: the build is complete; the card agrees with its config
    (:func:`card_problems`); the mesh asset files are those the card pins (:func:`asset_problems`); every split
    group's and array's metadata, and its consolidated copy, is what the card implies
    (:func:`metadata_problems`); the time axis holds the config's edges; every shard of every split is present,
    its bytes hash to the card's sha256 and its done marker records the same hashes.

    Args:
        path: the dataset directory.
        notes: when given, receives lines about what could not be checked (e.g. a card without pinned assets).
        progress: a tqdm bar over the shards on stderr (hashing a large dataset takes minutes).
    Returns:
        one line per problem (empty: the dataset is intact), each naming the file, or the split, shard and
        array.
    Raises:
        FileNotFoundError: no datagen dataset at ``path``. ConfigError: the card's room distribution cannot be
            loaded (asset folders that are gone are a note instead: the shards are checked all the same).
    """
    root = Path(path)
    card = read_card(root)
    problems = []
    if card.get("status") != "complete":
        problems.append(f"build not complete ({card.get('shards_done', 0)} of {card.get('shards_total', '?')} "
                        "shards): run `datagen build CONFIG --out PATH --resume`")
    try:
        config = config_from_json(card["config"])
    except (KeyError, TypeError, ValueError) as exc:
        return problems + [f"{root / 'zarr.json'}: the card holds no valid config ({type(exc).__name__}): damaged"]
    problems += card_problems(card, config)
    problems += asset_problems(card, config, notes)
    try:
        problems += metadata_problems(root, card)
    except DatasetCorruptError as exc:
        return problems + [str(exc)]
    problems += _time_axis_problems(root, config)
    fields = card_fields(card)
    tasks = plan_shards(config)
    if progress:
        from tqdm.auto import tqdm
        tasks = tqdm(tasks, unit="shard", desc=f"verify {root.name}", leave=False)
    for task in tasks:
        entry = card.get("shards", {}).get(task.split, {}).get(f"{task.shard:06d}")
        where = f"{task.label} (samples {task.start}-{task.stop - 1})"
        if entry is None:
            problems.append(f"{where}: not in the dataset card")
            continue
        marker = read_marker(root, task.split, task.shard)
        if marker is None:
            problems.append(f"{where}: done marker missing ({marker_path(root, task.split, task.shard)})")
        elif marker.get("sha256") != entry.get("sha256"):
            problems.append(f"{where}: the done marker's hashes differ from the card's")
        problems += [f"{where}: {line}" for line in shard_problems(root, task, entry.get("sha256", {}), fields)]
    return problems


# ---------------------------------------------------------------------------------------------------------
# Repair (build --resume)


def repair_store(root: str | Path, card: dict, config: DatasetConfig) -> list[str]:
    """Make an existing store safe to resume: rewrite every split group / array ``zarr.json`` that differs from
    :func:`expected_metadata` (a stale consolidated copy is reported: the build consolidates again when it
    completes), and un-mark every done shard whose files are missing or whose bytes differ from its marker's
    sha256 (marker first, then its files), so the build recomputes it.

    Returns:
        one line per repair (what was rewritten or will be rebuilt).
    """
    root = Path(root)
    repairs = []
    for key, raw in sorted(expected_metadata(card).items()):
        path = root / key
        if _read_json(path) != json.loads(raw):
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            tmp.write_bytes(raw)
            os.replace(tmp, path)
            repairs.append(f"rewrote {path}")
    stale = [line for line in metadata_problems(root, card) if "consolidated metadata" in line]
    if stale:   # the build re-consolidates from the (now repaired) arrays' zarr.json when it completes
        repairs.append(f"{stale[0]}: consolidated again at the end of the build")
    fields = card_fields(card)
    for task in plan_shards(config):
        marker = read_marker(root, task.split, task.shard)
        if marker is None:
            continue
        bad = shard_problems(root, task, marker.get("sha256", {}), fields)
        if bad:
            marker_path(root, task.split, task.shard).unlink()
            remove_shard_files(root, task, fields)
            repairs.append(f"{task.label}: {bad[0]}: rebuilding it")
    return repairs


def remove_shard_files(root: str | Path, task: ShardTask, fields: dict) -> None:
    """Delete the shard files of ``task`` (every field), so the next write starts from nothing."""
    for name, (shape, _) in fields.items():
        shard_file(root, task.split, name, task.shard, 1 + len(shape)).unlink(missing_ok=True)


# ---------------------------------------------------------------------------------------------------------
# Loader checks


def check_split(path: str | Path, card: dict, split: str, names: list[str]) -> None:
    """Refuse to read ``names`` of ``split`` when their metadata differs from what the card implies.

    Raises:
        DatasetCorruptError: the first problem, how many there are, and :data:`REMEDY`.
    """
    problems = metadata_problems(path, card, splits=[split], names=list(names))
    if problems:
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise DatasetCorruptError(f"{problems[0]}{more}; the loader reads nothing from a store whose metadata "
                                  f"disagrees with its card: {REMEDY}")


def read_shard_index(fd: int, path: str, shard_size: int) -> np.ndarray:
    """The (shard_size, 2) uint64 index (offset, nbytes per inner chunk) of the open shard file ``fd``, after
    checking its length, its crc32c and that every chunk lies inside the file.

    Raises:
        DatasetCorruptError: a truncated file, a bad index checksum or a chunk beyond the end (names ``path``).
    """
    import google_crc32c

    nbytes = shard_size * INDEX_ENTRY_BYTES + 4
    size = os.fstat(fd).st_size
    if size < nbytes:
        raise DatasetCorruptError(f"{path}: {size} bytes, shorter than its shard index ({nbytes} bytes): "
                                  f"truncated; {REMEDY}")
    raw = os.pread(fd, nbytes, size - nbytes)
    if google_crc32c.value(raw[:-4]) != int.from_bytes(raw[-4:], "little"):
        raise DatasetCorruptError(f"{path}: the shard index checksum does not match: damaged or truncated; {REMEDY}")
    index = np.frombuffer(raw, dtype="<u8", count=2 * shard_size).reshape(shard_size, 2)
    present = index[:, 0] != EMPTY_CHUNK
    if np.any(index[present, 0] + index[present, 1] > size - nbytes):
        raise DatasetCorruptError(f"{path}: a chunk lies beyond the end of the file: damaged; {REMEDY}")
    return index


def corrupt_chunk(path: str, index: int, exc: BaseException) -> DatasetCorruptError:
    """The error for sample ``index`` whose chunk in shard file ``path`` cannot be read or decoded."""
    reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:160]
    return DatasetCorruptError(f"{path}: sample {index} cannot be read ({reason}); {REMEDY}")


def sample_index(index) -> int:
    """``index`` as an int when it is an integer (Python, numpy or a 0-d integer tensor; not bool).

    Raises:
        TypeError: a float (``1.5``, even ``1.0``), bool, string or anything else.
    """
    import operator
    if isinstance(index, bool) or isinstance(index, (float, np.floating)):
        raise TypeError(f"sample index must be an integer, got {index!r} ({type(index).__name__})")
    try:
        return operator.index(index)
    except TypeError:
        raise TypeError(f"sample index must be an integer, got {index!r} ({type(index).__name__})") from None


# ---------------------------------------------------------------------------------------------------------
# Readers: the build must be complete


RESUME = "datagen build CONFIG --out {path} --resume"
"""The remedy an incomplete build's refusal names (``CONFIG``: the dataset config the build was started with)."""


def number_ranges(numbers) -> str:
    """Sorted integers as compact ranges: ``[3, 5, 6, 7, 8, 9]`` → ``"3, 5-9"`` (empty: ``""``)."""
    values = sorted(set(int(n) for n in numbers))
    parts, i = [], 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        parts.append(str(values[i]) if i == j else f"{values[i]}-{values[j]}")
        i = j + 1
    return ", ".join(parts)


def missing_shards(root: str | Path, config: DatasetConfig) -> dict[str, tuple[list[int], int]]:
    """Per split with unbuilt shards: (shard numbers without a done marker, shard count of the split), in split
    order; the done markers are the truth while a build runs (the card is filled from them at its end)."""
    out: dict[str, tuple[list[int], int]] = {}
    totals: dict[str, int] = {}
    for task in plan_shards(config):
        totals[task.split] = totals.get(task.split, 0) + 1
        if not marker_path(root, task.split, task.shard).is_file():
            out.setdefault(task.split, ([], 0))[0].append(task.shard)
    return {split: (shards, totals[split]) for split, (shards, _) in out.items()}


def require_complete(path: str | Path, card: dict | None = None) -> dict:
    """Refuse to read a dataset whose build has not finished; the one check every reader makes first (the
    loader, ``datagen score``, ``inspect``, ``view``, ``export-tal``, ``detect``).

    Args:
        path: the dataset directory.
        card: its card, when already read (:func:`datagen.dataset.read_card`); read here otherwise.
    Returns:
        the card (a dict), when its status is ``complete``.
    Raises:
        FileNotFoundError: no datagen dataset at ``path``; ValueError: a damaged card;
        DatasetIncompleteError (a ValueError): the build is not complete. The message names the dataset, the
        splits and the shard numbers that are not built (``train shards 3, 5-9 of 12``, from the done
        markers) and the remedy ``datagen build CONFIG --out PATH --resume``.
    """
    root = Path(path)
    card = read_card(root) if card is None else card
    if card.get("status") == "complete":
        return card
    remedy = RESUME.format(path=root)
    try:
        missing = missing_shards(root, config_from_json(card["config"]))
    except (KeyError, TypeError, ValueError):
        raise DatasetIncompleteError(f"{root}: the dataset build is not complete and its card holds no valid "
                                     f"config (interrupted while it initialised?); run `{remedy}`") from None
    if not missing:
        what = "every shard is built but the build did not finish (its card was not completed)"
    else:
        what = "; ".join(f"{split} shard{'s' if len(shards) > 1 else ''} {number_ranges(shards)} of {total}"
                            for split, (shards, total) in missing.items()) + " not built"
    raise DatasetIncompleteError(f"{root}: the dataset build is not complete ({what}); finish it with "
                                 f"`{remedy}`")


def is_dataset(path: str | Path) -> bool:
    """Whether ``path`` holds a datagen dataset: a ``zarr.json`` whose attributes are a dataset card (a
    ``zarr.json`` that is not JSON is not recognisably one: False)."""
    try:
        read_card(path)
    except (FileNotFoundError, ValueError):
        return False
    return True
