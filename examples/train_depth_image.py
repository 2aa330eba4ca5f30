"""Baseline network for the confocal wall scans: a small CNN from the (1, T, H, W) scan to the ``wall_depth`` image,
CPU-sized; writes its validation predictions in the layout of ``datagen score``.

    python -m examples.train_depth_image data/wall_baseline          # → data/wall_baseline_net_val.npz
    datagen score data/wall_baseline_net_val.npz --dataset data/wall_baseline --split val
    python -m examples.train_depth_image data/wall128 --pool 4       # 128×128 scans pooled to 32×32 inputs
    python -m examples.train_depth_image data/lct_release --input lct --pool 2 --mask --epochs 20 --save lct_net.pt
    python benchmarks/real_low_light.py FOLDER --network lct_net.pt  # ... run it on the LCT release's captures

Reads the ``train`` and ``val`` splits with ``NLOSDataset(..., layout="network")`` (envelope and counts as
(1, T, H, W), ``wall_depth`` as (1, H, W)) into memory. Training inputs are fresh SPAD counts every step, drawn in
the batch from the stored envelope with :class:`datagen.SPADNoise` (the split's detector); validation reads the
stored (frozen) counts. Input log(1 + counts), standardised.

Network (``--arch cnn``, :class:`DepthNet`, ≈ 24 k parameters): the same temporal encoder at every scan point
((k, 1, 1) 3-D convolutions over time), then 2-D convolutions over the scan grid to one depth per pixel; ≈ 1 s of
CPU per epoch of 200 samples of 16 × 16 × 256 on 2 threads. ``--arch unet`` (:class:`DepthUNet`, ≈ 0.3 M
parameters, always with the mask head) puts a two-level U-Net over the scan grid after the same temporal encoder,
its input also each column's maximum: its field of view spans a 32 × 32 grid, where DepthNet's three 3 × 3 layers
see 7 × 7 points. ``--augment`` turns each training batch by one of the 8 symmetries of the square (a confocal scan
of a turned or mirrored scene is the scan turned or mirrored the same way, its labels too).

Network-resolution scans (``configs/datasets/wall128.yaml``, ``confocal64.yaml``): ``--pool K`` sums the scan over
K × K blocks of scan points on loading (a 128 × 128 × 512 scan is 32 MiB; its full-resolution forward pass and
SPAD draw cost ≈ 1 s per sample on this CPU), the network runs on the (H/K, W/K) grid and its depth image is
upsampled bilinearly to the label's (H, W) grid, where the loss and ``datagen score`` compare it. The fresh counts
of the pooled scan are drawn by a SPADNoise whose DCR and ambient rate are K² the split's (the summed background):
exact for the Poisson detector (a sum of independent Poisson counts), for the pile-up detector exact only at low
flux (these scans detect ≪ 1 photon per cycle and bin); the validation input is the stored counts, summed.
Results on small builds of both configs: docs/datasets.md ("Network resolution").

Loss: mean squared depth error over the pixels where the label sees the hidden object (``wall_depth > 0``), the
pixels ``datagen score`` scores. The trivial baseline is the training set's mean depth over those pixels, everywhere.

The LCT input (``--input lct``, for ``configs/datasets/lct_release.yaml``; docs/training.md): each sample's stored
counts reconstructed by LCT as ``datagen reconstruct`` does (256 depth bins of 4.8 mm, on the scan grid, pooled by
``--pool``), divided by its maximum; the network's depth output is a correction to the depth of each column's
strongest voxel. On the raw counts the mask head does not learn where a cut-out is (the hidden light of one scan
point comes from the whole object: a 3 × 3 neighbourhood of 16 × 16 pooled points does not see the shape); on the
LCT volume each column holds its own point's object. The mask loss weighs the object pixels by the training set's
background-to-object ratio and adds a soft Dice term (:func:`mask_loss`); the probability threshold is the one of
best validation IoU (:data:`MASK_THRESHOLDS`), kept in the saved record. The mask learnt is the label's outline,
with ``--mask-label lct`` what the LCT of the noise-free scan finds near the object (:func:`lct_seen`), the kind of
mask benchmarks/real_low_light.py's reference is (docs/real.md weighs them), or with ``counts`` what the LCT of the
sample's own stored counts finds, made as that reference is made from a capture. A saved network also records the
data it was trained on (the card's ``config_sha256``, its split counts and the code that built it), the code that
trained it and the command (:func:`describe`); ``examples/weights/lct_release_net.pt`` is one, a DepthUNet on the
unpooled LCT volume with two mask heads (``--input lct --pool 1 --arch unet --augment --pos-weight 1 --epochs 20
--mask-label lct --outline-head --depth-over mask --seed 8``) trained on the first 2000 + 100 samples of
``configs/datasets/lct_release.yaml``: docs/training.md.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

import datagen
from datagen.dataset.score import score_predictions
from examples.depth_nets import (  # noqa: F401  (re-exported: the names this module's users import)
    ARCHS, BASE_BINS, LCT_BINS, DepthNet, DepthUNet, describe, dihedral, lct_input, load_model, moved_mean, pool_scan,
    predict_depth, save_model, temporal_encoder, upsample_nearest)


def scan_pitch(params) -> float:
    """Grid pitch (m) of a confocal sample's scan: its laser grid's side over its points (cell centres); ``params``
    the sample's parameters, as a dict or as the JSON text the store holds (str, or a 0-d array of it)."""
    params = params if isinstance(params, dict) else json.loads(str(np.asarray(params).item()))
    grid = params["room"]["sensor"]["scan"]["laser_grid"]
    return float(grid["size"][0]) / int(grid["points"][0])


