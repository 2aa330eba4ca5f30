"""The baselines on the Stanford LCT release's captures at their full exposure and thinned to 1/10 and 1/100 of it:
the low-photon regime a network trained on datagen is meant for, and the figures it has to beat (docs/real.md,
"Baselines at lower exposures").

    python benchmarks/real_low_light.py FOLDER [--exposures 1 0.1 0.01] [--methods lct phasor fbp fk] [--seed 0]
                                               [--draws 1]
                                               [--network FILE.pt ... | none] [--network-depth first|mean]
                                               [--venv /opt/venvs/tal-bench]
                                               [--png DIR] [--sim DATA [--sim-split test]] [--background none]

FOLDER holds the release's ``data_*.mat`` files (the project never ships them; the release is published with
O'Toole, Lindell & Wetzstein, Nature 555, 338 (2018)). For each file, read as ``datagen import-capture
--bin-resolution 4ps`` reads it (datagen's orientation, docs/capture_io.md):

1. **Thinning.** A capture at a fraction f of its exposure is the counts thinned binomially, each detection kept
   with probability f (``Generator.binomial``, seeded by ``--seed`` and the file's place in the sorted folder):
   what the same SPAD would have counted over f of the time, up to the pile-up that a shorter exposure does not
   change (pile-up acts per cycle, thinning per detection). ``--draws N`` thins each exposure below the full one N
   times (independent streams spawned from that seed; the first is the one a single draw takes) and ends with a
   summary per capture, exposure and method: the depth's and the IoU's mean and range over the draws, and in how many
   draws the IoU reaches 0.6 (:func:`summarize`). One thinning is one draw of the counts: on the charts at 1/10 a
   network's IoU moves by 0.1–0.17 between draws.
2. **Reconstruction.** Each method of ``datagen reconstruct`` as shipped
   (:func:`datagen.analysis.reconstruct.confocal_volume`: each point's background floor subtracted, the direct
   light trimmed, 512 bins of 16 ps, the t² falloff and snr 0.8 of the release's script, on every capture as
   ``datagen reconstruct`` does by default), and
   its depth map (:func:`~datagen.analysis.reconstruct.depth_map`: the strongest voxel's depth where the front
   view reaches 0.25 of the way from its pedestal, its 5th percentile, to its maximum, NaN elsewhere).
   **f-k migration** ("fk", Lindell, Wetzstein & O'Toole 2019) is tal's, ``tal.reconstruct.fk`` of y-tal 0.20.0, run
   as benchmarks/bench_recon.py runs it: in tal's separate environment (``--venv``, default ``$TAL_BENCH_VENV`` or
   /opt/venvs/tal-bench, made by ``bash benchmarks/tal/setup_env.sh``; without it the run says so in one line and goes
   on without f-k), through benchmarks/tal/recon_side.py (``bench_recon.tal_side``, a private HOME). It gets what LCT
   gets: the same thinned counts summed to 512 bins of 16 ps, the same floor subtracted and direct light zeroed
   (:func:`fk_input`), written as a tal HDF5 capture (``datagen.io.write_tal_hdf5``: t_start 0, the release's grid, no
   laser position, so no laser cos/d² compensation) in a temporary folder. tal's f-k has no parameters of its own: it
   weights H by a ramp linear in t (0 to 1 over the time axis; the f-k release's script takes √(H·t²), tal |H·t|, so
   tal's volume grows as the counts squared where LCT's grows as the counts), zero-pads to 2T × 2N × 2N, maps the
   spectrum by the Stolt transform (linear interpolation; the half-width from the grid, the depth range T·cΔt/2) and
   returns |·|²; no t² falloff, no snr. Its voxel k lies (k + ½)·cΔt/2 from the wall, as LCT's; the voxels up to the
   trimmed depth are left out, as :func:`~datagen.analysis.reconstruct.confocal_volume` zeroes them; and
   :func:`~datagen.analysis.reconstruct.depth_map`'s rule makes its depth map from the strongest voxel of each column
   (:func:`fk_depth`). f-k needs an N × N scan of one pitch (the release's are). Its time is tal's solve alone,
   without the export, the subprocess and tal's import (about 2.5 s per reconstruction more).
3. **Reference.** The object's mask is the full-exposure LCT reconstruction's found points (that same depth map's
   non-NaN points): a shape reference made from the capture itself, so that LCT at full exposure scores IoU 1 by
   construction. Depths are referred to the charts' nominal 0.40 / 0.65 m and the diffuse "S"'s 0.50 m
   (:data:`benchmarks.real_captures.DEPTHS`); the other captures have no stated depth.
4. **Scores.** Per capture, exposure and method: the median depth over the reference mask (m; NaN where the method
   found nothing there), its difference from the reference depth, and the IoU of the method's found points with the
   reference mask.
5. **A network** (``--network FILE.pt``, written by ``python -m examples.train_depth_image DATA --save FILE.pt``;
   by default the one shipped in :data:`SHIPPED`, trained on ``configs/datasets/lct_release.yaml``; ``--network
   none`` leaves it out): the same thinned counts, as its record says it reads them (the LCT volume of the scan,
   or the counts summed to its time axis and over its pool of scan points), its depth image, whose median over the
   reference mask is its depth; with a mask head (``--mask``) the IoU is of where it sees the object (its
   probability ≥ the record's threshold; with two heads, ``--outline-head``, the mean of the two probabilities,
   each moved so that its threshold sits at 0.5, ≥ 0.5), without one it is not scored (NaN); several files
   (``--network A.pt B.pt``) are averaged, the depth the first's or, with ``--network-depth mean``, the mean of their
   depth maps (:func:`network_depth`). The run prints what the record says of the network's training
   (``examples.train_depth_image.describe``) and a warning when the dataset config it was trained on is no longer
   the repository's (:func:`stale`).

6. **Pictures** (``--png DIR``): ``DIR/low_light_<capture>.png``, every method's depth map (where it found the
   object) at every exposure, methods down and exposures across, the reference mask outlined on each.
7. **Sim-to-sim** (``--sim DATA``): the network on a build of its dataset config's held-out split (``--sim-split``,
   default ``test``: ``datagen build configs/datasets/lct_release.yaml --splits test=100``), its stored counts: the
   mean |error| of its median depth over the label's object pixels and the mean IoU of its mask with the label's
   (:func:`sim_scores`), printed before the captures' rows: the figure beside the sim-to-real one.

The printed table is the one docs/real.md quotes.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))                   # examples.train_depth_image: the networks' loading and inputs
from real_captures import DEPTHS  # noqa: E402  (the reference depths, one table for both benchmarks)

from datagen.analysis.reconstruct import FOUND_PEDESTAL  # noqa: E402

EXPOSURES = (1.0, 0.1, 0.01)
"""Fractions of each capture's exposure."""

