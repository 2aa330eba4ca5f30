"""The baselines on the Stanford LCT release's captures at their full exposure and thinned to 1/10 and 1/100 of it:
the low-photon regime a network trained on datagen is meant for, and the figures it has to beat (docs/real.md,
"Baselines at lower exposures").

    python benchmarks/real_low_light.py FOLDER [--exposures 1 0.1 0.01] [--methods lct phasor fbp] [--seed 0]
                                               [--network FILE.pt | none]

FOLDER holds the release's ``data_*.mat`` files (the project never ships them; the release is published with
O'Toole, Lindell & Wetzstein, Nature 555, 338 (2018)). For each file, read as ``datagen import-capture
--bin-resolution 4ps`` reads it (datagen's orientation, docs/capture_io.md):

1. **Thinning.** A capture at a fraction f of its exposure is the counts thinned binomially, each detection kept
   with probability f (``Generator.binomial``, seeded by ``--seed`` and the file's place in the sorted folder):
   what the same SPAD would have counted over f of the time, up to the pile-up that a shorter exposure does not
   change (pile-up acts per cycle, thinning per detection).
2. **Reconstruction.** Each method of ``datagen reconstruct`` as shipped
   (:func:`datagen.analysis.reconstruct.confocal_volume`: the direct light trimmed, 512 bins of 16 ps, the t²
   falloff and snr 0.8 of the release's script, on every capture as ``datagen reconstruct`` does by default), and
   its depth map (:func:`~datagen.analysis.reconstruct.depth_map`: the strongest voxel's depth where the front
   view reaches 0.25 of its maximum, NaN elsewhere).
3. **Reference.** The object's mask is the full-exposure LCT reconstruction's found points (that same depth map's
   non-NaN points): a shape reference made from the capture itself, so that LCT at full exposure scores IoU 1 by
   construction. Depths are referred to the charts' nominal 0.40 / 0.65 m and the diffuse "S"'s 0.50 m
   (:data:`benchmarks.real_captures.DEPTHS`); the other captures have no stated depth.
4. **Scores.** Per capture, exposure and method: the median depth over the reference mask (m; NaN where the method
   found nothing there), its difference from the reference depth, and the IoU of the method's found points with the
   reference mask.
5. **A network** (``--network FILE.pt``, written by ``python -m examples.train_depth_image DATA --save FILE.pt``;
   by default the one shipped in :data:`SHIPPED`, trained on ``configs/datasets/lct_release.yaml``; ``--network
   none`` leaves it out): the same thinned counts, as its record says it reads them (the LCT volume of the scan,
   or the counts summed to its time axis and over its pool of scan points), its depth image, whose median over the
   reference mask is its depth; with a mask head (``--mask``) the IoU is of where it sees the object (its
   probability ≥ the record's threshold), without one it is not scored (NaN). The run prints what the record says
   of the network's training (``examples.train_depth_image.describe``) and a warning when the dataset config it
   was trained on is no longer the repository's (:func:`stale`).

f-k migration is not among the methods here: datagen runs it through tal in a separate environment
(benchmarks/bench_recon.py); its column is to come. The printed table is the one docs/real.md quotes.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from real_captures import DEPTHS  # noqa: E402  (the reference depths, one table for both benchmarks)

EXPOSURES = (1.0, 0.1, 0.01)
"""Fractions of each capture's exposure."""

SHIPPED = ROOT / "examples" / "weights" / "lct_release_net.pt"
"""The network trained on ``configs/datasets/lct_release.yaml`` that ships with the repository (docs/training.md)."""


