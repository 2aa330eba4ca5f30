"""tal's reconstructions of exported benchmark samples (issue 27). Runs in the SEPARATE tal venv of setup_env.sh
(y-tal 0.20); benchmarks/bench_recon.py calls it as a subprocess, once per suite variant:

    recon_side.py --files a.hdf5 b.hdf5 ... --methods fbp,fk,pf --depths Z0 DZ NZ --out depths.npz

For each tal HDF5 capture (``datagen export-tal``) and method it reconstructs a volume over the wall-view grid
(the scan grid for a confocal capture, the laser grid for a single-sensor exhaustive one) times NZ depths
Z0 + k·DZ along the wall normal, and keeps the depth of each pixel's strongest voxel. Writes ``depth_<method>``
(N, Sx, Sy) metres, ``peak_<method>`` (N, Sx, Sy) the strongest |voxel| and ``seconds_<method>`` (N,) the solve time.

Methods (y-tal 0.20's ``tal.reconstruct``):
  fbp  tal.reconstruct.fbp (backprojection of the phasor-filtered H, filter wavelength pf_wavelength: 4 grid spacings, at
       least 4 bins of path length)
  pf   tal.reconstruct.pf_dev (phasor-field RSD, Liu et al. 2019; same filter, camera at t = 0), non-confocal
       captures only: pf_dev refuses confocal captures and tal.reconstruct.pf stops with an AttributeError in its
       propagator (y-tal 0.20), so confocal captures get datagen's own (datagen.analysis.phasor)
  fk   tal.reconstruct.fk (f-k migration, Lindell et al. 2019; confocal only). tal's fk takes the half-width of
       the scan from sensor_grid_xyz[-1, -1, 0], i.e. it assumes the wall in the plane z = 0 centred on the origin;
       a datagen capture's wall is x = relay_x, so the grid is first expressed in the wall's own frame (u, v, 0)
       (nothing else changes). Its volume's depth k is (k + ½)·delta_t/2 (t_start 0); the depth map keeps the
       strongest voxel between the first and the last of the --depths, like the other methods.
A confocal capture first gets tal.reconstruct.compensate_laser_cos_dsqr (for datagen's aperture convention with a
co-located sensor it undoes the wall → sensor leg's cos/d², docs/scans.md "Checks"), unless it records no laser
position (a lab file's, e.g. the LCT release's rectified counts that benchmarks/real_low_light.py exports: nothing
to undo, and tal's compensation needs the position); a single-sensor exhaustive capture needs none (its sensor
leg is one constant factor).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def pf_wavelength(spacing: float, delta_l: float) -> float:
    """Central wavelength (m) of the phasor filter: 4 grid spacings, and at least 4 bins of path length (tal's
    filter needs λ > (1 + 1/√2)·2·Δl to stay below the Nyquist frequency)."""
    return max(4 * spacing, 4 * delta_l)


def wall_frame(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, u, v) of a (Sx, Sy, 3) wall grid: u along its first axis, v along its second."""
    c = grid.reshape(-1, 3).mean(0)
    u = grid[-1, 0] - grid[0, 0]
    v = grid[0, -1] - grid[0, 0]
    return c, u / max(np.linalg.norm(u), 1e-12), v / max(np.linalg.norm(v), 1e-12)


def solve_one(path: str, methods: list[str], depths: np.ndarray) -> dict:
    import tal
    from tal.enums import CameraSystem, VolumeFormat

    d = tal.io.read_capture(path)
    d.H = np.asarray(d.H, dtype=np.float64)
    confocal = bool(d.is_confocal())
    if confocal:
        if np.shape(d.laser_xyz) == (3,):               # an empty dataset reads as h5py.Empty: no position
            tal.reconstruct.compensate_laser_cos_dsqr(d)
        grid, normal = np.asarray(d.sensor_grid_xyz), np.asarray(d.sensor_grid_normals)[0, 0]
    else:
        grid, normal = np.asarray(d.laser_grid_xyz), np.asarray(d.laser_grid_normals)[0, 0]
    spacing = float(np.linalg.norm(grid[1, 0] - grid[0, 0]))
    vol = grid[:, :, None, :] + depths[None, None, :, None] * normal          # (Sx, Sy, Z, 3)
    out = {}
    for m in methods:
        t0 = time.perf_counter()
        if m == "fk":
            if not confocal:
                continue
            c, u, v = wall_frame(grid)
            local = np.stack([(grid - c) @ u, (grid - c) @ v, np.zeros(grid.shape[:2])], axis=-1)
            saved = d.sensor_grid_xyz, d.laser_grid_xyz
            d.sensor_grid_xyz = d.laser_grid_xyz = local                     # is_confocal() compares the two
            try:
                rec = np.abs(tal.reconstruct.fk.solve(d))                    # (T, Sx, Sy)
            finally:
                d.sensor_grid_xyz, d.laser_grid_xyz = saved
            z = (np.arange(len(rec)) + 0.5) * float(d.delta_t) / 2 + float(d.t_start) / 2
            inside = (z >= depths[0]) & (z <= depths[-1])      # the same depth range as the other methods
            k = np.argmax(rec[inside], axis=0)
            depth = z[inside][k]
            peak = rec[inside].max(axis=0)
        else:
            kw = dict(volume_xyz=vol, volume_format=VolumeFormat.X_Y_Z_3, progress=False)
            wl = pf_wavelength(spacing, float(d.delta_t))
            if m == "fbp":
                rec = tal.reconstruct.fbp.solve(d, wl_mean=wl, wl_sigma=wl / np.sqrt(2),
                                                camera_system=CameraSystem.DIRECT_LIGHT, **kw)
            elif m == "bp":
                rec = tal.reconstruct.bp.solve(d, camera_system=CameraSystem.DIRECT_LIGHT, **kw)
            elif m == "pf":
                if confocal:
                    continue
                # nt given explicitly: pf_dev 0.20 sizes its padded axis from the nt argument (None by default)
                rec = tal.reconstruct.pf_dev.solve(d, wl_mean=wl, wl_sigma=wl / np.sqrt(2), nt=d.H.shape[0],
                                                   camera_system=CameraSystem.DIRECT_LIGHT, **kw)
            else:
                raise SystemExit(f"unknown method {m!r}")
            rec = np.abs(np.asarray(rec)).reshape(vol.shape[:3])
            depth = depths[np.argmax(rec, axis=2)]
            peak = rec.max(axis=2)
        print(f"{path}: {m} {time.perf_counter() - t0:.2f} s", flush=True)
        out[m] = (depth.astype(np.float32), peak.astype(np.float32), time.perf_counter() - t0)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--files", nargs="+", required=True)
    p.add_argument("--methods", required=True)
    p.add_argument("--depths", type=float, nargs=3, required=True, metavar=("Z0", "DZ", "NZ"))
    p.add_argument("--out", required=True)
    a = p.parse_args()
    methods = a.methods.split(",")
    depths = a.depths[0] + a.depths[1] * np.arange(int(a.depths[2]))
    results = [solve_one(f, methods, depths) for f in a.files]
    arrays = {}
    for m in methods:
        if all(m in r for r in results):
            arrays[f"depth_{m}"] = np.stack([r[m][0] for r in results])
            arrays[f"peak_{m}"] = np.stack([r[m][1] for r in results])
            arrays[f"seconds_{m}"] = np.array([r[m][2] for r in results])
    np.savez(a.out, **arrays)
    print(json.dumps({"methods": sorted(k[6:] for k in arrays if k.startswith("depth_")), "files": len(a.files)}))


if __name__ == "__main__":
    main()
