"""Baseline of the multi-zone dataset (configs/datasets/multizone.yaml; docs/multizone.md, "The multi-zone dataset").

Each sample stores what the sensor outputs: one histogram per zone, ``counts`` (Z_y, Z_x, T), drawn by the build
with the dataset's detector from the zones' envelope. ``--seeds``: 0 reads the stored counts, s >= 1 the loader's
re-drawn ones of epoch s (``NLOSDataset(..., noise="resample")``, ``set_epoch(s)``: the same detector, fresh
noise). From the counts alone, background removed (its expected level, the loader's ``background``), five
features per sample: the peak time and the first moment
of the zone-summed transient, the signal-weighted zone centroid (u, v) and the log of the total signal. A least
squares fit (train) predicts the hidden object's centre: its distance from the relay wall (``depth``), across
(``y``) and up (``z``); validation RMSE against the trivial baseline (the training mean). Plain script::

    python examples/multizone_baseline.py data/multizone --seeds 0,1,2
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from datagen.dataset import NLOSDataset  # noqa: E402

TARGETS = ("depth", "y", "z")


def features(counts: np.ndarray, background: float, centers: np.ndarray) -> np.ndarray:
    """Five features of one sample's zone counts (Zy, Zx, T), background removed."""
    signal = np.clip(counts - background, 0.0, None)
    total_t = signal.sum(axis=(0, 1))
    k = np.arange(len(total_t), dtype=np.float64)
    peak = float(np.argmax(total_t))
    keep = total_t >= 0.2 * total_t.max() if total_t.max() > 0 else np.ones_like(total_t, bool)
    moment = float((k * total_t * keep).sum() / max((total_t * keep).sum(), 1e-12))
    per_zone = signal.sum(axis=-1)
    s = max(per_zone.sum(), 1e-12)
    cu = float((per_zone * centers[..., 0]).sum() / s)
    cv = float((per_zone * centers[..., 1]).sum() / s)
    return np.array([peak, moment, cu, cv, np.log1p(s)])


def dataset_arrays(path: Path, split: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 5) features of ``split``'s zone counts (``seed`` 0: the stored ones; s >= 1: the loader's re-draw of
    epoch s) and (N, 3) targets (depth, y, z; m)."""
    ds = NLOSDataset(path, split=split, fields=("counts", "background", "params"),
                     noise="resample" if seed else "frozen")
    ds.set_epoch(seed)
    x, y = [], []
    for i in range(len(ds)):
        item = ds[i]
        counts = item["counts"].numpy().astype(np.float64)                  # (Zy, Zx, T) detections
        zy, zx = counts.shape[:2]
        centers = np.stack(np.meshgrid(np.arange(zx) + 0.5, np.arange(zy) + 0.5), axis=-1)   # (Zy, Zx, 2)
        x.append(features(counts, float(item["background"]), centers))
        params = ds.params(i)
        c = params["objects"][0]["center"]
        y.append([params["room"]["room"]["relay_x"] - c[0], c[1], c[2]])
    return np.array(x), np.array(y)


def fit_predict(x_train: np.ndarray, y_train: np.ndarray, x_val: np.ndarray) -> np.ndarray:
    """Least squares on standardised features with a constant (a tiny ridge keeps it well posed)."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-12
    a = np.hstack([(x_train - mu) / sd, np.ones((len(x_train), 1))])
    b = np.hstack([(x_val - mu) / sd, np.ones((len(x_val), 1))])
    coef = np.linalg.solve(a.T @ a + 1e-6 * np.eye(a.shape[1]), a.T @ y_train)
    return b @ coef


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--seeds", default="0", help="comma separated: 0 the stored counts, s >= 1 the loader's "
                        "re-drawn counts of epoch s")
    args = parser.parse_args(argv)
    out = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        x_tr, y_tr = dataset_arrays(args.dataset, "train", seed)
        x_va, y_va = dataset_arrays(args.dataset, "val", seed)
        pred = fit_predict(x_tr, y_tr, x_va)
        rmse = np.sqrt(((pred - y_va) ** 2).mean(0))
        trivial = np.sqrt(((y_tr.mean(0) - y_va) ** 2).mean(0))
        out[seed] = {t: (float(r), float(q)) for t, r, q in zip(TARGETS, rmse, trivial)}
        print(f"seed {seed}: " + "; ".join(f"{t} RMSE {r:.3f} m vs trivial {q:.3f} m (x{r / q:.2f})"
                                          for t, (r, q) in out[seed].items()))
    return out


if __name__ == "__main__":
    main()
