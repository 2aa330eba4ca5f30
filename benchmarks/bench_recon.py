"""The reconstruction benchmark (issue 27): every baseline on every suite variant, scored by ``datagen suite score``.

    python benchmarks/bench_recon.py [--suites a,b] [--venv /opt/venvs/tal-bench] [--no-docs]

1. Builds each suite of configs/suites/ that is missing under benchmarks/out/suites/NAME (``datagen suite build``,
   2 workers) and checks its content hash against the suite file when one is recorded.
2. For each variant (clean: the envelope; low-photon: the SPAD counts) and each test sample, reconstructs a depth
   map on the wall-view grid with
     trivial  the training mean: the mean label depth over the object pixels of the suite's train split
     fbp      tal.reconstruct.fbp (filtered backprojection)                      [tal venv, benchmarks/tal/recon_side.py]
     lct      datagen.analysis.lct (light-cone transform; y-tal 0.20 has none)   [confocal]
     fk       tal.reconstruct.fk (f-k migration)                                  [tal venv; confocal]
     rsd      phasor-field RSD: datagen.analysis.phasor on confocal scans (tal's fails there),
              tal.reconstruct.pf_dev on the single-sensor scans                  [tal venv for the latter]
   Each method's depth is that of the strongest voxel of each pixel's column (the volume's argmax along the wall
   normal) within the suite's depth range (Z_RANGE). Solve times per sample are recorded (tal's: the solve alone, not its import).
3. Scores each predictions file with :func:`datagen.dataset.suite_score.score_suite`, checks datagen's RSD against
   tal's pf_dev on the same single-sensor captures (depth within one voxel on the object pixels), and writes the
   leaderboard into docs/benchmark.md (between its RESULTS markers) and one figure per suite,
   docs/benchmark_<suite>.png (labels beside each method's depth map, clean variant, the first three test samples
   with object pixels).

Everything is cached under benchmarks/out/recon/ (or --cache: exported captures, each method's predictions): a
second run only scores and writes. Delete a method's .npz to recompute it.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from datagen.analysis.lct import depth_from_volume, lct_volume  # noqa: E402
from datagen.analysis.phasor import phasor_rsd  # noqa: E402
from datagen.dataset import NLOSDataset, read_card  # noqa: E402
from datagen.dataset.export import sample_result  # noqa: E402
from datagen.dataset.suite import build_suite, content_hash, load_suite, suite_names  # noqa: E402
from datagen.dataset.suite_score import score_suite  # noqa: E402
from datagen.io import write_tal_hdf5  # noqa: E402
from datagen.units import SPEED_OF_LIGHT  # noqa: E402

OUT = HERE / "out"
RECON = OUT / "recon"
"""The cache of exported captures and predictions (--cache)."""
METHODS = ["trivial", "fbp", "lct", "fk", "rsd"]
IMPL = {"trivial": "training mean", "fbp": "tal.reconstruct.fbp", "lct": "datagen.analysis.lct",
        "fk": "tal.reconstruct.fk", "rsd": "datagen.analysis.phasor (confocal) / tal.reconstruct.pf_dev (single sensor)"}
BINS_PER_PLANE = 3
"""Depth planes of fbp / RSD volumes: every 3 time bins' worth of depth (c·Δt/2 each)."""
Z_RANGE = {"wall-meshes-v1": (0.3, 1.8), "single-pixel-v1": (0.3, 1.8), "confocal-rooms-v1": (0.2, 3.5)}
"""Depths (m from the wall) the fbp / RSD volumes span: the suites' hidden objects."""
FIGURE_SAMPLES = 3
PF_DEV_CHECK = False
"""--pf-dev-check: also run tal's pf_dev on test sample 0 of each single-sensor suite (≈ 9 min per scan on this
machine) and compare datagen's RSD with it."""


def pf_wavelength(pitch: float, bin_width: float) -> float:
    """The phasor filter's central wavelength (m): benchmarks/tal/recon_side.py's (4 grid spacings, at least 4 bins
    of path length), so datagen's RSD and tal's fbp / pf_dev filter alike."""
    return max(4 * pitch, 4 * SPEED_OF_LIGHT * bin_width)


