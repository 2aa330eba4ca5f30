"""Score reconstructions against a dataset split's labels: depth MAE / RMSE over the hidden objects, occupancy IoU.

``datagen score PRED --dataset D --split test`` (:func:`score_predictions`). The predictions file ``PRED`` is a
NumPy ``.npz`` archive with any of:

=================  ===========================  =================================================================
key                shape, dtype                 meaning
=================  ===========================  =================================================================
``depth``          (N, H, W) float, metres      depth image of sample ``index[n]``, on the grid of the label
                                                field (default ``wall_depth``: orthographic distance from the
                                                scanned wall rectangle, row 0 at its bottom); a (N, 1, H, W) array
                                                (the network layout) is accepted
``occupancy``      (N, V, V, V) any number      occupancy grid on the label's grid (axes x, y, z); a voxel counts as
                                                occupied where the value exceeds ``threshold`` (0.5)
``index``          (N,) int                     sample indices in the split (default 0 … N − 1), each at most once
=================  ===========================  =================================================================

N ≥ 1. Refused, with one line naming the file, the key and the value: a 0-d or empty array, a dtype that is not
a number (an integer for ``index``), a shape that is not the labels', an index outside the split or repeated, a
depth that is not finite (or beyond ±``MAX_EXTENT`` m) on the hidden-object mask, an occupancy value that is not
finite, a threshold that is not finite, and a dataset whose build is not complete or whose files are damaged
(the labels are read through the loader, docs/reliability.md "Reading a dataset").

Metrics per sample (docs/datasets.md, "Scoring"): ``depth_mae`` = mean |d̂ − d| and ``depth_rmse`` = √mean
(d̂ − d)² over the pixels where the label sees a hidden object (label depth > 0: the union of the wall masks);
predictions outside that mask do not count. ``occupancy_iou`` = |P ∩ L| / |P ∪ L| of the occupied voxels (NaN
when both are empty). The summary gives the mean over samples of each metric (NaNs left out), the pixel-pooled
depth MAE / RMSE, the number of samples and ``depth_samples``, how many of them have object pixels (the
samples the depth means are over: a sample whose objects are out of the wall's view has NaN depth metrics).
:func:`write_scores` writes ``<PRED>_scores.csv`` (one row per sample) and ``<PRED>_scores.json`` (summary and
rows), named after the predictions file so that several predictions in one folder keep their own scores.
"""
from __future__ import annotations

import csv
import json
import math
import zipfile
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..scene.parts import MAX_EXTENT

DEFAULT_DEPTH_FIELD = "wall_depth"
OCCUPANCY_THRESHOLD = 0.5

LAYOUTS = {"depth": "(N, H, W) real numbers (m)", "occupancy": "(N, V, V, V) real numbers or booleans",
           "index": "(N,) integers"}
"""What each key of a predictions file must hold (the module doc's table)."""

KINDS = {"depth": "iuf", "occupancy": "biuf", "index": "iu"}
"""numpy dtype kinds each key accepts."""


