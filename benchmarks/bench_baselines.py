"""What each shipped dataset config teaches (issue 16): build a small set per config on 2 cores, train the
baseline of ``examples/train_single_pixel.py`` briefly, print each documented target's validation metric
next to its trivial baseline. Plain script::

    python benchmarks/bench_baselines.py                 # default: 256 + 128, objects: 512 + 128 samples; seed 0
    python benchmarks/bench_baselines.py --seeds 0,1     # the same with two training seeds
    python benchmarks/bench_baselines.py --quick         # half the training samples, 20 epochs
    python benchmarks/bench_baselines.py --out out/bench_baselines   # where the builds go (reused when complete)

Configs and targets (docs/datasets.md, "What each config teaches"):

* ``configs/datasets/default.yaml`` (counts): ``fov_distance`` and ``first_return`` (taught), ``object_count``
  and ``nearest_object`` (not taught: shown at their trivial baseline);
* ``configs/datasets/objects.yaml``: ``object_count``, ``nearest_object`` from the counts alone and with the
  stored empty-room reference subtracted (``--input subtracted``), and ``first_return``;
* ``configs/datasets/wall_baseline.yaml`` (the scanned wall distribution of ``wall.yaml`` at 16 × 16 × 256, built
  as shipped: 200 + 50 samples) and ``configs/datasets/confocal_baseline.yaml`` (the rooms of ``confocal.yaml`` at
  16 × 16 × 256, 200 + 50 samples): the ``wall_depth`` image over the object pixels from
  ``examples/train_depth_image.py`` (per training seed) and ``examples/backprojection_baseline.py`` (no
  training; depths searched to ``BP_FAR``), each scored by ``datagen score``'s
  :func:`~datagen.dataset.score.score_predictions` on ``val`` against the trivial baseline (the training mean
  depth over the object pixels).

``--configs default,objects,wall_baseline,confocal_baseline`` (the default) selects what runs.

``smoke.yaml`` is a build check (40 tiny samples), not a training set, and is not run. A target counts as
taught ("yes") when its RMSE is at most ``TAUGHT_RMSE`` × the trivial baseline's (the training mean), or its
accuracy beats the majority class by at least ``TAUGHT_SE`` binomial standard errors of the majority's
accuracy; depth images, when their val RMSE (mean over samples) is at most ``TAUGHT_RMSE`` × the trivial
one's. The machine is shared: the build and training times are indicative only.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from datagen.dataset import build_dataset, load_dataset_config, read_card  # noqa: E402
from datagen.dataset.config import SplitSpec  # noqa: E402
from datagen.dataset.score import score_predictions  # noqa: E402
from examples import backprojection_baseline, train_depth_image  # noqa: E402
from examples.train_single_pixel import train  # noqa: E402

TAUGHT_RMSE = 0.8
TAUGHT_SE = 3.0

RUNS = [  # config, input, targets
    ("default", "counts", ["fov_distance", "first_return", "object_count", "nearest_object"]),
    ("objects", "counts", ["object_count", "nearest_object", "first_return"]),
    ("objects", "subtracted", ["object_count", "nearest_object", "first_return"]),
]
SIZES = {"default": (256, 128), "objects": (512, 128)}
SCAN_CONFIGS = ("wall_baseline", "confocal_baseline")   # built as shipped (200 + 50 each), never cut by --quick
SCAN_EPOCHS = 40
BP_FAR = {"wall_baseline": 1.9, "confocal_baseline": 4.0}   # m searched by the backprojection (objects ≤ 1.5 / ≈ 3 m out)


def build(name: str, out: Path, n_train: int | None = None, n_val: int | None = None) -> Path:
    """Build (or reuse a complete build of the same config) ``configs/datasets/<name>.yaml`` cut to the sizes
    (None: the config's own splits and shard size)."""
    config = load_dataset_config(ROOT / "configs" / "datasets" / f"{name}.yaml")
    if n_train is None:
        n_train, n_val = config.splits["train"].count, config.splits["val"].count
    else:
        config = config.model_copy(update={"splits": {"train": SplitSpec(count=n_train),
                                                      "val": SplitSpec(count=n_val)}, "shard_size": 32})
    path = out / f"{name}-{n_train}-{n_val}"
    if path.exists():
        try:
            card = read_card(path)
            if card.get("status") == "complete" and card.get("config_sha256") == config.fingerprint():
                print(f"{name}: reusing {path}")
                return path
        except FileNotFoundError:
            pass
        import shutil
        shutil.rmtree(path)
    t0 = time.perf_counter()
    build_dataset(config, path, workers=2, progress=False)
    print(f"{name}: built {n_train} + {n_val} samples in {time.perf_counter() - t0:.0f} s -> {path}")
    return path


def verdict(r) -> tuple[str, str]:
    """(margin text, yes/no) for one result."""
    if r.kind == "regression":
        return f"RMSE x{r.ratio:.2f}", "yes" if r.ratio <= TAUGHT_RMSE else "no"
    se = math.sqrt(max(r.trivial * (1 - r.trivial), 1e-9) / r.count)
    return f"{r.ratio:+.3f} ({r.ratio / se:+.1f} se)", "yes" if r.ratio >= TAUGHT_SE * se else "no"


def scan_rows(path: Path, seeds: list[int], epochs: int, out: Path, far: float) -> list[tuple]:
    """[(method, seed or None, MAE, RMSE, trivial MAE, trivial RMSE, samples scored)] of the depth-image baselines on
    ``val``, each written as a ``datagen score`` .npz under ``out`` and scored with it (mean over samples)."""
    def scored(name: str, pred: dict) -> tuple[float, float, int]:
        f = out / f"{path.name}-{name}.npz"
        np.savez(f, depth=pred["depth"], index=pred["index"])
        scores = score_predictions(f, path, "val")
        s, seen = scores["summary"], sum(r["depth_pixels"] > 0 for r in scores["rows"])
        return s["mean_depth_mae"], s["mean_depth_rmse"], f"the {seen} of {s['samples']} samples with object pixels"

    rows, trivial = [], None
    for seed in seeds:
        t0 = time.perf_counter()
        pred = train_depth_image.train(path, epochs=epochs, seed=seed, log=None)
        print(f"{path.name} / depth CNN / seed {seed}: trained in {time.perf_counter() - t0:.0f} s")
        trivial = scored("trivial", {"depth": pred["trivial"], "index": pred["index"]})
        rows.append(("depth CNN (counts)", seed) + scored(f"net-seed{seed}", pred)[:2] + trivial)
    for field in ("counts", "envelope"):        # the envelope: the noise-free bound of the same method
        t0 = time.perf_counter()
        bp = backprojection_baseline.predict(path, "val", field, far=far)
        print(f"{path.name} / backprojection of the {field}: {time.perf_counter() - t0:.0f} s")
        rows.append((f"backprojection ({field})", None) + scored(f"backprojection-{field}", bp)[:2] + trivial)
    return rows


def main():
    parser = argparse.ArgumentParser(description="baselines per shipped dataset config")
    parser.add_argument("--out", default=str(ROOT / "out" / "bench_baselines"))
    parser.add_argument("--quick", action="store_true", help="half the training samples, 20 epochs")
    parser.add_argument("--seeds", default="0", help="training seeds, comma separated")
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--configs", default=",".join(("default", "objects") + SCAN_CONFIGS),
                        help="comma separated")
    args = parser.parse_args()
    configs = args.configs.split(",")
    torch.set_num_threads(args.threads)
    seeds = [int(x) for x in args.seeds.split(",")]
    scale = 2 if args.quick else 1
    if args.quick:
        args.epochs = min(args.epochs, 20)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    paths = {name: build(name, out, n_tr // scale, n_va) for name, (n_tr, n_va) in SIZES.items() if name in configs}
    for name in SCAN_CONFIGS:
        if name in configs:
            paths[name] = build(name, out)
    rows = []
    for name, inp, targets in (run for run in RUNS if run[0] in configs):
        for seed in seeds:
            t0 = time.perf_counter()
            results = train(paths[name], targets, inp, epochs=args.epochs, seed=seed, log=None)
            print(f"{name} / {inp} / seed {seed}: trained in {time.perf_counter() - t0:.0f} s")
            rows += [(name, inp, seed, r) for r in results]
    if rows:
        sizes = ", ".join(f"{k} {v[0] // scale}" for k, v in SIZES.items() if k in configs)
        print(f"\nvalidation metric vs trivial baseline (train {sizes}; val 128 each; {args.epochs} epochs; taught "
              f"= RMSE <= {TAUGHT_RMSE} x trivial or accuracy >= {TAUGHT_SE:g} se above the majority class)")
        print(f"{'config':8s} {'input':11s} {'seed':>4s} {'target':15s} {'metric':>11s} {'network':>8s} "
              f"{'trivial':>8s} {'margin':>18s} {'taught':>6s}")
        for name, inp, seed, r in rows:
            margin, taught = verdict(r)
            metric = f"RMSE {r.unit}" if r.kind == "regression" else "accuracy"
            print(f"{name:8s} {inp:11s} {seed:4d} {r.target:15s} {metric:>11s} {r.model:8.3f} {r.trivial:8.3f} "
                  f"{margin:>18s} {taught:>6s}")
    for name in (c for c in SCAN_CONFIGS if c in configs):
        epochs = SCAN_EPOCHS // scale
        scan = scan_rows(paths[name], seeds, epochs, out, BP_FAR[name])
        print(f"\n{name}: val wall_depth over the object pixels (datagen score, mean over {scan[0][-1]}; CNN "
              f"{epochs} epochs; trivial = training mean depth; taught = RMSE <= {TAUGHT_RMSE} x trivial)")
        print(f"{'method':26s} {'seed':>4s} {'MAE m':>7s} {'RMSE m':>7s} {'trivial MAE':>11s} {'trivial RMSE':>12s} "
              f"{'margin':>11s} {'taught':>6s}")
        for method, seed, mae, rmse, t_mae, t_rmse, _ in scan:
            taught = "yes" if rmse <= TAUGHT_RMSE * t_rmse else "no"
            print(f"{method:26s} {'-' if seed is None else seed:>4} {mae:7.3f} {rmse:7.3f} {t_mae:11.3f} "
                  f"{t_rmse:12.3f} {f'RMSE x{rmse / t_rmse:.2f}':>11s} {taught:>6s}")
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s (machine shared with other jobs)")


if __name__ == "__main__":
    main()
