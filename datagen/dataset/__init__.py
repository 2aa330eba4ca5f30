"""Dataset stage: procedural rooms → simulations → labelled, sharded Zarr datasets → a PyTorch loader.

In: a dataset config (YAML, ``configs/datasets/*.yaml``: seed, splits, shard size, a room distribution
``configs/rooms/*.yaml``, simulation overrides, a detector, label settings). Out: per sample ``i`` of split ``s``
a :class:`Sample` (:func:`make_sample`: fixed-shape arrays — envelope (…, T) and components, SPAD counts, labels
— plus JSON parameters and timings), a function of (config, s, i) only; a dataset directory built from them
shard by shard (:func:`build_dataset`) with its card (:func:`read_card`) and integrity check
(:func:`verify_dataset`); and :class:`NLOSDataset`, a torch ``Dataset`` of dicts of tensors (docs/datasets.md;
docs/physics.md §7).

Exported here, what users call: the config (:class:`DatasetConfig`, :func:`load_dataset_config`), one sample
(:func:`make_sample`, :func:`sample_setup`, :func:`scene_of_sample`), builds and their checks
(:func:`build_dataset`, :class:`BuildError`, :func:`verify_dataset`, :func:`read_card`,
:class:`DatasetCorruptError`), room distributions and labels (:func:`load_room_distribution`,
:func:`sample_room`, :class:`LabelSpec`, :func:`scene_labels`) and the loader (:class:`NLOSDataset`,
:class:`BatchNoise`, :func:`plot_sample`). Everything else is imported from its module.

Modules (they import each other directly, never through this package):

- :mod:`~datagen.dataset.config`: :class:`DatasetConfig`, the seed streams (:data:`STREAMS`,
  :func:`split_key`, :func:`resample_rng`), :func:`draw_room` and :func:`make_sample`;
- :mod:`~datagen.dataset.ranges`: uniform ranges and counts of the distributions (:class:`Range`,
  :class:`CountRange`);
- :mod:`~datagen.dataset.rooms`: the room distribution schema (:class:`RoomDistribution`,
  :func:`load_room_distribution`, :func:`check_feasible`);
- :mod:`~datagen.dataset.scan`: scanned captures in room distributions (``capture.scan``: confocal or
  exhaustive laser grids over a rectangle of the relay wall);
- :mod:`~datagen.dataset.assets`: mesh assets as hidden objects (asset folders, reading, placing);
- :mod:`~datagen.dataset.cutouts`: planar cut-outs of the LCT release's kind (glyphs, signs, dot and bar charts)
  as mesh assets (``scripts/make_cutouts.py``, ``assets/meshes/cutouts``);
- :mod:`~datagen.dataset.detector_draws`: a detector drawn per sample at build time (``detector_draws``: IRF,
  background, gain and background maps, direct light);
- :mod:`~datagen.dataset.sample_params`: pieces of a sample's ``params`` record;
- :mod:`~datagen.dataset.sampler`: :func:`sample_room` → :class:`SampledRoom` (its generator keys are
  ``datagen.dataset.sampler.STREAMS``; the config's stream ids are ``datagen.dataset.config.STREAMS``);
- :mod:`~datagen.dataset.obb`: exact oriented-box geometry (overlaps, beam and view tests, points inside);
- :mod:`~datagen.dataset.labels`: ground-truth labels (:class:`LabelSpec`, :func:`scene_labels`);
- :mod:`~datagen.dataset.wall_view`: the networks' orthographic depth / normal / albedo / mask images seen from
  the scanned wall rectangle;
- :mod:`~datagen.dataset.store`: the dataset's on-disk layout, build lock and card;
- :mod:`~datagen.dataset.integrity`: what the files must be; verification, resume repairs, the loader's checks;
- :mod:`~datagen.dataset.workers`: worker processes that die with the build (no orphans after a SIGKILL);
- :mod:`~datagen.dataset.build`: the shard task and the build engines (in process, process pool, Dask);
- :mod:`~datagen.dataset.probe`: what the build's probe sample says before the build spends (a missed tolerance);
- :mod:`~datagen.dataset.sample_scene`: :func:`scene_of_sample`, a built sample's room drawn again from the
  card (``datagen view``, ``datagen inspect``), and :func:`sample_setup` (a sample's scene and simulation config,
  to regenerate it at any accuracy);
- :mod:`~datagen.dataset.loader`: :class:`NLOSDataset`, :class:`BatchNoise` and :func:`plot_sample` (import
  torch and matplotlib on first use: ``import datagen.dataset`` stays light);
- :mod:`~datagen.dataset.shard_reader`: the loader's per-sample reads of shard files (one ``pread`` each);
- :mod:`~datagen.dataset.layout`: the networks' (1, T, H, W) layout of scans (``NLOSDataset(layout="network")``)
  and the axis names the card records;
- :mod:`~datagen.dataset.export`: one stored sample as a simulation result with its wall grids (``datagen
  export-tal DATASET --split --index``);
- :mod:`~datagen.dataset.score`: scoring reconstructions against a split's labels (``datagen score``);
- :mod:`~datagen.dataset.figures`: pictures of scanned samples (``datagen inspect``).
- :mod:`~datagen.dataset.components`: the ``components`` field's slots and array;
- :mod:`~datagen.dataset.zones`: multi-zone samples (a flood's zones, ``node_envelope``);
- :mod:`~datagen.dataset.sequences`: capture-sequence samples (rooms with walkers: frames, tracks; docs/motion.md);
- :mod:`~datagen.dataset.dtypes`: the stored dtypes a config chooses (``store.counts_dtype``);
- :mod:`~datagen.dataset.dask_engine`: the Dask engine of builds (``--scheduler``, ``LocalCluster``);
- :mod:`~datagen.dataset.forkserver_preload`: preloaded by the build's fork server, ties its life to the build;
- :mod:`~datagen.dataset.legacy`: dataset configs with the older key names (renamed keys, the note that lists
  them, the canonical form cards are compared in);
- :mod:`~datagen.dataset.suite`: frozen benchmark suites (named, versioned builds with a content hash) and
  :mod:`~datagen.dataset.suite_score`: their leaderboard scores (docs/benchmark.md).
"""
from ..lazy import lazy_attributes

__all__ = [
    # config and one sample
    "DatasetConfig", "load_dataset_config", "make_sample", "sample_setup", "scene_of_sample",
    # builds and their checks
    "build_dataset", "BuildError", "verify_dataset", "read_card", "DatasetCorruptError",
    # room distributions and labels
    "load_room_distribution", "sample_room", "LabelSpec", "scene_labels",
    # loader
    "NLOSDataset", "BatchNoise", "plot_sample",
]

_LAZY = {"BuildError": "build", "build_dataset": "build", "DatasetConfig": "config",
         "load_dataset_config": "config", "make_sample": "config", "DatasetCorruptError": "integrity",
         "verify_dataset": "integrity", "LabelSpec": "labels", "scene_labels": "labels",
         "load_room_distribution": "rooms", "sample_setup": "sample_scene", "scene_of_sample": "sample_scene",
         "sample_room": "sampler", "read_card": "store", "NLOSDataset": "loader", "BatchNoise": "loader",
         "plot_sample": "loader"}
"""Every public name, imported from its module on first use: ``import datagen.dataset`` (and the loader alone)
stays light: the builder's simulator and numba load only when a build or a sample needs them."""


__getattr__ = lazy_attributes(__name__, _LAZY)


def __dir__() -> list[str]:
    """The module's names with the lazy ones (``help(datagen.dataset)`` and completion list them)."""
    return sorted(set(globals()) | set(__all__))
