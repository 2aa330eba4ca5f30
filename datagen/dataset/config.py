"""Dataset configuration and the pure function "make sample i" (docs/physics.md §7).

A dataset config (YAML, see ``configs/datasets/*.yaml``) names a root ``seed``, the ``splits`` (name →
``count`` and optional ``room_overrides`` for held-out material or geometry splits), the ``shard_size``, the
room distribution (``room``: a path to ``configs/rooms/*.yaml`` or an inline mapping, see
:mod:`datagen.dataset.rooms`), ``simulation`` overrides (passed to :func:`datagen.simulation.run.resolve_config`),
the ``detector`` (a preset path such as ``configs/detectors/hwu_single_pixel.yaml`` or an inline mapping of
:class:`datagen.spad.DetectorConfig` fields), the ``labels`` (:class:`datagen.dataset.labels.LabelSpec`) and which
fields to ``store``.

Seeds. Every random stream of sample ``i`` of split ``s`` is drawn from
``SeedSequence(seed, spawn_key=(split_key(s), i, stream))`` with the fixed stream ids of :data:`STREAMS`
(geometry 0, materials 1, sensor 2, sampling 3, noise 4). ``split_key`` is the CRC-32 of the split's name, so
adding, removing or reordering splits never changes another split's samples. A sample therefore depends only
on (config, split, i): not on the worker count, the shard size or the engine that computed it.

:func:`make_sample` runs room sampling → :func:`datagen.simulation.run.simulate` → labels and returns fixed-shape
arrays (sample axis not included) plus the JSON-able parameters and per-stage timings.
"""
from __future__ import annotations

import copy
import dataclasses
import warnings
import hashlib
import json
import time
import zlib
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..errors import ConfigError, DatagenError
from ..scene.yamlfile import format_validation_error, read_yaml
from ..simulation.replicas import MIN_TOLERANCE
from ..threads import one_blas_thread
from ..units import parse_duration, parse_fraction
from .components import COMPONENT_ROOM, OTHER_COMPONENTS, component_arrays, component_slots  # noqa: F401
from .components import MULTIBOUNCE, orders_summary  # noqa: F401
from .dtypes import stored_counts
from .legacy import RENAMED_KEYS, note_old_keys, room_blocks
from .sample_params import accuracy_record, params_array

STREAMS: dict[str, int] = {"geometry": 0, "materials": 1, "sensor": 2, "sampling": 3, "noise": 4}
"""Stream ids: the last entry of the spawn_key of each random stream of a sample (fixed forever)."""

MAX_SHARDS = 10**6
"""Most shards per split (shard labels have six digits; the card holds each shard's hash)."""

RESAMPLE_NOISE = STREAMS["noise"]
"""Stream id of the loader's per-epoch noise, spawn_key (split_key, epoch, index, RESAMPLE_NOISE): a 4-entry
key, so it never coincides with a build stream (3-entry keys)."""

PRESET_TIME_FIELDS = ("bin_width", "t_start")
"""Fields of a detector preset file that the dataset's ``simulation.time`` axis replaces."""


def split_key(name: str) -> int:
    """Stable integer id of a split: CRC-32 of its UTF-8 name (first entry of every spawn_key)."""
    return zlib.crc32(name.encode("utf-8"))


def sample_seed_sequence(seed: int, split: str, index: int, stream: str | int) -> np.random.SeedSequence:
    """``SeedSequence(seed, spawn_key=(split_key(split), index, STREAMS[stream]))`` (docs/physics.md §7); an int
    ``stream`` is a stream id outside :data:`STREAMS` (the detector draw's, :mod:`.detector_draws`)."""
    sid = STREAMS[stream] if isinstance(stream, str) else int(stream)
    return np.random.SeedSequence(seed, spawn_key=(split_key(split), int(index), sid))


def sample_rngs(seed: int, split: str, index: int) -> dict[str, np.random.Generator]:
    """One independent PCG64 generator per stream of :data:`STREAMS` for sample ``index`` of ``split``."""
    return {name: np.random.default_rng(sample_seed_sequence(seed, split, index, name)) for name in STREAMS}


