"""The benchmark leaderboard's scores: ``datagen suite score NAME PRED`` (docs/benchmark.md).

A method's predictions file is the ``.npz`` of ``datagen score`` (:mod:`datagen.dataset.score`: ``depth`` (N, H, W)
m on the wall-view grid, optional ``occupancy`` and ``index``), scored on the suite's test split, plus optionally

=================  ===========================  =================================================================
key                shape, dtype                 meaning
=================  ===========================  =================================================================
``normal``         (N, H, W, 3) float           unit surface normal per wall-view pixel (world frame, facing the
                                                wall, as the ``wall_normal`` label); (N, 3, H, W) is accepted
=================  ===========================  =================================================================

Metrics per sample, over the pixels where the label sees a hidden object (``wall_depth > 0``): the existing depth
MAE / RMSE and occupancy IoU (:func:`datagen.dataset.score.score_predictions`), the depth accuracy within δ
(:func:`delta_accuracy`: the fraction of pixels with max(d̂/d, d/d̂) < δ for δ = 1.25, 1.25², 1.25³; a depth
≤ 0 counts as wrong) and, when the method gives normals, the normal angle error (:func:`normal_angle_error`:
mean and median angle in degrees between predicted and labelled normals).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .score import score_predictions, write_scores

DELTAS = (1.25, 1.25 ** 2, 1.25 ** 3)
"""Thresholds of the depth accuracy within δ (Eigen et al. 2014, the monocular-depth convention)."""


def delta_accuracy(pred: np.ndarray, label: np.ndarray, mask: np.ndarray, delta: float) -> float:
    """Fraction of the ``mask`` pixels where max(pred/label, label/pred) < ``delta``.

    Args:
        pred, label: (H, W) depths in metres (label > 0 on the mask); mask: (H, W) bool.
        delta: threshold > 1.
    Returns:
        a fraction in [0, 1]; NaN for an empty mask. A predicted depth ≤ 0 counts as wrong.
    """
    p = np.asarray(pred, np.float64)[mask]
    d = np.asarray(label, np.float64)[mask]
    if d.size == 0:
        return math.nan
    ok = p > 0
    ratio = np.full(d.shape, np.inf)
    ratio[ok] = np.maximum(p[ok] / d[ok], d[ok] / p[ok])
    return float((ratio < delta).mean())


def normal_angle_error(pred: np.ndarray, label: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Angles in degrees between predicted and labelled normals on the ``mask`` pixels.

    Args:
        pred, label: (H, W, 3) normals (``pred`` need not be unit length; a zero vector counts as 90°);
        mask: (H, W) bool.
    Returns:
        (M,) float64 degrees in [0, 180], one per mask pixel.
    """
    p = np.asarray(pred, np.float64)[mask]
    q = np.asarray(label, np.float64)[mask]
    norm = np.linalg.norm(p, axis=-1) * np.linalg.norm(q, axis=-1)
    cos = np.where(norm > 0, (p * q).sum(-1) / np.where(norm > 0, norm, 1.0), 0.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _normals(pred: Path, data: dict, n: int, shape: tuple[int, int]) -> np.ndarray | None:
    """The ``normal`` array of the predictions, as (N, H, W, 3) float64, or None.

    Raises:
        DatasetError: naming the file, the key and the value (dtype, shape, a non-finite entry).
    """
    if "normal" not in data:
        return None
    normal = data["normal"]
    if normal.dtype.kind not in "iuf":
        raise DatasetError(f"{pred}: normal has dtype {normal.dtype}; expected (N, H, W, 3) real numbers")
    if normal.ndim == 4 and normal.shape[1] == 3 and normal.shape[-1] != 3:
        normal = np.moveaxis(normal, 1, -1)           # the network layout (N, 3, H, W)
    if normal.shape != (n, *shape, 3):
        raise DatasetError(f"{pred}: normal has shape {data['normal'].shape}; expected {(n, *shape, 3)} (N, H, W, 3)")
    normal = np.asarray(normal, np.float64)
    if not np.isfinite(normal).all():
        k = int(np.argmax(~np.isfinite(normal).reshape(n, -1).all(axis=1)))
        raise DatasetError(f"{pred}: normal of position {k} of the file is not finite: give finite normals")
    return normal


def score_suite(pred: str | Path, dataset: str | Path, name: str | None = None, variant: str | None = None) -> dict:
    """Score the predictions file ``pred`` on the test split of the suite built at ``dataset``.

    Args:
        pred: ``.npz`` (module doc). dataset: a build of the suite (``datagen suite build``).
        name: the suite the predictions are for; refused when ``dataset`` is a build of another suite.
        variant: the variant the method reconstructed from (recorded in the summary; default: the suite's first).
    Returns:
        {"summary": {...}, "rows": [...]} as :func:`datagen.dataset.score.score_predictions`, each row with
        ``delta_1.25``, ``delta_1.5625``, ``delta_1.953`` and (with normals) ``normal_angle_mean_deg``,
        ``normal_angle_median_deg``; the summary adds ``suite``, ``variant``, ``full_suite`` and the means.
    Raises:
        what :func:`score_predictions` and :func:`datagen.dataset.suite.suite_of_dataset` raise; DatasetError:
        ``dataset`` is another suite's build, an unknown variant, or bad normals (named).
    """
    from .loader import NLOSDataset
    from .suite import suite_of_dataset

    suite, full = suite_of_dataset(dataset)
    if name is not None and name != suite.name:
        raise DatasetError(f"{dataset} is a build of suite {suite.name}, not {name}")
    variant = variant or next(iter(suite.spec.variants))
    if variant not in suite.spec.variants:
        raise DatasetError(f"suite {suite.name} has no variant {variant!r} (variants: "
                           f"{', '.join(suite.spec.variants)})")
    split = suite.spec.test_split
    scores = score_predictions(pred, dataset, split, extra_keys=("normal",))
    with np.load(pred, allow_pickle=False) as f:
        data = {k: np.asarray(f[k]) for k in f.files}
    rows, summary = scores["rows"], scores["summary"]
    depth = data.get("depth")
    if depth is not None and depth.ndim == 4 and depth.shape[1] == 1:
        depth = depth[:, 0]
    fields = ["wall_depth"] + (["wall_normal"] if "normal" in data else [])
    labels = NLOSDataset(dataset, split=split, fields=fields)
    shape = tuple(labels.read(0)["wall_depth"].shape)
    normals = _normals(Path(pred), data, len(rows), shape)
    for k, row in enumerate(rows):
        truth = labels.read(row["index"])
        d = np.asarray(truth["wall_depth"], np.float64)
        mask = d > 0
        if depth is not None:
            for delta in DELTAS:
                row[f"delta_{delta:.4g}"] = delta_accuracy(depth[k], d, mask, delta)
        if normals is not None:
            angles = normal_angle_error(normals[k], truth["wall_normal"], mask)
            row["normal_angle_mean_deg"] = float(angles.mean()) if angles.size else math.nan
            row["normal_angle_median_deg"] = float(np.median(angles)) if angles.size else math.nan
    keys = [f"delta_{delta:.4g}" for delta in DELTAS] if depth is not None else []
    keys += ["normal_angle_mean_deg", "normal_angle_median_deg"] if normals is not None else []
    for key in keys:
        values = [r[key] for r in rows if key in r and not math.isnan(r[key])]
        summary[f"mean_{key}"] = float(np.mean(values)) if values else math.nan
    summary.update({"suite": suite.name, "variant": variant, "full_suite": full,
                    "suite_content_sha256": suite.spec.content_sha256})
    return scores


def write_suite_scores(scores: dict, out: str | Path, stem: str) -> tuple[Path, Path]:
    """Write ``<stem>.csv`` (one row per sample, every metric) and ``<stem>.json`` (summary and rows; NaN as null)
    into folder ``out`` (:func:`datagen.dataset.score.write_scores` with every column the rows hold)."""
    return write_scores(scores, out, stem, columns=list(dict.fromkeys(k for r in scores["rows"] for k in r)))
