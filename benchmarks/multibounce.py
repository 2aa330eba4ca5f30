"""Light of every order: what it costs and how close it lands (docs/accuracy.md, "Light of every order").

For each scene: ``simulate_to_tolerance`` with the area estimator at the tolerance, once with ``orders: 2`` (primary
and secondary, the old model) and once with ``orders: auto`` (the planner's pilot adds every order ≥ 3 when the
scene calls for it), CPU seconds of each measured in this one run; then a converged all-order reference (the same
unbiased estimators, the deep orders unsmoothed (``multibounce: {smoothing: false}``), at a tolerance four times tighter, a different seed) and the actual relative L2 distance of each
result to it on 1 ns bins (IRF applied), against the result's stated error.

    python benchmarks/multibounce.py [--tolerance 0.01] [--scenes a.yaml b.yaml ...] [--paths N]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import datagen
from datagen.simulation.tolerance import simulate_to_tolerance

SCENES = ["scene_library/demo_room.yaml", "scene_library/office_room.yaml", "scene_library/closed_corridor.yaml"]


def rebin(y: np.ndarray, edges: np.ndarray, width: float = 1e-9) -> np.ndarray:
    """Sum the bins of y (..., T) into bins of ``width`` seconds (the last partial one dropped)."""
    k = max(1, int(round(width / (edges[1] - edges[0]))))
    t = (y.shape[-1] // k) * k
    return y[..., :t].reshape(y.shape[:-1] + (t // k, k)).sum(-1)


def rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def run(scene_file: str, tolerance: float, paths: int, seed: int = 0):
    scene = datagen.load_scene(scene_file)
    warm = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 512}, "orders": "auto",
                                          "replicas": 2})
    datagen.simulate(scene, warm)             # compiled kernels loaded before any timing
    out = {}
    for orders in (2, "auto"):
        cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 65536}, "orders": orders,
                                             "multibounce": {"paths": paths}, "seed": seed})
        t = time.process_time()
        r = simulate_to_tolerance(scene, cfg, tolerance)
        out[orders] = (r, time.process_time() - t)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 65536}, "orders": "auto",
                                         "multibounce": {"paths": paths, "smoothing": False},
                                         "seed": seed + 1000})
    t = time.process_time()
    ref = simulate_to_tolerance(scene, cfg, tolerance / 4, max_replicas=4096)
    t_ref = time.process_time() - t
    edges = ref.time_edges
    ref_env = rebin(ref.envelope, edges)
    rows = []
    for orders, (r, cpu) in out.items():
        share = r.components.get("multibounce", np.zeros(1)).sum() / r.envelope.sum()
        rows.append((orders, cpu, r.attrs["error"]["rel_l2"], rel_l2(rebin(r.envelope, edges), ref_env), share,
                     r.attrs["error"].get("smoothing")))
    ref_share = ref.components["multibounce"].sum() / ref.envelope.sum() if "multibounce" in ref.components else 0
    return rows, (t_ref, ref.attrs["error"]["rel_l2"], ref_share)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerance", type=float, default=0.01)
    ap.add_argument("--paths", type=int, default=None, help="multibounce.paths (default: the config's default)")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    a = ap.parse_args()
    print(f"tolerance {a.tolerance:.2%}, area estimator, multibounce.paths {a.paths or 'default'}; CPU s in this run")
    print("| scene | orders | CPU s | stated error (smoothing bias in it) | actual rel L2 vs all orders (1 ns) | "
          "orders ≥ 3 share | cost ratio |")
    print("|---|---|---|---|---|---|---|")
    for f in a.scenes:
        rows, (t_ref, ref_err, ref_share) = run(f, a.tolerance, a.paths)
        base = rows[0][1]
        for orders, cpu, stated, actual, share, smooth in rows:
            bias = f" ({smooth:.2%})" if smooth is not None else ""
            print(f"| {f.split('/')[-1]} | {orders} | {cpu:.1f} | {stated:.2%}{bias} | {actual:.2%} | {share:.1%} | "
                  f"{cpu / base:.2f}× |", flush=True)
        print(f"| {f.split('/')[-1]} | reference | {t_ref:.1f} | {ref_err:.2%} | — | {ref_share:.1%} | — |", flush=True)


if __name__ == "__main__":
    main()
