"""One stored sample as a simulation result: what tal export and reconstructions need beyond the stored arrays.

A dataset stores per sample the envelope (or counts) and the parameters, not the wall grids. They are a pure
function of (config, split, index) (docs/physics.md §7), so :func:`sample_result` regenerates the sample's room
(:func:`datagen.dataset.sampler.sample_room`, milliseconds, no transport), resolves its capture
(:func:`datagen.scene.resolve_capture`: laser points, sensor points, wall normal) and wraps the stored array in a
:class:`datagen.simulation.Result` with the attributes :func:`datagen.io.write_tal_hdf5` reads (capture type and
convention, emitter and sensor positions, which time legs the axis counts). ``datagen export-tal DATASET --split
S --index I --out F.hdf5`` writes it in tal's HDF5 layout.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..scene import RayCaster, resolve_capture


def sample_result(path: str | Path, split: str, index: int, field: str = "envelope"):
    """Stored ``field`` ("envelope" or "counts") of sample ``index`` of ``split`` as a Result with its capture grids.

    Returns:
        :class:`datagen.simulation.Result`: envelope (float64, the stored field), counts (the stored counts or
        zeros), time_edges (T+1,) s, laser_points (ly, lx, 3), sensor_points (ny, nx, 3), wall_normal (3,),
        attrs with ``capture`` (type, convention, emitter_position, sensor_position), ``config``
        (count_laser_leg, count_sensor_leg) and ``dataset`` (path, split, index, field).
    Raises:
        FileNotFoundError: no dataset at ``path``; DatasetError: unknown split, index out of range, a field that
        is not stored, a multi-zone dataset (no single laser point per transient), or a regenerated room whose
        grids do not match the stored array (a changed code version);
        ValueError: what the loader refuses (:class:`datagen.dataset.NLOSDataset`: an incomplete build, a missing
        or damaged shard, named).
    """
    from ..simulation import Result
    from .config import config_from_json
    from .sampler import sample_room
    from .config import sample_rngs
    from .loader import NLOSDataset
    from .store import read_card

    card = read_card(path)
    if split not in card.get("splits", {}):
        raise DatasetError(f"{path}: split {split!r} not in the dataset (splits: {sorted(card.get('splits', {}))})")
    info = card["splits"][split]
    if not 0 <= index < info["count"]:
        raise DatasetError(f"{path}: index {index} is outside split {split!r} (count {info['count']})")
    if field not in ("envelope", "counts") or field not in info["fields"]:
        raise DatasetError(f"{path}: field {field!r} is not stored (stored: {sorted(info['fields'])}); "
                         "export envelope or counts")
    stored = [field] + (["counts"] if field != "counts" and "counts" in info["fields"] else [])
    reader = NLOSDataset(path, split, fields=stored)   # the loader's checks: complete build, shard index, chunks
    item = reader.read(index)
    data = np.asarray(item[field], dtype=np.float64)
    counts = np.asarray(item["counts"]) if "counts" in info["fields"] else np.zeros(data.shape, np.int64)
    time_edges = np.asarray(reader.time_edges, dtype=np.float64)
    config = config_from_json(card["config"])
    scan = config.room_distribution(split).capture.scan
    if scan is not None and scan.flood is not None:
        raise DatasetError(f"{path}: a multi-zone dataset: its samples are zones lit by a flood, with no single "
                           "laser point per transient, which the capture files (LCT, f-k, ZNLOS, tal) hold; read "
                           "them with datagen.NLOSDataset (docs/multizone.md)")
    rngs = sample_rngs(config.seed, split, index)
    room = sample_room(config.room_distribution(split), {k: rngs[k] for k in ("geometry", "materials", "sensor")})
    capture = resolve_capture(room.scene, RayCaster(room.scene))
    if capture.channel_shape() != data.shape[:-1]:
        raise DatasetError(f"{path}: sample ({split}, {index}): the regenerated capture has channels "
                         f"{capture.channel_shape()}, the stored {field} {data.shape[:-1]} (built by another code "
                         "version?)")
    sim = config.simulation_config(split)
    lx, ly = capture.laser_shape
    attrs = {"capture": {"type": capture.kind, "convention": capture.convention,
                         "emitter_position": capture.emitter.tolist(), "sensor_position": capture.sensor.tolist()},
             "config": {"count_laser_leg": sim.count_laser_leg, "count_sensor_leg": sim.count_sensor_leg},
             "dataset": {"path": str(path), "split": split, "index": int(index), "field": field,
                         "units": "expected detected photons per laser pulse per bin" if field == "envelope"
                         else "SPAD detections over the exposure",
                         "objects": json.loads(json.dumps(room.objects))}}
    return Result(time_edges, data, {}, counts, attrs, laser_points=capture.spots.reshape(ly, lx, 3),
                  sensor_points=capture.sensor_points(), wall_normal=capture.fov_normal.copy())
