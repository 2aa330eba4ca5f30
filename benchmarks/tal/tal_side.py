"""The y-tal / mitransient side of the comparison. Runs in the SEPARATE venv made by setup_env.sh
(y-tal 0.20 pins numpy < 2), never in datagen's environment; compare.py calls it as a subprocess.

Commands (each prints one JSON object on its last stdout line):

  render CONFIG --spp N --seed S --out FILE.hdf5 [--mode tal|loop|native] [--threads T]
      mitransient render of a tal render YAML, written as a tal HDF5 file (tal.io.write_capture).
      tal:    ``tal render`` itself (one Mitsuba process per laser point, as users run it);
      loop:   tal's scene XML and per-point laser focusing, all in this process (no per-point process start);
      native: tal's scene XML with mitransient 1.3's own confocal capture (capture_type confocal: all points in
              one render) — mitransient's fastest way to a confocal scan; for single scans it equals ``loop``.
      --threads is the number of Dr.Jit worker threads (tal's -t N gives N - 1).
      "seconds" is the wall time of the rendering alone (scene load, JIT and render; not the Python import),
      "cpu_seconds" its CPU time over all threads (for ``tal``: the whole tal render and its child processes).
  read FILE
      tal.io.read_capture(FILE): field names, shapes, dtypes, enums and metadata, to check datagen's files load.
  bp FILE [--resolution M]
      tal.reconstruct.bp / fbp on a confocal capture (coarse volume, then a fine one around its maximum);
      the strongest voxel's position.
  bp-box FILE --lo X Y Z --hi X Y Z [--coarse M] [--resolution M] [--window M]
      the same for a confocal capture in any frame (a datagen dataset sample, scan_sample.py): coarse volume over
      the box [lo, hi], fine cube of side --window around its maximum, half-maximum centroid.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml


def _config(path: Path, spp: int) -> dict:
    from tal.config import local_file_path
    from tal.render.mitsuba3_transient_nlos import get_default_variant

    defaults = yaml.safe_load(open(local_file_path("render/scene_defaults.yaml")))
    defaults["mitsuba_variant"] = get_default_variant()
    config = {**defaults, **(yaml.safe_load(path.read_text()) or {})}
    config.pop("datagen", None)
    config["sample_count"] = int(spp)
    return config


def _capture(config: dict, H: np.ndarray, args: dict):
    """tal's NLOSCaptureData for a render, built by tal's own metadata code (as tal render does)."""
    import tal.render.render as rr

    ns = argparse.Namespace(**args)
    get_meta = getattr(rr, "_" + "_write_metadata_and_get_laser_lookats")  # module-private in tal 0.20
    scan_type, lookats, capture = get_meta(ns, config)
    capture.H = H.astype(np.float32)
    return scan_type, lookats, capture


def _to_tal(result) -> np.ndarray:
    """tal's run_mitsuba post-processing: (ny, nx, T, C) film → (T, nx, ny), channels summed."""
    result = np.array(result)
    if result.ndim == 2:
        nt, nc = result.shape
        result = result.reshape((nt, 1, 1, nc))
    result = np.moveaxis(result, 2, 0)
    result = np.swapaxes(result, 1, 2)
    if result.ndim == 4:
        result = np.sum(result, axis=-1)
    return result


