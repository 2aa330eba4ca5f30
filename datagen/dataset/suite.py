"""Frozen benchmark suites: named, versioned dataset builds identified by a content hash (docs/benchmark.md).

A suite is a YAML file in ``configs/suites/`` (``NAME.yaml``) with two blocks:

``suite``
    ``name`` (the file's stem, e.g. ``wall-meshes-v1``), ``description``, ``train_split`` (where a trivial
    baseline takes its training mean), ``test_split`` (the split every method is scored on), ``variants`` (name →
    ``input``: the stored field a method reconstructs from, ``envelope`` for the clean variant, ``counts`` for the
    low-photon one; both come from one build), ``content_sha256`` (the content hash of the reference build,
    null until it is recorded) and ``earlier_sha256`` (the hashes of reference builds by earlier datagen code of
    the same definition, whose values differ from today's in float round-off only; :func:`hash_verdict`) and
    ``pins``: simulation settings whose default changed after the reference build, at the values it was built with
    (e.g. ``error: {confidence: null}``, the stated error as the RMS estimate it then was), so that the frozen
    ``dataset`` block builds the same samples; they are merged into its ``simulation`` block, block by block.
``dataset``
    an ordinary dataset config (:class:`datagen.dataset.DatasetConfig`: config, splits, seed, exposure, noise
    and detector); relative paths are relative to the suite file.

:func:`build_suite` builds it with :func:`datagen.dataset.build_dataset` (the same build as ``datagen build``;
``splits`` builds a prefix of each split, for smoke tests). :func:`content_hash` hashes every stored array of
every split (decoded values, in sample order), so the hash depends on the samples only: not on the worker
count, the engine, the shard layout on disk or the compression. :func:`verify_suite` checks the shards against
the card (:func:`datagen.dataset.verify_dataset`) and the content hash against the suite file.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..errors import ConfigError, DatasetError
from ..scene.load import format_validation_error, read_yaml
from .config import DatasetConfig, config_from_json, load_dataset_config

SUITES_DIR = Path(__file__).resolve().parents[2] / "configs" / "suites"
"""Where the named suites live (``configs/suites/NAME.yaml`` of this checkout)."""

HASH_BLOCK = 64
"""Samples read at once while hashing (bounds memory)."""


class VariantSpec(BaseModel):
    """One variant of a suite: the stored field a method reconstructs from."""

    model_config = ConfigDict(extra="forbid")
    input: Literal["envelope", "counts"]
    description: str = ""


class SuiteSpec(BaseModel):
    """The ``suite`` block of a suite file (module doc)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9-]*-v[0-9]+$")
    description: str = ""
    train_split: str
    test_split: str
    variants: dict[str, VariantSpec] = Field(min_length=1)
    content_sha256: str | None = Field(None, pattern=r"^[0-9a-f]{64}$")
    earlier_sha256: list[Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]] = []
    pins: dict = {}


@dataclass
class Suite:
    """A loaded suite: its ``spec``, its resolved dataset ``config`` and the ``path`` of its file."""

    spec: SuiteSpec
    config: DatasetConfig
    path: Path

    @property
    def name(self) -> str:
        return self.spec.name


def pinned(simulation: dict, pins: dict) -> dict:
    """``simulation`` with ``pins`` over it, a block of both (e.g. ``error``) merged key by key."""
    out = dict(simulation)
    for key, value in pins.items():
        old = out.get(key)
        out[key] = {**old, **value} if isinstance(old, dict) and isinstance(value, dict) else value
    return out


def suite_names(folder: Path = SUITES_DIR) -> list[str]:
    """Names of the suites in ``folder`` (default :data:`SUITES_DIR`), sorted."""
    return sorted(p.stem for p in Path(folder).glob("*.yaml"))


