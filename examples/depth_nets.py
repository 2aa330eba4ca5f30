"""The depth networks of ``examples/train_depth_image.py`` and what runs them: their inputs (the scan's counts, or its
LCT volume: :func:`lct_input`), the architectures (:class:`DepthNet`, :class:`DepthUNet`), the saved file
(:func:`save_model`, :func:`load_model`, :func:`describe`) and the forward pass on one scan (:func:`predict_depth`),
which ``benchmarks/real_low_light.py`` runs on the LCT release's captures. Training, labels and the command line stay
in ``examples/train_depth_image.py``, which re-exports these names (docs/training.md)."""
from __future__ import annotations

import numpy as np
import torch


def pool_scan(scan: torch.Tensor, pool: int) -> torch.Tensor:
    """(1, T, H, W) → (1, T, H/pool, W/pool): sums over pool × pool blocks of scan points (counts stay counts)."""
    if pool == 1:
        return scan
    _, t, h, w = scan.shape
    if h % pool or w % pool:
        raise ValueError(f"--pool {pool} does not divide the {h} × {w} scan")
    return scan.reshape(1, t, h // pool, pool, w // pool, pool).sum((3, 5))


LCT_BINS = 256
"""Depth bins of the LCT input (``--input lct``): the dataset's 512 bins of 16 ps summed pairwise, 4.8 mm each."""

BASE_BINS = (LCT_BINS, 512)
"""Depth bins of the LCT volume whose strongest voxel the network's depth corrects (``--base-bins``,
:func:`lct_input`): the input's own, or 512 (16 ps, 2.4 mm)."""


def lct_input(counts: np.ndarray, bin_width: float, pitch: float | tuple[float, float],
              pool: int, base_bins: int = LCT_BINS) -> tuple[torch.Tensor, torch.Tensor]:
    """((1, LCT_BINS, H/pool, W/pool) float32 in [0, 1], (H/pool, W/pool) float32 m): the LCT volume of one scan of
    counts (H, W, T) (bin width s, grid pitch m, as :func:`datagen.analysis.reconstruct.confocal_volume` takes them),
    reconstructed from the counts summed over pool × pool scan points (the pitch times pool) and LCT_BINS bins, as
    ``datagen reconstruct --background none`` runs it (the direct light trimmed, t² falloff, snr 0.8; the floor
    kept, as the shipped weights were trained), depth on the first axis, divided
    by its maximum; and the depth of each column's strongest voxel (the network's depth is a correction to it) in
    that volume (``base_bins`` LCT_BINS), or with ``base_bins`` 512 (:data:`BASE_BINS`) in the LCT volume of the
    same counts in up to that many bins (16 ps, 2.4 mm voxels, ``datagen reconstruct``'s default; the input's
    4.8 mm voxels put the release's 40 cm charts' base 1.2–3.6 mm deeper than LCT at 16 ps reads them, docs/real.md).

    Raises:
        ValueError: ``base_bins`` not in :data:`BASE_BINS`."""
    from datagen.analysis.reconstruct import confocal_volume

    if base_bins not in BASE_BINS:
        raise ValueError(f"base_bins must be one of {', '.join(map(str, BASE_BINS))}, got {base_bins}")
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    scan = pool_scan(torch.as_tensor(np.moveaxis(np.asarray(counts, np.float32), -1, 0))[None], pool)[0]
    data, grid = np.moveaxis(scan.double().numpy(), 0, -1), (pitch_y * pool, pitch_x * pool)

    def lct(bins: int) -> tuple[np.ndarray, np.ndarray]:
        volume, depths, _ = confocal_volume(data, bin_width, grid, "lct", max_bins=bins, background=None)
        return volume[..., :bins], depths[:bins]

    volume, depths = lct(LCT_BINS)
    top = volume.max()
    base, base_depths = (volume, depths) if base_bins == LCT_BINS else lct(base_bins)
    strongest = base_depths[np.argmax(base, axis=-1)].astype(np.float32)
    volume = np.moveaxis(volume / top if top > 0 else volume, -1, 0)[None].astype(np.float32)
    return torch.as_tensor(volume), torch.as_tensor(strongest)


def upsample_nearest(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(B, h, w) → (B, *size), each pixel the value of the input pixel it falls in (an integer factor: repeats)."""
    return torch.nn.functional.interpolate(image[:, None], size=tuple(size), mode="nearest")[:, 0]



def temporal_encoder() -> torch.nn.Sequential:
    """(B, 1, T, h, w) → (B, 16, T/32, h, w): (k, 1, 1) 3-D convolutions over each scan point's transient (8-bin
    patches, then two stride-2 layers), the same at every point."""
    relu = torch.nn.ReLU
    return torch.nn.Sequential(
        torch.nn.Conv3d(1, 16, (8, 1, 1), stride=(8, 1, 1)), relu(),
        torch.nn.Conv3d(16, 16, (3, 1, 1), stride=(2, 1, 1), padding=(1, 0, 0)), relu(),
        torch.nn.Conv3d(16, 16, (3, 1, 1), stride=(2, 1, 1), padding=(1, 0, 0)), relu())


class DepthNet(torch.nn.Module):
    """(B, 1, T, H, W) standardised scan → (B, H, W) standardised depth (module doc). ≈ 24 k parameters at 256
    bins: (k, 1, 1) 3-D convolutions encode each scan point's transient (8-bin patches, then two stride-2
    layers), a 1 × 1 convolution maps its T/32 × 16 features to 32, three 2-D convolutions mix neighbours."""

    def __init__(self, bins: int, features: int = 32, mask: bool = False):
        super().__init__()
        self.mask, self.mask_heads = mask, int(mask)
        if bins % 32:
            raise ValueError(f"DepthNet: the scan needs a multiple of 32 time bins, got {bins}")
        self.bins = bins
        relu = torch.nn.ReLU
        self.temporal = temporal_encoder()
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

    def logits(self, out: torch.Tensor) -> torch.Tensor | None:
        """(B, mask_heads, h, w): the logits of every mask head of a forward output, or None without a mask head."""
        return out[:, 1:] if self.mask else None


class DepthUNet(torch.nn.Module):
    """(B, 1, T, H, W) standardised LCT volume → (B, 1 + heads, H, W): DepthNet's temporal encoder at every scan
    point, then a small U-Net over the scan grid (two 2 × 2 max-pool levels, bilinear up-sampling with skip
    connections), whose field of view spans the whole 32 × 32 grid of a pooled scan; its input also holds each
    column's maximum (the front view). ≈ 0.3 M parameters at 256 bins. ``--arch unet`` (module doc); always with a
    mask head (``mask`` is taken, as :class:`DepthNet` takes it, and ignored); ``heads`` mask heads (a second one:
    ``--outline-head``, the label's outline beside another mask label)."""

    def __init__(self, bins: int, features: int = 32, mask: bool = True, heads: int = 1):
        super().__init__()
        if bins % 32:
            raise ValueError(f"DepthUNet: the scan needs a multiple of 32 time bins, got {bins}")
        if heads < 1:
            raise ValueError(f"DepthUNet: at least one mask head, got {heads}")
        self.bins, self.mask, self.mask_heads = bins, True, heads
        relu, f = torch.nn.ReLU, features

        def block(c_in: int, c_out: int) -> torch.nn.Sequential:
            return torch.nn.Sequential(torch.nn.Conv2d(c_in, c_out, 3, padding=1), relu(),
                                       torch.nn.Conv2d(c_out, c_out, 3, padding=1), relu())

        self.temporal = temporal_encoder()
        self.stem = torch.nn.Sequential(torch.nn.Conv2d(16 * (bins // 32) + 1, f, 1), relu(), block(f, f))
        self.down1, self.down2 = block(f, 2 * f), block(2 * f, 2 * f)
        self.up1, self.up2 = block(4 * f, 2 * f), block(3 * f, f)
        self.out = torch.nn.Conv2d(f, 1 + heads, 1)

    def forward(self, x: torch.Tensor, size: tuple[int, int] | None = None) -> torch.Tensor:
        """(B, 1, T, h, w) → (B, 1 + heads, h, w), or (B, 1 + heads, *size) upsampled bilinearly: the standardised
        depth and each mask head's logit (a grid whose sides are not multiples of 4 is padded by replication to
        them, and cut back)."""
        b, _, _, h, w = x.shape
        pool, up = torch.nn.functional.max_pool2d, torch.nn.functional.interpolate
        s = self.stem(torch.cat([self.temporal(x).reshape(b, -1, h, w), x.amax(2)], 1))
        s = torch.nn.functional.pad(s, (0, -w % 4, 0, -h % 4), mode="replicate")
        d1 = self.down1(pool(s, 2))
        d2 = self.down2(pool(d1, 2))
        u1 = self.up1(torch.cat([up(d2, size=d1.shape[-2:], mode="bilinear", align_corners=False), d1], 1))
        out = self.out(self.up2(torch.cat([up(u1, size=s.shape[-2:], mode="bilinear", align_corners=False), s], 1)))
        out = out[..., :h, :w]
        if size is not None and tuple(size) != (h, w):
            out = up(out, size=tuple(size), mode="bilinear", align_corners=False)
        return out

    heads, logits = DepthNet.heads, DepthNet.logits


ARCHS = {"cnn": DepthNet, "unet": DepthUNet}
"""The networks ``--arch`` names."""


def dihedral(arrays, k: int):
    """The arrays (..., h, w) of a batch, each turned by the k-th (0–7) symmetry of the square: k % 4 quarter turns,
    then transposed when k ≥ 4 (a confocal scan of a mirrored or turned scene is the scan mirrored or turned)."""
    out = [torch.rot90(a, k % 4, (-2, -1)) for a in arrays]
    return [a.transpose(-2, -1) for a in out] if k >= 4 else out


def save_model(path, net: DepthNet, pool: int, x_norm: tuple[float, float], d_norm: tuple[float, float],
               data, **provenance) -> None:
    """Write the trained network, what its input needs (bins, pool, the input's standardisation) and its depth
    scale to ``path`` (torch.save of a dict; :func:`load_model` reads it), with the data set it was trained on and
    ``provenance`` (str, float, int or lists or dicts of them: :func:`train` writes ``input``, ``mask_threshold``,
    ``mask_thresholds`` (with two mask heads: each head's), ``config_sha256``, ``splits``, ``dataset_code_version``,
    ``code_version``, ``command``, ``mask_label``, ``depth_over``, ``train_seconds``, ``val``)."""
    arch = next(name for name, cls in ARCHS.items() if type(net) is cls)
    torch.save({"state": net.state_dict(), "arch": arch, "bins": net.bins, "mask": net.mask, "pool": pool,
                **({"mask_heads": net.mask_heads} if net.mask_heads > 1 else {}),
                "x_norm": x_norm, "d_norm": d_norm, "data": str(data), **provenance}, path)


def load_model(path) -> tuple[DepthNet, dict]:
    """(network in eval mode, its record) of a :func:`save_model` file; :func:`describe` says what the record holds
    of its training."""
    record = torch.load(path, map_location="cpu", weights_only=True)
    heads = {"heads": record["mask_heads"]} if "mask_heads" in record else {}
    net = ARCHS[record.get("arch", "cnn")](record["bins"], mask=record.get("mask", False), **heads)
    net.load_state_dict(record["state"])
    return net.eval(), record


def describe(record: dict) -> str:
    """One line: the network's input, the data set it was trained on (the card's ``config_sha256``, split counts,
    the code that built it), the code that trained it and the command."""
    splits = ", ".join(f"{k}={v}" for k, v in record.get("splits", {}).items()) or "?"
    sha = str(record.get("config_sha256", "?"))[:16]
    return (f"input {record.get('input', 'counts')}, pool {record['pool']}, {record['bins']} bins; data "
            f"{record['data']} (config_sha256 {sha}…, {splits}, built by {record.get('dataset_code_version', '?')}); "
            f"trained by {record.get('code_version', '?')}: {record.get('command', '?')}")


def predict_depth(net: DepthNet, record: dict, counts: np.ndarray, bin_width: float | None = None,
                  pitch: float | tuple[float, float] | None = None, probability: bool = False) -> tuple:
    """(H, W) float64 depth (m) of one scan of counts (H, W, T), the depth upsampled back to (H, W); and (H, W) bool
    where it sees the object (its mask head's probability ≥ ``record["mask_threshold"]``, 0.5 where the record has none;
    True everywhere for a network without a mask head), or with ``probability`` that probability (float32) moved so that
    the threshold sits at 0.5 (sigmoid(logit − logit(threshold))). A network with several mask heads
    (``record["mask_thresholds"]``, one per head read, the first heads; a head past them is not read: an auxiliary
    one) sees the object where the mean of those heads' probabilities, each so moved, reaches 0.5, and with
    ``probability`` returns that mean. A network on counts (``record["input"]`` "counts",
    the default) takes them on its time axis (``record["bins"]`` bins of its training set's width) and sums them over
    ``record["pool"]`` × ``record["pool"]`` scan points; one on the LCT volume (``"lct"``) takes them at their own bin
    width (``bin_width`` s and the grid ``pitch`` m are then required: :func:`lct_input`), which, summed pairwise to at
    most LCT_BINS bins, must come to its training set's (32 ps for ``lct_release``: the release's 2048 bins of 4 ps, the
    data set's 512 of 16 ps); that is not checked (the record does not hold it).

    Raises:
        ValueError: an LCT-input network without ``bin_width`` and ``pitch``.
    """
    (x_mean, x_std), (d_mean, d_std) = record["x_norm"], record["d_norm"]
    if record.get("input", "counts") == "lct":
        if bin_width is None or pitch is None:
            raise ValueError("predict_depth: a network on the LCT volume needs the scan's bin_width and pitch")
        x, strongest = lct_input(counts, bin_width, pitch, record["pool"], record.get("base_bins", LCT_BINS))
        x, base = x[None], upsample_nearest(strongest[None], tuple(counts.shape[:2]))[0].double().numpy()
    else:
        base = 0.0
        x = torch.as_tensor(np.moveaxis(np.asarray(counts, dtype=np.float32), -1, 0))[None]
        x = torch.log1p(pool_scan(x, record["pool"])[None])
    with torch.no_grad():
        out = net((x - x_mean) / x_std, tuple(counts.shape[:2]))
    depth, logits = net.heads(out)[0], net.logits(out)
    depth = base + (depth[0] * d_std + d_mean).double().numpy()
    if logits is None:
        return depth, np.ones(depth.shape, bool)
    thresholds = record.get("mask_thresholds", [record.get("mask_threshold", 0.5)])
    if len(thresholds) == 1 and not probability:
        return depth, torch.sigmoid(logits[0, 0]).numpy() >= thresholds[0]
    moved = moved_mean(logits[0], thresholds).numpy()
    return depth, moved if probability else moved >= 0.5


def moved_mean(logits: torch.Tensor, thresholds) -> torch.Tensor:
    """(..., h, w) float32: the mean over the first len(``thresholds``) mask heads of ``logits`` (..., K, h, w) of each
    head's probability moved so that its threshold sits at 0.5, sigmoid(logit − logit(threshold)); a point is seen
    where it reaches 0.5 (:func:`predict_depth`; ``benchmarks/real_low_light.py --network A.pt B.pt`` averages
    networks' so)."""
    moved = [torch.sigmoid(logits[..., k, :, :] - float(np.log(t / (1 - t)))) for k, t in enumerate(thresholds)]
    return torch.stack(moved).mean(0)
