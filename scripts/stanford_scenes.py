"""Write the Stanford LCT release's scenes as datagen scene files (scene_library/stanford_*.yaml), read off
datagen's own reconstructions of the release's captures (docs/real.md).

Usage: PYTHONPATH=. python scripts/stanford_scenes.py [FOLDER]   (FOLDER: the release's data_*.mat files; default
$DATAGEN_REAL_CAPTURES or ../shared/real). The files are not shipped; the scene files this writes are.

Each capture is read as ``datagen import-capture --bin-resolution 4ps`` reads it, reconstructed as ``datagen
reconstruct --method lct`` does as shipped (t² falloff, snr 0.8: on the diffuse "S" too, whose t⁴ reconstruction is
noisier; only its outline and depth are read here), and:
- the dot charts become nine disks (diameter read off the front view's half maximum, less the reconstruction's blur)
  on a grid of 0.10 m about the centre the front view gives, on the plane fitted to the depth map over the dots;
- the other scenes become a mask of the front view (the reconstruction's maximum over depth, smoothed over one
  pitch for the noisy diffuse "S", at :data:`MASK_LEVEL` of its maximum) on a plane fitted to the depth map where
  it found something (the "S U": one plane per letter).
Everything is in the frame of an imported LCT capture (docs/capture_io.md, "Orientation"): the wall y = 0, the
hidden side +y, columns along +x, rows up +z; so ``simulate --like`` puts the scan points exactly where the import
has them.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from datagen.units import SPEED_OF_LIGHT

ROOT = Path(__file__).resolve().parents[1]
MASK_LEVEL = 0.5
DISK_PITCH = 0.0025           # m: the cells of the charts' disks
CHART_SPACING = 0.10          # m: the dots' spacing (the front views give 0.097–0.101)

SCENES = {  # file: (capture, width, falloff, snr, material, what the paper says)
    "stanford_dot_chart_40cm": ("data_dot_chart_40cm.mat", "retroreflective", 0.8,
                                "the release's dot chart, 40 cm from the wall (retroreflective)"),
    "stanford_dot_chart_65cm": ("data_dot_chart_65cm.mat", "retroreflective", 0.8,
                                "the same dot chart, 65 cm from the wall (retroreflective)"),
    "stanford_diffuse_s": ("data_diffuse_s.mat", "retroreflective", 0.8, "a white diffuse (Lambertian) letter S"),
    "stanford_s_u": ("data_s_u.mat", "retroreflective", 0.8, "the letters S and U (retroreflective)"),
    "stanford_exit_sign": ("data_exit_sign.mat", "retroreflective", 0.8,
                           "an exit sign, 0.61 m x 0.61 m (retroreflective; its text and arrow are not)"),
}

RETRO = {"kind": "retroreflective", "albedo": 0.9, "specular": 0.9, "lobe_width": 0.005}
"""The retroreflective scenes' sheeting. Its lobe width agrees with published road-sign sheeting figures
(docs/physics.md, "Retroreflective"): ASTM D4956's minimum coefficients of retroreflection of sheeting Types I–III
fall from 0.2° to 0.5° of observation angle to 0.38–0.43, as a GGX lobe of α = 0.005 does. The release does not say
which sheeting its charts, letters and sign are."""

CHART_SHEETING = {**RETRO, "entrance_falloff": 2}
"""The sheeting of every retroreflective scene: :data:`RETRO` with an entrance-angle falloff cos^2, fitted with
:data:`CHART_SETUP` on the two dot-chart captures (docs/real.md "The set-up fitted on the dot charts": the 40 / 65 cm
hidden-count ratio wants the falloff, the return's width and relative L2 want it small; the road-sign tables' m is
3.6–6.0). The letters and the sign are assumed to be of the charts' sheeting (the release does not say)."""

CHART_SETUP = {"wall_albedo": 0.41, "detector_fov": "35mm"}
"""The set-up fitted on the two dot-chart captures (docs/real.md, "The set-up fitted on the dot charts"): the
detector's field of view on the wall (``capture.detector_fov``; with the sheeting's falloff it sets the 40 / 65 cm
hidden-count ratio, real 1.79) and the wall's albedo (the second round trip: real 0.42 % of the main return); with
them :data:`PHOTONS` of the charts. Every scene has it: one scanner and one wall (the "S U"'s two letters, 0.64 and
1.04 m out, test it: docs/real.md)."""
DIFFUSE = {"kind": "lambertian", "albedo": 0.8}


