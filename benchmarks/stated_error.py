"""How often the stated error bounds the actual one: held-out samples of the shipped dataset configs against an
independent all-order reference (docs/accuracy.md, "What the stated error means").

For each sample: the envelope and its stated error as a build stores them (``make_sample``, at the config's
tolerance and cost cap), and ``datagen.converged_reference`` of the same scene and config (every order the config
asks for, the deep orders unsmoothed: unbiased; another seed; converged to a quarter of the tolerance). The actual
error is the same measure as the stated one (:func:`datagen.simulation.replicas.relative_difference`: relative L2
over the bins above 1 % of the reference's peak), against the reference. Prints one row per sample and the coverage:
the share of samples whose actual error is within the stated one, and the largest ratio.

    python benchmarks/stated_error.py [--samples 10] [--budget 300] [--csv out.csv] [--references DIR]
        [--configs configs/datasets/default.yaml:test_closed configs/datasets/objects.yaml:test ...]
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

import datagen
from datagen.dataset import load_dataset_config
from datagen.dataset.config import make_sample
from datagen.simulation.replicas import relative_difference

HELD_OUT = ("configs/datasets/default.yaml:test", "configs/datasets/default.yaml:test_closed",
            "configs/datasets/default.yaml:test_glossy", "configs/datasets/objects.yaml:test")
"""The held-out splits measured by default (config:split): none of them was used to tune the estimators."""


def reference(config, split: str, index: int, budget: float, cache: Path | None) -> tuple[np.ndarray, float, bool]:
    """(envelope, stated error, converged) of the sample's converged reference; read from, or written to,
    ``cache`` (one .npz per sample) when given, so that a change to the stated error is re-measured against the
    same references."""
    file = cache / f"{config.name}-{split}-{index}.npz" if cache is not None else None
    if file is not None and file.is_file():
        with np.load(file) as z:
            return z["envelope"], float(z["error"]), bool(z["converged"])
    scene, sim = datagen.sample_setup(config, split, index)
    ref = datagen.converged_reference(scene, sim, rel_tol=config.tolerance / 4, max_seconds=budget, min_replicas=8,
                                      workers=1)
    out = ref.envelope, float(ref.error_estimate["rel_l2"]), bool(ref.converged)
    if file is not None:
        file.parent.mkdir(parents=True, exist_ok=True)
        np.savez(file, envelope=out[0], error=out[1], converged=out[2])
    return out


def measure(path: str, split: str, index: int, budget: float, cache: Path | None = None) -> dict:
    """One sample's stated and actual error (see the module docstring)."""
    config = load_dataset_config(path)
    t = time.process_time()
    s = make_sample(config, split, index)
    cpu = time.process_time() - t
    ref, ref_error, converged = reference(config, split, index, budget, cache)
    env = np.asarray(s.arrays["envelope"], dtype=np.float64).reshape(ref.shape)
    actual = float(relative_difference(env, ref, ref))
    stated = float(s.arrays["envelope_error"])
    return {"config": path, "split": split, "index": index, "tolerance": config.tolerance, "stated": stated,
            "actual": actual, "ratio": actual / stated, "reference_error": ref_error,
            "reference_converged": converged, "sample_cpu_s": cpu}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=list(HELD_OUT), help="config:split pairs")
    ap.add_argument("--samples", type=int, default=8, help="samples 0..N-1 of each split")
    ap.add_argument("--budget", type=float, default=300.0, help="most CPU seconds of one reference")
    ap.add_argument("--csv", help="also write the rows here")
    ap.add_argument("--references", type=Path, help="cache of the references (one .npz per sample): read if there")
    args = ap.parse_args()
    rows = []
    print("| config | split | sample | stated | actual | actual / stated | reference error | sample CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for spec in args.configs:
        path, split = spec.rsplit(":", 1)
        for i in range(args.samples):
            r = measure(path, split, i, args.budget, args.references)
            rows.append(r)
            print(f"| {path.rsplit('/', 1)[-1]} | {split} | {i} | {r['stated']:.2%} | {r['actual']:.2%} | "
                  f"{r['ratio']:.2f} | {r['reference_error']:.2%}{'' if r['reference_converged'] else ' (not converged)'}"
                  f" | {r['sample_cpu_s']:.1f} |", flush=True)
            if args.csv:
                with open(args.csv, "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=list(rows[0]))
                    w.writeheader()
                    w.writerows(rows)
    ratios = np.array([r["ratio"] for r in rows])
    print(f"\n{len(rows)} samples: actual <= stated in {np.mean(ratios <= 1):.0%}, <= 1.25 x stated in "
          f"{np.mean(ratios <= 1.25):.0%}; median ratio {np.median(ratios):.2f}, largest {ratios.max():.2f}")


if __name__ == "__main__":
    main()