def load_split(path, split: str, pool: int = 1, lct: bool = False,
               mask_label: str = "outline", workers: int = 0,
               base_bins: int = LCT_BINS) -> dict[str, torch.Tensor]:
    """{"envelope", "counts": (N, 1, T, H/pool, W/pool) float32 (summed over pool × pool scan points), "depth":
    (N, H, W) float32 m (the label's grid)} of one split, in memory; with ``lct`` instead of the envelope and counts
    "lct": (N, 1, LCT_BINS, H/pool, W/pool) float16 the LCT volume of each sample's stored counts and "strongest":
    (N, H/pool, W/pool) the depth m of its strongest voxels (:func:`lct_input`, in ``base_bins`` bins); with
    ``mask_label`` "lct" or "counts" also "seen": (N, H, W) bool, what the LCT of the sample's noise-free envelope or
    of its stored counts finds (:func:`lct_seen`). ``workers`` > 0 prepares the samples in that many processes (a
    torch DataLoader's workers; the LCTs run on one core each), 0 in this one; the result is the same."""
    if mask_label not in MASK_LABELS:
        raise ValueError(f"mask_label must be one of {', '.join(MASK_LABELS)}, got {mask_label!r}")
    fields = ("counts", "wall_depth") + (("params",) if lct or mask_label != "outline" else ()) + \
        (("envelope",) if not lct or mask_label == "lct" else ())          # params: the pitch; envelope: lct_seen
    ds = datagen.NLOSDataset(path, split=split, fields=fields, layout="network", counts_dtype=torch.float32)
    if len(ds) == 0:
        raise ValueError(f"{path}: split {split!r} holds no samples")
    prepared = _Prepared(ds, float(ds.card["time_edges"]["bin_width"]), pool, lct, mask_label, base_bins)
    # Each output is one block per split, allocated at the first sample: rows kept one by one between the LCT's
    # freed buffers fragmented the heap (with 2 threads, 17 MB of memory per sample for 2 MiB kept).
    for i, row in enumerate(torch.utils.data.DataLoader(prepared, batch_size=None, num_workers=workers)):
        if i == 0:
            blocks = {key: torch.empty((len(ds),) + tuple(v.shape), dtype=v.dtype) for key, v in row.items()}
        for key, value in row.items():
            blocks[key][i] = value
    return blocks