def reconstruct(path: Path, falloff: str, snr: float):
    from datagen.analysis.confocal import align_confocal
    from datagen.analysis.reconstruct import confocal_volume, depth_map
    from datagen.io.lab_formats import read_lab_capture

    cap = read_lab_capture(path, bin_resolution=4e-12)
    width = float(np.squeeze(cap.raw["width"]))
    n = cap.data().shape[0]
    pitch = 2 * width / (n - 1)
    scan, dt = align_confocal(cap.data(), cap.time_edges(), cap.time_offsets())
    vol, depths, _ = confocal_volume(scan, dt, pitch, "lct", falloff, snr, background=None)   # the floor kept,
    # as the shipped scene files were read off
    depth, front = depth_map(vol, depths, pedestal=None)   # a share of the maximum, as the scene files were read
    return width, pitch, front, depth


def rows_of(mask: np.ndarray) -> list[str]:
    return ["".join("#" if c else "." for c in r) for r in mask[::-1]]


class Plane(NamedTuple):
    """An object's plane read off a depth map: depth ≈ d0 + a·u + b·v (m; u, v on the wall), ``rms`` m off it."""
    d0: float
    a: float
    b: float
    rms: float

    def depth_at(self, u: float, v: float) -> float:
        return self.d0 + self.a * u + self.b * v

    @property
    def tilt(self) -> float:
        """Degrees off parallel to the wall."""
        return float(np.degrees(np.arctan(np.hypot(self.a, self.b))))

    def frame(self) -> tuple[list[float], list[float]]:
        """Unit u, v of the plane y = d0 + a x + b z (v made perpendicular to u), rounded to 1e-6."""
        u = np.array([1.0, self.a, 0.0]) / np.hypot(1.0, self.a)
        v = np.array([0.0, self.b, 1.0])
        v = v - (v @ u) * u
        v /= np.linalg.norm(v)
        return [round(float(x), 6) for x in u], [round(float(x), 6) for x in v]


def plane(depth: np.ndarray, found: np.ndarray, g: np.ndarray) -> Plane:
    """The least-squares plane of the (n, n) depth map over the points ``found`` (bool), rows along v and columns
    along u at the scan's positions ``g`` (n,) m."""
    v, u = np.meshgrid(g, g, indexing="ij")
    A = np.column_stack([np.ones(found.sum()), u[found], v[found]])
    coef, *_ = np.linalg.lstsq(A, depth[found], rcond=None)
    rms = float(np.sqrt(np.mean((A @ coef - depth[found]) ** 2)))
    return Plane(float(coef[0]), float(coef[1]), float(coef[2]), rms)