def _load_predictions(pred: Path, extra_keys: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays of the predictions file, each checked for its dtype and for having a sample axis
    (``extra_keys``: further keys allowed, returned unchecked, for a caller that scores them).

    Raises:
        FileNotFoundError: no file; DatasetError: not an .npz archive, an unknown key, neither depth nor
        occupancy, a dtype that is not a number (or an integer for ``index``), or a 0-d array.
    """
    if not pred.is_file():
        raise FileNotFoundError(f"predictions file not found: {pred}")
    try:
        with np.load(pred, allow_pickle=False) as f:
            data = {k: np.asarray(f[k]) for k in f.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:      # a truncated archive: BadZipFile
        raise DatasetError(f"{pred}: not a NumPy .npz archive, or a truncated one "
                           f"({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    unknown = sorted(set(data) - {"depth", "occupancy", "index", *extra_keys})
    if unknown:
        raise DatasetError(f"{pred}: unknown key {unknown[0]!r} (expected "
                           f"{', '.join(['depth', 'occupancy', 'index', *extra_keys])})")
    if "depth" not in data and "occupancy" not in data:
        raise DatasetError(f"{pred}: holds neither depth nor occupancy")
    for key, value in data.items():
        if key in extra_keys:
            continue
        if value.dtype.kind not in KINDS[key]:
            raise DatasetError(f"{pred}: {key} has dtype {value.dtype}; expected {LAYOUTS[key]}")
        if value.ndim == 0:
            raise DatasetError(f"{pred}: {key} has shape () (a single value); expected {LAYOUTS[key]}")
    return data


def _check_index(pred: Path, index: np.ndarray, n: int, split: str, count: int) -> None:
    """``index``: (n,) integers inside the split, each at most once.

    Raises:
        DatasetError: naming the file, the key ``index`` and the bad value (shape, out of range, repeated).
    """
    if index.shape != (n,):
        raise DatasetError(f"{pred}: index has shape {index.shape}; expected ({n},) integers, one per sample")
    if index.min() < 0 or index.max() >= count:
        bad = int(index.min()) if index.min() < 0 else int(index.max())
        raise DatasetError(f"{pred}: index {bad} is outside split {split!r} (count {count})")
    values, counts = np.unique(index, return_counts=True)
    if np.any(counts > 1):
        value = int(values[np.argmax(counts > 1)])
        where = np.flatnonzero(index == value)
        shown = ", ".join(str(int(k)) for k in where[:5]) + (", …" if len(where) > 5 else "")
        raise DatasetError(f"{pred}: index repeats {value} ({len(where)} times, at positions {shown}): each sample "
                         "is scored at most once")


def _first_bad(values: np.ndarray, bad: np.ndarray) -> tuple[float, tuple[int, ...]]:
    """(value, position) of the first True of ``bad`` in ``values`` (same shape)."""
    pos = tuple(int(k) for k in np.unravel_index(int(np.argmax(bad)), bad.shape))
    return float(values[pos]), pos


def score_predictions(pred: str | Path, dataset: str | Path, split: str, depth_field: str = DEFAULT_DEPTH_FIELD,
                      threshold: float = OCCUPANCY_THRESHOLD, extra_keys: tuple[str, ...] = ()) -> dict:
    """Score the predictions file ``pred`` (layout in the module doc) against ``split`` of ``dataset``.

    The labels are read through :class:`datagen.dataset.NLOSDataset`, so the dataset is checked as every
    reader checks it (docs/reliability.md, "Reading a dataset"): a complete build, metadata as the card
    implies, shard files present and undamaged.

    Args:
        pred: ``.npz`` with ``depth`` (N, H, W) or (N, 1, H, W) m and/or ``occupancy`` (N, V, V, V), optional
            ``index`` (N,) integers (default 0 … N − 1), N ≥ 1.
        threshold: a voxel of ``occupancy`` is occupied where its value exceeds this (finite).
        extra_keys: further keys the file may hold, left to the caller (``datagen suite score``: ``normal``).
    Returns:
        {"summary": {...}, "rows": [{index, depth_mae, depth_rmse, depth_pixels, occupancy_iou}, ...]}
        (metres; NaN where a metric does not apply: no object pixels, or nothing occupied in either grid).
    Raises:
        FileNotFoundError: no predictions file or dataset; DatasetIncompleteError (a ValueError): the build is
        not complete (names the missing shards); DatasetCorruptError: damaged dataset files; DatasetError: a
        bad archive, key, dtype or shape (0-d, no samples, not the labels'), an index out of range or
        repeated, a depth that is not finite or beyond ±MAX_EXTENT m on the hidden-object mask, an occupancy
        value that is not finite, a threshold that is not finite, or a label field the dataset does not store
        (each message names the file, the key and the value).
    """
    from .integrity import require_complete
    from .loader import NLOSDataset

    try:
        threshold = float(threshold)
    except (TypeError, ValueError):
        raise DatasetError(f"occupancy threshold (--threshold) must be a finite number, got {threshold!r}") from None
    if not math.isfinite(threshold):
        raise DatasetError(f"occupancy threshold (--threshold) must be a finite number, got {threshold!r}")
    pred = Path(pred)
    data = _load_predictions(pred, tuple(extra_keys))
    card = require_complete(dataset)
    if split not in card.get("splits", {}):
        raise DatasetError(f"{dataset}: split {split!r} not in the dataset (splits: {sorted(card.get('splits', {}))})")
    info = card["splits"][split]
    depth = data.get("depth")
    if depth is not None and depth.ndim == 4 and depth.shape[1] == 1:
        depth = depth[:, 0]                        # the network layout (N, 1, H, W)
    fields = []
    if depth is not None:
        if depth_field not in info["fields"]:
            raise DatasetError(f"{dataset}: split {split!r} stores no {depth_field} label (stored: "
                             f"{sorted(info['fields'])}); choose --depth-field")
        fields.append(depth_field)
    if "occupancy" in data:
        if "occupancy" not in info["fields"]:
            raise DatasetError(f"{dataset}: split {split!r} stores no occupancy label")
        fields.append("occupancy")
    first = "depth" if depth is not None else "occupancy"
    n = int(data[first].shape[0])
    if n == 0:
        raise DatasetError(f"{pred}: {first} holds no samples (shape {data[first].shape}); expected {LAYOUTS[first]} "
                         "with N >= 1")
    if depth is not None:
        label_shape = tuple(info["fields"][depth_field]["shape"])
        if depth.shape != (n,) + label_shape:
            raise DatasetError(f"{pred}: depth has shape {data['depth'].shape}, the labels' {depth_field} is "
                             f"{(n,) + label_shape} (N, H, W)")
    if "occupancy" in data:
        label_shape = tuple(info["fields"]["occupancy"]["shape"])
        if data["occupancy"].shape != (n,) + label_shape:
            raise DatasetError(f"{pred}: occupancy has shape {data['occupancy'].shape}, the labels' is "
                             f"{(n,) + label_shape} (N, V, V, V)"
                             + (f" with N = {n} as in depth" if depth is not None else ""))
    index = data.get("index", np.arange(n))
    _check_index(pred, index, n, split, int(info["count"]))
    occupancy = data.get("occupancy")
    if occupancy is not None and occupancy.dtype.kind == "f" and not np.isfinite(occupancy).all():
        k, (value, pos) = _first_bad_sample(occupancy)
        raise DatasetError(f"{pred}: occupancy of sample {int(index[k])} (position {k} of the file) is {value} at "
                         f"voxel {pos}: give finite values (a voxel is occupied where above the threshold)")
    labels = NLOSDataset(dataset, split=split, fields=fields)   # checks the metadata; reads check the shards
    rows = [{"index": int(i)} for i in index]
    pooled = [0.0, 0.0, 0]
    for k, (row, i) in enumerate(zip(rows, index)):
        truth = labels.read(int(i))
        if depth is not None:
            d = np.asarray(truth[depth_field], dtype=np.float64)
            d_hat = np.asarray(depth[k], dtype=np.float64)
            mask = d > 0
            bad = mask & ~(np.abs(d_hat) <= MAX_EXTENT)          # NaN, ±inf or beyond any scene
            if bad.any():
                value, pos = _first_bad(d_hat, bad)
                raise DatasetError(f"{pred}: depth of sample {int(i)} (position {k} of the file) is {value} at "
                                 f"pixel {pos}, on the hidden-object mask: give finite depths within "
                                 f"±{MAX_EXTENT:g} m")
            err = (d_hat - d)[mask]
            row["depth_pixels"] = int(mask.sum())
            row["depth_mae"] = float(np.abs(err).mean()) if err.size else math.nan
            row["depth_rmse"] = float(np.sqrt((err ** 2).mean())) if err.size else math.nan
            pooled[0] += float(np.abs(err).sum())
            pooled[1] += float((err ** 2).sum())
            pooled[2] += int(err.size)
        if "occupancy" in data:
            p, q = np.asarray(occupancy[k]) > threshold, np.asarray(truth["occupancy"]) > 0
            union = int((p | q).sum())
            row["occupancy_iou"] = float((p & q).sum() / union) if union else math.nan
    summary = {"dataset": str(dataset), "split": split, "predictions": str(pred), "samples": n,
               "depth_field": depth_field if depth is not None else None,
               "occupancy_threshold": threshold if "occupancy" in data else None}
    for key in ("depth_mae", "depth_rmse", "occupancy_iou"):
        values = [r[key] for r in rows if key in r and not math.isnan(r[key])]
        summary[f"mean_{key}"] = float(np.mean(values)) if values else math.nan
    if depth is not None:
        summary["pooled_depth_mae"] = pooled[0] / pooled[2] if pooled[2] else math.nan
        summary["pooled_depth_rmse"] = math.sqrt(pooled[1] / pooled[2]) if pooled[2] else math.nan
        summary["depth_pixels"] = pooled[2]
        summary["depth_samples"] = sum(1 for r in rows if r.get("depth_pixels", 0) > 0)
    return {"summary": summary, "rows": rows}


def _first_bad_sample(values: np.ndarray) -> tuple[int, tuple[float, tuple[int, ...]]]:
    """(sample, (value, voxel)) of the first non-finite entry of ``values`` (N, ...)."""
    bad = ~np.isfinite(values)
    i = int(np.argmax(bad.reshape(len(values), -1).any(axis=1)))
    return i, _first_bad(values[i], bad[i])


def write_scores(scores: dict, out: str | Path, stem: str = "scores",
                 columns: list[str] | None = None) -> tuple[Path, Path]:
    """Write ``<stem>.csv`` (one row per sample) and ``<stem>.json`` (summary + rows; NaN as null) into folder
    ``out`` (``datagen score`` names them after the predictions file: ``pred_scores.csv`` for ``pred.npz``).
    ``columns``: the CSV's columns (default: index and the metrics of :func:`score_predictions` the rows hold)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if columns is None:
        columns = ["index"] + [c for c in ("depth_mae", "depth_rmse", "depth_pixels", "occupancy_iou")
                               if any(c in r for r in scores["rows"])]
    csv_path, json_path = out / f"{stem}.csv", out / f"{stem}.json"
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        for row in scores["rows"]:
            writer.writerow({c: row.get(c, "") for c in columns})

    def plain(v):
        return None if isinstance(v, float) and math.isnan(v) else v

    json_path.write_text(json.dumps({"summary": {k: plain(v) for k, v in scores["summary"].items()},
                                     "rows": [{k: plain(v) for k, v in r.items()} for r in scores["rows"]]},
                                    indent=1) + "\n")
    return csv_path, json_path