METHODS = ("lct", "phasor", "fbp", "fk")
"""Methods ``--methods`` takes: datagen's three baselines and tal's f-k migration (module doc)."""

SHIPPED = ROOT / "examples" / "weights" / "lct_release_net.pt"
"""The network trained on ``configs/datasets/lct_release.yaml`` that ships with the repository (docs/training.md)."""


def default_venv() -> Path:
    """tal's venv for fk: ``$TAL_BENCH_VENV``, else /opt/venvs/tal-bench (benchmarks/bench_recon.py's default)."""
    return Path(os.environ.get("TAL_BENCH_VENV", "/opt/venvs/tal-bench"))


def config_fingerprint(record: dict) -> str:
    """sha256 of the repository's dataset config named in a network's record (``configs/datasets/<config_name>.yaml``)
    cut to the record's split counts, as ``datagen build --splits`` cuts it: the card's ``config_sha256`` of a build
    of that config today (:meth:`datagen.dataset.DatasetConfig.fingerprint`).

    Raises:
        FileNotFoundError: no such config in the repository.
    """
    from datagen.dataset import load_dataset_config

    config = load_dataset_config(ROOT / "configs" / "datasets" / f"{record['config_name']}.yaml")
    splits = {name: config.splits[name].model_copy(update={"count": n}) for name, n in record["splits"].items()}
    return config.model_copy(update={"splits": splits}).fingerprint()


