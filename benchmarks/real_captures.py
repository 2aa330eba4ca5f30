"""datagen against the Stanford LCT release's captures, per capture: the baselines' depths and the matched
simulation's distance (docs/real.md).

    python benchmarks/real_captures.py FOLDER [--out DIR] [--methods lct phasor fbp] [--only NAME ...]

FOLDER holds the release's ``data_*.mat`` files (the project never ships them; the release is published with
O'Toole, Lindell & Wetzstein, Nature 555, 338 (2018)). For each file with a scene file
``scene_library/stanford_<name>.yaml`` it runs, as a user would:

1. ``datagen import-capture FILE --bin-resolution 4ps`` (the release's bins);
2. ``datagen reconstruct STORE --method M`` for each method, and reads the median depth it prints;
3. ``datagen estimate-capture STORE`` (the two-tail IRF, background and gain maps, docs/detector.md);
4. ``datagen simulate SCENE --like STORE --detector EST/detector.yaml``;
5. ``datagen compare-capture STORE SIM --gain direct`` and reads its hidden-signal figures (docs/capture_io.md),
   the power of the direct counts its gain took among them.

It prints one table row per capture (with the second round trip of the real and the simulated scan where it falls
inside the record: :func:`datagen.analysis.second_round_trip.second_round_trip`, docs/real.md) and, when both dot
charts are present, their hidden-count ratio (bins 600–1899 of 4 ps less the per-bin floor of bins 1900–2047, the
measure of the release's README), and the real one again with the direct light's slow tail taken out
(:func:`datagen.analysis.hidden_ratio.hidden_count_ratio`): the simulations carry no direct light, so theirs is
compared with that one. Wall times are of this machine, one run each.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from datagen.analysis.hidden_ratio import hidden_count_ratio, release_hidden_counts
from datagen.units import SPEED_OF_LIGHT

ROOT = Path(__file__).resolve().parents[1]
DEPTHS = {"dot_chart_40cm": 0.40, "dot_chart_65cm": 0.65, "resolution_chart_40cm": 0.40, "resolution_chart_65cm": 0.65,
          "diffuse_s": 0.50}
"""Reference depths (m): the charts' nominal distances (their file names), the diffuse "S" where the release's
script puts it."""

FIGURES = {   # compare-capture's hidden-signal lines → (name, pattern)
    "rel_l2": r"relative L2 \(scan-summed hidden\) ([0-9.]+) \(noise floor ([0-9.]+)",
    "edge": r"leading edge sim - real over \d+ points: median ([-+0-9.]+) ps",
    "map_r": r"hidden-count maps: correlation ([-0-9.]+)",
    "gain_power": r"direct counts to the power ([0-9.]+)",
    "fwhm": r"return FWHM: real ([0-9.]+) ps, sim ([0-9.]+) ps",
}


def datagen(*args) -> str:
    """Run ``datagen args`` in a subprocess; its output, or SystemExit with its last lines on failure."""
    proc = subprocess.run([sys.executable, "-m", "datagen.cli", *map(str, args)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"datagen {' '.join(map(str, args))} failed:\n{(proc.stdout + proc.stderr)[-800:]}")
    return proc.stdout + proc.stderr


def scan(store: Path, expected: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(data (ny, nx, K) float64, time edges (K+1,) s) of a store: its counts (a capture), or with ``expected`` a
    simulation's expected envelope (its counts when it has none)."""
    from datagen.io.lab_formats import read_capture_store
    result, _ = read_capture_store(store)
    counts = np.asarray(result.counts)
    data = result.envelope if expected or not counts.any() else counts
    return np.asarray(data, dtype=np.float64), np.asarray(result.time_edges, dtype=np.float64)


def summed(store: Path) -> np.ndarray:
    """(K,) float64: a store's counts summed over the scan."""
    data, _ = scan(store)
    return data.reshape(-1, data.shape[-1]).sum(axis=0)


def echo(store: Path, expected: bool = False):
    """The second round trip of a store's scan (real: with its counting noise from 100 Poisson redraws), or None
    when it falls too late in the record to be measured."""
    from datagen.analysis.second_round_trip import second_round_trip
    data, edges = scan(store, expected)
    try:
        return second_round_trip(data, edges, draws=0 if expected else 100, rng=np.random.default_rng(0))
    except ValueError:
        return None


