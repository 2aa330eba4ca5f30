"""A/B of the area sampler's compiled kernels (datagen/transport/area/kernels.py) against a baseline revision.

    python benchmarks/bench_area_kernels.py [--quick] [--baseline c2cf3e2] [--rounds 3]

Extracts ``--baseline`` (git archive) into a temporary directory and measures, alternately in fresh processes of
this checkout and of the baseline, the CPU seconds per sample of ``configs/datasets/default.yaml`` train
samples 1..N (``make_sample``, after a warm-up sample that pays imports and numba's cached-kernel load) and of the
demo room at the area sampler's ≤ 1 % setting (49152 hidden samples in 2 replicas, one process) and of tal's
hidden-square single capture (benchmarks/tal/hidden_square.yaml: the quadrature at h = 4 cm, the area sampler at
65536 samples; the tal comparison's settings, docs/tal.md); prints the
best of ``--rounds`` rounds of each and the new/old ratio, and checks that the envelopes agree to float32
rounding (the kernels keep the random streams; only the floating-point order of a few sums differs).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import datagen
from datagen.dataset import load_dataset_config, make_sample
n = int(sys.argv[2])
config = load_dataset_config(sys.argv[1] + "/configs/datasets/default.yaml")
make_sample(config, "train", 0)
t0 = time.process_time()
envs = [make_sample(config, "train", i).arrays["envelope"].astype(float).tolist() for i in range(1, n + 1)]
dataset_cpu = (time.process_time() - t0) / n
scene = datagen.load_scene(sys.argv[1] + "/scene_library/demo_room.yaml")
sim = datagen.resolve_config(scene, {"estimator": "area", "area_samples": 49152, "replicas": 2, "workers": 1})
datagen.simulate(scene, sim)
t0 = time.process_time()
demo = datagen.simulate(scene, sim)
demo_cpu = time.process_time() - t0
from datagen.io import scene_from_tal_yaml
tal_scene, _ = scene_from_tal_yaml(sys.argv[1] + "/benchmarks/tal/hidden_square.yaml")
tal_cpu = {}
for name, setting in (("tal_quadrature", {"estimator": "quadrature", "quadrature_edge": 0.04}),
                      ("tal_area", {"estimator": "area", "area_samples": 65536})):
    cfg = datagen.resolve_config(tal_scene, {**setting, "seed": 0})
    datagen.simulate(tal_scene, cfg)
    t0 = time.process_time()
    datagen.simulate(tal_scene, cfg)
    tal_cpu[name] = time.process_time() - t0
print(json.dumps({"dataset": dataset_cpu, "demo": demo_cpu, **tal_cpu, "envs": envs,
                  "demo_env": demo.envelope.ravel().tolist()}))
"""


def measure(tree: Path, n: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(tree), str(n)], capture_output=True, text=True, check=True,
                         cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", default="c2cf3e2", help="git revision without the kernels")
    parser.add_argument("--samples", type=int, default=8, help="default-config samples per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="4 samples, 2 rounds")
    args = parser.parse_args()
    if args.quick:
        args.samples, args.rounds = 4, 2
    import numpy as np

    with tempfile.TemporaryDirectory(prefix="bench_area_ab_") as tmp:
        archive = subprocess.run(["git", "archive", args.baseline], cwd=ROOT, capture_output=True, check=True).stdout
        tarfile.open(fileobj=BytesIO(archive)).extractall(tmp)
        runs = {"new": [], "old": []}
        for _ in range(args.rounds):                         # alternate, so both see the same machine load
            runs["new"].append(measure(ROOT, args.samples))
            runs["old"].append(measure(Path(tmp), args.samples))
    a, b = runs["new"][0], runs["old"][0]
    env_diff = max(float(np.max(np.abs(np.subtract(x, y))) / max(np.max(np.abs(y)), 1e-300))
                   for x, y in zip(a["envs"] + [a["demo_env"]], b["envs"] + [b["demo_env"]]))
    print(f"\n| area sampler | baseline {args.baseline} CPU-s | kernels CPU-s | new/old |")
    print("|---|---:|---:|---:|")
    for key, label in (("dataset", f"default-config sample (mean of {args.samples})"),
                       ("demo", "demo room, 49152 hidden samples in 2 replicas, 1 process"),
                       ("tal_quadrature", "tal hidden square, single spot 16×16, quadrature h = 4 cm"),
                       ("tal_area", "tal hidden square, single spot 16×16, area sampler 65536 samples")):
        old = min(r[key] for r in runs["old"])
        new = min(r[key] for r in runs["new"])
        print(f"| {label} | {old:.3f} | {new:.3f} | {new / old:.2f} |")
    print(f"largest relative difference of the envelopes (kernels vs baseline, same seeds): {env_diff:.1e}")


if __name__ == "__main__":
    main()
