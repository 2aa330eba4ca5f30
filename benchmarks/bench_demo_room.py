"""Run times and secondary share of the demo room at the paper's samplings (README: benchmarks).

    python benchmarks/bench_demo_room.py [--quick]

Prints one row per (lookins, secondary estimator, albedo): wall time, total, secondary share and peak times.
The paper reports ≈1 h (full) / <30 s (optimized) at 10×10×60×60 and 3 h 34 min / 2 min at 45×45×60×60.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import datagen
from datagen.brdf import Material
from datagen.scene import Scene, SceneObject


def with_albedo(scene: Scene, albedo: float) -> Scene:
    objects = [SceneObject(o.name, o.label, Material(**{**o.material.model_dump(), "albedo": albedo}),
                           o.vertices, o.faces) for o in scene.objects]
    return Scene(objects, scene.laser, scene.sensor, scene.name, scene.source, scene.defaults)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="10x10 only")
    args = parser.parse_args()
    base = datagen.load_scene("scene_library/demo_room.yaml")
    rows = []
    grids = ["10x10"] if args.quick else ["10x10", "45x45"]
    for grid in grids:
        for secondary in ("full", "optimized"):
            for albedo in (1.0, 0.5):
                scene = with_albedo(base, albedo)
                config = datagen.resolve_config(scene, {"lookins": grid, "secondary": secondary})
                t0 = time.perf_counter()
                r = datagen.simulate(scene, config)
                dt = time.perf_counter() - t0
                total = r.area()
                rows.append((grid, secondary, albedo, dt, total, r.area("secondary") / total,
                             r.peak_time("box") * 1e9, r.peak_time("room") * 1e9, r.peak_time("pillar") * 1e9,
                             r.peak_time("secondary") * 1e9))
                print(f"{grid:>6} {secondary:>9} albedo {albedo:3.1f}: {dt:7.1f} s  total {total:.4e}  "
                      f"secondary share {rows[-1][5]:6.1%}  peaks box/room/pillar/secondary "
                      f"{rows[-1][6]:.2f}/{rows[-1][7]:.2f}/{rows[-1][8]:.2f}/{rows[-1][9]:.2f} ns", flush=True)
    print("\n| lookins×pixels | secondary | albedo | wall time (s) | secondary share |")
    print("|---|---|---|---|---|")
    for row in rows:
        print(f"| {row[0]}×60x60 | {row[1]} | {row[2]} | {row[3]:.1f} | {row[5]:.1%} |")
    np.set_printoptions(precision=3)


if __name__ == "__main__":
    main()
