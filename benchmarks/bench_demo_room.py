"""Run times and secondary share of the demo room at the paper's samplings (README: benchmarks).

    python benchmarks/bench_demo_room.py [--quick] [--workers 2]

Prints one row per (lookins, secondary estimator, albedo): wall time, total, secondary share and peak times,
then the exact secondary at 45×45×60×60 on 1 and 2 worker processes (issue 5's target: ≤ 2 s) and its
relative L2 difference to the full O(Ñ²) secondary, then the area sampler at its cheapest ≤ 1 % setting on 1 and
2 workers with its error estimate and its actual error against the converged reference (issue 12's target:
≤ 0.25 s on 2 cores; ``--area-only``). The paper reports ≈1 h (full) / <30 s (optimized) at
10×10×60×60 and 3 h 34 min / 2 min at 45×45×60×60. Times are best of ``--repeat`` runs in one process.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

import datagen  # noqa: E402
from datagen.scene import Material  # noqa: E402
from datagen.scene import Scene, SceneObject  # noqa: E402


def with_albedo(scene: Scene, albedo: float) -> Scene:
    objects = [SceneObject(o.name, o.label, Material(**{**o.material.model_dump(), "albedo": albedo}),
                           o.vertices, o.faces) for o in scene.objects]
    return Scene(objects, scene.laser, scene.sensor, scene.name, scene.source, scene.defaults)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="10x10 only")
    parser.add_argument("--repeat", type=int, default=3, help="runs per exact-secondary timing (best is kept)")
    parser.add_argument("--exact-only", action="store_true", help="only the exact-secondary timings")
    parser.add_argument("--area-only", action="store_true", help="only the area sampler to 1 %%")
    parser.add_argument("--cache-dir", default=None, help="converged-reference cache (default: bench accuracy's)")
    args = parser.parse_args()
    if args.exact_only:
        exact_timings(args.repeat)
        return
    if args.area_only:
        area_timings(args.repeat, args.cache_dir)
        return
    base = datagen.load_scene("scene_library/demo_room.yaml")
    rows = []
    grids = ["10x10"] if args.quick else ["10x10", "45x45"]
    for grid in grids:
        for secondary in ("full", "optimized", "exact"):
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
    exact_timings(args.repeat)
    if not args.quick:
        area_timings(args.repeat, args.cache_dir)


AREA_TO_1PCT = {"estimator": "area", "area_samples": 49152, "replicas": 2}
"""The demo room's cheapest area-sampler setting at <= 1 % (2 replicas of 24576 hidden samples; issue 12)."""


def area_timings(repeat: int, cache_dir: str | None) -> None:
    """The area sampler at ``AREA_TO_1PCT`` on 1 and 2 worker processes: best wall time of ``repeat`` runs (seeds
    0, 1, …), the error estimate and the actual relative L2 error against the converged reference (rel_tol 1e-3,
    cached)."""
    from datagen.analysis import converged_reference, relative_l2
    from datagen.cli.bench import default_cache_dir

    scene = datagen.load_scene("scene_library/demo_room.yaml")
    ref = converged_reference(scene, datagen.resolve_config(scene), rel_tol=1e-3,
                              cache_dir=cache_dir or default_cache_dir())
    print(f"\n| demo room, area sampler {AREA_TO_1PCT['area_samples']} hidden samples in "
          f"{AREA_TO_1PCT['replicas']} replicas | workers | best wall time (s) | runs (s) | estimate | actual |")
    print("|---|---:|---:|---|---:|---:|")
    for workers in (1, 2):
        config = datagen.resolve_config(scene, {**AREA_TO_1PCT, "workers": workers})
        datagen.simulate(scene, config)                    # warm-up (imports, caches)
        times, est, act = [], [], []
        for seed in range(repeat):
            t0 = time.perf_counter()
            r = datagen.simulate(scene, config.model_copy(update={"seed": seed}))
            times.append(time.perf_counter() - t0)
            est.append(r.attrs["error"]["rel_l2"])
            act.append(relative_l2(r.envelope, ref.envelope))
        print(f"| demo room | {workers} | {min(times):.3f} | {', '.join(f'{t:.3f}' for t in times)} | "
              f"{max(est):.2%} (max) | {max(act):.2%} (max) |", flush=True)


def exact_timings(repeat: int) -> None:
    """The exact secondary at 45×45×60×60 on 1 and 2 workers, best of ``repeat``, vs the full secondary."""
    scene = datagen.load_scene("scene_library/demo_room.yaml")
    print("\n| 45×45×60×60, exact secondary | workers | best wall time (s) | runs (s) |")
    print("|---|---|---|---|")
    results = {}
    for workers in (1, 2):
        config = datagen.resolve_config(scene, {"lookins": "45x45", "pixels": "60x60", "secondary": "exact",
                                                "workers": workers})
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            results[workers] = datagen.simulate(scene, config)
            times.append(time.perf_counter() - t0)
        print(f"| demo room | {workers} | {min(times):.2f} | {', '.join(f'{t:.2f}' for t in times)} |", flush=True)
    assert np.array_equal(results[1].envelope, results[2].envelope), "workers changed the result"
    full = datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "45x45", "pixels": "60x60",
                                                                   "secondary": "full"}))
    a, b = results[1].components["secondary"], full.components["secondary"]
    m = b > 0.01 * b.max()
    print(f"exact vs full secondary at 45×45×60×60: relative L2 {np.linalg.norm((a - b)[m]) / np.linalg.norm(b[m]):.2e},"
          f" totals {a.sum():.6e} / {b.sum():.6e}; 1 and 2 workers bit-identical")


if __name__ == "__main__":
    main()
