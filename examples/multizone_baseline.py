"""Baseline of the multi-zone dataset (configs/datasets/multizone.yaml; docs/multizone.md, "The multi-zone dataset").

Each sample's zone histograms are composed from its stored exhaustive envelope (flood nodes × zones,
:func:`datagen.simulation.multizone.compose_zones` with :func:`datagen.scene.flood.node_weights` of the stored
laser grid and emitter), then one exposure of counts per zone is drawn with the dataset's detector
(:func:`datagen.spad.sample_histogram`; the generator of ``--seeds``). From the counts alone, background removed
(its expected level, the loader's ``background``), five features per sample: the peak time and the first moment
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

from datagen import spad  # noqa: E402
from datagen.dataset import NLOSDataset  # noqa: E402
from datagen.scene.flood import FloodProfile, node_weights  # noqa: E402
from datagen.simulation.multizone import compose_zones  # noqa: E402

TARGETS = ("depth", "y", "z")


def grid_nodes(grid: dict, relay_x: float) -> np.ndarray:
    """(ny·nx, 3) cell centres of a stored wall grid on the relay wall x = relay_x (u = +y, v = +z; docs/datasets.md)."""
    (nx, ny), (w, h), c = grid["points"], grid["size"], np.asarray(grid["center"], dtype=np.float64)
    a = ((np.arange(nx) + 0.5) / nx - 0.5) * w
    b = ((np.arange(ny) + 0.5) / ny - 0.5) * h
    pts = np.zeros((ny, nx, 3))
    pts[..., 0] = relay_x
    pts[..., 1] = c[1] + a[None, :]
    pts[..., 2] = c[2] + b[:, None]
    return pts.reshape(-1, 3)


def zone_envelope(ds: NLOSDataset, index: int, profile: FloodProfile) -> tuple[np.ndarray, dict]:
    """(Zy, Zx, T) float64 zone envelope of sample ``index`` (expected detected photons per pulse per bin) and its
    params."""
    item = ds.read(index)
    params = ds.params(index)
    room = params["room"]
    env = np.asarray(item["envelope"], dtype=np.float64)              # (ny, nx, Zy, Zx, T)
    ny, nx, zy, zx, n_t = env.shape
    nodes = grid_nodes(room["sensor"]["scan"]["laser_grid"], room["room"]["relay_x"])
    normals = np.broadcast_to([-1.0, 0.0, 0.0], nodes.shape)          # the relay wall faces −x
    w = node_weights(nodes, normals, room["laser"]["emitter"], profile)
    return compose_zones(env.reshape(ny * nx, zy * zx, n_t), w).reshape(zy, zx, n_t), params


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


def dataset_arrays(path: Path, split: str, seed: int, profile: FloodProfile) -> tuple[np.ndarray, np.ndarray]:
    """(N, 5) features of ``split`` (counts drawn with ``seed``) and (N, 3) targets (depth, y, z; m)."""
    ds = NLOSDataset(path, split=split)
    det = ds.detector_config()
    rng = np.random.default_rng([seed, len(split)])
    x, y = [], []
    for i in range(len(ds)):
        env, params = zone_envelope(ds, i, profile)
        zy, zx = env.shape[:2]
        centers = np.stack(np.meshgrid(np.arange(zx) + 0.5, np.arange(zy) + 0.5), axis=-1)   # (Zy, Zx, 2)
        counts = spad.sample_histogram(spad.rates_from_envelope(env, det), det, rng)
        background = float(ds.read(i)["background"])
        x.append(features(counts, background, centers))
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
    parser.add_argument("--seeds", default="0", help="noise seeds, comma separated (one count draw per seed)")
    parser.add_argument("--profile", default="uniform_intensity",
                        choices=["uniform_intensity", "uniform_irradiance", "gaussian"])
    args = parser.parse_args(argv)
    profile = FloodProfile(kind=args.profile)
    out = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        x_tr, y_tr = dataset_arrays(args.dataset, "train", seed, profile)
        x_va, y_va = dataset_arrays(args.dataset, "val", seed, profile)
        pred = fit_predict(x_tr, y_tr, x_va)
        rmse = np.sqrt(((pred - y_va) ** 2).mean(0))
        trivial = np.sqrt(((y_tr.mean(0) - y_va) ** 2).mean(0))
        out[seed] = {t: (float(r), float(q)) for t, r, q in zip(TARGETS, rmse, trivial)}
        print(f"seed {seed}: " + "; ".join(f"{t} RMSE {r:.3f} m vs trivial {q:.3f} m (x{r / q:.2f})"
                                          for t, (r, q) in out[seed].items()))
    return out


if __name__ == "__main__":
    main()
