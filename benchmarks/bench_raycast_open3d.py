"""Ray casting: embreex (datagen's RayCaster) against open3d's RaycastingScene on the transport's own rays.

The rays are every batch the lookin estimator casts in one ``simulate`` of the demonstration room (recorded
by wrapping ``RayCaster.intersect`` and ``RayCaster.visible`` while it runs, one worker): the lookins and
their hemispherical cameras (first hits) and the shadow rays (occlusion: laser shadows of the observed
points, sensor visibility of the FoV points, the secondary's connections). Each backend then replays the same
batches, in the same float32 centred coordinates, and is timed (best of ``--repeat`` rounds, every backend
once per round, so that load from other processes hits them alike):

- embreex raw: ``EmbreeScene.run`` on the float32 rays (what Embree itself costs; datagen uses this BVH);
- embreex via RayCaster: datagen's public ``intersect`` / ``visible`` (adds the float64 hit refinement);
- open3d ``RaycastingScene.cast_rays`` / ``test_occlusions`` with 1 and 2 threads (Embree 4 inside, its own
  threading).

Agreement: the fraction of rays with the same hit face (first hits) and the same verdict (occlusion).

    python benchmarks/bench_raycast_open3d.py            # 16x16 lookins x 60x60 pixels, exact secondary
    python benchmarks/bench_raycast_open3d.py --quick    # 8x8 x 30x30, one repeat
    python benchmarks/bench_raycast_open3d.py --subdivide 4   # every triangle split into 4**4 (BVH scaling)

It only measures (issue 15): datagen would offer open3d as a ray-casting backend only if it were faster here,
and it is not. Measured on the 2-core machine while other jobs loaded it (load average 5-8; 4 runs of the
default, --repeat 7, interleaved): open3d's cast_rays took 0.93-1.07× embreex's time on the 900 367 first-hit
rays with 1 thread and 0.95-1.16× with 2; test_occlusions 1.00-1.56× and 0.99-1.98× on the 298 899 shadow rays;
at its best it would change a whole simulate by -0.6 % to +2.3 %. Both give the same hit face and verdict on
every ray. Two threads do not help batches of ~24 000 rays, and ``--workers 2`` already uses both cores.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

from datagen.scene import RayCaster, Scene, load_scene  # noqa: E402
from datagen.simulation import resolve_config, simulate  # noqa: E402

SCENE = Path(__file__).resolve().parent.parent / "scene_library" / "demo_room.yaml"


def subdivided(scene: Scene, levels: int) -> Scene:
    """The scene with every triangle split into 4**levels (same surfaces, more triangles: BVH scaling)."""
    objects = []
    for o in scene.objects:
        v, f = o.vertices, o.faces
        for _ in range(levels):
            tri = v[f]                                                    # (F, 3, 3)
            mid = 0.5 * (tri + np.roll(tri, -1, axis=1))                  # edge midpoints 01, 12, 20
            parts = [np.stack([tri[:, 0], mid[:, 0], mid[:, 2]], 1), np.stack([mid[:, 0], tri[:, 1], mid[:, 1]], 1),
                     np.stack([mid[:, 2], mid[:, 1], tri[:, 2]], 1), np.stack([mid[:, 0], mid[:, 1], mid[:, 2]], 1)]
            soup = np.concatenate(parts)
            v, f = soup.reshape(-1, 3), np.arange(3 * len(soup)).reshape(-1, 3)
        objects.append(replace(o, vertices=v, faces=f))
    return replace(scene, objects=objects)


def record_rays(scene: Scene, overrides: dict) -> tuple[list, list, float]:
    """Run ``simulate`` once, recording the arguments of every RayCaster.intersect and .visible call.

    Returns:
        (intersect calls [(origins, directions)], visible calls [(p, n_p, q, n_q)], wall time of the run s).
    """
    calls: dict[str, list] = {"intersect": [], "visible": []}
    original = {name: getattr(RayCaster, name) for name in calls}

    def recording(name):
        def method(self, *args):
            calls[name].append(tuple(None if a is None else np.array(a) for a in args))
            return original[name](self, *args)
        return method

    for name in calls:
        setattr(RayCaster, name, recording(name))
    try:
        t0 = time.perf_counter()
        simulate(scene, resolve_config(scene, {**overrides, "workers": 1}))
        seconds = time.perf_counter() - t0
    finally:
        for name, method in original.items():
            setattr(RayCaster, name, method)
    return calls["intersect"], calls["visible"], seconds


def float32_rays(caster: RayCaster, calls: list) -> list[tuple[np.ndarray, np.ndarray]]:
    """First-hit batches as RayCaster.intersect hands them to Embree: centred float32 (n, 3) origins and
    directions."""
    out = []
    for origins, directions in calls:
        shape = np.broadcast_shapes(origins.shape, directions.shape)
        o = np.broadcast_to((origins - caster.center).astype(np.float32), shape).reshape(-1, 3)
        out.append((np.ascontiguousarray(o), np.ascontiguousarray(directions.astype(np.float32).reshape(shape)
                                                                  .reshape(-1, 3))))
    return out


def float32_segments(caster: RayCaster, calls: list) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Shadow-ray batches as RayCaster.visible hands them to Embree: centred float32 start points (n, 3),
    unit directions (n, 3) and lengths (n,) stopping ``offset`` short of the far end."""
    out = []
    for p, n_p, q, n_q in calls:
        a = (p - caster.center + (0 if n_p is None else caster.offset * n_p)).astype(np.float32)
        b = (q - caster.center + (0 if n_q is None else caster.offset * n_q)).astype(np.float32)
        shape = np.broadcast_shapes(a.shape, b.shape)
        seg = np.broadcast_to(b - a, shape).reshape(-1, 3)
        a = np.broadcast_to(a, shape).reshape(-1, 3)
        length = np.linalg.norm(seg, axis=1)
        ok = length > caster.offset
        d = seg[ok] / length[ok, None]
        out.append((np.ascontiguousarray(a[ok]), np.ascontiguousarray(d.astype(np.float32)),
                    (length[ok] - np.float32(caster.offset)).astype(np.float32)))
    return out