def chart(front: np.ndarray, depth: np.ndarray, width: float, pitch: float):
    """Nine disks: (centre (u, v), diameter m, mask (ny, nx), mask centre, depth m, notes)."""
    n = front.shape[0]
    g = np.linspace(-width, width, n)
    lab, k = ndimage.label(front > 0.3 * front.max())
    cents, diams = [], []
    for i in range(1, k + 1):
        sel = lab == i
        if sel.sum() < 5:
            continue
        w = front * sel
        cy, cx = ndimage.center_of_mass(w)
        m = sel & (front >= 0.5 * front[sel].max())
        cents.append((np.interp(cx, np.arange(n), g), np.interp(cy, np.arange(n), g)))
        diams.append(2 * np.sqrt(m.sum() * pitch ** 2 / np.pi))
    cents = np.array(cents)
    # the grid's centre: each dot's offset from the nearest grid node, averaged (merged blobs skipped by the median)
    c0 = np.median(cents - np.round((cents - np.median(cents, 0)) / CHART_SPACING) * CHART_SPACING, axis=0)
    blur = 3e8 * 60e-12 * np.nanmedian(depth) / (2 * width)          # the LCT's lateral resolution, c·FWHM·z/(2w)
    diam = float(np.sqrt(max(np.median(diams) ** 2 - blur ** 2, (0.5 * np.median(diams)) ** 2)))
    centres = [(c0[0] + i * CHART_SPACING, c0[1] + j * CHART_SPACING) for i in (-1, 0, 1) for j in (-1, 0, 1)]
    cs = np.array(centres)
    lo, hi = cs.min(0) - diam / 2 - DISK_PITCH, cs.max(0) + diam / 2 + DISK_PITCH
    nu, nv = (int(np.ceil((hi[i] - lo[i]) / DISK_PITCH)) for i in (0, 1))
    uu = lo[0] + (np.arange(nu) + 0.5) * DISK_PITCH
    vv = lo[1] + (np.arange(nv) + 0.5) * DISK_PITCH
    U, V = np.meshgrid(uu, vv)
    mask = np.zeros(U.shape, bool)
    for c in cs:
        mask |= (U - c[0]) ** 2 + (V - c[1]) ** 2 <= (diam / 2) ** 2
    # the chart's plane, fitted to the depth map over the dots (as the cut-outs' planes are): a chart set up by hand
    # stands a degree or two off parallel to the wall, which moves each point's return by tens of ps
    fit = plane(depth, np.isfinite(depth) & (lab > 0), g)
    cu, cv = (uu[0] + uu[-1]) / 2, (vv[0] + vv[-1]) / 2
    d = fit.depth_at(cu, cv)
    notes = [f"dots: 3 x 3 disks {diam * 100:.1f} cm across (front view's half maximum {np.median(diams) * 100:.1f} "
             f"cm less the LCT's blur {blur * 100:.1f} cm; +- 1 cm), {CHART_SPACING:.2f} m apart about u = "
             f"{c0[0]:+.4f}, v = {c0[1]:+.4f} m (+- 5 mm)",
             f"plane fitted to datagen's LCT depth map over the dots: depth {d:.4f} m at the chart's centre, tilted "
             f"{fit.tilt:.1f} deg (slopes {fit.a:+.3f} along u, {fit.b:+.3f} along v), rms {fit.rms * 1000:.1f} mm off "
             "the plane (+- 2.4 mm, one 16 ps bin)"]
    return [("dot_chart", mask, DISK_PITCH, (cu, d, cv), *fit.frame(), CHART_SHEETING)], notes


def cutouts(name: str, front: np.ndarray, depth: np.ndarray, width: float, pitch: float, material: dict):
    n = front.shape[0]
    g = np.linspace(-width, width, n)
    f = ndimage.gaussian_filter(front, 1.0) if name == "stanford_diffuse_s" else front
    found = np.isfinite(depth)
    if name == "stanford_s_u":                                       # two letters at two depths
        groups = [("letter_s", found & (depth < 0.85)), ("letter_u", found & (depth >= 0.85))]
    else:
        groups = [(name.removeprefix("stanford_"), found)]
    parts, notes = [], []
    for part, region in groups:
        mask = region & (f >= MASK_LEVEL * f[region].max())          # each letter at half its own maximum
        lab, k = ndimage.label(mask)
        sizes = ndimage.sum(mask, lab, range(1, k + 1))
        sel = np.isin(lab, 1 + np.flatnonzero(sizes >= 10))          # specks of a few cells are noise
        fit = plane(depth, sel, g)
        ys, xs = np.nonzero(sel)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        cu, cv = (g[x0] + g[x1 - 1]) / 2, (g[y0] + g[y1 - 1]) / 2
        centre = (cu, fit.depth_at(cu, cv), cv)
        parts.append((part, sel[y0:y1, x0:x1], pitch, centre, *fit.frame(), material))
        notes.append(f"{part}: plane fitted to the depth map where the front view reaches {MASK_LEVEL:g} of its "
                     f"maximum (its own): depth {centre[1]:.4f} m at its centre, tilted {fit.tilt:.1f} deg (slopes "
                     f"{fit.a:+.3f} along u, {fit.b:+.3f} along v), rms {fit.rms * 1000:.0f} mm off the plane; "
                     f"outline: the front view at {MASK_LEVEL:g} of its maximum, one cell = the scan pitch "
                     f"{pitch * 1000:.2f} mm (+- a cell, and the reconstruction's blur of about 1-2 cm); cells "
                     "projected on the wall (a tilted letter is "
                     f"{100 * (1 / np.cos(np.radians(fit.tilt)) - 1):.0f} % longer across its tilt)")
    return parts, notes