def depth_planes(suite: str, bin_width: float) -> np.ndarray:
    lo, hi = Z_RANGE[suite]
    dz = BINS_PER_PLANE * SPEED_OF_LIGHT * bin_width / 2
    return lo + dz * np.arange(int((hi - lo) / dz) + 1)


def ensure_suite(name: str) -> Path:
    path = OUT / "suites" / name
    suite = load_suite(name)
    card = read_card(path) if (path / "zarr.json").exists() else {}
    if card.get("status") != "complete":
        t0 = time.perf_counter()
        _, digest = build_suite(name, path, workers=2, resume=(path / "zarr.json").exists(), progress=False)
        print(f"{name}: built in {time.perf_counter() - t0:.0f} s, content sha256 {digest}", flush=True)
    else:
        digest = content_hash(path)
    if suite.spec.content_sha256 not in (None, digest):
        raise SystemExit(f"{name}: content hash {digest} differs from the suite file's {suite.spec.content_sha256}")
    return path


def training_mean(path: Path, split: str) -> float:
    ds = NLOSDataset(path, split=split, fields=["wall_depth"])
    depths = [ds.read(i)["wall_depth"] for i in range(len(ds))]
    values = np.concatenate([d[d > 0] for d in depths])
    return float(values.mean())


def tal_side(files: list[Path], methods: list[str], planes: np.ndarray, out: Path, venv: Path) -> None:
    env = {**os.environ, "HOME": str(OUT / "tal-home")}
    (OUT / "tal-home").mkdir(parents=True, exist_ok=True)
    env_sh = venv / "env.sh"
    if env_sh.exists() and "DRJIT_LIBLLVM_PATH" not in env:
        for line in env_sh.read_text().splitlines():
            if line.startswith("export DRJIT_LIBLLVM_PATH="):
                env["DRJIT_LIBLLVM_PATH"] = line.split("=", 1)[1].strip('"')
    dz = float(planes[1] - planes[0])
    cmd = [str(venv / "bin" / "python"), str(HERE / "tal" / "recon_side.py"), "--methods", ",".join(methods),
           "--depths", str(planes[0]), str(dz), str(len(planes)), "--out", str(out), "--files", *map(str, files)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"recon_side.py failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")


