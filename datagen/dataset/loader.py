"""PyTorch loader of datagen datasets: a map-style ``Dataset`` returning a dict of tensors (docs/physics.md §7).

``NLOSDataset(path, split="train", fields=None, noise="frozen", transform=None, counts_dtype=None,
object_order="stored")`` reads the dataset built by :mod:`datagen.dataset.build`. Nothing is opened in
``__init__`` except the small JSON metadata, and no file handle or cache is pickled, so each ``DataLoader``
worker opens the store lazily on its first item.

Reading (:mod:`datagen.dataset.shard_reader`): each field's shard index is read once per shard and worker
(cached), then each sample is one ``pread`` and decode of its chunk, so shuffled access is as fast as sequential
access.

Integrity (docs/reliability.md, "Verify and the loader"). On opening, the split's metadata is checked against
the card; on each read, the shard index's length, crc32c and bounds, and that the chunk decodes. Neither sees a
byte changed inside a chunk's compressed data (it decodes to other values): ``verify=True`` hashes each shard
file whole against the sha256 the card records before returning any sample of it, once per process (each
``DataLoader`` worker hashes the shards it reads once, as no cache is pickled).

Normalisation. Every item also carries ``cycles`` (laser cycles of the exposure, repetition_rate ×
exposure), ``photons_per_pulse`` (the laser's Φ, the scale inside the envelope) and ``background`` (expected
background counts per bin over the exposure, (PDE·ambient + DCR)·bin_width·cycles): ``envelope × cycles`` is
the expected signal counts at low flux, ``counts / cycles`` the detections per cycle, ``envelope /
photons_per_pulse`` the transient per emitted photon (docs/datasets.md, "Loading").

Object slots. ``object_*`` arrays (and the ``object_k`` slots of ``components``) list the hidden objects in the
room generator's order, pillars first then boxes, padding last (class −1, 0.0 elsewhere);
``object_order="distance"`` sorts the real objects by the distance of their centre to the relay-wall plane
(nearest first), padding still last.

Noise. ``noise="frozen"`` returns the stored SPAD counts (evaluation sets). ``noise="resample"`` re-draws
them from the stored envelope with the split's detector (:func:`datagen.spad.rates_from_envelope`,
:func:`datagen.spad.sample_histogram`) and the generator ``SeedSequence(seed, spawn_key=(split_key, epoch,
index, 4))`` (:func:`datagen.dataset.config.resample_rng`): fresh every epoch (``set_epoch``), identical for the
same epoch and index in any worker. The stored envelope is float32 by default, so the re-drawn rates carry
its rounding (relative 6e-8).

Detector randomisation. With ``noise="resample"``, ``detector_ranges`` (e.g. ``{"exposure": ("1ms", "10ms"),
"ambient_rate": (0, 1e5), "pde": (0.2, 0.4)}``; fields of :data:`datagen.spad.ranges.RANDOMISED_FIELDS`, each a
number or a (low, high) range, the others the split's detector) draws each sample's detector per epoch from the
same generator (four uniforms through a ``torch.Generator`` seeded from it, :func:`datagen.spad.ranges.
draw_detector_params`, the rule :class:`datagen.SPADNoise` uses), rescales the envelope by pde / the split's PDE
(the envelope contains the PDE it was simulated with, docs/physics.md §2) and draws the counts with that
detector. The item records the draw as :data:`DETECTOR_FIELDS` (float64 0-d: exposure s, ambient_rate Hz, dcr
Hz, pde) and its ``cycles`` and ``background`` are the drawn detector's.
"""
from __future__ import annotations

import inspect
import json
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Literal

import numpy as np
import torch

from .store import read_card
from .config import resample_rng
from .integrity import check_split, sample_index
from .shard_reader import FieldReader

PLOT_DYNAMIC_RANGE = 1e-6
"""Lowest envelope value drawn, relative to its peak (IRF tails and FFT round-off lie far below)."""

SCALE_FIELDS = ("cycles", "photons_per_pulse", "background")
"""Per-item normalisation fields the loader adds (float64 0-d tensors; see the module doc)."""