class _Prepared(torch.utils.data.Dataset):
    """One split's samples as :func:`load_split` keeps them: the i-th item the dict of its rows for sample i."""

    def __init__(self, ds, bin_width: float, pool: int, lct: bool, mask_label: str, base_bins: int):
        self.ds, self.bin_width, self.pool, self.lct, self.mask_label = ds, bin_width, pool, lct, mask_label
        self.base_bins = base_bins

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        item, row = self.ds[i], {}
        pitch = scan_pitch(item["params"]) if "params" in item else None
        if self.lct:
            volume, row["strongest"] = lct_input(np.moveaxis(item["counts"][0].numpy(), 0, -1), self.bin_width,
                                                 pitch, self.pool, self.base_bins)
            row["lct"] = volume.half()                                # float16: 2 MiB per 64 × 64 sample
        else:
            row["envelope"], row["counts"] = (pool_scan(item[k], self.pool) for k in ("envelope", "counts"))
        row["depth"] = item["wall_depth"][0]
        if self.mask_label != "outline":
            scan = item["envelope" if self.mask_label == "lct" else "counts"][0].numpy()
            row["seen"] = lct_seen(scan, self.bin_width, pitch, row["depth"], measured=self.mask_label == "counts")
        return row


MASK_LABELS = ("outline", "lct", "counts")
"""What the mask head learns (``--mask-label``): "outline", the label's own mask (``wall_depth > 0``: the cut-out's
exact outline on the scan grid); "lct", what a long exposure's LCT finds near the object (:func:`lct_seen` of the
noise-free envelope), the kind of mask the real-capture evaluation's reference is (benchmarks/real_low_light.py: the
full-exposure LCT's found points); "counts", what the LCT of the sample's own stored counts finds near the object,
made as that reference is made from a measured capture (:func:`lct_seen` with ``measured``: the noise and the floor
of the sample's full exposure in it, the floor subtracted)."""


def lct_seen(scan: np.ndarray, bin_width: float, pitch, depth: torch.Tensor, measured: bool = False) -> torch.Tensor:
    """(H, W) bool: where the LCT of a scan (T, H, W) finds something, kept within LCT's resolution of the object. The
    scan is a noise-free ``envelope``, reconstructed as ``datagen reconstruct --background none`` runs it
    (:func:`datagen.analysis.reconstruct.confocal_volume`; in LCT_BINS bins, as the input); or with ``measured`` a
    capture's counts (noise and floor), reconstructed as the real-capture evaluation's reference is (each point's
    floor subtracted, up to :data:`~datagen.analysis.reconstruct.MAX_BINS` bins). Found: the front view at 0.25 of
    the way from its pedestal to its maximum (:func:`datagen.analysis.reconstruct.depth_map` as shipped, the rule of
    the evaluation's reference); kept within LCT's resolution of the label's outline (``depth`` (H, W) m, 0 where
    the object is not seen) dilated by Δx = c·γ·√(w² + z²) / (2w) (O'Toole, Lindell & Wetzstein 2018, the confocal
    set-up's lateral resolution; γ = :data:`RESOLUTION_FWHM`, w the scan's half-width, z the outline's median
    depth). Nothing where the outline is empty."""
    from scipy.ndimage import distance_transform_edt

    from datagen.analysis.reconstruct import confocal_volume, depth_map
    from datagen.units import SPEED_OF_LIGHT

    outline = np.asarray(depth) > 0
    if not outline.any():
        return torch.zeros(outline.shape, dtype=torch.bool)
    volume, depths, _ = confocal_volume(np.moveaxis(np.asarray(scan, np.float64), 0, -1), bin_width, pitch, "lct",
                                        **({} if measured else {"max_bins": LCT_BINS, "background": None}))
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    half = 0.25 * (pitch_y * outline.shape[0] + pitch_x * outline.shape[1])
    z = float(np.median(np.asarray(depth)[outline]))
    reach = SPEED_OF_LIGHT * RESOLUTION_FWHM * np.hypot(half, z) / (2 * half)
    near = distance_transform_edt(~outline, sampling=(pitch_y, pitch_x)) <= reach
    # the rule of the real-capture evaluation's reference: 0.25 of the way from the front view's pedestal to its maximum
    return torch.as_tensor(np.isfinite(depth_map(volume, depths)[0]) & near)


OUTLINE_HEADS = ("mean", "auxiliary")
"""What a second mask head learning the outline (``--outline-head``) does to the mask: "mean", the mean of the two
heads' probabilities, each moved so that its threshold sits at 0.5, reaches 0.5; "auxiliary", the first head alone
(the outline head only shapes the training through its loss)."""

DEPTH_OVER = ("outline", "mask")
"""Where the depth head learns (``--depth-over``): "outline", the label's own mask; "mask", the label's outline and
the mask the mask head learns (:data:`MASK_LABELS`), the points past the outline given the depth of the outline's
nearest point (:func:`extend_depth`): with ``--mask-label lct`` the mask reaches past the outline by LCT's blur, and a
depth read where the mask is found is then a learnt one."""