def scene_text(name: str, what: str, capture: str, width: float, parts, notes, photons: float) -> str:
    lines = [f"# {what}: a scene of the Stanford LCT release (O'Toole, Lindell & Wetzstein, Nature 555, 338 (2018)),",
             f"# its capture {capture} ({2 * width:.2f} m x {2 * width:.2f} m scanned at 64 x 64, 4 ps bins). Written by",
             "# scripts/stanford_scenes.py from datagen's own LCT reconstruction of the capture (docs/real.md).",
             "# Frame: an imported LCT capture's (docs/capture_io.md, \"Orientation\"): the relay wall is y = 0, the",
             "# hidden side +y, u = +x to the right as the wall sees the scene, v = +z up.",
             "# Uncertainty:"]
    lines += [f"#   {t}" for t in notes]
    lines += ["#   laser / SPAD position, the wall's albedo, the laser's energy and the detector are not in the files:",
              "#   fitted on the two dot-chart captures (docs/real.md): the detector's field of view on the wall,",
              ("#   the wall's albedo, the sheeting's entrance falloff and photons_per_pulse; the rest assumed (below)."
               if "dot_chart" in name else
               "#   the wall's albedo and the sheeting's entrance falloff; photons_per_pulse is set so the simulated\n"
               "#   hidden counts are about the capture's; the rest assumed (below)."),
              "# Simulate the capture: datagen simulate THIS.yaml --like STORE --out DIR  (STORE: datagen import-capture",
              f"#   {capture} --bin-resolution 4ps --out STORE); compare: datagen compare-capture STORE DIR.",
              f"#   simulate --like took {SECONDS[name]} s on two cores (docs/real.md).",
              f"name: {name}", "", "objects:",
              "  - builder: quad", "    name: relay_wall", "    label: relay_wall",
              f"    corner: [{-width - 0.2:.2f}, 0.0, {-width - 0.2:.2f}]",
              f"    edge_u: [{2 * width + 0.4:.2f}, 0.0, 0.0]", f"    edge_v: [0.0, 0.0, {2 * width + 0.4:.2f}]",
              f"    material: {{kind: lambertian, albedo: {CHART_SETUP['wall_albedo']}}}      "
              + "# fitted: the charts' second round trip"]
    for part, mask, pitch, centre, u, v, mat in parts:
        lines += ["  - builder: mask", f"    name: {part}", f"    pitch: {pitch:.6g}",
                  f"    center: [{centre[0]:.5f}, {centre[1]:.5f}, {centre[2]:.5f}]",
                  f"    u: {list(u)}", f"    v: {list(v)}",
                  "    material: {" + ", ".join(f"{k}: {v}" for k, v in mat.items()) + "}",
                  "    rows:"]
        lines += [f"      - \"{r}\"" for r in rows_of(mask)]
    lines += ["", "laser:                           # beside the scene, off the hidden objects' side: no beam crosses them",
              "  emitter: [-2.5, 1.5, 0.0]", "  spot: [0.0, 0.0, 0.0]", f"  photons_per_pulse: {photons:.3g}", "",
              "sensor:", "  position: [-2.5, 1.5, 0.0]", "  aperture_radius: 20mm", "",
              "capture:                         # --like replaces the grid by the capture's (same centre)",
              "  type: confocal",
              f"  laser_grid: {{center: [0.0, 0.0, 0.0], size: [{2 * width * 64 / 63:.5f}, {2 * width * 64 / 63:.5f}], "
              "points: [64, 64]}"]
    lines += [f"  detector_fov: {CHART_SETUP['detector_fov']}              # fitted: the charts' 40 / 65 cm hidden-count ratio"]
    lines += ["", "simulation:",
              "  estimator: {kind: quadrature, " + ESTIMATOR[name]]
    lines += orders_lines(name, parts)
    lines += ["  count_laser_leg: false", "  count_sensor_leg: false",
              "  time: {t_start: 0ns, bin_width: 4ps, n_bins: 2048}   # the release's rectified bins",
              "  irf: {fwhm: 60ps}               # the paper's 60 ps; real SPADs add a slow tail (not modelled here)",
              "  detector:", "    model: poisson", "    pde: 0.3", "    dcr: 1.0e5                    # ~0.1 MHz floor",
              "    repetition_rate: 1.0e7        # assumed (not in the paper)",
              "    exposure: 100ms               # the paper's 0.1 s per point (exit sign)", ""]
    return "\n".join(lines)


RECORD_END = 2048 * 4e-12     # s: the release's rectified record (bin k a round trip of k · 4 ps)
ECHO_MARGIN = 0.5e-9          # s: record wanted after the second round trip starts (its bump, the baseline after it)
ECHO_PATHS = 4096             # light paths per scan point of the order-3 tracer (docs/real.md, "The second round trip")


