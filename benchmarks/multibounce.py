"""Light of every order: what it costs and how close it lands (docs/accuracy.md, "Light of every order").

For each scene and seeds 0…N−1 (``--seeds``; the replicas a seed's tolerance loop lands on vary, so one seed's cost
is luck): ``simulate_to_tolerance`` with the area estimator at the tolerance, once at orders 1–2 without the planner's pilot
(:func:`estimator_alone`: the old model's cost) and once with ``orders: auto`` (the planner's pilot adds every order ≥ 3
when the scene calls for it), CPU seconds of each measured in this one run and summed over the seeds; then a converged all-order reference (the same
unbiased estimators, the deep orders unsmoothed (``multibounce: {smoothing: false}``), at a tolerance four times tighter, a different seed) and the actual relative L2 distance of each
result to it on 1 ns bins (IRF applied), against the result's stated error.

    python benchmarks/multibounce.py [--tolerance 0.01] [--scenes a.yaml b.yaml ...] [--paths N] [--seeds 4]
        [--albedo 0.9]
    python benchmarks/multibounce.py --dataset configs/datasets/default.yaml [--split train] [--samples 8]
    python benchmarks/multibounce.py --reference configs/datasets/confocal.yaml [--split test] [--index 0]
        [--rel-tol 0.01] [--budget 600]

``--dataset``: the per-sample CPU of a dataset build (``make_sample`` of the first samples of a split, at the
config's tolerance and cost cap), with the estimator's own orders alone (1–2, or 1 beside a quadrature whose
secondary is off; no pilot: :func:`estimator_alone`) and with ``orders: auto``, both in this run, and each sample's
stated error and multibounce share.
"""
from __future__ import annotations

import argparse
import contextlib
import time
from unittest import mock

import numpy as np

import datagen
from datagen.simulation.tolerance import simulate_to_tolerance

SAMPLES = 16384
"""The first round: 2 replicas of 8192 hidden samples, as the dataset configs' (``default.yaml``); the tolerance loop
adds replicas of that size until the estimate meets the tolerance, so the cost is what 1 % asks for, not what a
larger first round happens to spend."""

SCENES = ["scene_library/demo_room.yaml", "scene_library/office_room.yaml", "scene_library/closed_corridor.yaml"]


