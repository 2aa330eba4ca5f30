"""A dataset sample that is a capture sequence: a room whose walkers move over its frames (docs/motion.md).

:func:`make_sample` hands a room with moving objects (a distribution with ``motion.walkers``) to
:func:`sequence_arrays`, which simulates its frames with :func:`datagen.simulation.sequence.simulate_sequence` (the
"changes" method, the sample's sampling stream as the root of the sequence's streams) and lays out the arrays a
sequence sample stores, with a leading frame axis F:

- ``envelope``, ``counts`` (F, …, T): each frame's envelope and SPAD histogram at the frame's exposure;
- ``envelope_error`` () float32: the largest stated error of a frame (the build's tolerance check reads it),
  ``frame_error`` (F,) float32: each frame's;
- ``frame_times`` (F,) float64 s: each frame's start;
- ``track_position``, ``track_velocity`` (F, M, 3) float32 m and m/s, ``track_box`` (F, M, 2, 3) float32 m: the
  M = ``motion.walkers.max`` walkers' anchors, velocities and axis-aligned boxes at each frame's middle (NaN for a
  walker slot the room does not fill);
- the room's labels (:func:`~datagen.dataset.labels.scene_labels`), the images among them (depth, normals, the
  wall-view labels) per frame (F, …), the object lists (the static hidden objects) once.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..errors import ConfigError
from .dtypes import stored_counts
from .labels import scene_labels
from .layout import FRAME_FIELDS


def sequence_sample(config, split: str, index: int, room, sim_config, drawn: dict, times: tuple[float, float],
                    root: np.random.SeedSequence, ids: dict) -> tuple:
    """The fields of the :class:`~datagen.dataset.config.Sample` (arrays, time_edges, seconds, component names,
    axes, orders, accuracy) of sample ``index`` of ``split`` whose room has walkers: its sequence's arrays
    (:func:`sequence_arrays`, ``root`` the sample's sampling stream), ``photons_per_pulse``, ``params`` (as every
    sample's, :func:`~datagen.dataset.sample_params.params_array` with ``ids``; the walkers in ``room.motion``) and
    the accuracy record. ``times``: the build's clock at the sample's start and after its room was drawn."""
    from .layout import array_axes, capture_kind
    from .sample_params import params_array

    where = f"sample ({split}, {index})"
    motion = config.room_distribution(split).motion
    arrays, seq = sequence_arrays(config, room, sim_config, root, motion, where)
    t2 = time.perf_counter()
    ref = seq.attrs["reference"]
    arrays["photons_per_pulse"] = np.asarray(ref["photons_per_pulse"], dtype=np.float64)
    accuracy = {"tolerance": config.tolerance, "envelope_error": float(np.max(seq.error)),
                "met": bool(np.max(seq.error) <= config.tolerance), "replicas": ref["error"]["replicas"],
                "replica_setting": ref["error"]["replica_setting"], "nominal_seconds": None,
                "sequence": {"method": seq.attrs["method"], "change_split": seq.attrs["change_split"],
                             "difference_error": seq.difference_error}}
    if config.store.params:
        arrays["params"] = params_array(ids, room, ref, accuracy, drawn)
    axes = array_axes(arrays, capture_kind(room.scene))
    t0, t1 = times
    seconds = {"room": t1 - t0, "simulate": t2 - t1, "labels": 0.0, "total": time.perf_counter() - t0}
    return arrays, np.asarray(seq.time_edges, dtype=np.float64), seconds, [], axes, {}, accuracy


def sequence_arrays(config, room, sim_config, root: np.random.SeedSequence, motion, where: str):
    """(arrays, the :class:`~datagen.simulation.sequence.SequenceResult`) of a sequence sample (module docstring),
    with the ``motion.walkers.max`` track slots and the change split of ``motion``
    (:class:`~datagen.dataset.rooms.MotionDist`).

    Raises:
        ConfigError: a store option a sequence has no array for (components, reference, node envelopes), naming it.
    """
    from ..simulation.sequence import simulate_sequence

    for option in ("components", "reference", "node_envelope"):
        if getattr(config.store, option):
            raise ConfigError(f"{where}: store.{option}: not stored for capture sequences (a room with walkers)")
    seq = simulate_sequence(room.scene, sim_config, change_split=motion.change_split, streams=root)
    arrays: dict[str, np.ndarray] = {}
    if config.store.envelope:
        arrays["envelope"] = np.asarray(seq.envelopes, dtype=config.store.envelope_dtype)
    if config.store.counts:
        arrays["counts"] = stored_counts(seq.counts, config.store.counts_dtype, where)
    arrays["envelope_error"] = np.asarray(np.max(seq.error), dtype=np.float32)
    arrays["frame_error"] = np.asarray(seq.error, dtype=np.float32)
    arrays["frame_times"] = np.asarray(seq.frame_times, dtype=np.float64)
    slots = motion.walkers.max
    pos = np.full((len(seq.frame_times), slots, 3), np.nan, dtype=np.float32)
    vel, box = pos.copy(), np.full((len(seq.frame_times), slots, 2, 3), np.nan, dtype=np.float32)
    m = len(seq.moving)
    pos[:, :m], vel[:, :m], box[:, :m] = seq.positions, seq.velocities, seq.boxes
    arrays.update({"track_position": pos, "track_velocity": vel, "track_box": box})
    if config.store.labels:
        spec = config.label_spec()
        first = scene_labels(room, spec)
        mids = seq.frame_times + room.scene.capture.frames.exposure / 2
        frames = [scene_labels(dataclasses.replace(room, scene=room.scene.at(t)), spec) for t in mids]
        for name, value in first.items():
            arrays[name] = (np.stack([f[name] for f in frames]) if name in FRAME_FIELDS else np.asarray(value))
    return arrays, seq