def one_capture(mat: Path, scene: Path, work: Path, methods: list[str]) -> dict:
    """The figures of one capture (module doc); stores under ``work``."""
    name = mat.stem.removeprefix("data_")
    real, est, sim = work / f"real_{name}", work / f"est_{name}", work / f"sim_{name}"
    datagen("import-capture", mat, "--bin-resolution", "4ps", "--out", real)
    row = {"capture": name}
    for method in methods:
        out = datagen("reconstruct", real, "--method", method, "--out", work / f"recon_{name}_{method}")
        found = re.search(r"median depth ([0-9.]+) m", out)
        row[method] = float(found.group(1)) if found else float("nan")
    datagen("estimate-capture", real, "--out", est)
    t0 = time.perf_counter()
    datagen("simulate", scene, "--like", real, "--detector", est / "detector.yaml", "--out", sim, "--quiet")
    row["sim_s"] = time.perf_counter() - t0
    out = datagen("compare-capture", real, sim, "--gain", "direct", "--png", work / f"compare_{name}.png")
    for key, pattern in FIGURES.items():
        found = re.search(pattern, out)
        row[key] = tuple(float(g) for g in found.groups()) if found else None
    row["summed"] = summed(real)
    row["hidden"] = (release_hidden_counts(row["summed"]), release_hidden_counts(summed(sim)))
    row["echo"] = (echo(real), echo(sim, expected=True))
    return row


def far_onset(depth: float, margin: float = 0.05, bin_width: float = 4e-12) -> int:
    """The bin before which a confocal capture of an object ``depth`` m from the wall holds no hidden light: its
    round trip from ``margin`` m nearer (the chart's tilt, its dots' extent and the IRF's core fit inside 5 cm)."""
    return int(2 * (depth - margin) / SPEED_OF_LIGHT / bin_width)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the release's data_*.mat files")
    parser.add_argument("--out", type=Path, default=None, help="keep the stores here (default: a temporary folder)")
    parser.add_argument("--methods", nargs="+", default=["lct"], choices=["lct", "phasor", "fbp"])
    parser.add_argument("--only", nargs="+", default=None, help="capture names, e.g. dot_chart_40cm")
    args = parser.parse_args()
    mats = sorted(args.folder.glob("data_*.mat"))
    if not mats:
        raise SystemExit(f"{args.folder}: no data_*.mat files (the Stanford LCT release's captures)")
    work = args.out or Path(tempfile.mkdtemp(prefix="real_captures_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for mat in mats:
        name = mat.stem.removeprefix("data_")
        scene = ROOT / "scene_library" / f"stanford_{name}.yaml"
        if (args.only and name not in args.only) or not scene.is_file():
            continue
        rows.append(one_capture(mat, scene, work, args.methods))
        r = rows[-1]
        depths = ", ".join(f"{m} {r[m]:.4f} m" for m in args.methods)
        ref = f" (reference {DEPTHS[name]:.2f} m)" if name in DEPTHS else ""
        l2, edge, map_r, fwhm = r["rel_l2"], r["edge"], r["map_r"], r["fwhm"]
        power = f"to the power {r['gain_power'][0]:.2f}" if r["gain_power"] else "as they are, their power not read"
        print(f"{name}: depth {depths}{ref}; simulate --like {r['sim_s']:.0f} s; hidden relative L2 {l2[0]:.3f} "
              f"(noise floor {l2[1]:.3f}); leading edge {edge[0]:+.1f} ps; map correlation {map_r[0]:.3f} (gain: the "
              f"direct counts {power}); FWHM real "
              f"{fwhm[0]:.0f} ps, sim {fwhm[1]:.0f} ps ({fwhm[1] / fwhm[0] - 1:+.1%})", flush=True)
        er, es = r["echo"]
        if er is not None and es is not None:
            print(f"  second round trip: real {er.size:.3%} of the main return (noise {er.size_sd:.3%}) at "
                  f"{er.time * 1e9:.3f} ns (noise {er.time_sd * 1e12:.0f} ps), sim {es.size:.3%} at "
                  f"{es.time * 1e9:.3f} ns: size {es.size / er.size - 1:+.0%}, time {(es.time - er.time) * 1e12:+.0f} ps",
                  flush=True)
    charts = {r["capture"]: r for r in rows}
    if {"dot_chart_40cm", "dot_chart_65cm"} <= set(charts):
        near, far = charts["dot_chart_40cm"], charts["dot_chart_65cm"]
        (r40, s40), (r65, s65) = near["hidden"], far["hidden"]
        ratio = hidden_count_ratio(near["summed"], far["summed"], far_onset(DEPTHS["dot_chart_65cm"]))
        low, high = ratio.hidden_range
        print(f"hidden counts 40 cm / 65 cm: real {r40 / r65:.2f} by the release's measure, {ratio.hidden:.3f} with "
              f"the direct light's slow tail taken out ({low:.3f}–{high:.3f} by its extrapolation; the tail "
              f"{ratio.tail_share[0]:.1%} / {ratio.tail_share[1]:.1%} of the windows, its shape on the two charts "
              f"{ratio.shape_check:.3f} apart); simulated {s40 / s65:.3f} (no direct light simulated: "
              f"{s40 / s65 / ratio.hidden - 1:+.1%} against the hidden light alone)")
    print(f"stores and comparison PNGs in {work}")


if __name__ == "__main__":
    main()