def render_in_process(config_path: Path, spp: int, seed: int, mode: str, threads: int) -> tuple[np.ndarray, float, dict]:
    import mitsuba as mi

    config = _config(config_path, spp)
    from tal.render.mitsuba3_transient_nlos import get_scene_xml

    _, __, xml = get_scene_xml(config, random_seed=seed)   # (switches Mitsuba to scalar_rgb internally)
    mi.set_variant(config["mitsuba_variant"])
    import mitransient as mitr                              # registers its plugins for the current variant
    scan = config["scan_type"]
    native = mode == "native" and scan == "confocal"
    if native:
        # mitransient 1.3: one render of the whole confocal grid (film = grid, capture_type confocal)
        w, h = config["sensor_width"], config["sensor_height"]
        xml = xml.replace(f'<integer name="original_film_width" value="{w}"/>', "")
        xml = xml.replace(f'<integer name="original_film_height" value="{h}"/>', "")
        xml = xml.replace('<integer name="width" value="1"/>', f'<integer name="width" value="{w}"/>')
        xml = xml.replace('<integer name="height" value="1"/>', f'<integer name="height" value="{h}"/>')
        xml = xml.replace('<integrator type="transient_nlos_path">',
                          '<integrator type="transient_nlos_path">\n<string name="capture_type" value="confocal"/>')
    workdir = Path(tempfile.mkdtemp(prefix="tal_side_"))
    try:
        xml_path = workdir / "nlos_scene.xml"
        xml_path.write_text(xml)
        args = {"seed": seed, "threads": threads, "dry_run": False}
        _, lookats, capture = _capture(config, np.zeros(1), args)
        t0, c0 = time.perf_counter(), time.process_time()
        cwd = os.getcwd()
        os.chdir(config_path.parent)   # tal resolves mesh filenames from the working directory
        try:
            scene = mi.load_file(str(xml_path))
        finally:
            os.chdir(cwd)
        integrator = scene.integrator()
        import drjit as dr
        dr.set_thread_count(threads)   # worker threads (mitr.utils.set_thread_count(n) gives n - 1)
        relay = next(s for s in scene.shapes() if s.id() == "relay_wall")
        laser = next(e for e in scene.emitters() if e.id() == "laser")
        nt = config["num_bins"]
        if scan == "single" or native:
            lx, ly = lookats[0][2:] if scan == "single" else (config["sensor_width"] / 2, config["sensor_height"] / 2)
            mitr.nlos.focus_emitter_at_relay_wall_pixel(mi.Point2f(lx, ly), relay, laser)
            _, transient = integrator.render(scene, seed=seed)
            H = _to_tal(transient)
        elif scan == "confocal":
            H = np.zeros((nt, config["sensor_width"], config["sensor_height"]), dtype=np.float64)
            for i, (ix, iy, px, py) in enumerate(lookats):
                mitr.nlos.focus_emitter_at_relay_wall_pixel(mi.Point2f(px, py), relay, laser)
                _, transient = integrator.render(scene, seed=seed * 100003 + i)
                H[:, ix:ix + 1, iy:iy + 1] = _to_tal(transient)
        else:
            raise SystemExit(f"mode {mode} does not do {scan} scans; use --mode tal")
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return H, (seconds, cpu), config


