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
``index``          (N,) int                     sample indices in the split (default 0 … N − 1)
=================  ===========================  =================================================================

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
from pathlib import Path

import numpy as np

from ..scene import SceneError

DEFAULT_DEPTH_FIELD = "wall_depth"
OCCUPANCY_THRESHOLD = 0.5


def _load_predictions(pred: Path) -> dict[str, np.ndarray]:
    if not pred.is_file():
        raise FileNotFoundError(f"predictions file not found: {pred}")
    try:
        with np.load(pred, allow_pickle=False) as f:
            data = {k: np.asarray(f[k]) for k in f.files}
    except (ValueError, OSError) as exc:
        raise SceneError(f"{pred}: not a NumPy .npz archive ({' '.join(str(exc).split())})") from None
    unknown = sorted(set(data) - {"depth", "occupancy", "index"})
    if unknown:
        raise SceneError(f"{pred}: unknown key {unknown[0]!r} (expected depth, occupancy, index)")
    if "depth" not in data and "occupancy" not in data:
        raise SceneError(f"{pred}: holds neither depth nor occupancy")
    return data


def score_predictions(pred: str | Path, dataset: str | Path, split: str, depth_field: str = DEFAULT_DEPTH_FIELD,
                      threshold: float = OCCUPANCY_THRESHOLD) -> dict:
    """Score the predictions file ``pred`` (layout in the module doc) against ``split`` of ``dataset``.

    Returns:
        {"summary": {...}, "rows": [{index, depth_mae, depth_rmse, depth_pixels, occupancy_iou}, ...]}
        (metres; NaN where a metric does not apply).
    Raises:
        FileNotFoundError: no predictions file or dataset; SceneError: a bad archive, key, shape or index, or a
        label field the dataset does not store (each message names the file, the key and the value).
    """
    from .store import read_card, zarr_module

    pred = Path(pred)
    data = _load_predictions(pred)
    card = read_card(dataset)
    if split not in card.get("splits", {}):
        raise SceneError(f"{dataset}: split {split!r} not in the dataset (splits: {sorted(card.get('splits', {}))})")
    info = card["splits"][split]
    n = len(next(iter(v for k, v in data.items() if k != "index")))
    index = data.get("index", np.arange(n))
    if index.shape != (n,) or not np.issubdtype(index.dtype, np.integer):
        raise SceneError(f"{pred}: index must be ({n},) integers, got {index.shape} {index.dtype}")
    if n and (index.min() < 0 or index.max() >= info["count"]):
        raise SceneError(f"{pred}: index {int(index.max() if index.max() >= info['count'] else index.min())} is "
                         f"outside split {split!r} (count {info['count']})")
    group = zarr_module().open_group(str(Path(dataset) / split), mode="r")
    rows = [{"index": int(i)} for i in index]
    pooled = [0.0, 0.0, 0]
    if "depth" in data:
        if depth_field not in info["fields"]:
            raise SceneError(f"{dataset}: split {split!r} stores no {depth_field} label (stored: "
                             f"{sorted(info['fields'])}); choose --depth-field")
        label_shape = tuple(info["fields"][depth_field]["shape"])
        depth = data["depth"]
        if depth.ndim == 4 and depth.shape[1] == 1:
            depth = depth[:, 0]
        if depth.shape != (n,) + label_shape:
            raise SceneError(f"{pred}: depth has shape {data['depth'].shape}, the labels' {depth_field} is "
                             f"{(n,) + label_shape} (N, H, W)")
        labels = group[depth_field]
        for row, i, d_hat in zip(rows, index, depth.astype(np.float64)):
            d = np.asarray(labels[int(i)], dtype=np.float64)
            mask = d > 0
            err = (d_hat - d)[mask]
            if not np.isfinite(err).all():
                raise SceneError(f"{pred}: depth of sample {int(i)} is not finite on the hidden-object mask")
            row["depth_pixels"] = int(mask.sum())
            row["depth_mae"] = float(np.abs(err).mean()) if err.size else math.nan
            row["depth_rmse"] = float(np.sqrt((err ** 2).mean())) if err.size else math.nan
            pooled[0] += float(np.abs(err).sum())
            pooled[1] += float((err ** 2).sum())
            pooled[2] += int(err.size)
    if "occupancy" in data:
        if "occupancy" not in info["fields"]:
            raise SceneError(f"{dataset}: split {split!r} stores no occupancy label")
        label_shape = tuple(info["fields"]["occupancy"]["shape"])
        if data["occupancy"].shape != (n,) + label_shape:
            raise SceneError(f"{pred}: occupancy has shape {data['occupancy'].shape}, the labels' is "
                             f"{(n,) + label_shape} (N, V, V, V)")
        labels = group["occupancy"]
        for row, i, occ in zip(rows, index, data["occupancy"]):
            p, q = np.asarray(occ) > threshold, np.asarray(labels[int(i)]) > 0
            union = int((p | q).sum())
            row["occupancy_iou"] = float((p & q).sum() / union) if union else math.nan
    summary = {"dataset": str(dataset), "split": split, "predictions": str(pred), "samples": n,
               "depth_field": depth_field if "depth" in data else None,
               "occupancy_threshold": threshold if "occupancy" in data else None}
    for key in ("depth_mae", "depth_rmse", "occupancy_iou"):
        values = [r[key] for r in rows if key in r and not math.isnan(r[key])]
        summary[f"mean_{key}"] = float(np.mean(values)) if values else math.nan
    if "depth" in data:
        summary["pooled_depth_mae"] = pooled[0] / pooled[2] if pooled[2] else math.nan
        summary["pooled_depth_rmse"] = math.sqrt(pooled[1] / pooled[2]) if pooled[2] else math.nan
        summary["depth_pixels"] = pooled[2]
        summary["depth_samples"] = sum(1 for r in rows if r.get("depth_pixels", 0) > 0)
    return {"summary": summary, "rows": rows}


def write_scores(scores: dict, out: str | Path, stem: str = "scores") -> tuple[Path, Path]:
    """Write ``<stem>.csv`` (one row per sample) and ``<stem>.json`` (summary + rows) into folder ``out``
    (``datagen score`` names them after the predictions file: ``pred_scores.csv`` for ``pred.npz``)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
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