def rebin(y: np.ndarray, edges: np.ndarray, width: float = 1e-9) -> np.ndarray:
    """Sum the bins of y (..., T) into bins of ``width`` seconds (the last partial one dropped)."""
    k = max(1, int(round(width / (edges[1] - edges[0]))))
    t = (y.shape[-1] // k) * k
    return y[..., :t].reshape(y.shape[:-1] + (t // k, k)).sum(-1)


def rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def estimator_alone():
    """A context in which a fixed ``orders`` of 1 or 2 runs no pilot (the planner's ``order_shares`` gives None):
    what the estimator's own orders cost, with nothing of orders ≥ 3 measured, as before ``orders`` existed."""
    return mock.patch("datagen.planner.decisions.order_shares", return_value=None)


def with_albedo(scene_file: str, albedo: float | None):
    """The scene of ``scene_file``, with every material's albedo set to ``albedo`` when given (a brighter room of
    the same geometry: the issue's closed corridor at 0.9)."""
    if albedo is None:
        return datagen.load_scene(scene_file)
    import yaml
    from pathlib import Path
    from datagen.scene.load import scene_from_dict

    def bright(node):
        if isinstance(node, dict):
            return {k: (albedo if k == "albedo" else bright(v)) for k, v in node.items()}
        return [bright(v) for v in node] if isinstance(node, list) else node

    data = bright(yaml.safe_load(Path(scene_file).read_text()))
    return scene_from_dict(data, source=f"{scene_file} (every albedo {albedo:g})", base=Path(scene_file).parent)


def run(scene_file: str, tolerance: float, paths: int, seeds: int = 4, albedo: float | None = None):
    scene = with_albedo(scene_file, albedo)
    warm = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 512}, "orders": "auto",
                                          "replicas": 2})
    datagen.simulate(scene, warm)             # compiled kernels loaded before any timing
    out = []
    for seed in range(seeds):                 # the replicas a seed's loop lands on vary: the cost is their sum
        for orders in (2, "auto"):
            cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": SAMPLES}, "replicas": 2,
                                                 "multibounce": {"paths": paths}, "seed": seed, "orders": orders})
            t = time.process_time()
            with estimator_alone() if orders == 2 else contextlib.nullcontext():
                r = simulate_to_tolerance(scene, cfg, tolerance)
            out.append((seed, orders, r, time.process_time() - t))
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 65536}, "orders": "auto",
                                         "multibounce": {"paths": paths, "smoothing": False},
                                         "seed": 1000})
    t = time.process_time()
    ref = simulate_to_tolerance(scene, cfg, tolerance / 4, max_replicas=4096)
    t_ref = time.process_time() - t
    edges = ref.time_edges
    ref_env = rebin(ref.envelope, edges)
    rows = []
    for seed, orders, r, cpu in out:
        share = r.components.get("multibounce", np.zeros(1)).sum() / r.envelope.sum()
        rows.append((seed, orders, cpu, r.attrs["error"]["rel_l2"], rel_l2(rebin(r.envelope, edges), ref_env), share,
                     r.attrs["error"].get("smoothing"), r.attrs["tolerance"]["met"]))
    ref_share = ref.components["multibounce"].sum() / ref.envelope.sum() if "multibounce" in ref.components else 0
    return rows, (t_ref, ref.attrs["error"]["rel_l2"], ref_share)


def dataset_costs(path: str, split: str, samples: int) -> None:
    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import make_sample
    config = load_dataset_config(path)
    old = {k: v for k, v in config.simulation.items() if k != "orders"}
    alone = 1 if (old.get("effects") or {}).get("secondary") is False else 2   # the estimator's own orders
    variants = {"orders 1-2": config.model_copy(update={"simulation": {**old, "orders": alone}}),
                "auto": config.model_copy(update={"simulation": {**old, "orders": "auto"}})}
    make_sample(variants["auto"], split, 0)                 # compiled kernels loaded before any timing
    print(f"{path} ({split}, samples 0–{samples - 1}): CPU s per sample in this run")
    print("| sample | orders | CPU s | envelope_error | multibounce share |")
    print("|---|---|---|---|---|")
    totals = {}
    for i in range(samples):
        for name, cfg in variants.items():
            t = time.process_time()
            with estimator_alone() if name != "auto" else contextlib.nullcontext():
                s = make_sample(cfg, split, i)
            cpu = time.process_time() - t
            totals[name] = totals.get(name, 0.0) + cpu
            share = s.orders.get("multibounce_share", 0.0) if s.orders else 0.0
            print(f"| {i} | {name} | {cpu:.2f} | {float(s.arrays['envelope_error']):.2%} | {share:.1%} |", flush=True)
    print(f"mean per sample: orders 1-2 {totals['orders 1-2'] / samples:.2f} s, auto {totals['auto'] / samples:.2f} s: "
          f"{totals['auto'] / totals['orders 1-2']:.2f}×")