def cmd_render(a) -> dict:
    import tal

    config_path = Path(a.config).resolve()
    out = Path(a.out).resolve()
    if a.mode == "tal":
        work = Path(tempfile.mkdtemp(prefix="tal_render_", dir=out.parent))
        cfg = yaml.safe_load(config_path.read_text())
        cfg.pop("datagen", None)
        cfg["sample_count"] = int(a.spp)
        (work / config_path.name).write_text(yaml.safe_dump(cfg, sort_keys=False))
        t0 = time.perf_counter()
        r0 = os.times()
        proc = subprocess.run([str(Path(sys.executable).parent / "tal"), "render", config_path.name, "--no-steady",
                               "--no-ground-truth", "--no-logging", "-t", str(a.threads + 1), "-s", str(a.seed)],
                              cwd=work, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        r1 = os.times()
        cpu = (r1.children_user + r1.children_system) - (r0.children_user + r0.children_system)
        files = list(work.glob("*/*.hdf5"))
        if proc.returncode != 0 or not files:
            raise SystemExit(f"tal render failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
        shutil.move(str(files[0]), out)
        shutil.rmtree(work, ignore_errors=True)
        H = tal.io.read_capture(str(out)).H
    else:
        H, (seconds, cpu), config = render_in_process(config_path, a.spp, a.seed, a.mode, a.threads)
        args = {"command": "tal_side render", "config_file": [str(config_path)], "seed": a.seed,
                "threads": a.threads, "mode": a.mode, "dry_run": False}
        _, __, capture = _capture(config, H, args)
        if config["scan_type"] == "confocal":
            capture.sensor_grid_xyz = capture.laser_grid_xyz   # the points measured (see datagen/io/tal.py)
        tal.io.write_capture(str(out), capture)
    return {"out": str(out), "seconds": seconds, "cpu_seconds": cpu, "spp": a.spp, "seed": a.seed, "mode": a.mode,
            "H_sum": float(np.sum(H, dtype=np.float64)), "shape": list(np.shape(H))}


def cmd_read(a) -> dict:
    import tal

    d = tal.io.read_capture(a.file)
    out = {}
    for key, value in d.as_dict().items():
        if isinstance(value, np.ndarray):
            out[key] = {"shape": list(value.shape), "dtype": str(value.dtype),
                        "sum": float(np.sum(value, dtype=np.float64))}
        elif hasattr(value, "name") and hasattr(value, "value"):
            out[key] = {"enum": type(value).__name__, "name": value.name, "value": int(value.value)}
        elif isinstance(value, dict):
            out[key] = {"keys": sorted(value)}
        elif isinstance(value, (np.generic,)):
            out[key] = value.item()
        else:
            out[key] = value
    out["is_confocal"] = bool(d.is_confocal())
    out["is_laser_paired_to_sensor"] = bool(d.is_laser_paired_to_sensor())
    return out


def cmd_bp(a) -> dict:
    """Backprojection (bp) and filtered backprojection (fbp) of a confocal capture: a coarse pass over
    x, y in [-0.6, 0.6], z in [0.5, 1.5] (4 cm voxels) finds the depth, then a fine pass (``--resolution``) over
    x, y in [-0.6, 0.6] and ±20 cm around that depth; the object's position is the magnitude-weighted centroid
    of the voxels above half the maximum (also reported: the strongest voxel)."""
    import tal
    from tal.enums import CameraSystem, VolumeFormat

    d = tal.io.read_capture(a.file)
    d.H = d.H.astype(np.float64)
    # the laser's cos/d² falloff from the emitter to each wall point (tal render's K_l) varies ~100x over
    # this grid; tal's own compensation removes it so the image is not pulled toward the emitter
    tal.reconstruct.compensate_laser_cos_dsqr(d)
    spacing = float(np.linalg.norm(d.sensor_grid_xyz[1, 0] - d.sensor_grid_xyz[0, 0]))

    def solve(name, vol):
        if name == "bp":
            rec = tal.reconstruct.bp.solve(d, volume_xyz=vol, volume_format=VolumeFormat.X_Y_Z_3,
                                           camera_system=CameraSystem.DIRECT_LIGHT, progress=False)
        else:
            # phasor-field (Gaussian band-pass) filter at ~4 grid spacings, tal's usual choice
            rec = tal.reconstruct.fbp.solve(d, wl_mean=4 * spacing, wl_sigma=4 * spacing / np.sqrt(2),
                                            volume_xyz=vol, volume_format=VolumeFormat.X_Y_Z_3,
                                            camera_system=CameraSystem.DIRECT_LIGHT, progress=False)
        return np.abs(rec)

    out = {"grid_spacing_m": spacing, "fine_resolution_m": a.resolution}
    for name in ("bp", "fbp"):
        t0 = time.perf_counter()
        coarse = tal.reconstruct.get_volume_min_max_resolution(np.array([-0.6, -0.6, 0.5]),
                                                               np.array([0.6, 0.6, 1.5]), 0.04)
        mag = solve(name, coarse)
        c = coarse[np.unravel_index(int(np.argmax(mag)), mag.shape)]
        # an extended object reconstructs as a plate: its position is the centroid of the strong voxels
        fine = tal.reconstruct.get_volume_min_max_resolution(np.array([-0.6, -0.6, c[2] - 0.2]),
                                                             np.array([0.6, 0.6, c[2] + 0.2]), a.resolution)
        mag = solve(name, fine)
        k = np.unravel_index(int(np.argmax(mag)), mag.shape)
        strong = mag >= 0.5 * mag.max()
        centroid = (fine[strong] * mag[strong][:, None]).sum(0) / mag[strong].sum()
        out[name] = {"coarse_argmax_xyz": c.tolist(), "argmax_xyz": fine[k].tolist(),
                     "half_max_centroid_xyz": centroid.tolist(), "strong_voxels": int(strong.sum()),
                     "seconds": time.perf_counter() - t0}
    return out


def cmd_bp_box(a) -> dict:
    """bp and fbp (see cmd_bp) of a confocal capture over the box [lo, hi]: coarse pass, then a fine cube of side
    ``--window`` around the coarse maximum; the half-maximum centroid of each."""
    import tal
    from tal.enums import CameraSystem, VolumeFormat

    d = tal.io.read_capture(a.file)
    d.H = d.H.astype(np.float64)
    # datagen's aperture convention: the wall → sensor leg falls as cos/d² from the (co-located) sensor, the same
    # form tal compensates for its laser (a confocal scan's aperture follows the laser: no cos θ_ap to undo)
    tal.reconstruct.compensate_laser_cos_dsqr(d)
    spacing = float(np.linalg.norm(d.sensor_grid_xyz[1, 0] - d.sensor_grid_xyz[0, 0]))
    lo, hi = np.array(a.lo), np.array(a.hi)
    out = {"grid_spacing_m": spacing}
    for name in ("bp", "fbp"):
        t0 = time.perf_counter()
        kwargs = {} if name == "bp" else {"wl_mean": 4 * spacing, "wl_sigma": 4 * spacing / np.sqrt(2)}

        def solve(vol):
            mod = tal.reconstruct.bp if name == "bp" else tal.reconstruct.fbp
            return np.abs(mod.solve(d, volume_xyz=vol, volume_format=VolumeFormat.X_Y_Z_3,
                                    camera_system=CameraSystem.DIRECT_LIGHT, progress=False, **kwargs))

        coarse = tal.reconstruct.get_volume_min_max_resolution(lo, hi, a.coarse)
        mag = solve(coarse)
        c = coarse[np.unravel_index(int(np.argmax(mag)), mag.shape)]
        fine = tal.reconstruct.get_volume_min_max_resolution(np.maximum(c - a.window / 2, lo),
                                                             np.minimum(c + a.window / 2, hi), a.resolution)
        mag = solve(fine)
        strong = mag >= 0.5 * mag.max()
        centroid = (fine[strong] * mag[strong][:, None]).sum(0) / mag[strong].sum()
        out[name] = {"coarse_argmax_xyz": c.tolist(), "half_max_centroid_xyz": centroid.tolist(),
                     "strong_voxels": int(strong.sum()), "seconds": time.perf_counter() - t0}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render")
    r.add_argument("config")
    r.add_argument("--spp", type=int, required=True)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--out", required=True)
    r.add_argument("--mode", choices=("tal", "loop", "native"), default="native")
    r.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    rd = sub.add_parser("read")
    rd.add_argument("file")
    b = sub.add_parser("bp")
    b.add_argument("file")
    b.add_argument("--resolution", type=float, default=0.02)
    bb = sub.add_parser("bp-box")
    bb.add_argument("file")
    bb.add_argument("--lo", type=float, nargs=3, required=True)
    bb.add_argument("--hi", type=float, nargs=3, required=True)
    bb.add_argument("--coarse", type=float, default=0.04)
    bb.add_argument("--resolution", type=float, default=0.02)
    bb.add_argument("--window", type=float, default=1.0)
    a = p.parse_args()
    result = {"render": cmd_render, "read": cmd_read, "bp": cmd_bp, "bp-box": cmd_bp_box}[a.cmd](a)
    print(json.dumps(result, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


if __name__ == "__main__":
    main()
