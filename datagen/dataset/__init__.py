"""Dataset stage: procedural rooms → simulations → labelled, sharded Zarr datasets → a PyTorch loader.

In: a dataset config (YAML, ``configs/datasets/*.yaml``: seed, splits, shard size, a room distribution
``configs/rooms/*.yaml``, simulation overrides, a detector, label settings). Out: per sample ``i`` of split ``s``
a :class:`Sample` (:func:`make_sample`: fixed-shape arrays — envelope (…, T) and components, SPAD counts, labels
— plus JSON parameters and timings), a function of (config, s, i) only; a dataset directory built from them
shard by shard (:func:`build_dataset`) with its card (:func:`read_card`) and integrity check
(:func:`verify_dataset`); and :class:`NLOSDataset`, a torch ``Dataset`` of dicts of tensors (docs/datasets.md;
docs/physics.md §7).

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
- :mod:`~datagen.dataset.sampler`: :func:`sample_room` → :class:`SampledRoom` (its generator keys are
  ``datagen.dataset.sampler.STREAMS``, not re-exported here: :data:`STREAMS` is the config's stream ids);
- :mod:`~datagen.dataset.obb`: exact oriented-box geometry (overlaps, beam and view tests, points inside);
- :mod:`~datagen.dataset.labels`: ground-truth labels (:class:`LabelSpec`, :func:`scene_labels`);
- :mod:`~datagen.dataset.wall_view`: the networks' orthographic depth / normal / albedo / mask images seen from
  the scanned wall rectangle;
- :mod:`~datagen.dataset.store`: the dataset's on-disk layout, build lock and card;
- :mod:`~datagen.dataset.integrity`: what the files must be; verification, resume repairs, the loader's checks;
- :mod:`~datagen.dataset.workers`: worker processes that die with the build (no orphans after a SIGKILL);
- :mod:`~datagen.dataset.build`: the shard task and the build engines (in process, process pool, Dask);
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
"""
from .build import (DEFAULT_RETRIES, DEFAULT_TASKS_PER_CHILD, BuildError, BuildReport, build_dataset,
                    write_shard)
from .config import (COMPONENT_ROOM, OTHER_COMPONENTS, RESAMPLE_NOISE, STREAMS, DatasetConfig, Sample, SplitSpec,
                     StoreSpec, component_slots, config_from_json, draw_room, load_dataset_config, make_sample,
                     resample_rng, sample_rngs, sample_seed_sequence, split_key)
from .labels import PAD_INT, LabelSpec, camera_directions, camera_frame, label_shapes, occupancy_grid, scene_labels
from .obb import (box_hits_pyramid, box_hits_segment, boxes_overlap, convex_overlap, obb_vertices, points_in_box,
                  yaw_matrix)
from .rooms import (MATERIAL_CLASSES, OBJECT_CLASSES, PACKING_LIMIT, UNIFORMS_PER_MATERIAL, CountRange, LabelRegion,
                    MaterialDist, Range, RoomDistribution, check_feasible, load_room_distribution)
from .sampler import SampledRoom, sample_room
from .sample_scene import sample_setup, scene_of_sample
from .store import (DONE_DIR, FORMAT, FORMAT_VERSION, LOCK_NAME, UNITS, BuildLock, BuildLockedError, ShardTask,
                    code_version, file_sha256, marker_path, plan_shards, read_card, read_marker, shard_file, shard_key)
from .integrity import (DatasetCorruptError, card_problems, check_split, expected_metadata, metadata_problems,
                        repair_store, verify_dataset)

__all__ = [
    # config and samples
    "STREAMS", "RESAMPLE_NOISE", "COMPONENT_ROOM", "OTHER_COMPONENTS", "component_slots", "split_key", "sample_seed_sequence",
    "sample_rngs", "resample_rng", "SplitSpec", "StoreSpec", "DatasetConfig", "load_dataset_config",
    "config_from_json", "Sample", "draw_room", "make_sample", "sample_setup", "scene_of_sample",
    # room distributions and sampling
    "OBJECT_CLASSES", "MATERIAL_CLASSES", "UNIFORMS_PER_MATERIAL", "PACKING_LIMIT", "Range", "CountRange",
    "MaterialDist", "LabelRegion", "RoomDistribution", "load_room_distribution", "check_feasible", "SampledRoom",
    "sample_room",
    # oriented boxes
    "yaw_matrix", "obb_vertices", "convex_overlap", "boxes_overlap", "box_hits_segment", "box_hits_pyramid",
    "points_in_box",
    # labels
    "PAD_INT", "LabelSpec", "label_shapes", "camera_frame", "camera_directions", "occupancy_grid", "scene_labels",
    # store
    "FORMAT", "FORMAT_VERSION", "LOCK_NAME", "DONE_DIR", "UNITS", "BuildLockedError", "BuildLock", "ShardTask",
    "plan_shards", "shard_key", "shard_file", "file_sha256", "marker_path", "read_marker", "read_card",
    "code_version",
    # integrity
    "DatasetCorruptError", "expected_metadata", "metadata_problems", "card_problems", "check_split", "repair_store",
    "verify_dataset",
    # build
    "DEFAULT_RETRIES", "DEFAULT_TASKS_PER_CHILD", "BuildError", "BuildReport", "build_dataset", "write_shard",
    # loader (lazy)
    "NLOSDataset", "BatchNoise", "plot_sample",
]


def __getattr__(name: str):
    """``NLOSDataset``, ``BatchNoise`` and ``plot_sample`` import torch on first use only (``import datagen.dataset``
    stays light)."""
    if name in ("NLOSDataset", "BatchNoise", "plot_sample"):
        from . import loader
        return getattr(loader, name)
    raise AttributeError(f"module 'datagen.dataset' has no attribute {name!r}")
