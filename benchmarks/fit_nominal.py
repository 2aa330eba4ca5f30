"""Fit of the nominal rates that cap a dataset sample's work (``cost_cap``): the lookin estimator's
(``datagen.transport.lookin.estimator.NOMINAL_SECONDS``) and the quadrature's
(``datagen.transport.quadrature.estimator.NOMINAL_SECONDS``). Plain script::

    python benchmarks/fit_nominal.py lookin          # 72 runs, the fit, each run's residual (≈ 8 min)
    python benchmarks/fit_nominal.py quadrature      # 30 levels of the quadrature (≈ 3 min)
    python benchmarks/fit_nominal.py lookin --quick  # a third of the runs (a check, not a fit)

lookin: each run is ``Replicas.run(n)`` (one worker, orders 1–2: the tracer has its own rates,
``NOMINAL_TRACER_SECONDS``) on a shipped scene or a sampled smoke room (the smoke dataset's simulation block with the
12 ns window of issue 69), at the lookin grids, cameras and secondary modes of ``LOOKIN_SETTINGS``; its CPU time
covers the replicas' transport, sinks and binning, not the scene's set-up. quadrature: each run is one level of the
tolerance loop, ``Replicas(...)`` on the planned scene and its ``run(1)`` (orders 1, no secondary: the area sampler
has its own rates), on the scan and single-pixel dataset rooms at the edges of ``QUADRATURE_EDGES``.

The CPU time (``time.process_time``: every thread of this process, so the compiled quadrature's two threads count
twice) is regressed on the counters the estimator's ``nominal_seconds()`` weighs, by non-negative least squares on
relative errors (every run weighs the same). Prints the rates (paste them into ``NOMINAL_SECONDS``), the RMS and
worst relative residual, the ratio nominal / CPU of the rates in the code, and per run its CPU and residual. CPU
time depends on the machine's load: run it on an otherwise idle machine.
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

from datagen.dataset import load_dataset_config  # noqa: E402
from datagen.dataset.config import draw_room  # noqa: E402
from datagen.scene import load_scene  # noqa: E402
from datagen.simulation import resolve_config  # noqa: E402
from datagen.simulation.config import STREAM_SAMPLING, stream_rng  # noqa: E402
from datagen.simulation.run import Replicas  # noqa: E402
from datagen.transport.lookin import estimator as lookin  # noqa: E402
from datagen.transport.quadrature import estimator as quadrature  # noqa: E402

SCENES = ("scene_library/demo_room.yaml", "scene_library/office_room.yaml", "scene_library/closed_corridor.yaml")

LOOKIN_SETTINGS = [(2, 16, "none", 200), (2, 16, "full", 200), (4, 16, "full", 60), (2, 32, "full", 40),
                   (4, 32, "none", 40), (4, 32, "full", 16), (3, 60, "full", 6), (5, 60, "none", 6),
                   (4, 60, "optimized", 6), (6, 60, "exact", 6), (8, 24, "exact", 20), (1, 16, "full", 400)]
"""(lookins per replica side, camera pixels per side, secondary, replicas run): small replicas (per-run work) to
large cameras (per-ray and per-pair work)."""

QUADRATURE_DATASETS = {"configs/datasets/confocal_smoke.yaml": (0.5, 0.35, 0.25),
                       "configs/datasets/wall_smoke.yaml": (0.12, 0.08, 0.06),
                       "configs/datasets/confocal.yaml": (0.3, 0.21),
                       "configs/suites/single-pixel-v2.yaml": (0.08, 0.056)}
"""Dataset or suite config → the quadrature edges (m) each of its rooms is run at."""

SMOKE = ROOT / "configs/datasets/smoke.yaml"


def _dataset(path: Path):
    if path.parent.name == "suites":
        from datagen.dataset.suite import load_suite
        return load_suite(path.stem).config
    return load_dataset_config(path)


def lookin_runs(smoke_rooms: int):
    """(label, scene, overrides, n): every lookin run."""
    config = load_dataset_config(SMOKE)
    scenes = [(path, load_scene(ROOT / path), {}) for path in SCENES]
    for index in range(smoke_rooms):
        room, _ = draw_room(config, "train", index)
        scenes.append((f"smoke train {index}", room.scene, {**config.simulation_overrides(),
                       "time": {"t_start": 15e-9, "bin_width": 2e-10, "n_bins": 60}}))
    for name, scene, overrides in scenes:
        for side, pixels, secondary, n in LOOKIN_SETTINGS:
            over = {**overrides, "estimator": {"kind": "lookin", "lookins": [2 * side, 2 * side],   # 4 replicas:
                                               "pixels": [pixels, pixels]},                         # each side / 2
                    "secondary": secondary, "replicas": 4, "orders": 2 if secondary != "none" else 1, "workers": 1}
            if "effects" in overrides:
                over["effects"] = {**overrides["effects"], "secondary": secondary != "none"}
            yield f"{name}: {n} x {side}x{side} lookins, {pixels}x{pixels} px, {secondary}", scene, over, n


def quadrature_runs(rooms: int):
    """(label, scene, overrides, edge): every quadrature level."""
    for path, edges in QUADRATURE_DATASETS.items():
        config = _dataset(ROOT / path)
        split = next(iter(config.splits))
        for index in range(rooms):
            room, _ = draw_room(config, split, index)
            over = {**config.simulation_overrides(), "secondary": "none", "orders": 1, "workers": 1}
            over["effects"] = {**over.get("effects", {}), "secondary": False}
            for edge in edges:
                yield f"{Path(path).stem} {split} {index}: edge {edge} m", room.scene, over, edge


def measure_lookin(scene, overrides, n):
    """(counters, CPU seconds, nominal seconds of the code's rates) of ``n`` replicas."""
    config = resolve_config(scene, overrides)
    runs = Replicas(scene, config, stream_rng(0, STREAM_SAMPLING))
    runs.run(1)                                    # warm: caches
    before, nominal0 = dict(vars(runs.transport.stats)), runs.transport.nominal_seconds()
    t0 = time.process_time()
    runs.run(n)
    cpu = time.process_time() - t0
    after = vars(runs.transport.stats)
    counts = np.array([after[k] - before[k] for k in lookin.NOMINAL_SECONDS], dtype=float)
    return counts, cpu, runs.transport.nominal_seconds() - nominal0


def measure_quadrature(scene, overrides, edge):
    """(counters, CPU seconds, nominal seconds of the code's rates) of one level at ``edge``: the quadrature's
    set-up on the planned scene and its run."""
    config = resolve_config(scene, overrides)
    config = config.with_estimator(**config.estimator.at_edge(edge))
    rng = stream_rng(0, STREAM_SAMPLING)
    warm = Replicas(scene, config, rng)            # plans the scene; compiles and caches the kernels
    warm.run(1)
    t0 = time.process_time()
    runs = Replicas(scene, config, rng, planned=warm.planned)
    runs.run(1)
    cpu = time.process_time() - t0
    q = runs.transport
    counted = [q.stats] + ([q.refine_stats] if getattr(q, "refine_stats", None) is not None else [])
    counts = np.array([sum(getattr(st, k) for st in counted) for k in quadrature.NOMINAL_SECONDS], dtype=float)
    return counts, cpu, q.nominal_seconds()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("estimator", choices=["lookin", "quadrature"])
    parser.add_argument("--quick", action="store_true", help="every third run only")
    parser.add_argument("--rooms", type=int, default=3, help="sampled rooms per dataset config")
    args = parser.parse_args()
    if args.estimator == "lookin":
        runs, measure, features = lookin_runs(args.rooms), measure_lookin, tuple(lookin.NOMINAL_SECONDS)
    else:
        runs, measure, features = quadrature_runs(args.rooms), measure_quadrature, tuple(quadrature.NOMINAL_SECONDS)
    rows, cpus, names, nominals = [], [], [], []
    for k, (label, scene, overrides, n) in enumerate(runs):
        if args.quick and k % 3:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            counts, cpu, nominal = measure(scene, overrides, n)
        rows.append(counts), cpus.append(cpu), names.append(label), nominals.append(nominal)
        print(f"{label}: CPU {cpu:.3f} s, nominal {nominal:.3f} s", flush=True)
    a, b = np.array(rows), np.array(cpus)
    scale = 1.0 / b                                    # relative errors: every run weighs the same
    rates, _ = nnls(a * scale[:, None], b * scale)
    rel = a @ rates / b - 1.0
    print("\nrates (seconds per unit):")
    for key, rate in zip(features, rates):
        print(f"    {key!r}: {rate:.2g},")
    print(f"{len(b)} runs, CPU {b.min():.3f}-{b.max():.3f} s; relative residual RMS {np.sqrt(np.mean(rel ** 2)):.1%}, "
          f"worst {np.abs(rel).max():.1%} ({names[int(np.argmax(np.abs(rel)))]})")
    ratio = np.array(nominals) / b
    print(f"the rates in NOMINAL_SECONDS now: nominal / CPU {ratio.min():.2f}-{ratio.max():.2f}, "
          f"median {np.median(ratio):.2f}")
    for label, r, cpu in zip(names, rel, b):
        print(f"    {r:+7.1%}  {cpu:7.3f} s  {label}")


if __name__ == "__main__":
    main()