def load_suite(name: str | Path) -> Suite:
    """The suite ``name`` (a name in :data:`SUITES_DIR`, or a path to a suite YAML).

    Raises:
        ConfigError: no such suite (the message lists the known ones), an unreadable file, an invalid field
            (named with its dotted path and value), a ``name`` other than the file's stem, split names that are
            not in the dataset config, or a dataset config that does not store a variant's input field.
    """
    path = Path(name)
    if path.suffix not in (".yaml", ".yml"):
        path = SUITES_DIR / f"{name}.yaml"
        if not path.is_file():
            raise ConfigError(f"no benchmark suite {str(name)!r} (suites: {', '.join(suite_names()) or 'none'}; "
                              f"their files are in {SUITES_DIR})")
    elif not path.is_file():
        raise ConfigError(f"suite file not found: {path}")
    data = read_yaml(path, "suite")
    if not isinstance(data, dict) or set(data) != {"suite", "dataset"}:
        keys = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise ConfigError(f"{path}: a suite file has exactly the blocks 'suite' and 'dataset', got {keys}")
    try:
        spec = SuiteSpec.model_validate(data["suite"])
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, f"{path} (suite)")) from None
    if spec.name != path.stem:
        raise ConfigError(f"{path}: suite.name is {spec.name!r}, the file is {path.stem}.yaml: they must agree")
    dataset = data["dataset"]
    if spec.pins and isinstance(dataset, dict):   # settings whose default changed after the reference build
        dataset = {**dataset, "simulation": pinned(dataset.get("simulation") or {}, spec.pins)}
    config = load_dataset_config(dataset, base_dir=path.parent)
    for key in ("train_split", "test_split"):
        split = getattr(spec, key)
        if split not in config.splits:
            raise ConfigError(f"{path}: suite.{key} {split!r} is not a split of the dataset "
                              f"({', '.join(config.splits)})")
    for variant, v in spec.variants.items():
        if not getattr(config.store, v.input):
            raise ConfigError(f"{path}: suite.variants.{variant}.input is {v.input!r}, which dataset.store does "
                              "not store")
    return Suite(spec, config, path)


def cut_splits(config: DatasetConfig, counts: dict[str, int]) -> DatasetConfig:
    """``config`` with only the splits of ``counts`` at those counts (each a prefix of the full split: sample i
    depends on (config, split, i) only, docs/physics.md §7).

    Raises:
        DatasetError: an unknown split or a negative count.
    """
    splits = {}
    for split, n in counts.items():
        if split not in config.splits:
            raise DatasetError(f"suite {config.name}: no split {split!r} (splits: {', '.join(config.splits)})")
        if int(n) < 0:
            raise DatasetError(f"suite {config.name}: count of split {split!r} must be >= 0, got {n}")
        splits[split] = config.splits[split].model_copy(update={"count": int(n)})
    return config.model_copy(update={"splits": splits})


def build_suite(name: str | Path, out: str | Path, workers: int | None = None,
                splits: dict[str, int] | None = None, resume: bool = False, progress: bool = True):
    """Build suite ``name`` into ``out`` with :func:`datagen.dataset.build_dataset` and hash it.

    Args:
        splits: build only these splits with these counts (a prefix of the suite, for smoke tests); default: the
            whole suite.
        workers, resume, progress: as for :func:`datagen.dataset.build_dataset`.
    Returns:
        (:class:`datagen.dataset.build.BuildReport`, content hash: 64 hex characters).
    Raises:
        what :func:`load_suite` and :func:`datagen.dataset.build_dataset` raise.
    """
    from .build import build_dataset

    suite = load_suite(name)
    config = suite.config if splits is None else cut_splits(suite.config, splits)
    report = build_dataset(config, out, workers=workers, resume=resume, progress=progress)
    return report, content_hash(out)


def _array_digest(arr) -> str:
    """sha256 of a stored array's decoded values: dtype, shape, then the values in C order, read in blocks of
    :data:`HASH_BLOCK` samples (string arrays: each string's UTF-8 bytes with its length)."""
    h = hashlib.sha256(f"{arr.dtype}|{tuple(arr.shape)}|".encode())
    n = arr.shape[0] if arr.ndim else 1
    step = HASH_BLOCK if arr.ndim else 1
    for start in range(0, n, step):
        block = np.asarray(arr[start:start + step] if arr.ndim else arr[()])
        if block.dtype.kind in "OTU":
            for s in block.ravel():
                b = str(s).encode("utf-8")
                h.update(len(b).to_bytes(8, "little") + b)
        else:
            h.update(np.ascontiguousarray(block).tobytes())
    return h.hexdigest()


