"""The near-chart check: how deep a network reads simulated charts near the wall, against LCT, before any real
capture is read (docs/real.md, "The near-chart check").

    python benchmarks/near_charts.py DATA [--network FILE.pt ...] [--split val] [--fraction 0.1] [--near 0.5]

DATA is a build of ``configs/datasets/lct_release_charts.yaml`` (the release's dot and bar charts alone, 0.3–0.7 m
from the wall, retroreflective, 0.1 s per point): ``datagen build configs/datasets/lct_release_charts.yaml --out
DATA --workers 2``. Each sample with the chart in the scan's view (``wall_depth`` > 0 somewhere) is scored as
benchmarks/real_low_light.py scores a capture:

1. **Reference.** The mask is LCT's found points on the stored counts (the full exposure,
   :func:`real_low_light.found`), the depth the label's: the median of ``wall_depth`` over its object pixels (m).
2. **Thinning.** The counts thinned binomially to ``--fraction`` of the exposure (:func:`real_low_light.thin`),
   sample i with ``numpy.random.default_rng(i)``: the same draw for every network and every run.
3. **Depths.** LCT's and each network's (:func:`real_low_light.network_depth`) median depth over the reference mask
   on the thinned counts, minus the label's depth: the signed error (m) a capture's row gives against a chart's
   nominal distance.

It prints, for the charts nearer than ``--near`` (m) and for the rest, the median signed error over the samples and
its quartiles, per method (cm). A network whose near charts read deeper than LCT's reads the release's 40 cm charts
deeper too (docs/real.md): the check ranks trainings by the simulation alone.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
from real_low_light import SHIPPED, found, labelled_scans, load_network, network_depth, score, thin  # noqa: E402


def chart_errors(data: Path, networks: dict, split: str = "val", fraction: float = 0.1) -> tuple[np.ndarray, dict]:
    """Signed depth errors (m) of LCT and each network on a build of lct_release_charts.yaml (module doc).

    Args:
        data: the dataset's folder; networks: {name: (module, record)} as ``load_model`` returns them;
        split: the split scored; fraction: the exposure's share kept by the thinning, in (0, 1].
    Returns:
        (truth, errors): truth (n,) float64, the label's median depth (m) of the n samples with the chart in view
        and a non-empty reference; errors {"lct": (n,), name: (n,) ...} float64, median depth over the reference
        mask minus truth (m), NaN where the method found nothing there.
    Raises:
        datagen.DatagenError: DATA is not a readable dataset or lacks the split.
    """
    truth, errors = [], {name: [] for name in ["lct", *networks]}
    for i, counts, label, dt, pitch in labelled_scans(data, split):
        chart = label > 0
        if not chart.any():
            continue
        reference = ~np.isnan(found(counts, dt, pitch, "lct"))
        if not reference.any():
            continue
        truth.append(float(np.median(label[chart])))
        counts = thin(counts, fraction, np.random.default_rng(i))
        errors["lct"].append(score(found(counts, dt, pitch, "lct"), reference)[0] - truth[-1])
        for name, network in networks.items():
            errors[name].append(score(network_depth(network, counts, dt, pitch)[0], reference)[0] - truth[-1])
    return np.array(truth), {name: np.array(e) for name, e in errors.items()}


def quartiles(errors: np.ndarray) -> str:
    """'median [25 %, 75 %]' of signed errors (m) in cm, NaNs left out."""
    q = np.nanpercentile(errors, [50, 25, 75]) * 100 if np.isfinite(errors).any() else [np.nan] * 3
    return f"{q[0]:+.2f} [{q[1]:+.2f}, {q[2]:+.2f}] cm"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, help="a build of configs/datasets/lct_release_charts.yaml")
    parser.add_argument("--network", nargs="+", default=[str(SHIPPED)], help="trained networks (.pt), each scored")
    parser.add_argument("--split", default="val")
    parser.add_argument("--fraction", type=float, default=0.1, help="the exposure's share kept (default 0.1)")
    parser.add_argument("--near", type=float, default=0.5, help="charts nearer than this (m) are the near ones")
    args = parser.parse_args(argv)
    if not 0 < args.fraction <= 1:
        raise SystemExit(f"--fraction: a share of the exposure lies in (0, 1], got {args.fraction}")
    networks = {"shipped" if Path(path).resolve() == SHIPPED else Path(path).stem: load_network(path)
                for path in args.network}
    if not (args.data / "zarr.json").is_file():
        raise SystemExit(f"{args.data}: not a dataset (build one: datagen build "
                         "configs/datasets/lct_release_charts.yaml --out DIR)")
    truth, errors = chart_errors(args.data, networks, args.split, args.fraction)
    print(f"{len(truth)} charts in view at {truth.min():.3f}-{truth.max():.3f} m; depth over LCT's full-exposure "
          f"found points at {args.fraction:g} of the exposure minus the label's: median [quartiles] over the charts")
    for name, part in ((f"nearer than {args.near:g} m", truth < args.near),
                       (f"{args.near:g} m and beyond", truth >= args.near)):
        print(f"charts {name}: {part.sum()}")
        for method, e in errors.items():
            print(f"  {method}: {quartiles(e[part])}")
    return {"truth": truth, **errors}


if __name__ == "__main__":
    main()