def extend_depth(depth: torch.Tensor, over: torch.Tensor) -> torch.Tensor:
    """(N, H, W) float32 m: ``depth`` (N, H, W) m, 0 where the object is not seen, with each point of ``over``
    (N, H, W) bool outside the object given the depth of the object's nearest point (Euclidean, on the scan grid);
    0 elsewhere, and a sample without object stays 0."""
    from scipy.ndimage import distance_transform_edt

    out = torch.zeros_like(depth)
    for i, (d, o) in enumerate(zip(depth.numpy(), over.numpy())):
        seen = d > 0
        if not seen.any():
            continue
        near = distance_transform_edt(~seen, return_distances=False, return_indices=True)
        out[i] = torch.as_tensor(np.where(seen | o, d[near[0], near[1]], 0).astype(np.float32))
    return out


RESOLUTION_FWHM = 60e-12
"""s: the temporal resolution γ of :func:`lct_seen`'s resolution bound, the LCT release's system FWHM (its paper)."""


def draw_counts(noise: datagen.SPADNoise, envelope: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Fresh counts (B, 1, T, H, W) of envelopes in the network layout (SPADNoise wants time last)."""
    return noise(envelope.permute(0, 1, 3, 4, 2), gen).permute(0, 1, 4, 2, 3)


def mask_loss(logit: torch.Tensor, seen: torch.Tensor, pos_weight: float) -> torch.Tensor:
    """Binary cross-entropy of the mask logit (B, H, W) against ``seen`` (B, H, W) bool, its object pixels weighted
    ``pos_weight`` (by default the training set's background-to-object ratio: the objects cover 16 % of the
    lct_release scans; ``--pos-weight``),
    plus the soft Dice loss per sample, 1 − (2 Σ p·y + 1) / (Σ p + Σ y + 1), averaged over the batch."""
    y = seen.float()
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logit, y, pos_weight=torch.tensor(pos_weight))
    p = torch.sigmoid(logit)
    dice = 1 - (2 * (p * y).sum((1, 2)) + 1) / (p.sum((1, 2)) + y.sum((1, 2)) + 1)
    return bce + dice.mean()


def mask_iou(prob: torch.Tensor, seen: torch.Tensor, threshold: float) -> float:
    """Mean over the samples with object pixels of the IoU of ``prob`` (N, H, W) ≥ threshold with ``seen``."""
    hit = prob >= threshold
    keep = seen.flatten(1).any(1)
    inter, union = (hit & seen).flatten(1).sum(1), (hit | seen).flatten(1).sum(1)
    return float((inter[keep] / union[keep]).mean()) if keep.any() else float("nan")


MASK_THRESHOLDS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
"""Mask-probability thresholds tried on the validation split; the one of best mean IoU goes to the record."""


def best_threshold(logit: torch.Tensor, seen: torch.Tensor) -> tuple[float, float]:
    """(mean IoU, threshold): the one of :data:`MASK_THRESHOLDS` at which sigmoid(``logit``) (N, H, W) ≥ threshold
    has the best :func:`mask_iou` with ``seen`` (N, H, W) bool."""
    prob = torch.sigmoid(logit)
    return max((mask_iou(prob, seen, t), t) for t in MASK_THRESHOLDS)


def git_version(path: Path) -> str:
    """``git:`` + ``git describe --always --dirty`` of the checkout holding ``path``, or "unknown"."""
    import subprocess
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=path, capture_output=True, text=True,
                             timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"git:{out.stdout.strip()}" if out.returncode == 0 and out.stdout.strip() else "unknown"


def train(path, epochs: int = 40, batch: int = 16, seed: int = 0, lr: float = 3e-3, train_split: str = "train",
          val_split: str = "val", pool: int = 1, log=print, save: str | Path | None = None,
          stored: bool = False, mask: bool = False, lct: bool = False, command: str = "", arch: str = "cnn",
          augment: bool = False, pos_weight: float | None = None,
          mask_label: str = "outline", depth_over: str = "outline", workers: int = 0,
          outline_head: str | None = None, base_bins: int = LCT_BINS) -> dict[str, np.ndarray]:
    """Train on ``train_split``, predict ``val_split``, the scans summed over ``pool`` × ``pool`` scan points (module
    doc); with ``save`` the trained network goes to that file (:func:`save_model`, with the card's
    ``config_sha256``, split counts and code version, this checkout's code version and ``command``); with ``stored``
    the training inputs are the stored counts (each sample's own drawn detector: exposure, gain and background maps,
    IRF; one noise draw per sample) instead of fresh counts from the split's detector; with ``lct`` the input is the
    LCT volume of the stored counts (:func:`lct_input`; implies ``stored``); with ``mask`` the network also learns
    where the object is seen (a second output, :func:`mask_loss` against ``wall_depth > 0`` over every pixel, added
    to the depth loss, its object pixels weighted ``pos_weight``, by default the background-to-object ratio; its
    threshold the one of :data:`MASK_THRESHOLDS` of best validation IoU; with ``mask_label`` "lct" the mask learnt
    and validated is what a long exposure's LCT finds instead, :data:`MASK_LABELS`); the depth is learnt over
    the label's own mask, or with ``depth_over`` "mask" over it and the mask the mask head learns
    (:data:`DEPTH_OVER`; validated over the label's own mask either way); with ``outline_head`` (``--arch unet``, a
    ``mask_label`` other than "outline") a second mask head learns the label's outline beside it, its own threshold
    chosen the same way: with "mean" the network sees the object where the mean of the two heads' probabilities,
    each moved so that its threshold sits at 0.5, reaches 0.5, with "auxiliary" where the first head alone sees it
    (the outline head only a loss) (:func:`predict_depth` reads the heads ``mask_thresholds`` in the record lists;
    :data:`OUTLINE_HEADS`); with ``lct`` the depth learnt is the label less the strongest voxel's depth in the LCT
    volume of ``base_bins`` bins (:data:`BASE_BINS`; the record keeps it for :func:`predict_depth`);
    ``arch`` names the network (:data:`ARCHS`);
    with ``augment`` each batch is turned by a random symmetry of the square (:func:`dihedral`); ``workers`` the
    processes that prepare the samples (:func:`load_split`). Returns {"depth":
    (N, H, W) float32 m on the label's grid, "index": (N,), "trivial": (N, H, W) the training mean depth over the
    object pixels, "iou": the validation mask IoU (NaN without ``mask``)}."""
    if depth_over not in DEPTH_OVER:
        raise ValueError(f"depth_over must be one of {', '.join(DEPTH_OVER)}, got {depth_over!r}")
    if outline_head not in (None,) + OUTLINE_HEADS:
        raise ValueError(f"outline_head must be one of {', '.join(OUTLINE_HEADS)}, got {outline_head!r}")
    if base_bins != LCT_BINS and not lct:
        raise ValueError(f"--base-bins {base_bins} is the base of a network on the LCT volume: it needs --input lct")
    if outline_head and (arch != "unet" or mask_label == "outline"):
        raise ValueError(f"an outline head needs --arch unet and a mask label other than outline, got --arch {arch} "
                         f"--mask-label {mask_label}")
    torch.manual_seed(seed)
    t0 = time.perf_counter()
    version = git_version(Path(__file__).resolve().parent)          # of the code as it is loaded, at the start
    tr, va = (load_split(path, s, pool, lct, mask_label, workers, base_bins) for s in (train_split, val_split))
    ds = datagen.NLOSDataset(path, split=train_split, fields=("counts",))
    det = ds.detector_config()
    noise = ds.spad_noise() if pool == 1 else ds.spad_noise(dcr=det.dcr * pool ** 2,        # summed background
                                                            ambient_rate=det.ambient_rate * pool ** 2)
    size = tuple(tr["depth"].shape[1:])
    key = "lct" if lct else "counts"
    if log:
        log(f"  loaded {len(tr['depth'])} + {len(va['depth'])} samples, input {tuple(tr[key].shape[1:])}, "
            f"labels {size} ({time.perf_counter() - t0:.0f} s)")
    gen = torch.Generator().manual_seed(seed)
    seen_tr = tr.get("seen", tr["depth"] > 0)                   # what the mask head learns
    learnt = extend_depth(tr["depth"], seen_tr) if depth_over == "mask" else tr["depth"]
    mask_tr = learnt > 0                                        # where the depth is learnt
    for split in (tr, va):            # the depth learnt: the label less the LCT's strongest voxel (0 on counts)
        split["base"] = upsample_nearest(split["strongest"], size) if lct else torch.zeros_like(split["depth"])
    target = learnt - tr["base"]
    d_mean, d_std = target[mask_tr].mean(), target[mask_tr].std()
    if pos_weight is None:
        pos_weight = float((~seen_tr).sum() / seen_tr.sum().clamp(min=1))
    if lct:
        inputs = lambda rows: tr["lct"][rows].float()                           # noqa: E731
    elif stored:
        inputs = lambda rows: torch.log1p(tr["counts"][rows])                   # noqa: E731
    else:
        inputs = lambda rows: torch.log1p(draw_counts(noise, tr["envelope"][rows], gen))   # noqa: E731
    with torch.no_grad():
        x = inputs(torch.arange(min(64, len(tr["depth"]))))
        x_mean, x_std = x.mean(), x.std() + 1e-6
    net = ARCHS[arch](tr[key].shape[2], mask=mask, **({"heads": 2} if outline_head else {}))
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    n = len(tr["depth"])
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * -(-n // batch))
    for epoch in range(epochs):
        net.train()
        order = torch.randperm(n, generator=gen)
        for start in range(0, n, batch):
            rows = order[start:start + batch]
            x, obj, seen, want, outline = ((inputs(rows) - x_mean) / x_std, mask_tr[rows], seen_tr[rows],
                                           (target[rows] - d_mean) / d_std, tr["depth"][rows] > 0)
            if augment:
                x, obj, seen, want, outline = dihedral((x, obj, seen, want, outline),
                                                       int(torch.randint(8, (), generator=gen)))
            out = net(x, size)
            depth, logit = net.heads(out)
            err = depth - want
            loss = (err[obj] ** 2).mean() if obj.any() else (err * 0).sum()
            if logit is not None:
                loss = loss + mask_loss(logit, seen, pos_weight)
            if outline_head:
                loss = loss + mask_loss(net.logits(out)[:, 1], outline, pos_weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        if log and (epoch + 1) % max(1, epochs // 5) == 0:
            log(f"  epoch {epoch + 1}/{epochs}: train loss {loss.item():.3f} ({time.perf_counter() - t0:.0f} s)")
    net.eval()
    with torch.no_grad():
        x = ((va["lct"].float() if lct else torch.log1p(va["counts"])) - x_mean) / x_std
        out = torch.cat([net(x[s:s + 64], size) for s in range(0, len(x), 64)])
        (depth, logit), logits = net.heads(out), net.logits(out)
        depth = va["base"] + depth * d_std + d_mean
    obj_va = va["depth"] > 0
    seen_va = va.get("seen", obj_va)
    threshold, iou, heads, val_heads = 0.5, float("nan"), {}, {}
    if logit is not None:
        iou, threshold = best_threshold(logit, seen_va)
        if log:
            log(f"  validation mask IoU {iou:.3f} at probability ≥ {threshold}")
    if outline_head:                       # the outline head's threshold; the two heads' mean, as predict_depth
        outline_iou, outline_threshold = best_threshold(logits[:, 1], obj_va)
        both = moved_mean(logits, [threshold, outline_threshold])
        heads = {"mask_thresholds": [threshold, outline_threshold][:2 if outline_head == "mean" else 1],
                 "outline_head": outline_head, "outline_threshold": outline_threshold}
        val_heads = {"outline_iou": outline_iou, "both_iou": mask_iou(both, seen_va, 0.5),
                     "both_outline_iou": mask_iou(both, obj_va, 0.5)}
        if log:
            log(f"  validation outline IoU {outline_iou:.3f} at probability ≥ {outline_threshold}; the two heads "
                f"averaged: IoU {val_heads['both_iou']:.3f} against the mask label, "
                f"{val_heads['both_outline_iou']:.3f} against the outline")
    if save is not None:
        card = ds.card
        err = (depth - va["depth"]).abs()
        mae = float(np.mean([float(e[m].mean()) for e, m in zip(err, obj_va) if m.any()]))
        save_model(save, net, pool, (float(x_mean), float(x_std)), (float(d_mean), float(d_std)), path,
                   input="lct" if lct else "counts", mask_threshold=threshold,
                   config_sha256=card["config_sha256"], config_name=card["name"],
                   splits={s: int(card["splits"][s]["count"]) for s in (train_split, val_split)},
                   dataset_code_version=card.get("code_version", "unknown"),
                   code_version=version, command=command, mask_label=mask_label, depth_over=depth_over,
                   train_seconds=round(time.perf_counter() - t0, 1), **heads,
                   **({"base_bins": base_bins} if base_bins != LCT_BINS else {}),
                   val={"depth_mae_m": mae, "mask_iou": iou, **val_heads})
    n_va = len(va["depth"])
    return {"depth": depth.numpy().astype(np.float32), "index": np.arange(n_va),
            "trivial": np.full(tuple(va["depth"].shape), float(tr["depth"][tr["depth"] > 0].mean()), dtype=np.float32),
            "iou": iou}


def main(argv=None):
    parser = argparse.ArgumentParser(description="depth-image CNN baseline on a confocal wall scan dataset")
    parser.add_argument("data")
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2,
                        help="torch CPU threads, and the processes that prepare the samples")
    parser.add_argument("--train", default="train")
    parser.add_argument("--val", default="val")
    parser.add_argument("--pool", type=int, default=1, help="sum the scan over POOL × POOL scan points (module doc)")
    parser.add_argument("--out", default=None, help="predictions .npz (default: DATA_net_<val>.npz); the "
                                                    "trivial baseline goes to the same name with _trivial")
    parser.add_argument("--save", default=None, help="write the trained network to this file (.pt)")
    parser.add_argument("--mask", action="store_true", help="also learn where the object is seen (a mask head)")
    parser.add_argument("--stored-counts", action="store_true",
                        help="train on the stored counts (each sample's drawn detector) instead of fresh noise")
    parser.add_argument("--arch", choices=sorted(ARCHS), default="cnn",
                        help="the network: DepthNet (cnn) or DepthUNet (unet, always with a mask head)")
    parser.add_argument("--augment", action="store_true",
                        help="turn and mirror each training batch by a random symmetry of the square")
    parser.add_argument("--pos-weight", type=float, default=None,
                        help="the mask loss's weight of object pixels (default: the background-to-object ratio)")
    parser.add_argument("--mask-label", choices=MASK_LABELS, default="outline",
                        help="what the mask head learns: the label's outline, what the LCT of the noise-free scan "
                             "finds (lct), or of the sample's stored counts, as a capture's reference (counts)")
    parser.add_argument("--outline-head", nargs="?", const="mean", choices=OUTLINE_HEADS, default=None,
                        help="a second mask head learning the label's outline beside --mask-label's; the mask is "
                             "where the mean of the two heads' probabilities, each moved to its threshold, reaches "
                             "0.5 (mean, the default) or the first head's (auxiliary: the outline head only a loss)")
    parser.add_argument("--depth-over", choices=DEPTH_OVER, default="outline",
                        help="where the depth is learnt: the label's outline, or also the mask the mask head learns")
    parser.add_argument("--input", choices=["counts", "lct"], default="counts",
                        help="the network's input: the counts' log, or the LCT volume of the stored counts")
    parser.add_argument("--base-bins", type=int, choices=BASE_BINS, default=LCT_BINS,
                        help="with --input lct, the depth bins of the LCT volume whose strongest voxel the depth "
                             "corrects: the input's own 256 (4.8 mm) or 512 (16 ps, 2.4 mm)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    from datagen.errors import DatasetError

    try:
        pred = train(args.data, args.epochs, args.batch, args.seed, train_split=args.train, val_split=args.val,
                     pool=args.pool, save=args.save, stored=args.stored_counts,
                     mask=args.mask or args.arch == "unet", lct=args.input == "lct", arch=args.arch,
                     augment=args.augment, pos_weight=args.pos_weight, mask_label=args.mask_label,
                     depth_over=args.depth_over, workers=args.threads, outline_head=args.outline_head,
                     base_bins=args.base_bins,
                     command="python -m examples.train_depth_image " + " ".join(sys.argv[1:] if argv is None
                                                                                else argv))
    except (ValueError, DatasetError, FileNotFoundError) as exc:   # a data path, split or option that does not fit
        raise SystemExit(f"train_depth_image: {exc}") from None
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