def array_hashes(path: str | Path) -> dict[str, str]:
    """``{"split/field": sha256}`` of every stored array of the dataset at ``path`` (the time axis included).

    Raises:
        FileNotFoundError: no dataset at ``path``; DatasetError: the build is not complete.
    """
    from .integrity import require_complete
    from .store import zarr_module

    card = require_complete(path)
    root = zarr_module().open_group(str(path), mode="r")
    out = {}
    for split in sorted(card["splits"]):
        group = root[split]
        for field in sorted(group.array_keys()):
            out[f"{split}/{field}"] = _array_digest(group[field])
    return out


def content_hash(path: str | Path) -> str:
    """The suite's content hash: sha256 of the sorted ``{"split/field": sha256}`` of :func:`array_hashes` as JSON.

    Returns:
        64 hex characters; equal for two builds exactly when every stored value of every split is equal.
    """
    return hashlib.sha256(json.dumps(array_hashes(path), sort_keys=True).encode()).hexdigest()


def suite_of_dataset(path: str | Path) -> tuple[Suite, bool]:
    """The suite a built dataset belongs to (the card's name) and whether it is the whole suite.

    Returns:
        (suite, full): ``full`` is False for a prefix build (fewer splits or samples than the suite).
    Raises:
        FileNotFoundError: no dataset at ``path``; DatasetError: the card's name is not a suite's, or its config
            is not the suite's (other than split counts).
    """
    from .store import read_card

    card = read_card(path)
    name = str(card.get("name"))
    if name not in suite_names():
        raise DatasetError(f"{path}: dataset {name!r} is not a build of a benchmark suite (suites: "
                           f"{', '.join(suite_names())}; build one with `datagen suite build NAME`)")
    suite = load_suite(name)
    built = config_from_json(card["config"])
    counts = {s: spec.count for s, spec in built.splits.items()}
    # a card written before the suite pinned a setting lacks it: the suite's pins complete it
    pinned = built.model_copy(update={"simulation": {**built.simulation, **suite.spec.pins}})
    if cut_splits(suite.config, counts).fingerprint() not in (built.fingerprint(), pinned.fingerprint()):
        raise DatasetError(f"{path}: its config differs from suite {suite.name}'s ({suite.path}): not a build of "
                           "this suite (rebuild it with `datagen suite build`)")
    full = counts == {s: spec.count for s, spec in suite.config.splits.items()}
    return suite, full


def hash_verdict(suite: Suite, digest: str) -> tuple[bool, str]:
    """(accepted, what to print) for a full build's content hash against the suite file: the reference build's
    ``content_sha256``, or one of ``earlier_sha256`` (a build by earlier datagen code: the same samples up to float
    round-off, docs/benchmark.md), or neither (another platform or library version, or a broken build)."""
    expected = suite.spec.content_sha256
    if expected is None:
        return True, f"suite {suite.name} records no content_sha256 yet ({suite.path})"
    if digest == expected:
        return True, "matches the suite's"
    if digest in suite.spec.earlier_sha256:
        return True, (f"matches an earlier datagen's build of suite {suite.name}, which differs from today's "
                      f"reference {expected} in float round-off only (docs/benchmark.md)")
    return False, (f"differs from suite {suite.name}'s {expected} ({suite.path}): the stored values differ "
                   "(another datagen version or platform?)")


def verify_suite(path: str | Path, notes: list[str] | None = None) -> tuple[list[str], str]:
    """Check a built suite: every shard against the card (:func:`datagen.dataset.verify_dataset`), then the
    content hash against the suite file's ``content_sha256`` (a prefix build, or a suite without a recorded hash,
    gets a note instead).

    Returns:
        (problems: one line each, empty when the suite is intact; the content hash computed, or "" when the
        shards already failed).
    Raises:
        FileNotFoundError: no dataset at ``path``; DatasetError / ConfigError: not a build of a known suite.
    """
    from .integrity import verify_dataset

    notes = notes if notes is not None else []
    suite, full = suite_of_dataset(path)
    problems = verify_dataset(path, notes)
    if problems:
        return problems, ""
    digest = content_hash(path)
    if not full:
        notes.append(f"a prefix build of suite {suite.name} (fewer samples than the suite): its content hash is not "
                     "the suite's")
        return problems, digest
    accepted, verdict = hash_verdict(suite, digest)
    if not accepted:
        problems.append(f"content hash {digest} {verdict}")
    elif suite.spec.content_sha256 is None:
        notes.append(verdict)
    elif digest != suite.spec.content_sha256:
        notes.append(f"content hash {digest} {verdict}")
    return problems, digest