def run_variant(name: str, path: Path, variant: str, field: str, mean: float, venv: Path) -> dict:
    """Every method's predictions file for one suite variant (cached): {method: path}."""
    suite = load_suite(name)
    split = suite.spec.test_split
    n = suite.config.splits[split].count
    folder = RECON / name / variant
    folder.mkdir(parents=True, exist_ok=True)
    ds = NLOSDataset(path, split=split, fields=["wall_depth"])
    shape = ds.read(0)["wall_depth"].shape
    results = [sample_result(path, split, i, field) for i in range(n)]
    edges = results[0].time_edges
    dt = float(edges[1] - edges[0])
    confocal = results[0].attrs["capture"]["type"] == "confocal"
    planes = depth_planes(name, dt)
    files = {}

    def save(method, depth, seconds, extra=None):
        p = folder / f"{method}.npz"
        np.savez(p, depth=np.asarray(depth, np.float32), index=np.arange(n))
        (folder / f"{method}.json").write_text(json.dumps({"seconds": list(map(float, seconds)), **(extra or {})}))
        files[method] = p

    if not (folder / "trivial.npz").exists():
        save("trivial", np.full((n, *shape), mean), [0.0] * n, {"training_mean_m": mean})
    files["trivial"] = folder / "trivial.npz"
    # tal's methods, one subprocess for the variant
    tal_methods = ["fbp", "fk"] if confocal else ["fbp"]
    todo = [m for m in tal_methods if not (folder / f"{'rsd' if m == 'pf' else m}.npz").exists()]
    if todo:
        hdf5 = []
        for i, res in enumerate(results):
            f = folder / "hdf5" / f"{i}.hdf5"
            if not f.exists():
                f.parent.mkdir(exist_ok=True)
                write_tal_hdf5(res, f)
            hdf5.append(f)
        t0 = time.perf_counter()
        tal_side(hdf5, todo, planes, folder / "tal.npz", venv)
        print(f"{name}/{variant}: tal {','.join(todo)} in {time.perf_counter() - t0:.0f} s", flush=True)
        r = np.load(folder / "tal.npz")
        for m in todo:
            key = "rsd" if m == "pf" else m
            save(key, np.swapaxes(r[f"depth_{m}"], 1, 2), r[f"seconds_{m}"],
                 {"implementation": f"tal.reconstruct.{'pf_dev' if m == 'pf' else m}"})
    for m in ("fbp", "fk", "rsd"):
        if (folder / f"{m}.npz").exists():
            files[m] = folder / f"{m}.npz"
    if confocal:
        half = float(np.linalg.norm(results[0].sensor_points[0, -1] - results[0].sensor_points[0, 0]))
        for m in ("lct", "rsd"):
            if (folder / f"{m}.npz").exists():
                files[m] = folder / f"{m}.npz"
                continue
            depths, seconds = [], []
            for res in results:
                pts = res.sensor_points
                pitch = float(np.linalg.norm(pts[0, 1] - pts[0, 0]))
                scan = res.envelope
                t0 = time.perf_counter()
                if m == "lct":
                    zs = (np.arange(scan.shape[-1]) + 0.5) * SPEED_OF_LIGHT * dt / 2
                    inside = (zs >= planes[0]) & (zs <= planes[-1])     # the depth range of every method
                    vol = lct_volume(scan, dt, pitch * scan.shape[1] / 2)
                    d, _ = depth_from_volume(vol[..., inside], zs[inside])
                else:
                    d, _ = depth_from_volume(phasor_rsd(scan, dt, pitch, planes, pf_wavelength(pitch, dt),
                                                       t_start=float(edges[0])), planes)
                seconds.append(time.perf_counter() - t0)
                depths.append(d)
            save(m, depths, seconds, {"implementation": IMPL[m] if m == "lct" else "datagen.analysis.phasor",
                                      "half_width_m": half})
            print(f"{name}/{variant}: {m} {np.mean(seconds):.2f} s per sample", flush=True)
    elif not (folder / "rsd.npz").exists():   # ours on the single-sensor scans too (tal's pf_dev: ~9 min per scan)
        depths, seconds = [], []
        for res in results:
            lp = res.laser_points
            pitch = float(np.linalg.norm(lp[0, 1] - lp[0, 0]))
            s = res.sensor_points.reshape(-1, 3)[0]
            vox = lp[:, :, None, :] + planes[None, None, :, None] * res.wall_normal
            leg = np.linalg.norm(vox - s, axis=-1)
            t0 = time.perf_counter()
            vol = phasor_rsd(res.envelope.reshape(*lp.shape[:2], -1), dt, pitch, planes, pf_wavelength(pitch, dt),
                             t_start=float(edges[0]), sensor_leg=leg)
            seconds.append(time.perf_counter() - t0)
            depths.append(depth_from_volume(vol, planes)[0])
        save("rsd", depths, seconds, {"implementation": "datagen.analysis.phasor"})
    if not confocal:
        files["rsd"] = folder / "rsd.npz"
        if PF_DEV_CHECK and variant == "clean" and not (folder / "pf_dev_0.npz").exists():
            t0 = time.perf_counter()
            tal_side([folder / "hdf5" / "0.hdf5"], ["pf"], planes, folder / "pf_dev_0.npz", venv)
            print(f"{name}/{variant}: tal pf_dev on test 0 in {time.perf_counter() - t0:.0f} s", flush=True)
    return files