def config_fingerprint(record: dict) -> str:
    """sha256 of the repository's dataset config named in a network's record (``configs/datasets/<config_name>.yaml``)
    cut to the record's split counts, as ``datagen build --splits`` cuts it: the card's ``config_sha256`` of a build
    of that config today (:meth:`datagen.dataset.DatasetConfig.fingerprint`).

    Raises:
        FileNotFoundError: no such config in the repository.
    """
    from datagen.dataset import load_dataset_config

    config = load_dataset_config(ROOT / "configs" / "datasets" / f"{record['config_name']}.yaml")
    splits = {name: config.splits[name].model_copy(update={"count": n}) for name, n in record["splits"].items()}
    return config.model_copy(update={"splits": splits}).fingerprint()


def stale(record: dict) -> str | None:
    """None when a network's record was trained on a build of the repository's dataset config as it is now (or on a
    config the repository does not hold), else a one-line reason (the record's ``config_sha256`` and the config's)."""
    if "config_sha256" not in record:
        return "its record holds no config_sha256 (saved without a dataset card)"
    if not (ROOT / "configs" / "datasets" / f"{record['config_name']}.yaml").is_file():
        return None                     # a config of the user's own: nothing in the repository to compare with
    now = config_fingerprint(record)
    if now != record["config_sha256"]:
        return (f"trained on config_sha256 {record['config_sha256'][:16]}…, configs/datasets/{record['config_name']}"
                f".yaml cut to {record['splits']} hashes to {now[:16]}… now: retrain it (docs/training.md)")
    return None


def read_release_file(path: Path) -> tuple[np.ndarray, float, tuple[float, float]]:
    """(counts (ny, nx, T) float64 in datagen's orientation, bin width s, (row, column) pitch m) of a release file
    (4 ps bins where the file does not say; :func:`datagen.io.lab_formats.read_lab_capture`)."""
    from datagen.analysis.confocal import grid_pitches
    from datagen.io.lab_formats import read_lab_capture

    cap = read_lab_capture(path, bin_resolution=4e-12)
    return np.asarray(cap.data(), dtype=np.float64), float(cap.bin_width()), grid_pitches(cap.laser_points())