OBJECT_FIELDS = ("object_class", "object_center", "object_size", "object_yaw", "object_albedo", "object_brdf")
"""Per-object label arrays (first axis: object slot) that ``object_order`` permutes."""

DETECTOR_FIELDS = ("exposure", "ambient_rate", "dcr", "pde")
"""The drawn detector parameters an item carries with ``detector_ranges`` (float64 0-d; see the module doc)."""

TRANSFORM_KEYWORDS = ("index", "params")
"""Keyword arguments a ``transform`` may declare to receive the sample index and its parsed params."""


class NLOSDataset(torch.utils.data.Dataset):
    """Map-style dataset over one split of a datagen dataset.

    Args:
        path: the dataset directory (``datagen build ... --out PATH``).
        split: split name, a str (see the card's ``splits``).
        fields: fields to return (default: every stored numeric field and :data:`SCALE_FIELDS`; ``params``
            returns the JSON string). ``counts`` with ``noise="resample"`` is re-drawn from ``envelope`` (read even
            if not requested).
        noise: "frozen" (stored counts) or "resample" (fresh SPAD noise per epoch, see the module doc). For
            noise drawn on the training device, load ``envelope`` and apply :meth:`spad_noise` to each batch.
        transform: called on the dict of tensors before it is returned: ``transform(item)``, or with the
            keywords it declares among ``index`` (int) and ``params`` (the parsed params dict, needs
            ``store.params``), e.g. ``def transform(item, index, params)``.
        counts_dtype: dtype of ``counts`` (e.g. ``torch.float32``); default int64 (whatever ``store.counts_dtype``
            stored: int64, uint32 or uint16, converted straight to ``counts_dtype`` when given). It must hold every
            count exactly (:func:`datagen.spad.torch_noise.check_counts_dtype`): an integer or floating torch dtype
            whose exact range (``iinfo.max``; 2**24 float32, 2**11 float16, 2**8 bfloat16) reaches the laser
            cycles of the split's exposure (of the longest one in ``detector_ranges``), the most a pile-up bin
            counts; bool, complex and narrower dtypes are refused here, and each item's counts are checked
            against that range on reading (models whose bins can count more than the cycles).
        object_order: "stored" (pillars first, then boxes, as generated) or "distance" (nearest to the relay
            wall first); either way padding slots come last.
        layout: "stored" (the stored shapes) or "network": scans as (1, T, H, W) float32 and wall-view labels as
            (C, H, W), the reconstruction networks' layout (:mod:`datagen.dataset.layout`).
        detector_ranges: with ``noise="resample"``, field → number or (low, high) range of the detector's
            ``exposure`` (s or "1ms"), ``ambient_rate`` (Hz), ``dcr`` (Hz), ``pde``, drawn per sample and epoch
            (module doc "Detector randomisation"); the item gains :data:`DETECTOR_FIELDS`.
        verify: hash each shard file read against the sha256 the card records (the done marker's if the card
            has none) before returning any sample of it: once per shard and process (each DataLoader worker
            hashes the shards it reads), reading each shard file once more in full. Without it a byte changed
            inside a chunk's compressed data is returned as data (module doc "Integrity").
        clip: a capture sequence's split (docs/motion.md): items are clips of ``clip`` consecutive frames, the
            F // clip non-overlapping clips of each sequence in turn; the per-frame fields
            (:data:`~datagen.dataset.layout.FRAME_FIELDS`) are cut to the clip, and the item gains ``sequence``
            and ``first_frame`` (int64 ()).
    Item:
        dict field → torch tensor with the stored shape and dtype: envelope (*S, T) float32 expected detected
        photons per pulse per bin, counts (*S, T) int64, depth (H, W) float32 m, normal (H, W, 3),
        occupancy (V, V, V) uint8, object_* (K, …), object_count (), …; cycles, photons_per_pulse and
        background () float64; see ``docs/datasets.md``.
    Raises:
        FileNotFoundError: no datagen dataset at ``path``; TypeError: a ``split`` that is not a str (names the
        splits), a ``counts_dtype`` that is not a torch.dtype; ValueError: unknown split, field, noise mode or
        object order or layout, an incomplete build, ``noise="resample"`` without a stored envelope,
        ``detector_ranges`` without ``noise="resample"`` or with an unknown field or invalid range, a transform
        asking for params that are not stored, ``layout="network"`` for a capture that is not a scan, a
        ``counts_dtype`` that cannot hold the counts (here, or on reading an item's counts beyond it);
        DatasetCorruptError (a ValueError): metadata that disagrees with the card (here), a damaged or missing
        shard, or with ``verify=True`` a shard whose sha256 differs (on reading); TypeError: an index that is
        not an integer (``ds[1.5]``).
    """

    def __init__(self, path: str | os.PathLike, split: str = "train", fields: Iterable[str] | None = None,
                 noise: Literal["frozen", "resample"] = "frozen", transform: Callable | None = None,
                 counts_dtype: torch.dtype | None = None, object_order: Literal["stored", "distance"] = "stored",
                 layout: Literal["stored", "network"] = "stored", detector_ranges: dict[str, Any] | None = None,
                 verify: bool = False, clip: int | None = None):
        if not isinstance(split, str):
            raise TypeError(f"split must be one split name (a str), got {split!r} ({type(split).__name__}); "
                            f"splits: {sorted(read_card(Path(path))['splits'])}")
        self.path = Path(path)
        card = read_card(self.path)
        from .integrity import require_complete   # the check every reader makes (names the missing shards)
        require_complete(self.path, card)
        if split not in card["splits"]:
            raise ValueError(f"split {split!r} not in {self.path} (splits: {sorted(card['splits'])})")
        if noise not in ("frozen", "resample"):
            raise ValueError(f"noise must be 'frozen' or 'resample', got {noise!r}")
        if object_order not in ("stored", "distance"):
            raise ValueError(f"object_order must be 'stored' or 'distance', got {object_order!r}")
        info = card["splits"][split]
        stored = list(info["fields"])
        redraw = noise == "resample"
        if redraw and "envelope" not in stored:
            raise ValueError(f"noise='resample' needs the envelope, which {self.path} does not store")
        if detector_ranges is not None and not redraw:
            raise ValueError("detector_ranges needs noise='resample' (the stored counts have a fixed detector)")
        scales = [f for f in SCALE_FIELDS if f != "photons_per_pulse" or self._photons_source(stored)]
        scales += list(DETECTOR_FIELDS) if detector_ranges is not None else []
        if fields is None:
            fields = ([f for f in stored if f != "params"] + (["counts"] if redraw and "counts" not in stored else [])
                      + [f for f in scales if f not in stored])
        fields = list(fields)
        unknown = sorted(set(fields) - set(stored) - ({"counts"} if redraw else set()) - set(scales))
        if unknown:
            raise ValueError(f"fields {unknown} are not stored in {self.path}/{split} (stored: {stored}"
                             f"{'' if 'photons_per_pulse' in scales else '; photons_per_pulse needs params'})")
        self.split, self.fields, self.noise, self.transform = split, tuple(fields), noise, transform
        self.counts_dtype, self.object_order = counts_dtype, object_order
        self.seed = int(card["config"]["seed"])
        self.count = int(info["count"])
        self.detector = info.get("detector")
        self._detector_config = None
        self._ranges = self._cycles = None
        if detector_ranges is not None:     # datagen.spad.ranges: parsed and checked once, drawn per item
            from ..spad.ranges import detector_ranges as parse_ranges, fixed_cycles
            det = self.detector_config()
            self._ranges = parse_ranges(det, dict(detector_ranges), owner="NLOSDataset detector_ranges")
            self._cycles = fixed_cycles(det, dict(detector_ranges).get("exposure"))
            if det.pde == 0 and self._ranges["pde"] != (0.0, 0.0):
                raise ValueError("NLOSDataset detector_ranges: the split's pde is 0, so the envelope cannot be "
                                 "rescaled to another pde")
        if counts_dtype is not None:
            from ..spad.torch_noise import check_counts_dtype, exact_count_limit
            cycles = 0 if self.detector is None else self.detector_config().cycles
            if self._ranges is not None:
                cycles = self._cycles or max(1, round(self._ranges["exposure"][1] * det.repetition_rate))
            self._counts_limit = exact_count_limit(check_counts_dtype(counts_dtype, cycles, "counts_dtype",
                                                                      "NLOSDataset"))
        self.verify = bool(verify)
        self.epoch = 0
        self.card = card
        self._keywords = _transform_keywords(transform)
        if "params" in self._keywords and "params" not in stored:
            raise ValueError(f"the transform asks for params, which {self.path} does not store (store.params)")
        to_read = set(self.fields) - (set(SCALE_FIELDS) - set(stored)) - set(DETECTOR_FIELDS)
        if redraw and "counts" in to_read:
            to_read = (to_read - {"counts"}) | {"envelope"}
        if "photons_per_pulse" in self.fields and "photons_per_pulse" not in stored:
            to_read.add("params")
        if object_order == "distance" and to_read & set(OBJECT_FIELDS + ("components",)):
            to_read |= {"object_center", "object_count"}
        if "params" in self._keywords:
            to_read.add("params")
        check_split(self.path, card, split, sorted(to_read) + ["time_edges"])   # metadata as the card implies
        self._readers = {name: self._field_reader(name) for name in sorted(to_read)}
        self.time_edges = _read_small(self.path / split / "time_edges")
        # -- network layout (datagen.dataset.layout): checked here, applied per item -------------------------
        if layout not in ("stored", "network"):
            raise ValueError(f"layout must be 'stored' or 'network', got {layout!r}")
        self.layout = layout
        if layout == "network":
            from .layout import network_shapes
            network_shapes(info["fields"])
        self.clip, self._clips = None, 1
        if clip is not None:
            frames = info["fields"].get("frame_times", {}).get("shape", [0])[0]
            if not frames:
                raise ValueError(f"clip={clip}: {self.path}/{split} holds no capture sequences (no frame_times)")
            if isinstance(clip, bool) or not isinstance(clip, int) or not 1 <= clip <= frames:
                raise ValueError(f"clip must be an integer from 1 to the sequences' {frames} frames, got {clip!r}")
            self.clip, self._clips = clip, frames // clip

    def _field_reader(self, name: str) -> FieldReader:
        """The reader of field ``name``, with the card's per-shard sha256 of it when ``verify``."""
        shards = self.card.get("shards", {}).get(self.split, {}) if self.verify else None
        hashes = None if shards is None else {int(k): e.get("sha256", {}).get(name) for k, e in shards.items()}
        return FieldReader(self.path, self.split, name, hashes)

    @staticmethod
    def _photons_source(stored: list[str]) -> bool:
        return "photons_per_pulse" in stored or "params" in stored

    def __len__(self) -> int:
        return self.count * self._clips

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch of the re-drawn noise (call before iterating; a DataLoader with
        ``persistent_workers=True`` keeps its workers' copies, so re-create it or use the default)."""
        self.epoch = int(epoch)

    def detector_config(self):
        """The split's :class:`datagen.spad.DetectorConfig` (what the stored counts were drawn with)."""
        if self._detector_config is None:
            from .. import spad
            self._detector_config = spad.DetectorConfig.model_validate(self.detector)
        return self._detector_config

    def spad_noise(self, **ranges):
        """A :class:`datagen.SPADNoise` for this split's detector: batched SPAD noise on the training device.

        ``ranges`` are SPADNoise's keywords (``exposure``, ``ambient_rate``, ``dcr``, ``pde`` as numbers or
        (low, high) ranges drawn per sample, ``dtype``), e.g. ``ds.spad_noise(exposure=("1ms", "10ms"))``."""
        from ..spad.torch_noise import SPADNoise
        return SPADNoise(self.detector_config(), **ranges)

    def scales(self, photons_per_pulse: float | None = None, detector=None) -> dict[str, float]:
        """The split's normalisation constants: cycles, background (expected counts per bin over the exposure)
        and, when given, photons_per_pulse (see the module doc); of ``detector`` (a drawn
        :class:`datagen.spad.DetectorConfig`) instead of the split's when given."""
        det = detector or self.detector_config()
        width = float(self.time_edges[1] - self.time_edges[0])
        out = {"cycles": float(det.cycles), "background": det.background_rate * width * det.cycles}
        if photons_per_pulse is not None:
            out["photons_per_pulse"] = float(photons_per_pulse)
        return out

    def draw_detector(self, index: int) -> tuple[Any, dict[str, float] | None, np.random.Generator]:
        """(detector, drawn, generator) of sample ``index`` in this epoch: the split's detector and None without
        ``detector_ranges``, else the drawn :class:`datagen.spad.DetectorConfig` and its parameters (exposure,
        ambient_rate, dcr, pde, cycles as floats); the generator then draws the counts."""
        det = self.detector_config()
        rng = resample_rng(self.seed, self.split, self.epoch, index)
        if self._ranges is None:
            return det, None, rng
        from ..spad import DetectorConfig
        from ..spad.ranges import draw_detector_params
        gen = torch.Generator().manual_seed(int(rng.integers(2**63)))
        p = draw_detector_params(self._ranges, det.repetition_rate, self._cycles, 1, gen)
        drawn = {name: float(v[0]) for name, v in p.items()}
        update = {f: drawn[f] for f in ("ambient_rate", "dcr", "pde")} | {"exposure": None,
                                                                          "n_cycles": int(drawn["cycles"])}
        return DetectorConfig.model_validate(det.model_dump() | update), drawn, rng

    def _resampled_counts(self, envelope: np.ndarray, det, rng: np.random.Generator) -> np.ndarray:
        from .. import spad
        scale = det.pde / self.detector_config().pde if self._ranges is not None else 1.0
        rates = spad.rates_from_envelope(envelope.astype(np.float64) * scale, det)
        return spad.sample_histogram(rates, det, rng)

    def read(self, index: int) -> dict[str, np.ndarray]:
        """Sample ``index`` as numpy arrays (no transform), counts re-drawn if ``noise="resample"``, objects in
        ``object_order``, with the normalisation fields."""
        out = self._read(sample_index(index))
        return {name: out[name] for name in self.fields}

    def _read(self, index: int, widen: bool = True) -> dict[str, np.ndarray]:
        """Every array read for sample ``index`` (the fields, and what they were derived from); stored counts
        narrower than int64 widened to it if ``widen``."""
        if not -self.count <= index < self.count:
            raise IndexError(f"index {index} out of range for split {self.split!r} of {self.count} samples")
        index = index % self.count
        out = {name: reader.read(index) for name, reader in self._readers.items()}
        if widen and "counts" in out and out["counts"].dtype != np.int64:   # store.counts_dtype uint16 / uint32
            out["counts"] = out["counts"].astype(np.int64)
        det, drawn = None, None
        if self.noise == "resample":
            det, drawn, rng = self.draw_detector(index)
            if "counts" in self.fields:
                out["counts"] = self._resampled_counts(out["envelope"], det, rng)
            if drawn is not None:
                out.update({f: np.asarray(drawn[f], dtype=np.float64) for f in DETECTOR_FIELDS})
        if self.object_order == "distance" and "object_center" in out:
            out.update(_objects_by_distance(out, float(self.card["config"]["room"]["relay_x"])))
        wanted = [f for f in SCALE_FIELDS if f in self.fields]
        if wanted:
            photons = None
            if "photons_per_pulse" in wanted:
                photons = (float(out["photons_per_pulse"]) if "photons_per_pulse" in out
                           else _photons_from_params(json.loads(str(out["params"][()]))))
            scales = self.scales(photons, det if drawn is not None else None)
            out.update({f: np.asarray(scales[f], dtype=np.float64) for f in wanted})
        return out

    def __getitem__(self, index: int) -> dict[str, Any]:
        index = sample_index(index)
        clip = None
        if self.clip is not None:            # (sequence, clip) of a capture sequence's split
            if not -len(self) <= index < len(self):
                raise IndexError(f"index {index} out of range for the {len(self)} clips of split {self.split!r}")
            index, clip = divmod(index % len(self), self._clips)
        out = self._read(index, widen=self.counts_dtype is None and self.layout != "network")  # network: float32
        arrays = {name: out[name] for name in self.fields}
        if clip is not None:
            from .layout import FRAME_FIELDS
            first = clip * self.clip
            arrays = {name: (a[first:first + self.clip] if name in FRAME_FIELDS else a) for name, a in arrays.items()}
            arrays["sequence"], arrays["first_frame"] = np.array(index, dtype=np.int64), np.array(first, np.int64)
        if self.layout == "network":
            from .layout import to_network
            arrays = to_network(arrays)
        item = {name: (str(a[()]) if a.dtype == object else torch.from_numpy(a)) for name, a in arrays.items()}
        if self.counts_dtype is not None and "counts" in item:
            most = int(arrays["counts"].max()) if arrays["counts"].size else 0     # numpy: torch has no uint16 max
            if most > self._counts_limit:
                raise ValueError(f"NLOSDataset: counts_dtype={self.counts_dtype} holds counts up to "
                                 f"{self._counts_limit} exactly, but sample {index % self.count} of {self.split!r} "
                                 f"counts {most} in a bin; pass a wider counts_dtype")
            item["counts"] = item["counts"].to(self.counts_dtype)
        if self.transform is None:
            return item
        extra = {}
        if "index" in self._keywords:
            extra["index"] = index % self.count
        if "params" in self._keywords:
            extra["params"] = json.loads(str(out["params"][()]))
        return self.transform(item, **extra)

    def params(self, index: int) -> dict:
        """Every sampled parameter and the seeds of sample ``index`` (needs ``store.params``)."""
        if "params" not in self._readers:
            if "params" not in self.card["splits"][self.split]["fields"]:
                raise ValueError(f"{self.path} does not store params (store.params was false)")
            self._readers_extra = getattr(self, "_readers_extra", None) or {"params": self._field_reader("params")}
        reader = self._readers.get("params") or self._readers_extra["params"]
        return json.loads(str(reader.read(int(index))[()]))

    def plot(self, sample: dict | int, title: str | None = None):
        """Figure of one sample: envelope and counts vs time, depth map, occupancy seen from above.

        Args:
            sample: an item (dict of tensors/arrays) or an index.
        Returns:
            matplotlib Figure (Agg-safe; the caller saves or shows it).
        """
        return plot_sample(sample if isinstance(sample, dict) else self[int(sample)], self.time_edges,
                           title or (f"{self.split}[{sample}]" if not isinstance(sample, dict) else None))


class BatchNoise:
    """``collate_fn`` drawing SPAD counts per batch inside the ``DataLoader`` workers: ``default_collate``, then
    ``batch[key] = noise(batch["envelope"])`` with a :class:`datagen.SPADNoise` and a generator per worker
    (seeded by ``seed`` and the worker id, so a run repeats for a given worker count and sampler seed), plus
    ``batch["cycles"]`` of each drawn exposure. For CPU training, where the noise then runs beside the training
    step as loading does; on a GPU apply the module to the batch on the device instead.

    Example::

        ds = datagen.NLOSDataset(path, fields=("envelope", "depth"))
        loader = DataLoader(ds, batch_size=64, num_workers=2, collate_fn=BatchNoise(ds.spad_noise(), seed=1))
    """

    def __init__(self, noise, seed: int = 0, key: str = "counts"):
        self.noise, self.seed, self.key = noise, int(seed), key
        self._generator: torch.Generator | None = None

    def __call__(self, items: list[dict]) -> dict:
        batch = torch.utils.data.default_collate(items)
        if self._generator is None:
            info = torch.utils.data.get_worker_info()
            self._generator = torch.Generator().manual_seed(self.seed * 1_000_003 + (info.id + 1 if info else 0))
        batch[self.key], drawn = self.noise.sample(batch["envelope"], self._generator)
        batch["cycles"] = drawn["cycles"]
        return batch

    def __getstate__(self):      # each worker starts its own generator
        return {**self.__dict__, "_generator": None}


def _transform_keywords(transform: Callable | None) -> tuple[str, ...]:
    """The keywords of :data:`TRANSFORM_KEYWORDS` that ``transform`` declares (all with ``**kwargs``)."""
    if transform is None:
        return ()
    try:
        parameters = inspect.signature(transform).parameters
    except (TypeError, ValueError):   # builtins without a signature: the one-argument call
        return ()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return TRANSFORM_KEYWORDS
    return tuple(k for k in TRANSFORM_KEYWORDS if k in parameters)


def _photons_from_params(params: dict) -> float:
    """Φ of the sample's laser from its params (datasets built before ``photons_per_pulse`` was stored)."""
    from ..scene import Laser
    return float(Laser(**params["room"]["laser"]).photons)


def _objects_by_distance(arrays: dict[str, np.ndarray], relay_x: float) -> dict[str, np.ndarray]:
    """The per-object arrays (and components' object slots) of one sample with the real objects sorted by
    relay_x − centre x (nearest to the relay wall first), padding slots kept last."""
    count = int(arrays["object_count"])
    order = np.arange(len(arrays["object_center"]))
    order[:count] = np.argsort(relay_x - arrays["object_center"][:count, 0], kind="stable")
    out = {name: arrays[name][order] for name in OBJECT_FIELDS if name in arrays}
    if "components" in arrays:
        components = arrays["components"].copy()
        components[1:1 + len(order)] = arrays["components"][1:1 + len(order)][order]
        out["components"] = components
    return out


def _read_small(path: Path) -> np.ndarray:
    import zarr
    return np.asarray(zarr.open_array(str(path), mode="r")[...])


def _np(value) -> np.ndarray:
    return value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)