def resample_rng(seed: int, split: str, epoch: int, index: int) -> np.random.Generator:
    """Generator of the loader's re-drawn SPAD noise: spawn_key (split_key, epoch, index, RESAMPLE_NOISE)."""
    return np.random.default_rng(np.random.SeedSequence(
        seed, spawn_key=(split_key(split), int(epoch), int(index), RESAMPLE_NOISE)))


# ---------------------------------------------------------------------------------------------------------
# Schema


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class SplitSpec(_Model):
    """One split: ``count`` samples drawn from the room distribution with ``room_overrides`` deep-merged in
    (e.g. ``{"materials": {"box": {"kinds": {"phong": 1.0}}}}`` for a held-out material split)."""

    count: int = Field(ge=0)
    room_overrides: dict = Field(default_factory=dict)


class StoreSpec(_Model):
    """Which per-sample fields are written and how.

    Fields:
        envelope: store the envelope (expected detected photons per pulse per bin) as ``envelope_dtype``.
        counts: store the SPAD histogram as ``counts_dtype``.
        counts_dtype: "int64" (default), "uint32" or "uint16": stored dtype of ``counts`` (the loader returns int64);
            a sample with a count above its maximum stops with a one-line error (:func:`dtypes.stored_counts`).
        components: store per-component envelopes as ``components`` (sample, C, *envelope shape) with C =
            room, object_0 … object_{max_objects-1} (zero for absent objects), then :data:`OTHER_COMPONENTS`.
        labels: store the ground-truth labels of :func:`datagen.dataset.labels.scene_labels`.
        params: store every sampled room parameter and the seeds as one JSON string per sample.
        reference: also simulate the same room without its hidden objects (same capture, same sampling seed)
            and store its envelope as ``reference`` (as ``envelope_dtype``): the empty-room return that NLOS
            set-ups subtract to isolate the hidden objects (docs/datasets.md, "What each config teaches").
            Doubles the transport cost.
        compression: codec of every inner chunk: "lz4" (Blosc-LZ4, the default), "blosc-zstd" (Blosc with zstd
            inside), "zstd" (plain) or "none"; compared in docs/scans.md ("Storage and loading").
        compression_level: its level (Blosc 1 … 9, zstd 1 … 22).
        shuffle: the Blosc codecs' filter: "byte" (default) or "bit" (bitshuffle); plain zstd and "none" ignore it.
        node_envelope: a multi-zone capture (room ``capture.scan.flood``) also stores the per-node envelope
            (:mod:`datagen.dataset.zones`).
    """

    envelope: bool = True
    envelope_dtype: Literal["float32", "float64"] = "float32"
    counts: bool = True
    components: bool = False
    labels: bool = True
    params: bool = True
    reference: bool = False
    compression: Literal["lz4", "blosc-zstd", "zstd", "none"] = "lz4"
    compression_level: int = Field(5, ge=1, le=22)
    shuffle: Literal["byte", "bit"] = "byte"
    counts_dtype: Literal["int64", "uint32", "uint16"] = "int64"
    node_envelope: bool = False


STORE_DEFAULTS_UNHASHED = {"shuffle": "byte", "counts_dtype": "int64", "node_envelope": False}
"""Store keys :meth:`DatasetConfig.to_json` leaves out at these defaults: older configs keep their fingerprint."""