def sample_against_reference(path: str, split: str, index: int, rel_tol: float = 0.01,
                             budget: float = 600.0) -> None:
    """``datagen.converged_reference`` of one dataset sample (every order the config asks for, every core, at most
    ``budget`` seconds) and the sample's stored envelope and stated error against it."""
    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import make_sample
    from datagen.simulation.replicas import relative_difference
    config = load_dataset_config(path)
    scene, sim = datagen.sample_setup(config, split, index)
    t = time.perf_counter()
    ref = datagen.converged_reference(scene, sim, rel_tol=rel_tol, max_seconds=budget, min_replicas=4)
    wall = time.perf_counter() - t
    e = ref.error_estimate
    print(f"{path} {split} {index}: reference ({ref.settings['sampler']}) {ref.replicas} replicas, {wall:.0f} s wall "
          f"({ref.seconds:.0f} CPU-s), error {e['rel_l2']:.2%} (Monte Carlo {e.get('monte_carlo', e['rel_l2']):.2%}, "
          f"quadrature {e.get('refinement') or 0:.2%}), converged to {rel_tol:.2%}: {ref.converged}")
    s = make_sample(config, split, index)
    env = np.asarray(s.arrays["envelope"], dtype=np.float64).reshape(ref.envelope.shape)
    actual = relative_difference(env, ref.envelope, ref.envelope)
    stated = float(s.arrays["envelope_error"])
    print(f"stored envelope: stated {stated:.2%}, actual {actual:.2%} against the reference "
          f"({'within' if actual <= stated else 'above'} its stated error; the reference's own {e['rel_l2']:.2%})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerance", type=float, default=0.01)
    ap.add_argument("--paths", type=int, default=None, help="multibounce.paths (default: the config's default)")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 per scene: the cost is their sum")
    ap.add_argument("--albedo", type=float, default=None, help="set every material's albedo (e.g. 0.9)")
    ap.add_argument("--dataset", help="a dataset config: per-sample cost of its build with orders: auto")
    ap.add_argument("--split", default="train")
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--reference", help="a dataset config: one sample against converged_reference (--split, --index)")
    ap.add_argument("--index", type=int, default=0)
    ap.add_argument("--rel-tol", type=float, default=0.01, help="--reference: the reference's target error")
    ap.add_argument("--budget", type=float, default=600.0, help="--reference: its most wall seconds")
    a = ap.parse_args()
    if a.reference:
        sample_against_reference(a.reference, a.split, a.index, a.rel_tol, a.budget)
        return
    if a.dataset:
        dataset_costs(a.dataset, a.split, a.samples)
        return
    print(f"tolerance {a.tolerance:.2%}, area estimator, multibounce.paths {a.paths or 'default'}, seeds "
          f"0–{a.seeds - 1}{f', every albedo {a.albedo:g}' if a.albedo is not None else ''}; CPU s in this run")
    print("| scene | seed | orders | CPU s | stated error (smoothing bias in it) | actual rel L2 vs all orders (1 ns) | "
          "orders ≥ 3 share |")
    print("|---|---|---|---|---|---|---|")
    summary = []
    for f in a.scenes:
        name = f.split('/')[-1]
        rows, (t_ref, ref_err, ref_share) = run(f, a.tolerance, a.paths, a.seeds, a.albedo)
        for seed, orders, cpu, stated, actual, share, smooth, met in rows:
            bias = f" ({smooth:.2%})" if smooth is not None else ""
            print(f"| {name} | {seed} | {orders} | {cpu:.2f} | {stated:.2%}{bias}{'' if met else ' NOT met'} | "
                  f"{actual:.2%} | {share:.1%} |", flush=True)
        print(f"| {name} | — | reference | {t_ref:.1f} | {ref_err:.2%} | — | {ref_share:.1%} |", flush=True)
        cpu = {o: sum(r[2] for r in rows if r[1] == o) for o in (2, "auto")}
        worst = max(r[4] / r[3] for r in rows if r[1] == "auto")
        summary.append(f"| {name} | {cpu[2] / a.seeds:.2f} | {cpu['auto'] / a.seeds:.2f} | {cpu['auto'] / cpu[2]:.2f}× | "
                       f"{max(r[4] for r in rows if r[1] == 'auto'):.2%} | {worst:.2f} |")
    print("\n| scene | orders 1–2 CPU s (mean) | all orders CPU s (mean) | cost ratio | worst actual | "
          "worst actual / stated |")
    print("|---|---|---|---|---|---|")
    print("\n".join(summary))

if __name__ == "__main__":
    main()