def agreement(a: Path, b: Path, path: Path, split: str, voxel: float) -> float:
    """Fraction of object pixels whose depths in prediction files a and b differ by at most one voxel."""
    da, db = np.load(a)["depth"], np.load(b)["depth"]
    ds = NLOSDataset(path, split=split, fields=["wall_depth"])
    masks = np.stack([ds.read(i)["wall_depth"] > 0 for i in range(len(da))])
    return float((np.abs(da - db)[masks] <= voxel * 1.0001).mean())


def figure(name: str, path: Path, files: dict, out_png: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    suite = load_suite(name)
    ds = NLOSDataset(path, split=suite.spec.test_split, fields=["wall_depth"])
    methods = [m for m in METHODS if m in files and m != "trivial"]
    preds = {m: np.load(files[m])["depth"] for m in methods}
    fig = Figure(figsize=(2.3 * (len(methods) + 1), 2.3 * FIGURE_SAMPLES + 0.4), layout="constrained")
    axes = fig.subplots(FIGURE_SAMPLES, len(methods) + 1, squeeze=False)
    shown = [i for i in range(len(ds)) if (ds.read(i)["wall_depth"] > 0).any()][:FIGURE_SAMPLES]
    for r, i in enumerate(shown):
        label = ds.read(i)["wall_depth"]
        mask = label > 0
        lo, hi = (label[mask].min(), label[mask].max()) if mask.any() else (0.0, 1.0)
        lo, hi = lo - 0.1, hi + 0.1
        panels = [("label", np.where(mask, label, np.nan))] + [
            (m, np.where(mask, preds[m][i], np.nan)) for m in methods]
        for c, (title, img) in enumerate(panels):
            ax = axes[r, c]
            im = ax.imshow(img, origin="lower", vmin=lo, vmax=hi, cmap="viridis")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{title} (test {i})" if c == 0 else title, fontsize=8)
        fig.colorbar(im, ax=axes[r, -1], shrink=0.8, label="depth (m)")
    fig.suptitle(f"{name}, clean variant: depth on the object pixels (label left)", fontsize=9)
    fig.savefig(out_png, dpi=80)


def write_docs(rows: list[dict], checks: dict, build_info: dict) -> None:
    doc = ROOT / "docs" / "benchmark.md"
    text = doc.read_text()
    start, end = "<!-- RESULTS START (benchmarks/bench_recon.py) -->", "<!-- RESULTS END -->"
    lines = [start, "", "| suite | variant | method | implementation | depth MAE (m) | depth RMSE (m) | δ < 1.25 | "
             "δ < 1.25² | samples with objects | s per sample |", "| --- | --- | --- | --- | ---: | ---: | ---: | "
             "---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['suite']} | {r['variant']} | {r['method']} | {r['implementation']} | "
                     f"{r['mae']:.4f} | {r['rmse']:.4f} | {r['delta1']:.3f} | {r['delta2']:.3f} | "
                     f"{r['depth_samples']} | {r['seconds']:.2f} |")
    lines += ["", "Suites as built for this table (content sha256 of every stored array):", ""]
    for name, info in build_info.items():
        lines.append(f"- `{name}`: `{info['sha256']}`, training mean depth {info['mean']:.4f} m")
    lines += ["", "Checks of datagen's own implementations against tal's on the same captures:", ""]
    for k, v in checks.items():
        lines.append(f"- {k}: {v}")
    lines += ["", end]
    if start in text and end in text:
        text = text[:text.index(start)] + "\n".join(lines) + text[text.index(end) + len(end):]
    else:
        text += "\n" + "\n".join(lines) + "\n"
    doc.write_text(text)


def main() -> None:
    global PF_DEV_CHECK, RECON
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--suites", default=None, help="comma-separated (default: every suite)")
    p.add_argument("--venv", type=Path, default=Path(os.environ.get("TAL_BENCH_VENV", "/opt/venvs/tal-bench")))
    p.add_argument("--no-docs", action="store_true", help="do not write docs/benchmark.md and its figures")
    p.add_argument("--cache", type=Path, default=RECON, help="cache folder of captures and predictions")
    p.add_argument("--pf-dev-check", action="store_true",
                   help="run tal's pf_dev on test 0 of the single-sensor suites (slow) to check datagen's RSD")
    a = p.parse_args()
    PF_DEV_CHECK, RECON = a.pf_dev_check, a.cache
    t_all = time.perf_counter()
    names = a.suites.split(",") if a.suites else suite_names()
    rows, checks, build_info = [], {}, {}
    for name in names:
        suite = load_suite(name)
        path = ensure_suite(name)
        mean = training_mean(path, suite.spec.train_split)
        build_info[name] = {"sha256": content_hash(path), "mean": mean}
        for variant, spec in suite.spec.variants.items():
            files = run_variant(name, path, variant, spec.input, mean, a.venv)
            for m in METHODS:
                if m not in files:
                    continue
                s = score_suite(files[m], path, name, variant)["summary"]
                info = json.loads(files[m].with_suffix(".json").read_text())
                impl = info.get("implementation", IMPL[m])
                rows.append({"suite": name, "variant": variant, "method": m, "implementation": impl,
                             "mae": s["mean_depth_mae"], "rmse": s["mean_depth_rmse"],
                             "delta1": s["mean_delta_1.25"], "delta2": s["mean_delta_1.562"],
                             "depth_samples": s["depth_samples"], "seconds": float(np.mean(info["seconds"]))})
            if variant == "clean" and not a.no_docs:
                figure(name, path, files, ROOT / "docs" / f"benchmark_{name}.png")
            dt = float(read_card(path)["time_edges"]["bin_width"])
            plane = float(np.diff(depth_planes(name, dt))[0])
            pf_dev = RECON / name / variant / "pf_dev_0.npz"
            if pf_dev.exists() and "rsd" in files:
                theirs = RECON / name / variant / "pf_dev_0_depth.npz"
                np.savez(theirs, depth=np.swapaxes(np.load(pf_dev)["depth_pf"], 1, 2))
                mine = RECON / name / variant / "rsd_0_depth.npz"
                np.savez(mine, depth=np.load(files["rsd"])["depth"][:1])
                files["pf_dev_0"], files["rsd_0"] = theirs, mine
            if "fk" in files:      # confocal: our RSD against tal's fbp (same filter), our LCT against tal's fk
                pairs = [(files.get("rsd"), "fbp", "datagen.analysis.phasor",
                          "tal.reconstruct.fbp (the same phasor filter, backprojected)", plane),
                         (files.get("lct"), "fk", "datagen.analysis.lct", "tal.reconstruct.fk (tal has no LCT)",
                          SPEED_OF_LIGHT * dt / 2)]
            else:                  # single sensor: our RSD against tal's pf_dev on test 0
                pairs = [(files.get("rsd_0"), "pf_dev_0", "datagen.analysis.phasor (test 0)",
                          "tal.reconstruct.pf_dev (test 0)", plane)]
            for mine, other, what, against, voxel in pairs:
                if mine is not None and other in files:
                    frac = agreement(mine, files[other], path, suite.spec.test_split, voxel)
                    checks[f"{name} {variant}: {what} against {against}"] = (
                        f"depth within one voxel ({voxel * 100:.1f} cm) on {frac:.1%} of the object pixels")
        print(f"{name}: done ({time.perf_counter() - t_all:.0f} s so far)", flush=True)
    RECON.mkdir(parents=True, exist_ok=True)
    (RECON / "results.json").write_text(json.dumps({"rows": rows, "checks": checks, "suites": build_info},
                                                           indent=1))
    for r in rows:
        print(f"{r['suite']:<18} {r['variant']:<10} {r['method']:<8} MAE {r['mae']:.4f} RMSE {r['rmse']:.4f} "
              f"δ1 {r['delta1']:.3f} {r['seconds']:.2f} s/sample")
    for k, v in checks.items():
        print(f"{k}: {v}")
    if not a.no_docs:
        write_docs(rows, checks, build_info)
    print(f"total {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