def best_of(repeat: int, func) -> tuple[float, object]:
    """(smallest wall time in s over ``repeat`` calls, the last result)."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lookins", default="16x16")
    ap.add_argument("--pixels", default="60x60")
    ap.add_argument("--secondary", default="exact")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", type=Path, default=SCENE, help="scene YAML (default: the demo room)")
    ap.add_argument("--subdivide", type=int, default=0, help="split every triangle into 4**K (more triangles)")
    ap.add_argument("--quick", action="store_true", help="8x8 lookins x 30x30 pixels, one repeat")
    args = ap.parse_args()
    if args.quick:
        args.lookins, args.pixels, args.repeat = "8x8", "30x30", 1
    import embreex.mesh_construction as mesh_construction
    import embreex.rtcore_scene as rtcore_scene
    import open3d as o3d

    scene = load_scene(args.scene)
    if args.subdivide:
        scene = subdivided(scene, args.subdivide)
    first, shadow, run_s = record_rays(scene, {"lookins": args.lookins, "pixels": args.pixels,
                                               "secondary": args.secondary, "estimator": "lookin"})
    caster = RayCaster(scene)
    rays, segments = float32_rays(caster, first), float32_segments(caster, shadow)
    n_rays, n_seg = sum(len(o) for o, _ in rays), sum(len(a) for a, _, _ in segments)
    print(f"{args.scene.name}: {len(caster.faces):,} triangles; simulate --lookins {args.lookins} --pixels "
          f"{args.pixels} --secondary {args.secondary} (1 worker, {run_s:.2f} s) cast {len(rays)} first-hit batches "
          f"({n_rays:,} rays) and {len(segments)} shadow batches ({n_seg:,} rays)")

    tri32 = (caster.vertices[caster.faces] - caster.center).astype(np.float32)
    embree = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(embree, tri32)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles((caster.vertices - caster.center).astype(np.float32), caster.faces.astype(np.uint32))
    o3d_rays = [o3d.core.Tensor(np.concatenate([o, d], axis=1)) for o, d in rays]
    o3d_segs = [o3d.core.Tensor(np.concatenate([a, d * t[:, None]], axis=1)) for a, d, t in segments]
    rs.cast_rays(o3d_rays[0][:1])                                     # builds open3d's BVH (not timed)

    # every backend once per round, rounds repeated: load from other processes hits them alike
    backends = {
        ("first hit", "embreex raw (EmbreeScene.run)"):
            lambda: [embree.run(o, d, output=1)["primID"] for o, d in rays],
        ("first hit", "embreex via RayCaster.intersect"): lambda: [caster.intersect(o, d) for o, d in first],
        ("occlusion", "embreex raw (EmbreeScene.run)"):
            lambda: [embree.run(a, d, dists=tm, query="OCCLUDED") for a, d, tm in segments],
        ("occlusion", "embreex via RayCaster.visible"): lambda: [caster.visible(*c) for c in shadow],
    }
    for threads in (1, 2):
        label = f"{threads} thread{'s' * (threads > 1)}"
        backends["first hit", f"open3d cast_rays, {label}"] = \
            lambda n=threads: [rs.cast_rays(r, nthreads=n)["primitive_ids"].numpy() for r in o3d_rays]
        backends["occlusion", f"open3d test_occlusions, {label}"] = \
            lambda n=threads: [rs.test_occlusions(g, tnear=0.0, tfar=1.0, nthreads=n).numpy() for g in o3d_segs]
    best = {key: np.inf for key in backends}
    out = {}
    for _ in range(args.repeat):
        for key, func in backends.items():
            t, out[key] = best_of(1, func)
            best[key] = min(best[key], t)
    rows = [(kind, name, best[kind, name], n_rays if kind == "first hit" else n_seg)
            for kind in ("first hit", "occlusion") for name in [k[1] for k in backends if k[0] == kind]]
    raw, vis = out["first hit", "embreex raw (EmbreeScene.run)"], out["occlusion", "embreex raw (EmbreeScene.run)"]
    o3d_face = {n: out["first hit", f"open3d cast_rays, {n} thread{'s' * (n > 1)}"] for n in (1, 2)}
    o3d_occ = {n: out["occlusion", f"open3d test_occlusions, {n} thread{'s' * (n > 1)}"] for n in (1, 2)}

    miss = np.iinfo(np.uint32).max
    same_face = np.mean(np.concatenate([np.where(f == miss, -1, f.astype(np.int64)) == r
                                        for f, r in zip(o3d_face[2], raw)]))
    same_verdict = np.mean(np.concatenate([(o == 0) == (e == -1) for o, e in zip(o3d_occ[2], vis)])) if n_seg else 1.0
    print(f"\n{'rays':<10} {'backend':<36} {'time':>9} {'Mrays/s':>8} {'vs embreex raw':>15}")
    for kind, name, t, n in rows:
        ref = next(tr for k, nm, tr, _ in rows if k == kind and nm.startswith("embreex raw"))
        print(f"{kind:<10} {name:<36} {t:8.3f}s {n / t * 1e-6:8.2f} {t / ref:14.2f}×")
    print(f"\nsame hit face: {same_face:.4%} of first hits; same occlusion verdict: {same_verdict:.4%}")
    overrides = {"lookins": args.lookins, "pixels": args.pixels, "secondary": args.secondary, "estimator": "lookin",
                 "workers": 1}
    plain, _ = best_of(args.repeat, lambda: simulate(scene, resolve_config(scene, overrides)))
    embree_s = sum(best[k, n] for k, n in backends if n.startswith("embreex raw"))
    caster_s = sum(best[k, n] for k, n in backends if n.startswith("embreex via"))
    open3d_s = sum(min(best[k, n] for kk, n in backends if kk == k and n.startswith("open3d"))
                   for k in ("first hit", "occlusion"))
    print(f"the whole simulate (1 worker, not recording): {plain:.3f} s; its RayCaster calls {caster_s:.3f} s "
          f"({caster_s / plain:.0%}), of which Embree {embree_s:.3f} s; open3d at its best would change the run "
          f"by {(open3d_s - embree_s) / plain:+.1%}")


if __name__ == "__main__":
    main()