def plot_sample(sample: dict, time_edges: np.ndarray, title: str | None = None, fig=None):
    """Draw ``sample`` (dict of arrays/tensors) on a new Figure: envelope (log) and counts over time in ns,
    the depth map (m, pixel rows along the FoV's up axis) and the occupancy grid's max projection along z."""
    from matplotlib.figure import Figure

    panels = [k for k in ("depth", "occupancy") if k in sample]
    fig = fig or Figure(figsize=(4.2 * (1 + len(panels)) + 0.6, 3.6), layout="constrained")
    axes = fig.subplots(1, 1 + len(panels), squeeze=False)[0]
    t_ns = 0.5 * (time_edges[1:] + time_edges[:-1]) * 1e9
    ax = axes[0]
    if "envelope" in sample:
        env = _np(sample["envelope"]).astype(np.float64)
        env = env.reshape(-1, env.shape[-1]).sum(axis=0)
        ax.semilogy(t_ns, np.where(env > 0, env, np.nan), lw=1, label="envelope (det./pulse/bin)")
        if env.max() > 0:
            ax.set_ylim(env.max() * PLOT_DYNAMIC_RANGE, env.max() * 2)
        ax.set_ylabel("expected detections per pulse per bin")
    if "counts" in sample:
        counts = _np(sample["counts"]).reshape(-1, len(t_ns)).sum(axis=0)
        twin = ax.twinx() if "envelope" in sample else ax
        twin.step(t_ns, counts, where="mid", lw=0.6, color="0.4", label="SPAD counts")
        twin.set_ylabel("counts")
    ax.set_xlabel("time (ns)")
    ax.set_title("envelope and counts")
    for ax, key in zip(axes[1:], panels):
        data = _np(sample[key])
        if key == "depth":
            data = data[0] if data.ndim == 3 else data     # a capture sequence's: its first frame
            im = ax.imshow(np.where(data > 0, data, np.nan), origin="lower", cmap="viridis")
            fig.colorbar(im, ax=ax, label="depth (m)")
            ax.set_title("depth from the FoV centre" + (" (frame 0)" if _np(sample[key]).ndim == 3 else ""))
        else:
            ax.imshow(data.max(axis=2).T, origin="lower", cmap="Greys", interpolation="nearest")
            ax.set_title("occupancy (max over z; x →, y ↑)")
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title)
    return fig