def orders_lines(name: str, parts) -> list[str]:
    """The simulation block's orders: a retroreflective chart whose second round trip (laser spot → chart → wall →
    chart → FoV point, order 3) starts inside the record, 4 d / c with d its depth, simulates it with the light
    tracer (impulses unsmoothed: the echo is a few hundred ps wide); every other scene orders 1 (``secondary: none``).
    Order 2 is off: a planar chart before a planar wall has no path with two hidden vertices."""
    depth = parts[0][3][1]
    onset = 4 * depth / SPEED_OF_LIGHT
    direct = "  effects: {first_bounce: false%s}   # the direct light is not modelled (compare-capture excludes it)%s"
    if "chart" in name and onset + ECHO_MARGIN <= RECORD_END:
        return [f"  orders: 3                        # + the second round trip, chart -> wall -> chart, from "
                f"{onset * 1e9:.2f} ns (docs/real.md)",
                f"  multibounce: {{paths: {ECHO_PATHS}, smoothing: false}}   # light paths per scan point; impulses "
                "unsmoothed",
                direct % (", secondary: false", "; no order 2 (a planar chart and wall)")]
    note = (f"   # the second round trip (from {onset * 1e9:.2f} ns) is past the record's {RECORD_END * 1e9:.2f} ns"
            if "chart" in name else "")
    return ["  secondary: none" + note, direct % ("", "")]


ESTIMATOR = {
    "stanford_dot_chart_40cm": "edge: 0.01, fov_cells: 14}   # FoV cells 2.5 mm: the retroreflected cone integrated",
    "stanford_dot_chart_65cm": "edge: 0.01, fov_cells: 14}   # FoV cells 2.5 mm: the retroreflected cone integrated",
    "stanford_diffuse_s": "edge: 0.02, fov_cells: 3}   # FoV cells ~12 mm: Lambertian, smooth over the FoV",
    "stanford_s_u": "edge: 0.03, fov_cells: 8}   # FoV cells 4.4 mm (cheaper than the charts' 2.5 mm)",
    "stanford_exit_sign": "edge: 0.03, fov_cells: 8}   # FoV cells 4.4 mm (cheaper than the charts' 2.5 mm)",
}
"""The quadrature's settings per scene: cost against how finely the retroreflected cone is integrated."""

PHOTONS = {"stanford_dot_chart_40cm": 7.3e4, "stanford_dot_chart_65cm": 7.3e4, "stanford_diffuse_s": 3.1e6,
           "stanford_s_u": 4.7e4, "stanford_exit_sign": 1.0e5}
"""Photons per pulse, set so the simulated hidden counts over the 0.1 s exposure are about the capture's (the
compare-capture hidden counts of docs/real.md); not a prediction of the laser's power. The two dot-chart captures
share one value: the same set-up and laser (their direct light totals agree within 2 %), so that their simulated
40 cm / 65 cm hidden-count ratio is the model's, not a per-scene setting."""

SECONDS = {"stanford_dot_chart_40cm": 251, "stanford_dot_chart_65cm": 279, "stanford_diffuse_s": 31,
           "stanford_s_u": 1036, "stanford_exit_sign": 332}
"""Wall time of ``simulate --like`` on the 2-core machine the figures were measured on (docs/real.md; with
``--detector``, the 40 cm chart's with its second round trip; the "S U"'s with another job beside it part of the
time)."""


def main(folder: Path) -> None:
    for name, (capture, falloff, snr, what) in SCENES.items():
        path = folder / capture
        if not path.is_file():
            sys.exit(f"{path}: not found (give the folder of the release's data_*.mat files)")
        width, pitch, front, depth = reconstruct(path, falloff, snr)
        if "chart" in name:
            parts, notes = chart(front, depth, width, pitch)
        else:
            parts, notes = cutouts(name, front, depth, width, pitch,
                                  DIFFUSE if name == "stanford_diffuse_s" else CHART_SHEETING)
        out = ROOT / "scene_library" / f"{name}.yaml"
        out.write_text(scene_text(name, what, capture, width, parts, notes, PHOTONS[name]))
        print(f"wrote {out}")


if __name__ == "__main__":
    default = Path(os.environ.get("DATAGEN_REAL_CAPTURES", ROOT.parent / "shared" / "real"))
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else default)