def stale(record: dict) -> str | None:
    """None when a network's record was trained on a build of the repository's dataset config as it is now (or on a
    config the repository does not hold), else a one-line reason (the record's ``config_sha256`` and the config's)."""
    if "config_sha256" not in record:
        return "its record holds no config_sha256 (saved without a dataset card)"
    if not (ROOT / "configs" / "datasets" / f"{record['config_name']}.yaml").is_file():
        return None                     # a config of the user's own: nothing in the repository to compare with
    now = config_fingerprint(record)
    if now != record["config_sha256"]:
        return (f"trained on config_sha256 {record['config_sha256'][:16]}…, configs/datasets/{record['config_name']}"
                f".yaml cut to {record['splits']} hashes to {now[:16]}… now: retrain it (docs/training.md)")
    return None


def read_release_file(path: Path) -> tuple[np.ndarray, float, tuple[float, float]]:
    """(counts (ny, nx, T) float64 in datagen's orientation, bin width s, (row, column) pitch m) of a release file
    (4 ps bins where the file does not say; :func:`datagen.io.lab_formats.read_lab_capture`)."""
    from datagen.analysis.confocal import grid_pitches
    from datagen.io.lab_formats import read_lab_capture

    cap = read_lab_capture(path, bin_resolution=4e-12)
    return np.asarray(cap.data(), dtype=np.float64), float(cap.bin_width()), grid_pitches(cap.laser_points())


