"""Each order's share of the in-window light, for every shipped scene and a sample of each shipped dataset config
(docs/physics.md §2, "Orders").

The shares come from the light tracer of datagen/transport/multibounce from order 1 up (the planner's pilot,
datagen.planner.orders.order_shares, here with more paths), at the scene's centre laser point, with each scene's
own time window, IRF-free in-window energy, legs and physics. Orders 1 and 2 are what ``orders: 2`` simulates.

    python benchmarks/order_shares.py [--paths 65536] [--samples 2]
"""
from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import datagen
from datagen.dataset.sample_scene import sample_setup
from datagen.planner.orders import order_shares
from datagen.scene import RayCaster, resolve_capture

ROOT = Path(__file__).resolve().parents[1]


def shares(scene, config, paths: int):
    caster = RayCaster(scene)
    capture = resolve_capture(scene, caster)
    s = order_shares(scene, capture, caster, config.physics_settings(), (config.time.t_start, config.time.t_stop),
                     config.seed, paths)
    return float(s[0]), float(s[1]), float(s[2:].sum()), config.orders_setting()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=65536)
    ap.add_argument("--samples", type=int, default=2, help="samples of each dataset config (train split)")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    print("| scene or dataset sample | order 1 | order 2 | orders ≥ 3 | orders its config simulates |")
    print("|---|---|---|---|---|")
    for f in sorted((ROOT / "scene_library").rglob("*.yaml")):
        try:
            scene = datagen.load_scene(f)
            row = shares(scene, datagen.resolve_config(scene), a.paths)
        except Exception as exc:                      # a scene the tracer cannot take (say why)
            print(f"| {f.relative_to(ROOT)} | — | — | — | {type(exc).__name__}: {exc} |")
            continue
        print(f"| {f.relative_to(ROOT)} | {row[0]:.1%} | {row[1]:.1%} | {row[2]:.1%} | {row[3]} |", flush=True)
    for f in sorted((ROOT / "configs" / "datasets").glob("*.yaml")):
        for i in range(a.samples):
            try:
                scene, config = sample_setup(f, "train", i)
                row = shares(scene, config, a.paths)
            except Exception as exc:
                print(f"| {f.relative_to(ROOT)} train {i} | — | — | — | {type(exc).__name__}: {exc} |")
                continue
            print(f"| {f.relative_to(ROOT)} train {i} | {row[0]:.1%} | {row[1]:.1%} | {row[2]:.1%} | {row[3]} |",
                  flush=True)


if __name__ == "__main__":
    main()