class DatasetConfig(_Model):
    """A dataset: see the module docstring. Load from YAML with :func:`load_dataset_config`.

    ``tolerance`` (e.g. "1%", default 1 %) is the per-sample target of the envelope's estimated relative L2 error
    and ``cost_cap`` (e.g. "2s", at most an hour; old key ``time_cap``) the most nominal compute a sample may spend
    reaching it (:func:`datagen.simulation.simulate_to_tolerance`; nominal seconds are counted work at fixed rates,
    so the adaptive choice is deterministic). Each sample stores its estimate as ``envelope_error``; the card lists the
    samples that missed the tolerance.

    ``room`` and a string ``detector`` may be file paths in YAML; :func:`load_dataset_config` replaces them by
    the files' mappings, so the config a worker receives and the card records are self-contained.
    """

    name: str = "dataset"
    seed: int = Field(ge=0, lt=2**63)
    shard_size: int = Field(64, ge=1)
    splits: dict[str, SplitSpec]
    room: str | dict
    room_overrides: dict = Field(default_factory=dict, description="deep-merged into the room for every split, "
                                 "before the split's own room_overrides")
    simulation: dict = Field(default_factory=dict)
    detector: str | dict | None = None
    detector_draws: dict | None = None      # drawn per sample (datagen.dataset.detector_draws)
    labels: dict = Field(default_factory=dict)
    store: StoreSpec = StoreSpec()
    tolerance: float = Field(0.01, ge=MIN_TOLERANCE, lt=1)   # below: float64 round-off, not measurable
    cost_cap: float = Field(2.0, gt=0, le=3600.0, allow_inf_nan=False)   # an hour of nominal work per sample

    @model_validator(mode="before")
    @classmethod
    def _renamed(cls, data: Any) -> Any:
        """Old keys (:data:`RENAMED_KEYS`) take their new names (:func:`load_dataset_config` notes it)."""
        both = [k for k, v in RENAMED_KEYS.items() if isinstance(data, dict) and k in data and v in data]
        if both:
            raise ValueError(f"{both[0]} and {RENAMED_KEYS[both[0]]} are both given: keep {RENAMED_KEYS[both[0]]}")
        return {RENAMED_KEYS.get(k, k): v for k, v in data.items()} if isinstance(data, dict) else data

    @field_validator("tolerance", mode="before")
    @classmethod
    def _fraction(cls, value: Any) -> Any:
        """'1%' → 0.01 (a bare number is a fraction)."""
        return parse_fraction(value) if isinstance(value, str) and value.strip().endswith("%") else value

    @field_validator("cost_cap", mode="before")
    @classmethod
    def _duration(cls, value: Any) -> Any:
        """'2s', '500ms' → seconds (a bare number is seconds)."""
        return parse_duration(value) if isinstance(value, str) else value

    @field_validator("splits")
    @classmethod
    def _splits(cls, value: dict[str, SplitSpec], info) -> dict[str, SplitSpec]:
        if not value:
            raise ValueError("give at least one split, e.g. {train: {count: 100}}")
        size = info.data.get("shard_size")
        for name, spec in value.items():    # the build plans, and the card lists, every shard
            if isinstance(size, int) and -(-spec.count // size) > MAX_SHARDS:
                raise ValueError(f"{name}.count: {spec.count} samples in shards of {size} are more than {MAX_SHARDS} "
                                 "shards (the card lists each with its hash): lower the count or raise shard_size")
        if all(spec.count == 0 for spec in value.values()):
            raise ValueError(f"every split has count 0 ({', '.join(value)}): nothing to build")
        for name in value:
            if not name or "/" in name or name.startswith(("_", ".")):
                raise ValueError(f"split name {name!r} must be non-empty, without '/', not starting with _ or .")
        keys = {}
        for name in value:
            other = keys.setdefault(split_key(name), name)
            if other != name:  # pragma: no cover - CRC-32 collision of two names
                raise ValueError(f"splits {other!r} and {name!r} have the same split_key; rename one")
        return value

    @field_validator("simulation")
    @classmethod
    def _no_seed(cls, value: dict) -> dict:
        if "seed" in value:
            raise ValueError("the dataset's top-level seed keys every stream; remove simulation.seed")
        return value

    @model_validator(mode="after")
    def _components_split(self) -> "DatasetConfig":
        if self.store.components and self.simulation.get("split_components") is False:
            raise ValueError("store.components: true needs the per-object components; remove "
                             "simulation.split_components: false")
        return self

    # ---- derived -----------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The config as a JSON-able dict (what workers receive and the card records); an empty
        ``room_overrides`` is left out, so configs written before it existed keep their fingerprint."""
        data = self.model_dump(mode="json")
        for key in ("room_overrides", "detector_draws"):     # left out when empty: older fingerprints hold
            if not data[key]:
                del data[key]
        for key, default in STORE_DEFAULTS_UNHASHED.items():
            if data["store"].get(key) == default:
                del data["store"][key]
        return data

    def fingerprint(self) -> str:
        """sha256 of the canonical JSON of :meth:`to_json` (a build resumes only into the same config), with the
        mesh asset entries, which loading resolves to absolute paths, reduced to their folder or file names: the
        same config has the same fingerprint in any checkout or copy (the card's ``assets`` records each
        file's sha256: :func:`datagen.dataset.assets.asset_record`). Renamed keys are hashed under their old
        names (:data:`RENAMED_KEYS`), so an unchanged YAML keeps the fingerprint of the cards built before."""
        data = location_free_json(self.to_json())
        for old, new in RENAMED_KEYS.items():
            data[old] = data.pop(new)
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()

    def simulation_overrides(self) -> dict:
        """``simulation`` with the resolved ``detector`` merged in (input of resolve_config), and
        ``split_components`` from ``store.components`` unless the block sets it: a dataset that stores no
        components simulates the primary as one (the envelope is the same sum; less memory and binning)."""
        out = copy.deepcopy(self.simulation)
        out.setdefault("split_components", self.store.components)
        if self.detector is not None:
            out["detector"] = copy.deepcopy(self.detector)
        return out

    def simulation_config(self, split: str):
        """The split's resolved :class:`~datagen.simulation.run.SimulationConfig`: the room distribution's
        ``simulation`` block under :meth:`simulation_overrides`, as ``resolve_config`` merges them for every
        sampled scene (used for the card's per-split detector, which the loader's noise re-draw needs)."""
        from ..simulation import SimulationConfig
        from ..simulation.config import merge_overrides
        dist = self.room_distribution(split, meshes=False)       # the simulation block: no mesh file is needed
        merged, _ = merge_overrides(dict(getattr(dist, "simulation", {}) or {}), self.simulation_overrides())
        with warnings.catch_warnings():       # the room's old keys: noted when a scene of it is resolved
            warnings.simplefilter("ignore", FutureWarning)
            return SimulationConfig.model_validate(merged)

    def stores_multibounce(self) -> bool:
        """Whether the simulation's ``orders`` is "auto" or ≥ 3 (the first split's resolved config): then
        ``components`` has the :data:`~datagen.dataset.components.MULTIBOUNCE` slot."""
        setting = self.simulation_config(next(iter(self.splits))).orders_setting()
        return setting == "auto" or (isinstance(setting, int) and setting >= 3)

    def component_slots(self) -> list[str]:
        """The ``components`` slots of this dataset (:func:`~datagen.dataset.components.component_slots`)."""
        return component_slots(self.label_spec().max_objects, self.stores_multibounce())

    def label_spec(self):
        from .labels import LabelSpec
        return LabelSpec.model_validate(self.labels)

    def room_distribution(self, split: str, meshes: bool = True):
        """The split's room distribution: room with the dataset's ``room_overrides``, then the split's; cached
        per process. ``meshes`` False leaves the mesh objects out (:func:`~datagen.dataset.rooms.without_meshes`):
        what reading a store takes from the room (simulation block, capture, motion) holds without them, so a store
        opens where the asset folders its card names are gone. Raises ConfigError: an invalid room or override;
        with ``meshes``, an asset folder or file that exists nowhere."""
        from .rooms import without_meshes
        texts = [self.room, self.room_overrides, self.splits[split].room_overrides]
        return _distribution(*(json.dumps(t if meshes else without_meshes(t), sort_keys=True) for t in texts))


def location_free_json(data: dict) -> dict:
    """:meth:`DatasetConfig.to_json` output (or a card's ``config``) with the mesh asset entries reduced to their
    folder or file names, as :meth:`DatasetConfig.fingerprint` hashes it (a copy; the input is unchanged)."""
    data = copy.deepcopy(data)
    for room in room_blocks(data):
        mesh = (room.get("objects") or {}).get("mesh")
        if isinstance(mesh, dict) and isinstance(mesh.get("assets"), list):
            mesh["assets"] = [Path(entry).name if isinstance(entry, str) else entry for entry in mesh["assets"]]
    return data


@lru_cache(maxsize=16)
def _distribution(room_json: str, *overrides_json: str):
    from .rooms import load_room_distribution
    dist = load_room_distribution(json.loads(room_json))
    for text in overrides_json:
        overrides = json.loads(text)
        dist = dist.with_overrides(overrides) if overrides else dist
    return dist


def _find_file(value: str, base: Path | None, field_name: str) -> Path:
    candidates = ([base / value] if base is not None else []) + [Path(value)]
    for path in candidates:
        if path.is_file():
            return path
    looked = ", ".join(str(p) for p in dict.fromkeys(candidates))
    raise ConfigError(f"{field_name}: file not found: {value!r} (looked at {looked})")


def _read_yaml(path: Path, field_name: str) -> dict:
    try:
        data = read_yaml(path, "YAML file", ConfigError)   # bounded in size and alias expansion
    except DatagenError as exc:
        raise ConfigError(f"{field_name}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{field_name}: {path} must hold a mapping, got {type(data).__name__}")
    return data


def load_dataset_config(source: str | Path | dict, base_dir: str | Path | None = None) -> DatasetConfig:
    """Load, resolve and fully validate a dataset config.

    ``room`` and a string ``detector`` are read from their files (relative paths are tried against the
    config file's directory, then the working directory) and inlined; mesh assets in ``room_overrides`` (the
    dataset's or a split's) are resolved against the config file's directory, then the working directory; the room
    distribution of every split (with its overrides), the label spec, the simulation overrides and the detector
    are validated now, so a bad config fails before any work starts.

    Args:
        source: YAML path or an already parsed mapping; base_dir: directory for relative paths of a mapping.
    Returns:
        :class:`DatasetConfig` with ``room`` and ``detector`` as mappings.
    Raises:
        ConfigError: unreadable file or an invalid value; the message names the file, the dotted field
            (e.g. ``splits.val.room_overrides.materials.box.albedo``) and the value.
    """
    where = None
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ConfigError(f"dataset config not found: {path}")
        data = _read_yaml(path, "dataset config")
        base, where = path.parent, str(path)
    else:
        data, base = copy.deepcopy(source), Path(base_dir) if base_dir is not None else None
    prefix = f"{where}: " if where else ""
    note_old_keys(data, where or "dataset config")
    try:
        config = DatasetConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, where)) from None
    updates: dict[str, Any] = {}
    if isinstance(config.room, str):
        room_file = _find_file(config.room, base, f"{prefix}room")
        updates["room"] = _room_with_assets(_read_yaml(room_file, f"{prefix}room"), room_file.parent, str(room_file))
    else:
        updates["room"] = _room_with_assets(config.room, base, f"{prefix}room")
    updates["room_overrides"] = _room_with_assets(config.room_overrides, base, f"{prefix}room_overrides")
    updates["splits"] = {name: spec.model_copy(update={"room_overrides": _room_with_assets(
        spec.room_overrides, base, f"{prefix}splits.{name}.room_overrides")}) for name, spec in config.splits.items()}
    if isinstance(config.detector, str):
        det = _read_yaml(_find_file(config.detector, base, f"{prefix}detector"), f"{prefix}detector")
        det = det["detector"] if set(det) == {"detector"} else det
        # a preset's TDC axis is replaced by the dataset's time axis: the histogram bins are the envelope bins
        updates["detector"] = {k: v for k, v in det.items() if k not in PRESET_TIME_FIELDS}
    config = config.model_copy(update=updates)
    _validate_parts(config, prefix)
    return config


def _room_with_assets(room: dict, base: Path | None, where: str) -> dict:
    """The room mapping with its mesh asset folders as absolute paths (relative to ``base``, then the working
    directory), so workers and the card need no file context."""
    from .rooms import resolve_room_assets
    return resolve_room_assets(room, base, where) if isinstance(room, dict) else room


def config_from_json(data: dict) -> DatasetConfig:
    """Rebuild a resolved config from :meth:`DatasetConfig.to_json` (in workers; no file access)."""
    return DatasetConfig.model_validate(data)


def _field_errors(exc: ValidationError, prefix: str, head: str) -> str:
    """One ``file: head.dotted.field: message (got value)`` per problem, joined by '; '."""
    lines = []
    for err in exc.errors():
        loc = ".".join([head] + [str(p) for p in err["loc"]])
        value = err.get("input")
        shown = "" if isinstance(value, dict) else f" (got {value!r})"
        lines.append(f"{prefix}{loc}: {str(err['msg']).removeprefix('Value error, ')}{shown}")
    return "; ".join(lines)


def _validate_parts(config: DatasetConfig, prefix: str) -> None:
    from ..simulation import SimulationConfig
    from ..simulation.config import detector_error
    from .detector_draws import check_detector_draws
    check_detector_draws(config.detector_draws, prefix)
    try:
        spec = config.label_spec()
    except ValidationError as exc:
        raise ConfigError(_field_errors(exc, prefix, "labels")) from None
    overrides = config.simulation_overrides()
    detector = overrides.pop("detector", {})
    try:
        with warnings.catch_warnings():          # noted once by load_dataset_config
            warnings.simplefilter("ignore", FutureWarning)
            sim = SimulationConfig.model_validate(overrides)
    except ValidationError as exc:
        raise ConfigError(_field_errors(exc, prefix, "simulation")) from None
    sim = sim.model_copy(update={"detector": detector})
    try:
        sim.detector_config()
    except ValidationError as exc:   # a field the detector took from simulation.time is blamed on it
        head = "detector" if config.detector is not None else "simulation.detector"
        raise ConfigError(detector_error(exc, sim, prefix.removesuffix(": "), head, "simulation.time")) from None
    try:
        _distribution(json.dumps(config.room, sort_keys=True), "{}")
    except ValueError as exc:   # a DatagenError too
        raise ConfigError(f"{prefix}room: {' '.join(str(exc).split())}") from None
    try:
        _distribution(json.dumps(config.room, sort_keys=True), json.dumps(config.room_overrides, sort_keys=True))
    except ValueError as exc:   # a DatagenError too
        raise ConfigError(f"{prefix}room_overrides: {' '.join(str(exc).split())}") from None
    for name in config.splits:
        try:
            dist = config.room_distribution(name)
        except ValueError as exc:   # a DatagenError too
            raise ConfigError(f"{prefix}splits.{name}.room_overrides: {' '.join(str(exc).split())}") from None
        most = dist.objects.box.count.max + dist.objects.pillar.count.max
        if config.splits[name].count and most > spec.max_objects:
            raise ConfigError(f"{prefix}labels.max_objects: {spec.max_objects} is fewer than the {most} hidden objects "
                             f"split {name!r} may hold (objects.box.count.max + objects.pillar.count.max): raise it "
                             f"to at least {most}")


# ---------------------------------------------------------------------------------------------------------
# Make one sample


@dataclass
class Sample:
    """One computed sample.

    Attributes:
        arrays: field name → fixed-shape array (no sample axis): ``envelope`` (*S, T) float32/64 expected
            detected photons per pulse per bin (S the capture's leading axes, e.g. (ny, nx) FoV pixels or
            none), ``envelope_error`` () float32 the envelope's estimated relative L2 error (bins above 1 % of its
            peak), ``counts`` (*S, T) int64, ``components`` (C, *S, T) (slots named by
            ``component_names``: room, object_0 … object_{K-1}, then secondary and any other component of the
            result), ``reference`` (*S, T) the empty room's envelope if store.reference, the label arrays of
            :func:`datagen.dataset.labels.scene_labels`, ``photons_per_pulse`` (0-d float64: the laser's Φ, the
            scale inside the envelope) and ``params`` (0-d str, JSON; its ``plan`` holds each effect decision's
            on, forced and reason).
        time_edges: (T+1,) float64 seconds.
        seconds: wall time per stage (room, simulate, labels, total), s.
        axes: field name → axis names (per sample) of the fields whose axes have a fixed meaning
            (:func:`datagen.dataset.layout.axis_names`: e.g. envelope of a confocal scan ["scan_y", "scan_x", "time"]).
        orders: when the config's ``orders`` is "auto" or ≥ 3, the light of every order in this sample
            (:func:`~datagen.dataset.components.orders_summary`), else empty.
        accuracy: ``params``' accuracy and, when the sample missed its tolerance, why (``capped``, ``unreachable``, …:
            :func:`datagen.simulation.simulate_to_tolerance`); not stored (:func:`datagen.dataset.probe.probe_notice`).
    """

    arrays: dict[str, np.ndarray]
    time_edges: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)
    component_names: list[str] = field(default_factory=list)
    axes: dict[str, list[str]] = field(default_factory=dict)
    orders: dict = field(default_factory=dict)
    accuracy: dict = field(default_factory=dict)


def draw_room(config: DatasetConfig, split: str, index: int):
    """The room of sample ``index`` of ``split``: :func:`datagen.dataset.sampler.sample_room` on the split's
    distribution with the sample's geometry, materials and sensor streams (:func:`sample_rngs`; walkers: stream
    6), exactly as :func:`make_sample` draws it (``datagen view`` and ``datagen inspect`` re-draw rooms with it).
    Returns (room, rngs): the :class:`~datagen.dataset.sampler.SampledRoom` and the sample's streams (name →
    Generator; ``sampling`` and ``noise`` not yet used).
    Raises:
        ConfigError: the split is unknown, the index is out of range, or the room cannot be sampled.
    """
    from .sampler import MOTION_STREAM, sample_room

    if split not in config.splits:
        raise ConfigError(f"split {split!r} is not in the config (splits: {sorted(config.splits)})")
    if not 0 <= index < config.splits[split].count:
        raise ConfigError(f"index {index} is outside split {split!r} (count {config.splits[split].count})")
    rngs, dist = sample_rngs(config.seed, split, index), config.room_distribution(split)
    given = {k: rngs[k] for k in ("geometry", "materials", "sensor")} | (    # walkers: a stream of their own
        {"motion": np.random.default_rng(sample_seed_sequence(config.seed, split, index, MOTION_STREAM))}
        if dist.motion.walkers.max > 0 else {})
    return sample_room(dist, given), rngs


def setup_sample(config: DatasetConfig, split: str, index: int):
    """(sampled room, its resolved simulation config, the sample's generators) of sample ``index`` of ``split``."""
    from ..simulation import resolve_config

    room, rngs = draw_room(config, split, index)
    return room, resolve_config(room.scene, config.simulation_overrides()), rngs


@one_blas_thread()
def make_sample(config: DatasetConfig, split: str, index: int, progress: bool = False) -> Sample:
    """Compute sample ``index`` of ``split``: room → envelope to the config's tolerance and SPAD counts → labels.

    ``progress`` shows the transport's tqdm bar (the build's probe sample); it changes nothing computed.

    A pure function of (config, split, index): every random stream comes from :func:`sample_rngs`, and the
    adaptive sampling (replicas added until the error estimate meets ``config.tolerance``, within
    ``config.cost_cap`` nominal seconds) depends on nothing else.

    Raises:
        ConfigError: the split is unknown, the index is out of range, the room cannot be sampled, or it holds
            more hidden objects than ``labels.max_objects``; the message names the sample.
    """
    from .layout import array_axes, capture_kind
    from .labels import scene_labels
    from .zones import zone_capture
    from .detector_draws import DETECTOR_STREAM, draw_sample_detector, scale_to_hidden_counts
    from .sequences import sequence_sample
    from ..simulation import simulate_to_tolerance

    where = f"sample ({split}, {index})"
    t0 = time.perf_counter()
    room, sim_config, rngs = setup_sample(config, split, index)
    sim_config, drawn = draw_sample_detector(config.detector_draws, sample_seed_sequence(
        config.seed, split, index, DETECTOR_STREAM), room, sim_config)
    t1 = time.perf_counter()
    ids = {"dataset_seed": config.seed, "split": split, "split_key": split_key(split), "index": index,
           "streams": STREAMS}
    if room.scene.moving:                 # walkers: a capture sequence (datagen/dataset/sequences.py)
        return Sample(*sequence_sample(config, split, index, room, sim_config, drawn, (t0, t1),
                                       sample_seed_sequence(config.seed, split, index, "sampling"), ids))
    result = simulate_to_tolerance(room.scene, sim_config, config.tolerance, max_cost=config.cost_cap,
                                   sampling_rng=rngs["sampling"], noise_rng=rngs["noise"], progress=progress)
    result, sim_config, drawn = scale_to_hidden_counts(result, sim_config, drawn, rngs["noise"], f"{where}: ")
    result, nodes = zone_capture(config, split, room, sim_config, result,   # a flood: the zones' result
                                 sample_rngs(config.seed, split, index)["noise"], where)
    t2 = time.perf_counter()
    spec = config.label_spec()
    if len(room.objects) > spec.max_objects:
        raise ConfigError(f"{where}: {len(room.objects)} hidden objects > labels.max_objects={spec.max_objects}")
    labels = scene_labels(room, spec) if config.store.labels else {}
    t3 = time.perf_counter()

    arrays: dict[str, np.ndarray] = {}
    component_names: list[str] = []
    if config.store.envelope:
        arrays["envelope"] = np.asarray(result.envelope, dtype=config.store.envelope_dtype)
    if config.store.node_envelope:
        arrays["node_envelope"] = np.asarray(nodes, dtype=config.store.envelope_dtype)
    arrays["envelope_error"] = np.asarray(result.attrs["tolerance"]["estimate"], dtype=np.float32)
    if config.store.counts:
        arrays["counts"] = stored_counts(result.counts, config.store.counts_dtype, where)
    if config.store.components:
        component_names, arrays["components"] = component_arrays(result, room, spec.max_objects,
                                                                 config.store.envelope_dtype, where,
                                                                 config.stores_multibounce())
    if config.store.reference:          # the empty room: same walls, capture and sampling stream, no hidden objects
        hidden = {o["name"] for o in room.objects}
        empty = dataclasses.replace(room.scene, objects=[o for o in room.scene.objects if o.name not in hidden])
        again = sample_rngs(config.seed, split, index)
        arrays["reference"] = np.asarray(zone_capture(config, split, room, sim_config, simulate_to_tolerance(
            empty, sim_config, config.tolerance, max_cost=config.cost_cap, sampling_rng=again["sampling"],
            noise_rng=again["noise"]), again["noise"], where)[0].envelope, dtype=config.store.envelope_dtype)
    for name, value in labels.items():
        arrays[name] = np.asarray(value)
    arrays["photons_per_pulse"] = np.asarray(result.attrs["photons_per_pulse"], dtype=np.float64)  # envelope scale Φ
    if config.store.params:
        arrays["params"] = params_array(ids, room, result.attrs, accuracy_record(result.attrs), drawn,
                                        orders_summary(result) if "orders" in result.attrs else None)
    seconds = {"room": t1 - t0, "simulate": t2 - t1, "labels": t3 - t2, "total": time.perf_counter() - t0}
    axes = array_axes(arrays, "multizone" if nodes is not None else capture_kind(room.scene))
    why = ("capped", "unreachable", "projected_nominal_seconds", "monte_carlo", "omitted_orders", "smoothing")
    accuracy = {**accuracy_record(result.attrs), **{k: v for part in ("tolerance", "error")
                                               for k, v in result.attrs[part].items() if k in why}}
    return Sample(arrays, np.asarray(result.time_edges, dtype=np.float64), seconds, component_names, axes,
                  orders_summary(result) if "orders" in result.attrs else {}, accuracy)