def thin(counts: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Counts thinned binomially: each detection kept with probability ``fraction`` (0 < fraction ≤ 1); float64."""
    if not 0 < fraction <= 1:
        raise ValueError(f"an exposure fraction lies in (0, 1], got {fraction}")
    if fraction == 1:
        return np.asarray(counts, dtype=np.float64)
    return rng.binomial(np.asarray(counts, dtype=np.int64), fraction).astype(np.float64)


def found(scan: np.ndarray, dt: float, pitch, method: str, background: str | None = "auto",
          pedestal: float | None = FOUND_PEDESTAL) -> np.ndarray:
    """(ny, nx) depth map (m, NaN where nothing is found) of one method as ``datagen reconstruct`` runs it
    (``background`` None: as ``--background none`` does, each point's floor kept; ``pedestal`` as its
    ``--pedestal``)."""
    from datagen.analysis.reconstruct import confocal_volume, depth_map

    volume, depths, _ = confocal_volume(scan, dt, pitch, method, background=background)
    return depth_map(volume, depths, pedestal=pedestal)[0]


def fk_input(scan: np.ndarray, dt: float, background: str | None = "auto") -> tuple[np.ndarray, float, int]:
    """(data (ny, nx, M) float64, its bin width s, bins zeroed) of a scan as
    :func:`~datagen.analysis.reconstruct.confocal_volume` hands it to LCT by default
    (:func:`~datagen.analysis.reconstruct.prepare_scan`: summed to at most
    :data:`~datagen.analysis.reconstruct.MAX_BINS` bins, each point's floor subtracted, the direct light zeroed,
    zero-padded to a power of two)."""
    from datagen.analysis.reconstruct import prepare_scan

    return prepare_scan(scan, dt, background=background)


def fk_capture(data: np.ndarray, dt: float, pitch):
    """A datagen Result of a prepared scan (:func:`fk_input`) for ``write_tal_hdf5``: confocal, the time axis from 0
    (the hidden round trip, no wall legs), the release's grid of the scan's pitch in datagen's frame
    (``lct_scan_points``), no laser or sensor position.

    Raises:
        ValueError: a scan that is not N × N of one pitch (tal's f-k reads one N and one half-width).
    """
    from datagen.io.orientation import LCT_WALL_NORMAL, lct_half_width, lct_scan_points
    from datagen.simulation import Result

    ny, nx = data.shape[:2]
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    if ny != nx or not np.isclose(pitch_y, pitch_x, rtol=1e-6):
        raise ValueError(f"f-k (tal) takes an N x N scan of one pitch; got {ny} x {nx} at {pitch_y:g} / {pitch_x:g} m")
    points = lct_scan_points(lct_half_width(pitch_x, nx), (ny, nx))
    attrs = {"capture": {"type": "confocal", "convention": "counts"},
             "config": {"count_laser_leg": False, "count_sensor_leg": False}}
    return Result(np.arange(data.shape[-1] + 1) * dt, data, {}, np.zeros(data.shape, np.int64), attrs,
                  laser_points=points, sensor_points=points, wall_normal=LCT_WALL_NORMAL.copy())


def fk_depth(scan: np.ndarray, dt: float, pitch, venv: Path, background: str | None = "auto",
             pedestal: float | None = FOUND_PEDESTAL) -> tuple[np.ndarray, float]:
    """((ny, nx) depth map m, NaN where nothing is found; tal's solve time s) of tal's f-k migration on a scan of
    counts (module doc): exported in a temporary folder, reconstructed by benchmarks/tal/recon_side.py in the tal
    venv ``venv`` over the depths past the trimmed light, its strongest voxel per column put through
    :func:`~datagen.analysis.reconstruct.depth_map`'s rule.

    Raises:
        SystemExit: recon_side.py failed (its output in the message).
    """
    from bench_recon import tal_side

    from datagen.analysis.reconstruct import depth_map
    from datagen.io import write_tal_hdf5
    from datagen.units import SPEED_OF_LIGHT

    data, dt, n_trim = fk_input(scan, dt, background)
    voxel = SPEED_OF_LIGHT * dt / 2
    # recon_side keeps the voxels between the first and the last of these: past the trimmed depth n_trim·voxel,
    # the voxel edge between the last zeroed (n_trim − ½) and the first kept (n_trim + ½), up to the end
    planes = np.array([n_trim * voxel, (data.shape[-1] + 1) * voxel])
    with tempfile.TemporaryDirectory(prefix="real_low_light_fk_") as tmp:
        capture = write_tal_hdf5(fk_capture(data, dt, pitch), Path(tmp) / "scan.hdf5")
        tal_side([capture], ["fk"], planes, Path(tmp) / "fk.npz", venv)
        with np.load(Path(tmp) / "fk.npz") as out:            # (1, Sx, Sy): tal's H is (T, Sx, Sy)
            depth, front = out["depth_fk"][0].T.astype(np.float64), out["peak_fk"][0].T.astype(np.float64)
            seconds = float(out["seconds_fk"][0])
    # depth_map's rule on the one voxel per column recon_side keeps: 0 where its front view reaches the level, NaN
    # elsewhere, plus that voxel's depth
    return depth + depth_map(front[..., None], np.zeros(1), pedestal=pedestal)[0], seconds


def score(depth: np.ndarray, mask: np.ndarray, hit: np.ndarray | None = None) -> tuple[float, float]:
    """(median depth over ``mask`` where found, m (NaN: nothing found there); IoU of the found points with mask).
    The found points are ``hit`` where given (a network's mask output), else where the depth is not NaN."""
    hit = ~np.isnan(depth) if hit is None else hit
    inside = depth[mask & hit & ~np.isnan(depth)]
    union = int((hit | mask).sum())
    return (float(np.median(inside)) if inside.size else float("nan"),
            float((hit & mask).sum()) / union if union else float("nan"))


NETWORK_DEPTHS = ("first", "mean")
"""What averaged networks' depth is (``--network-depth``): the first network's, or the mean of their depth maps."""


def network_depth(network, scan: np.ndarray, dt: float, pitch,
                  depth: str = "first") -> tuple[np.ndarray, np.ndarray]:
    """((ny, nx) depth m, (ny, nx) bool where it sees the object) of ``network`` = (net, record)
    (``examples.train_depth_image.load_model``) on a scan of counts (ny, nx, T) of bin width ``dt`` and grid pitch
    ``pitch`` (m): a network on the LCT volume reconstructs it from the scan as it is; one on counts gets them summed
    pairwise to at most its bins, zero-padded to them. ``network`` a list of several (net, record) averages them
    (``--network A.pt B.pt``): the depth is the first's (``depth="first"``) or the mean of their (ny, nx) depth maps
    (``"mean"``, ``--network-depth mean``), the object is seen where the mean of their mask probabilities, each moved
    so that its record's threshold sits at 0.5 (``predict_depth(probability=True)``), reaches 0.5. Raises ValueError
    for a ``depth`` not in :data:`NETWORK_DEPTHS`."""
    from datagen.analysis.reconstruct import coarsen
    from examples.train_depth_image import predict_depth

    if depth not in NETWORK_DEPTHS:
        raise ValueError(f"depth must be one of {', '.join(NETWORK_DEPTHS)}, got {depth!r}")
    networks = [network] if isinstance(network, tuple) else list(network)
    maps = []
    for net, record in networks:
        data = scan
        if record.get("input", "counts") != "lct":
            data, _ = coarsen(scan, dt, record["bins"])
            data = np.concatenate([data, np.zeros(data.shape[:2] + (record["bins"] - data.shape[-1],))], axis=-1)
        maps.append(predict_depth(net, record, data, dt, pitch, probability=len(networks) > 1))
    if len(maps) == 1:
        return maps[0]
    depths = maps[0][0] if depth == "first" else np.mean([d for d, _ in maps], axis=0)
    return depths, np.mean([prob for _, prob in maps], axis=0) >= 0.5


def network_has_mask(network) -> bool:
    """Whether ``network`` ((net, record) or a list of them, :func:`network_depth`) says where it sees the object."""
    return all(net.mask for net, _ in ([network] if isinstance(network, tuple) else network))


def evaluate(counts: np.ndarray, dt: float, pitch, name: str, exposures=EXPOSURES, methods=("lct", "phasor", "fbp"),
             rng: np.random.Generator | None = None, network=None, venv: Path | None = None,
             background: str | None = "auto", pedestal: float | None = FOUND_PEDESTAL, draws: int = 1,
             network_depths: str = "first") -> list[dict]:
    """Rows {capture, exposure, draw, method, depth, error, iou, counts, seconds, map, reference} of one capture
    (module doc; "map" the (ny, nx) depth m where the method found the object, NaN elsewhere; "reference" the (ny, nx)
    bool reference mask, the same array in every row); ``draws`` thinnings of each exposure below the full one
    (draw 0 from ``rng``, draw d ≥ 1 from ``rng.spawn``'s d-th child, so draw 0 is the same whatever ``draws``; the
    full exposure is drawn once); ``network`` a
    loaded (net, record) adds its row (a list of them averaged, their depth by ``network_depths``,
    :func:`network_depth`); "fk" among the methods needs ``venv``, the tal venv; ``background`` the
    baselines' and the reference's floor ("auto" subtracted, None kept; the network reads its input as trained);
    ``pedestal`` their found points' rule (:func:`~datagen.analysis.reconstruct.depth_map`)."""
    if draws < 1:
        raise ValueError(f"draws must be at least 1, got {draws}")
    rng = rng if rng is not None else np.random.default_rng(0)
    streams = [rng] + rng.spawn(draws - 1)
    mask = ~np.isnan(found(counts, dt, pitch, "lct", background, pedestal))
    reference = DEPTHS.get(name)
    rows = []
    for fraction, draw in [(f, d) for f in exposures for d in range(draws if f < 1 else 1)]:
        scan = thin(counts, fraction, streams[draw])
        for method in list(methods) + (["network"] if network is not None else []):
            t0 = time.perf_counter()
            seconds = None
            if method == "network":                    # its depth over the object; its mask head's IoU
                depth_map, seen = network_depth(network, scan, dt, pitch, network_depths)
                depth = score(depth_map, mask)[0]
                iou = score(depth_map, mask, seen)[1] if network_has_mask(network) else float("nan")
                depth_map = np.where(seen, depth_map, np.nan)
            elif method == "fk":                       # tal's, in its venv; its time the solve alone
                if venv is None:
                    raise ValueError("the fk method needs the tal venv (venv=)")
                depth_map, seconds = fk_depth(scan, dt, pitch, venv, background, pedestal)
                depth, iou = score(depth_map, mask)
            else:
                depth_map = found(scan, dt, pitch, method, background, pedestal)
                depth, iou = score(depth_map, mask)
            rows.append({"capture": name, "exposure": fraction, "draw": draw, "method": method, "depth": depth,
                         "target": reference if reference is not None else float("nan"),
                         "error": depth - reference if reference is not None else float("nan"), "iou": iou,
                         "counts": float(scan.sum()), "map": depth_map, "reference": mask,
                         "seconds": time.perf_counter() - t0 if seconds is None else seconds})
    return rows


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--exposures", type=float, nargs="+", default=list(EXPOSURES))
    parser.add_argument("--methods", nargs="+", default=["lct", "phasor", "fbp"], choices=list(METHODS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--draws", type=int, default=1,
                        help="thinnings of each exposure below the full one; with more than 1 a summary over them "
                             "follows the rows (draw 0 is the same whatever --draws)")
    parser.add_argument("--only", nargs="+", default=None, help="captures by name (dot_chart_40cm ...)")
    parser.add_argument("--network", nargs="+", default=[str(SHIPPED)],
                        help="a trained network (.pt, module doc; default: the shipped one), several to average "
                             "them (the mean of their masks; their depth by --network-depth), or 'none'")
    parser.add_argument("--network-depth", choices=list(NETWORK_DEPTHS), default="first",
                        help="averaged networks' depth: the first's (default) or the mean of their depth maps")
    parser.add_argument("--venv", type=Path, default=default_venv(),
                        help="tal's venv for fk (bash benchmarks/tal/setup_env.sh makes it)")
    parser.add_argument("--png", type=Path, default=None,
                        help="write DIR/low_light_<capture>.png: every method's depth map at every exposure")
    parser.add_argument("--sim", type=Path, default=None,
                        help="a build of the network's dataset config: score the network on its held-out split too")
    parser.add_argument("--sim-split", default="test", help="the split of --sim to score (default: test)")
    parser.add_argument("--background", choices=["auto", "none"], default="auto",
                        help="the baselines' and the reference's floor: subtracted (auto, as datagen reconstruct "
                             "does by default) or kept (none)")
    parser.add_argument("--pedestal", type=float, default=FOUND_PEDESTAL,
                        help="the baselines' and the reference's found points: from this percentile of the front "
                             "view to its maximum, as datagen reconstruct --pedestal (0: a share of the maximum)")
    args = parser.parse_args(argv)
    methods = list(args.methods)
    if "fk" in methods and not (args.venv / "bin" / "python").is_file():
        print(f"fk: no tal venv at {args.venv} (make it with 'bash benchmarks/tal/setup_env.sh' or give --venv "
              "PATH); going on without f-k", file=sys.stderr)
        methods.remove("fk")
    network = None
    if args.network != ["none"]:
        network = [load_network(path) for path in args.network]
        if len(network) > 1 and not network_has_mask(network):
            raise SystemExit("--network: averaging networks needs each to have a mask head")
        network = network[0] if len(network) == 1 else network
    files = sorted(args.folder.glob("data_*.mat"))
    seeds = {path: k for k, path in enumerate(files)}           # a capture's stream is its place in the folder
    if args.only:
        files = [p for p in files if p.stem.removeprefix("data_") in args.only]
    if not files:
        raise SystemExit(f"{args.folder}: no data_*.mat files (give the folder of the release's captures)")
    if args.draws < 1:
        raise SystemExit(f"--draws: at least 1 thinning, got {args.draws}")
    for f in args.exposures:
        if not 0 < f <= 1:
            raise SystemExit(f"--exposures: a fraction lies in (0, 1], got {f}")
    if args.png is not None:
        args.png.mkdir(parents=True, exist_ok=True)
    if args.sim is not None:
        if network is None:
            raise SystemExit("--sim: scores a network; give one with --network")
        sim = sim_scores(network, args.sim, args.sim_split, args.network_depth)
        print(f"network on {args.sim} split {args.sim_split} (simulated, held out; {sim['samples']} samples, their "
              f"stored counts): median depth over the object off by {sim['depth_error']:.4f} m (mean |·|), mask "
              f"IoU {sim['iou']:.3f} (mean)")
    rows = []
    print("capture | exposure | method | median depth over the object (m) | minus reference (m) | IoU | counts | s")
    for path in files:
        name = path.stem.removeprefix("data_")
        counts, dt, pitch = read_release_file(path)
        found_here = []
        for row in evaluate(counts, dt, pitch, name, args.exposures, methods,
                            np.random.default_rng([args.seed, seeds[path]]), network, args.venv,
                            None if args.background == "none" else "auto", args.pedestal, args.draws,
                            args.network_depth):
            found_here.append(row)
            exposure = f"{row['exposure']:g}" + (f" (draw {row['draw']})" if row["draw"] else "")
            print(f"{row['capture']} | {exposure} | {row['method']} | {row['depth']:.4f} | "
                  f"{row['error']:+.4f} | {row['iou']:.3f} | {row['counts']:.3g} | {row['seconds']:.1f}", flush=True)
        if args.png is not None:
            drawn_first = [row for row in found_here if row["draw"] == 0]
            print(f"wrote {plot_capture(drawn_first, pitch, args.png / f'low_light_{name}.png')}")
        rows += found_here
    if args.draws > 1:
        print(f"over {args.draws} thinnings: capture | exposure | method | minus reference (m): mean [min, max] | "
              f"IoU: mean [min, max] | draws with IoU ≥ {MASK_TARGET:g}")
        for line in summarize(rows):
            print(line)
        verdicts = targets(rows)
        if verdicts:
            missed = ", ".join(f"{capture} {what}" for capture, what, met in verdicts if not met) or "none"
            print(f"network's targets at {TARGET_EXPOSURE:g} (mask IoU ≥ {MASK_TARGET:g}, chart depth within "
                  f"{DEPTH_TARGET * 100:g} cm; mean and 3/4 of the draws): {sum(m for _, _, m in verdicts)} of "
                  f"{len(verdicts)} met; missed: {missed}")
    return rows


def load_network(path) -> tuple:
    """(network, record) of a saved network (``examples.train_depth_image.load_model``), its record described in one
    printed line and a warning on stderr when the dataset config it was trained on is no longer the repository's
    (:func:`stale`). Raises SystemExit: no file at ``path`` (one line)."""
    from examples.train_depth_image import describe, load_model
    if not Path(path).is_file():
        raise SystemExit(f"--network: no file at {path}")
    net, record = load_model(path)
    print(f"network {path}: {describe(record)}")
    reason = stale(record) if "config_name" in record else None
    if reason is not None:
        print(f"warning: network {path} is stale: {reason}", file=sys.stderr)
    return net, record


def labelled_scans(data: Path, split: str):
    """Yield (i, counts (H, W, T) float64, wall-depth label (H, W) float64 m, 0 off the object, bin width s, scan
    pitch m) for each sample of a dataset split (its stored counts): what :func:`sim_scores` and
    benchmarks/near_charts.py score a network on."""
    import datagen
    from examples.train_depth_image import scan_pitch

    ds = datagen.NLOSDataset(data, split=split, fields=("counts", "wall_depth", "params"))
    dt = float(ds.card["time_edges"]["bin_width"])
    for i in range(len(ds)):
        item = ds[i]
        counts = np.asarray(item["counts"], np.float64)
        label = np.asarray(item["wall_depth"], np.float64).reshape(counts.shape[:2])
        yield i, counts, label, dt, scan_pitch(item["params"])


MASK_TARGET = 0.6
"""The mask IoU a network is asked for at 1/10 of the exposure (docs/real.md, "A network trained on datagen")."""

DEPTH_TARGET = 0.01
"""How far (m) a network's median depth on a chart may lie from its nominal distance at 1/10 of the exposure."""

TARGET_EXPOSURE = 0.1
"""The exposure, as a fraction of the capture's, at which :func:`targets` scores a method."""


def thinned_groups(rows: list[dict]) -> dict[tuple[str, float, str], list[dict]]:
    """The rows (:func:`evaluate`) of each exposure below the full one, by (capture, exposure, method), in their
    order: one list of draws each, what :func:`summarize` and :func:`targets` sum up."""
    groups: dict[tuple[str, float, str], list[dict]] = {}
    for row in rows:
        if row["exposure"] < 1:
            groups.setdefault((row["capture"], row["exposure"], row["method"]), []).append(row)
    return groups


def targets(rows: list[dict], method: str = "network") -> list[tuple[str, str, bool]]:
    """(capture, "mask" or "depth", met) of ``method`` over the rows' draws at :data:`TARGET_EXPOSURE`
    (:func:`evaluate`), by docs/real.md's rule ("Over eight thinnings"): a mask target is met when the IoU's mean
    reaches :data:`MASK_TARGET` and so do at least three quarters of the draws (6 of 8); a depth target, asked of the
    charts (the captures of :data:`~benchmarks.real_captures.DEPTHS` named "…chart…"), when the difference from
    the nominal distance, averaged over the draws that found the object (as :func:`summarize`), is within
    :data:`DEPTH_TARGET` and so is that of at least three quarters of the draws (a draw that found nothing misses).
    Empty when no row is of that method and exposure."""
    verdicts = []
    for (capture, exposure, of), group in thinned_groups(rows).items():
        if of != method or exposure != TARGET_EXPOSURE:
            continue
        need = int(np.ceil(0.75 * len(group)))
        iou = np.array([r["iou"] for r in group])
        verdicts.append((capture, "mask", bool(np.mean(iou) >= MASK_TARGET and np.sum(iou >= MASK_TARGET) >= need)))
        if "chart" in capture and capture in DEPTHS:
            error = np.array([r["error"] for r in group])
            found_it = error[np.isfinite(error)]               # a draw that found nothing: NaN, within nothing
            verdicts.append((capture, "depth", bool(found_it.size and abs(np.mean(found_it)) <= DEPTH_TARGET
                                                    and np.sum(np.abs(found_it) <= DEPTH_TARGET) >= need)))
    return verdicts


def summarize(rows: list[dict]) -> list[str]:
    """One line per capture, exposure below the full one and method over the rows' draws (:func:`evaluate`): the
    depth's difference from the reference (mean, min, max over the draws that found the object, and how many found
    nothing; m; "—" for a capture of no stated depth, its rows' ``target`` NaN), the IoU's mean, min and max, and how
    many draws reach :data:`MASK_TARGET`."""
    lines = []
    for (capture, exposure, method), group in thinned_groups(rows).items():
        error = np.array([r["error"] for r in group])
        iou = np.array([r["iou"] for r in group])
        known = error[np.isfinite(error)]        # the draws that found something over the object
        missed = f"nothing found in {len(error) - known.size} of {len(error)}"
        if not np.isfinite(group[0]["target"]):
            depth = "—"
        elif not known.size:
            depth = missed
        else:
            depth = f"{np.mean(known):+.4f} [{np.min(known):+.4f}, {np.max(known):+.4f}]" + \
                (f" ({missed})" if known.size < len(error) else "")
        lines.append(f"{capture} | {exposure:g} | {method} | {depth} | {np.mean(iou):.3f} [{np.min(iou):.3f}, "
                     f"{np.max(iou):.3f}] | {int(np.sum(iou >= MASK_TARGET))}/{len(group)}")
    return lines


def plot_capture(rows: list[dict], pitch, path: Path) -> Path:
    """The depth maps of one capture's rows (:func:`evaluate`), methods down and exposures across, the rows' reference
    mask (the full-exposure LCT's found points) outlined on each: ``datagen.plot.reconstruction.plot_depth_grid``."""
    from datagen.plot.reconstruction import plot_depth_grid

    methods = list(dict.fromkeys(r["method"] for r in rows))
    exposures = list(dict.fromkeys(r["exposure"] for r in rows))
    at = {(r["method"], r["exposure"]): r for r in rows}
    cells = [[(at[m, f]["map"], f"{at[m, f]['depth']:.3f} m (IoU {at[m, f]['iou']:.2f})") for f in exposures]
             for m in methods]
    name = rows[0]["capture"]
    reference = DEPTHS.get(name)
    depth_range = None if reference is None else (reference - 0.1, reference + 0.1)
    return plot_depth_grid(cells, methods, [f"exposure × {f:g}" for f in exposures], pitch, path,
                           f"{name}: depth where each method finds the object (outline: the full-exposure LCT's)",
                           outline=rows[0]["reference"], depth_range=depth_range)


def sim_scores(network, data: Path, split: str, network_depths: str = "first") -> dict:
    """The network on a dataset split's stored counts (simulated captures it was not trained on): {"samples": n with
    object pixels, "depth_error": mean over them of |median depth over the label's object pixels − the label's|
    (m), "iou": mean IoU of its mask with the label's (``wall_depth`` > 0)}, each scored by :func:`score` as the
    captures' rows are: the sim-to-sim figures beside the captures' (averaged networks' depth by
    ``network_depths``, :func:`network_depth`)."""
    errors, ious = [], []
    for _, counts, label, dt, pitch in labelled_scans(data, split):
        mask = label > 0
        if not mask.any():
            continue
        depth, seen = network_depth(network, counts, dt, pitch, network_depths)
        errors.append(abs(score(depth, mask)[0] - float(np.median(label[mask]))))
        ious.append(score(depth, mask, seen)[1])
    return {"samples": len(errors), "depth_error": float(np.mean(errors)) if errors else float("nan"),
            "iou": float(np.mean(ious)) if ious else float("nan")}


if __name__ == "__main__":
    main()