def thin(counts: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Counts thinned binomially: each detection kept with probability ``fraction`` (0 < fraction ≤ 1); float64."""
    if not 0 < fraction <= 1:
        raise ValueError(f"an exposure fraction lies in (0, 1], got {fraction}")
    if fraction == 1:
        return np.asarray(counts, dtype=np.float64)
    return rng.binomial(np.asarray(counts, dtype=np.int64), fraction).astype(np.float64)


def found(scan: np.ndarray, dt: float, pitch, method: str) -> np.ndarray:
    """(ny, nx) depth map (m, NaN where nothing is found) of one method as ``datagen reconstruct`` runs it."""
    from datagen.analysis.reconstruct import confocal_volume, depth_map

    volume, depths, _ = confocal_volume(scan, dt, pitch, method)
    return depth_map(volume, depths)[0]


def score(depth: np.ndarray, mask: np.ndarray, hit: np.ndarray | None = None) -> tuple[float, float]:
    """(median depth over ``mask`` where found, m (NaN: nothing found there); IoU of the found points with mask).
    The found points are ``hit`` where given (a network's mask output), else where the depth is not NaN."""
    hit = ~np.isnan(depth) if hit is None else hit
    inside = depth[mask & hit & ~np.isnan(depth)]
    union = int((hit | mask).sum())
    return (float(np.median(inside)) if inside.size else float("nan"),
            float((hit & mask).sum()) / union if union else float("nan"))


def network_depth(network, scan: np.ndarray, dt: float, pitch) -> tuple[np.ndarray, np.ndarray]:
    """((ny, nx) depth m, (ny, nx) bool where it sees the object) of ``network`` = (net, record)
    (``examples.train_depth_image.load_model``) on a scan of counts (ny, nx, T) of bin width ``dt`` and grid pitch
    ``pitch`` (m): a network on the LCT volume reconstructs it from the scan as it is; one on counts gets them summed
    pairwise to at most its bins, zero-padded to them."""
    from datagen.analysis.reconstruct import coarsen
    from examples.train_depth_image import predict_depth

    net, record = network
    if record.get("input", "counts") == "lct":
        return predict_depth(net, record, scan, dt, pitch)
    data, _ = coarsen(scan, dt, record["bins"])
    data = np.concatenate([data, np.zeros(data.shape[:2] + (record["bins"] - data.shape[-1],))], axis=-1)
    return predict_depth(net, record, data)


def evaluate(counts: np.ndarray, dt: float, pitch, name: str, exposures=EXPOSURES, methods=("lct", "phasor", "fbp"),
             rng: np.random.Generator | None = None, network=None) -> list[dict]:
    """Rows {capture, exposure, method, depth, error, iou, seconds} of one capture (module doc); ``network`` a
    loaded (net, record) adds its row."""
    rng = rng if rng is not None else np.random.default_rng(0)
    mask = ~np.isnan(found(counts, dt, pitch, "lct"))
    reference = DEPTHS.get(name)
    rows = []
    for fraction in exposures:
        scan = thin(counts, fraction, rng)
        for method in list(methods) + (["network"] if network is not None else []):
            t0 = time.perf_counter()
            if method == "network":                    # its depth over the object; its mask head's IoU
                depth_map, seen = network_depth(network, scan, dt, pitch)
                depth = score(depth_map, mask)[0]
                iou = score(depth_map, mask, seen)[1] if network[0].mask else float("nan")
            else:
                depth, iou = score(found(scan, dt, pitch, method), mask)
            rows.append({"capture": name, "exposure": fraction, "method": method, "depth": depth,
                         "error": depth - reference if reference is not None else float("nan"), "iou": iou,
                         "counts": float(scan.sum()), "seconds": time.perf_counter() - t0})
    return rows


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--exposures", type=float, nargs="+", default=list(EXPOSURES))
    parser.add_argument("--methods", nargs="+", default=["lct", "phasor", "fbp"], choices=["lct", "phasor", "fbp"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", nargs="+", default=None, help="captures by name (dot_chart_40cm ...)")
    parser.add_argument("--network", default=str(SHIPPED),
                        help="a trained network (.pt, module doc; default: the shipped one), or 'none'")
    args = parser.parse_args(argv)
    network = None
    if args.network != "none":
        sys.path.insert(0, str(ROOT))
        from examples.train_depth_image import describe, load_model
        if not Path(args.network).is_file():
            raise SystemExit(f"--network: no file at {args.network}")
        network = load_model(args.network)
        print(f"network {args.network}: {describe(network[1])}")
        reason = stale(network[1]) if "config_name" in network[1] else None
        if reason is not None:
            print(f"warning: network {args.network} is stale: {reason}", file=sys.stderr)
    files = sorted(args.folder.glob("data_*.mat"))
    seeds = {path: k for k, path in enumerate(files)}           # a capture's stream is its place in the folder
    if args.only:
        files = [p for p in files if p.stem.removeprefix("data_") in args.only]
    if not files:
        raise SystemExit(f"{args.folder}: no data_*.mat files (give the folder of the release's captures)")
    for f in args.exposures:
        if not 0 < f <= 1:
            raise SystemExit(f"--exposures: a fraction lies in (0, 1], got {f}")
    rows = []
    print("capture | exposure | method | median depth over the object (m) | minus reference (m) | IoU | counts | s")
    for path in files:
        name = path.stem.removeprefix("data_")
        counts, dt, pitch = read_release_file(path)
        for row in evaluate(counts, dt, pitch, name, args.exposures, args.methods,
                            np.random.default_rng([args.seed, seeds[path]]), network):
            rows.append(row)
            print(f"{row['capture']} | {row['exposure']:g} | {row['method']} | {row['depth']:.4f} | "
                  f"{row['error']:+.4f} | {row['iou']:.3f} | {row['counts']:.3g} | {row['seconds']:.1f}", flush=True)
    return rows


if __name__ == "__main__":
    main()
