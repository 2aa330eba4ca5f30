"""Baseline network for the confocal wall scans: a small CNN from the (1, T, H, W) scan to the ``wall_depth`` image,
CPU-sized; writes its validation predictions in the layout of ``datagen score``.

    python -m examples.train_depth_image data/wall_baseline          # → data/wall_baseline_net_val.npz
    datagen score data/wall_baseline_net_val.npz --dataset data/wall_baseline --split val
    python -m examples.train_depth_image data/wall128 --pool 4       # 128×128 scans pooled to 32×32 inputs
    python -m examples.train_depth_image data/lct_release --pool 4 --save lct_net.pt   # keep the network:
    python benchmarks/real_low_light.py FOLDER --network lct_net.pt  # ... and run it on the LCT release's captures

Reads the ``train`` and ``val`` splits with ``NLOSDataset(..., layout="network")`` (envelope and counts as
(1, T, H, W), ``wall_depth`` as (1, H, W)) into memory. Training inputs are fresh SPAD counts every step, drawn in
the batch from the stored envelope with :class:`datagen.SPADNoise` (the split's detector); validation reads the
stored (frozen) counts. Input log(1 + counts), standardised.

Network (:class:`DepthNet`, ≈ 24 k parameters): the same temporal encoder at every scan point ((k, 1, 1) 3-D
convolutions over time), then 2-D convolutions over the scan grid to one depth per pixel; ≈ 1 s of CPU per
epoch of 200 samples of 16 × 16 × 256 on 2 threads.

Network-resolution scans (``configs/datasets/wall128.yaml``, ``confocal64.yaml``): ``--pool K`` sums the scan over
K × K blocks of scan points on loading (a 128 × 128 × 512 scan is 32 MiB; its full-resolution forward pass and
SPAD draw cost ≈ 1 s per sample on this CPU), the network runs on the (H/K, W/K) grid and its depth image is
upsampled bilinearly to the label's (H, W) grid, where the loss and ``datagen score`` compare it. The fresh counts
of the pooled scan are drawn by a SPADNoise whose DCR and ambient rate are K² the split's (the summed background):
exact for the Poisson detector (a sum of independent Poisson counts), for the pile-up detector exact only at low
flux (these scans detect ≪ 1 photon per cycle and bin); the validation input is the stored counts, summed.
Results on small builds of both configs: docs/datasets.md ("Network resolution").

Loss: mean squared depth error over the pixels where the label sees the hidden object (``wall_depth > 0``), the
pixels ``datagen score`` scores. The trivial baseline is the training set's mean depth over those pixels, the same
for every pixel and sample.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import datagen
from datagen.dataset.score import score_predictions


def pool_scan(scan: torch.Tensor, pool: int) -> torch.Tensor:
    """(1, T, H, W) → (1, T, H/pool, W/pool): sums over pool × pool blocks of scan points (counts stay counts)."""
    if pool == 1:
        return scan
    _, t, h, w = scan.shape
    if h % pool or w % pool:
        raise ValueError(f"--pool {pool} does not divide the {h} × {w} scan")
    return scan.reshape(1, t, h // pool, pool, w // pool, pool).sum((3, 5))


def load_split(path, split: str, pool: int = 1) -> dict[str, torch.Tensor]:
    """{"envelope", "counts": (N, 1, T, H/pool, W/pool) float32 (summed over pool × pool scan points), "depth":
    (N, H, W) float32 m (the label's grid)} of one split, in memory."""
    ds = datagen.NLOSDataset(path, split=split, fields=("envelope", "counts", "wall_depth"), layout="network",
                             counts_dtype=torch.float32)
    out = {"envelope": [], "counts": [], "depth": []}
    for i in range(len(ds)):
        item = ds[i]
        out["envelope"].append(pool_scan(item["envelope"], pool))
        out["counts"].append(pool_scan(item["counts"], pool))
        out["depth"].append(item["wall_depth"][0])
    return {k: torch.stack(v) for k, v in out.items()}


class DepthNet(torch.nn.Module):
    """(B, 1, T, H, W) standardised scan → (B, H, W) standardised depth (module doc). ≈ 24 k parameters at 256
    bins: (k, 1, 1) 3-D convolutions encode each scan point's transient (8-bin patches, then two stride-2
    layers), a 1 × 1 convolution maps its T/32 × 16 features to 32, three 2-D convolutions mix neighbours."""

    def __init__(self, bins: int, features: int = 32, mask: bool = False):
        super().__init__()
        self.mask = mask
        if bins % 32:
            raise ValueError(f"DepthNet: the scan needs a multiple of 32 time bins, got {bins}")
        self.bins = bins
        relu = torch.nn.ReLU
        self.temporal = torch.nn.Sequential(
            torch.nn.Conv3d(1, 16, (8, 1, 1), stride=(8, 1, 1)), relu(),
            torch.nn.Conv3d(16, 16, (3, 1, 1), stride=(2, 1, 1), padding=(1, 0, 0)), relu(),
            torch.nn.Conv3d(16, 16, (3, 1, 1), stride=(2, 1, 1), padding=(1, 0, 0)), relu())
        self.spatial = torch.nn.Sequential(
            torch.nn.Conv2d(16 * (bins // 32), features, 1), relu(),
            torch.nn.Conv2d(features, 32, 3, padding=1), relu(),
            torch.nn.Conv2d(32, 32, 3, padding=1), relu(),
            torch.nn.Conv2d(32, 2 if mask else 1, 1))

    def forward(self, x: torch.Tensor, size: tuple[int, int] | None = None) -> torch.Tensor:
        """(B, 1, T, h, w) → (B, h, w), or (B, *size) upsampled bilinearly to a label grid ``size``; with ``mask``
        (B, 2, h, w): the standardised depth and the logit of "the hidden object is seen here"."""
        b, _, _, h, w = x.shape
        out = self.spatial(self.temporal(x).reshape(b, -1, h, w))
        if size is not None and tuple(size) != (h, w):
            out = torch.nn.functional.interpolate(out, size=tuple(size), mode="bilinear", align_corners=False)
        return out if self.mask else out[:, 0]

    def heads(self, out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(standardised depth (B, h, w), the mask logit (B, h, w) or None without a mask head) of a forward
        output."""
        return (out[:, 0], out[:, 1]) if self.mask else (out, None)


def draw_counts(noise: datagen.SPADNoise, envelope: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Fresh counts (B, 1, T, H, W) of envelopes in the network layout (SPADNoise wants time last)."""
    return noise(envelope.permute(0, 1, 3, 4, 2), gen).permute(0, 1, 4, 2, 3)


def save_model(path, net: DepthNet, pool: int, x_norm: tuple[float, float], d_norm: tuple[float, float],
               data) -> None:
    """Write the trained network, what its input needs (bins, pool, the log-count standardisation) and its depth
    scale to ``path`` (torch.save of a dict; :func:`load_model` reads it), with the data set it was trained on."""
    torch.save({"state": net.state_dict(), "bins": net.bins, "mask": net.mask, "pool": pool, "x_norm": x_norm,
                "d_norm": d_norm, "data": str(data)}, path)


def load_model(path) -> tuple[DepthNet, dict]:
    """(network in eval mode, its record) of a :func:`save_model` file."""
    record = torch.load(path, map_location="cpu", weights_only=True)
    net = DepthNet(record["bins"], mask=record.get("mask", False))
    net.load_state_dict(record["state"])
    return net.eval(), record


def predict_depth(net: DepthNet, record: dict, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float64 depth (m) of one scan of counts (H, W, T) on the network's time axis (``record["bins"]``
    bins of its training set's width), summed over ``record["pool"]`` × ``record["pool"]`` scan points, the depth
    upsampled back to (H, W); and (H, W) bool where it sees the object (its mask head's probability ≥ 0.5; True
    everywhere for a network without one)."""
    x = torch.as_tensor(np.moveaxis(np.asarray(counts, dtype=np.float32), -1, 0))[None]
    x = pool_scan(x, record["pool"])[None]
    (x_mean, x_std), (d_mean, d_std) = record["x_norm"], record["d_norm"]
    with torch.no_grad():
        depth, logit = net.heads(net((torch.log1p(x) - x_mean) / x_std, tuple(counts.shape[:2])))
    depth = (depth[0] * d_std + d_mean).double().numpy()
    return depth, (logit[0].numpy() >= 0.0 if logit is not None else np.ones(depth.shape, bool))


def train(path, epochs: int = 40, batch: int = 16, seed: int = 0, lr: float = 3e-3, train_split: str = "train",
          val_split: str = "val", pool: int = 1, log=print, save: str | Path | None = None,
          stored: bool = False, mask: bool = False) -> dict[str, np.ndarray]:
    """Train on ``train_split``, predict ``val_split``, the scans summed over ``pool`` × ``pool`` scan points (module
    doc); with ``save`` the trained network goes to that file (:func:`save_model`); with ``stored`` the training
    inputs are the stored counts (each sample's own drawn detector: exposure, gain and background maps, IRF; one
    noise draw per sample) instead of fresh counts from the split's detector; with ``mask`` the network also learns
    where the object is seen (a second output, binary cross-entropy against ``wall_depth > 0`` over every pixel,
    added to the depth loss). Returns {"depth": (N, H, W) float32 m on the label's grid, "index": (N,), "trivial":
    (N, H, W) the training mean depth over the object pixels}."""
    torch.manual_seed(seed)
    t0 = time.perf_counter()
    tr, va = load_split(path, train_split, pool), load_split(path, val_split, pool)
    ds = datagen.NLOSDataset(path, split=train_split, fields=("envelope",))
    det = ds.detector_config()
    noise = ds.spad_noise() if pool == 1 else ds.spad_noise(dcr=det.dcr * pool ** 2,        # summed background
                                                            ambient_rate=det.ambient_rate * pool ** 2)
    size = tuple(tr["depth"].shape[1:])
    if log:
        log(f"  loaded {len(tr['depth'])} + {len(va['depth'])} samples, input {tuple(tr['envelope'].shape[1:])}, "
            f"labels {size} ({time.perf_counter() - t0:.0f} s)")
    gen = torch.Generator().manual_seed(seed)
    mask_tr = tr["depth"] > 0
    d_mean, d_std = tr["depth"][mask_tr].mean(), tr["depth"][mask_tr].std()
    inputs = (lambda rows: tr["counts"][rows]) if stored else (lambda rows: draw_counts(noise, tr["envelope"][rows],
                                                                                          gen))
    with torch.no_grad():
        x = torch.log1p(inputs(torch.arange(min(64, len(tr["depth"])))))
        x_mean, x_std = x.mean(), x.std() + 1e-6
    net = DepthNet(tr["envelope"].shape[2], mask=mask)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    n = len(tr["depth"])
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * -(-n // batch))
    for epoch in range(epochs):
        net.train()
        order = torch.randperm(n, generator=gen)
        for start in range(0, n, batch):
            rows = order[start:start + batch]
            x = (torch.log1p(inputs(rows)) - x_mean) / x_std
            seen = mask_tr[rows]
            depth, logit = net.heads(net(x, size))
            err = depth - (tr["depth"][rows] - d_mean) / d_std
            loss = (err[seen] ** 2).mean() if seen.any() else (err * 0).sum()
            if logit is not None:
                loss = loss + torch.nn.functional.binary_cross_entropy_with_logits(logit, seen.float())
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        if log and (epoch + 1) % max(1, epochs // 5) == 0:
            log(f"  epoch {epoch + 1}/{epochs}: train loss {loss.item():.3f} ({time.perf_counter() - t0:.0f} s)")
    net.eval()
    if save is not None:
        save_model(save, net, pool, (float(x_mean), float(x_std)), (float(d_mean), float(d_std)), path)
    with torch.no_grad():
        x = (torch.log1p(va["counts"]) - x_mean) / x_std
        depth = net.heads(torch.cat([net(x[s:s + 64], size) for s in range(0, len(x), 64)]))[0] * d_std + d_mean
    n_va = len(va["depth"])
    return {"depth": depth.numpy().astype(np.float32), "index": np.arange(n_va),
            "trivial": np.full(tuple(va["depth"].shape), float(d_mean), dtype=np.float32)}


def main(argv=None):
    parser = argparse.ArgumentParser(description="depth-image CNN baseline on a confocal wall scan dataset")
    parser.add_argument("data")
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--train", default="train")
    parser.add_argument("--val", default="val")
    parser.add_argument("--pool", type=int, default=1, help="sum the scan over POOL × POOL scan points (module doc)")
    parser.add_argument("--out", default=None, help="predictions .npz (default: DATA_net_<val>.npz); the "
                                                    "trivial baseline goes to the same name with _trivial")
    parser.add_argument("--save", default=None, help="write the trained network to this file (.pt)")
    parser.add_argument("--mask", action="store_true", help="also learn where the object is seen (a mask head)")
    parser.add_argument("--stored-counts", action="store_true",
                        help="train on the stored counts (each sample's drawn detector) instead of fresh noise")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    pred = train(args.data, args.epochs, args.batch, args.seed, train_split=args.train, val_split=args.val,
                 pool=args.pool, save=args.save, stored=args.stored_counts, mask=args.mask)
    out = Path(args.out or f"{Path(args.data)}_net_{args.val}.npz")
    np.savez(out, depth=pred["depth"], index=pred["index"])
    trivial = out.with_name(out.stem + "_trivial.npz")
    np.savez(trivial, depth=pred["trivial"], index=pred["index"])
    for name, f in (("network", out), ("trivial", trivial)):
        s = score_predictions(f, args.data, args.val)["summary"]
        print(f"{name}: val depth MAE {s['mean_depth_mae']:.3f} m, RMSE {s['mean_depth_rmse']:.3f} m over the object "
              f"pixels (mean over samples) -> {f}")
    print(f"score: datagen score {out} --dataset {args.data} --split {args.val}")


if __name__ == "__main__":
    main()
