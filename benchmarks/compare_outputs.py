"""Prove that a refactor leaves every numeric output of datagen bit-identical.

What it proves
    The same fixed list of jobs is run once with the code of one source tree and once with another (e.g. the
    commit before a refactor and the working tree after it). Every array of every output (simulation
    result stores, a dataset store, tal HDF5 captures, SPAD detector draws) must have the same dtype, the
    same shape and the same bytes (so NaNs compare equal only if their bit patterns are equal, and -0.0 is not
    +0.0). Timings and version strings are not compared; the remaining JSON/YAML metadata (attributes) is
    compared too, but a difference there is only reported as a warning, never as a failure.

How to run it (from any directory; only numpy, zarr and h5py/pyyaml are needed in this process)::

    # dump the outputs of one tree (every job runs in a subprocess with PYTHONPATH=TREE, cwd=TREE):
    python benchmarks/compare_outputs.py dump --src /work/old --out /work/baseline_dump
    python benchmarks/compare_outputs.py dump --src /work/main --out /tmp/new_dump

    # compare two dumps, one line per array and a summary; exit code 0 only if everything is identical:
    python benchmarks/compare_outputs.py compare /work/baseline_dump /tmp/new_dump

    # both at once (dumps into temporary directories, removed afterwards unless --keep):
    python benchmarks/compare_outputs.py run --old /work/old --new /work/main

    # a subset of the jobs (names as printed by `list`; substrings match):
    python benchmarks/compare_outputs.py list
    python benchmarks/compare_outputs.py dump --src /work/old --out /tmp/d --only demo_exact,spad

Each job runs the tree's own CLI as ``python -c "from datagen.cli import main; main()" ARGS`` (after
checking that ``datagen.__file__`` lies inside TREE) on the tree's own input files, or (job ``spad_draws``)
this script's hidden ``_spad-job`` command, which reproduces the detector draws of
``benchmarks/bench_spad.py`` at smaller sizes through the public ``datagen.spad`` API (plus the two private
samplers bench_spad times, looked up by a list of candidate names and skipped with a warning when absent).

A dump directory holds ``manifest.json`` (per job: command, exit code, wall time, ``datagen.__file__``, the
list of arrays with dtype/shape/sha256, the normalised metadata), ``arrays/<job>.npz`` (every array, keys
are the paths inside the store or file) and ``logs/<job>.{stdout,stderr}``. A whole dump takes about
70–75 s on 2 cores (the two --tolerance jobs ~16 s each, the quadrature ~8 s, the SPAD draws ~8 s).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FORMAT = "datagen-compare-outputs/1"

# ------------------------------------------------------------------------------------------------------------
# Jobs
# ------------------------------------------------------------------------------------------------------------
SCENE = "scene_library/demo_room.yaml"
SMALL = ["--lookins", "10x10", "--pixels", "30x30"]
AREA_SAMPLES = 16384          # the area estimator's hidden samples per laser point (default 65536)
QUADRATURE_EDGE = "0.2"       # metres; 0.2 m runs in ~7 s on the demo room, 0.1 m in ~60 s


def _job(name, kind, args=(), **extra):
    return {"name": name, "kind": kind, "args": list(args), **extra}


JOBS = [
    # a. the demo room, `datagen simulate … --quiet`, every array of result.zarr
    _job("demo_lookin_full", "simulate", ["--estimator", "lookin", "--secondary", "full", *SMALL]),
    _job("demo_optimized", "simulate", ["--secondary", "optimized", *SMALL]),
    _job("demo_scene_defaults", "simulate", []),    # the scene's own settings: 10x10 lookins, 60x60, full
    _job("demo_exact", "simulate", ["--secondary", "exact", *SMALL],
         # and `datagen detect` on that result with two detector presets (free-running; gated, 25000 bins)
         detect=["configs/detectors/hwu_single_pixel.yaml", "configs/detectors/fast_gated_nlos.yaml"]),
    _job("demo_full_workers2", "simulate", ["--secondary", "full", "--workers", "2", *SMALL]),
    _job("demo_area", "simulate", ["--estimator", "area"], area_samples=AREA_SAMPLES),
    _job("demo_quadrature", "simulate", ["--estimator", "quadrature", "--edge", QUADRATURE_EDGE]),
    # --tolerance 2 % with the scene's own (full) secondary ends at 50x50x60x60 after ~5 min; 5 % stops at
    # 24x24x42x42 (~17 s). The 2 % target is run with the exact secondary (same estimator, O(N) cost, ~20 s).
    _job("demo_tolerance_5pct", "simulate", ["--tolerance", "5%"]),
    _job("demo_tolerance_2pct_exact", "simulate", ["--tolerance", "2%", "--secondary", "exact"]),
    # b. the smoke dataset, every array of every split
    _job("smoke_dataset", "build", ["configs/datasets/smoke.yaml"]),
    # the scan configs' smoke variants (the quadrature on confocal scans: a mesh before a wall, and rooms)
    _job("wall_smoke_dataset", "build", ["configs/datasets/wall_smoke.yaml"]),
    _job("confocal_smoke_dataset", "build", ["configs/datasets/confocal_smoke.yaml"]),
    # c. tal-render (default settings: the quadrature estimator, edge 0.02 m), every HDF5 dataset
    _job("tal_hidden_square", "tal", ["benchmarks/tal/hidden_square.yaml"]),
    _job("tal_hidden_square_confocal", "tal", ["benchmarks/tal/hidden_square_confocal.yaml"]),
    # d. the detector draws of benchmarks/bench_spad.py (smaller) and the other detector models / presets
    _job("spad_draws", "spad"),
]

VOLATILE_KEYS = {
    "timings_s", "timing", "timings", "versions", "version", "code_version", "created", "runs", "seconds",
    "wall_s", "finished", "host", "samples_per_s", "per_sample_s", "per_stage_mean_s", "elapsed", "wall_time",
}
"""Metadata keys dropped (at any depth) before the attributes are compared: timings, versions, dates."""

CHECK_AND_RUN_CLI = (
    "import os, sys, datagen\n"
    "f = os.path.realpath(datagen.__file__)\n"
    "t = os.path.realpath(os.environ['COMPARE_OUTPUTS_TREE'])\n"
    "sys.stderr.write('datagen_file=' + f + '\\n')\n"
    "if not f.startswith(t + os.sep):\n"
    "    sys.exit('datagen imported from ' + f + ', not from the tree ' + t)\n"
    "from datagen.cli import main; main()\n"
)


# ------------------------------------------------------------------------------------------------------------
# Reading outputs (plain file readers: no datagen import, work for the stores of both trees)
# ------------------------------------------------------------------------------------------------------------
def _plain_array(value) -> np.ndarray:
    """numpy array with a standard dtype: variable-width / object strings become fixed-width unicode."""
    arr = np.asarray(value)
    if arr.dtype.kind in "OT" or type(arr.dtype).__name__ == "StringDType":
        flat = [x.decode("utf-8", "surrogateescape") if isinstance(x, bytes) else str(x) for x in arr.ravel()]
        arr = np.array(flat, dtype=np.str_).reshape(arr.shape)
    return arr


def read_zarr_store(path: Path) -> tuple[dict, dict]:
    """(arrays, metadata) of every array / group under a Zarr store, walked generically from its files."""
    import warnings

    import zarr

    try:
        root = zarr.open_group(str(path), mode="r", use_consolidated=False)
    except TypeError:  # older zarr without use_consolidated
        root = zarr.open_group(str(path), mode="r")
    arrays, meta = {}, {}
    if dict(root.attrs):
        meta["/"] = dict(root.attrs)
    with warnings.catch_warnings():   # the dataset's _done/ markers are not zarr nodes
        warnings.filterwarnings("ignore", message="Object at .* is not recognized")
        members = sorted(root.members(max_depth=None), key=lambda kv: kv[0])
    for name, node in members:
        attrs = dict(node.attrs)
        if isinstance(node, zarr.Array):
            value = np.asarray(node[...])
            arrays[name] = _plain_array(value)
            if arrays[name].dtype != value.dtype:   # e.g. StringDType read as fixed-width unicode
                meta[f"{name}#stored_dtype"] = str(value.dtype)
        if attrs:
            meta[name] = attrs
    return arrays, meta


def read_hdf5(path: Path) -> tuple[dict, dict]:
    """(arrays, metadata) of an HDF5 file: numeric/bool datasets are arrays; string datasets (tal's YAML
    ``scene_info``) and all HDF5 attributes are metadata; null-dataspace datasets are recorded by dtype."""
    import h5py

    arrays, meta = {}, {}
    with h5py.File(path, "r") as f:
        if f.attrs:
            meta["/"] = {k: _jsonable(v) for k, v in f.attrs.items()}

        def visit(name, obj):
            if obj.attrs:
                meta[f"{name}@attrs"] = {k: _jsonable(v) for k, v in obj.attrs.items()}
            if not isinstance(obj, h5py.Dataset):
                return
            if obj.shape is None:
                meta[name] = {"null_dataspace_dtype": obj.dtype.str}
                return
            value = obj[()]
            arr = np.asarray(value)
            if arr.dtype.kind in "biufc":
                if arr.dtype.metadata:            # h5py's bool/enum dtypes carry metadata npz cannot store
                    arr = arr.astype(np.dtype(arr.dtype.str))
                arrays[name] = arr
            else:
                text = [x.decode("utf-8", "surrogateescape") if isinstance(x, bytes) else str(x)
                        for x in arr.ravel()]
                meta[name] = [_yaml_or_text(t) for t in text] if arr.ndim else _yaml_or_text(text[0])

        f.visititems(visit)
    return arrays, meta


def _yaml_or_text(text: str):
    try:
        import yaml
        return _jsonable(yaml.safe_load(text))
    except Exception:
        return text


def _jsonable(value):
    return json.loads(json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def normalise_meta(value, replacements: list[tuple[str, str]]):
    """Drop volatile keys at any depth; replace tree / work directory paths inside strings by placeholders."""
    if isinstance(value, dict):
        return {k: normalise_meta(v, replacements) for k, v in value.items() if k not in VOLATILE_KEYS}
    if isinstance(value, list):
        return [normalise_meta(v, replacements) for v in value]
    if isinstance(value, str):
        for old, new in replacements:
            value = value.replace(old, new)
        return value
    return value


# ------------------------------------------------------------------------------------------------------------
# The SPAD job (runs inside the subprocess, with PYTHONPATH=TREE)
# ------------------------------------------------------------------------------------------------------------
PRIVATE_SAMPLERS = {
    "sequential": ["_first_photon_sequential", "first_photon_sequential", "sample_first_photon_sequential",
                   "sequential_binomials", "_sequential_binomials"],
    "tree": ["_first_photon_tree", "first_photon_tree", "sample_first_photon_tree", "tree_binomials",
             "_tree_binomials"],
}
"""Names tried (in this order, in datagen.spad and then its submodules) for bench_spad's private samplers."""


def _find_spad_function(spad, candidates: list[str]):
    """(qualified name, function) of the first candidate found in ``spad`` or its submodules, else (None, None)."""
    for name in candidates:
        if callable(getattr(spad, name, None)):
            return f"{spad.__name__}.{name}", getattr(spad, name)
    if hasattr(spad, "__path__"):            # datagen.spad became a package: search its submodules
        import importlib
        import pkgutil
        for info in pkgutil.walk_packages(spad.__path__, spad.__name__ + "."):
            try:
                module = importlib.import_module(info.name)
            except Exception:
                continue
            for name in candidates:
                if callable(getattr(module, name, None)):
                    return f"{info.name}.{name}", getattr(module, name)
    return None, None


def _nlos_envelope(shape, bins, rng, window=(200, 800)):
    """bench_spad.nlos_envelope: a weak Gaussian return (σ = 4 bins) at a random bin in ``window`` per pixel."""
    t = np.arange(bins)
    centre = rng.uniform(window[0], window[1], size=shape + (1,))
    amplitude = rng.uniform(0.02, 0.1, size=shape + (1,))
    g = np.exp(-0.5 * ((t - centre) / 4.0) ** 2)
    return amplitude * g / g.sum(axis=-1, keepdims=True)


def spad_job(out_npz: Path, out_json: Path, tree: Path) -> None:
    """Detector draws of bench_spad.py (same functions, seeds and order of random draws; fewer pixels), then
    every detector model and the three presets of configs/detectors through the public datagen.spad API."""
    import datagen
    from datagen import spad

    arrays, errors, skipped, used = {}, {}, {}, {}
    f = os.path.realpath(datagen.__file__)
    if not f.startswith(os.path.realpath(tree) + os.sep):
        sys.exit(f"datagen imported from {f}, not from the tree {tree}")
    sys.stderr.write(f"datagen_file={f}\n")
    DetectorConfig = spad.DetectorConfig

    def api(name):      # a datagen.spad function, from the package or (names it does not export) a submodule
        return _find_spad_function(spad, [name])[1]

    def put(name, func):
        t0 = time.perf_counter()
        try:
            value = func()
            if os.environ.get("COMPARE_OUTPUTS_VERBOSE"):
                sys.stderr.write(f"{name}: {time.perf_counter() - t0:.3f} s\n")
        except Exception as exc:  # recorded: an error is a failure of the job in `compare`
            errors[name] = f"{type(exc).__name__}: {exc}"
            return None
        if isinstance(value, tuple):
            for i, v in enumerate(value):
                arrays[f"{name}/{i}"] = np.asarray(v)
        else:
            arrays[name] = np.asarray(value)
        return value

    # ---- bench_spad.py main(), PIXELS 64x64 -> 32x32 (still two SAMPLER_PIXEL_CHUNKs), free-running 8x8 ----
    pixels, bins, cycles, fr_pixels = (32, 32), 1024, 10**6, (8, 8)
    rng = np.random.default_rng(2024)
    cfg = DetectorConfig(repetition_rate="20MHz", n_cycles=cycles, bin_width="50ps", pde=0.3,
                         ambient_rate="1MHz", dcr="100cps")
    env = _nlos_envelope(pixels, bins, rng)
    arrays["bench/pileup_envelope"] = env
    rates = put("bench/pileup_rates", lambda: spad.rates_from_envelope(env, cfg))
    put("bench/pileup_sample_histogram", lambda: spad.sample_histogram(rates, cfg, np.random.default_rng(1)))
    r2 = rates.reshape(-1, bins)
    for key, candidates in PRIVATE_SAMPLERS.items():
        qualname, func = _find_spad_function(spad, candidates)
        if func is None:
            skipped[f"bench/pileup_{key}"] = f"none of {candidates} found in datagen.spad"
            continue
        used[key] = qualname
        put(f"bench/pileup_{key}", lambda func=func: func(np.random.default_rng(1), r2, cycles))
    pmf = put("bench/pileup_detection_pmf", lambda: api("detection_pmf")(r2))
    put("bench/pileup_numpy_multinomial", lambda: np.random.default_rng(1).multinomial(cycles, pmf))
    put("bench/pileup_expected_histogram", lambda: spad.expected_histogram(rates, cfg))
    fr = DetectorConfig(repetition_rate="20MHz", n_cycles=20_000, bin_width="50ps", pde=0.3,
                        ambient_rate="1MHz", dcr="100cps", model="free_running", dead_time="50ns")
    fr_env = _nlos_envelope(fr_pixels, 1000, rng) * 10
    arrays["bench/fr_envelope"] = fr_env
    fr_rates = put("bench/fr_rates", lambda: spad.rates_from_envelope(fr_env, fr))
    put("bench/fr_sample_histogram", lambda: spad.sample_histogram(fr_rates, fr, np.random.default_rng(2)))
    fr_long = DetectorConfig(**{**fr.model_dump(), "n_cycles": 2_000_000})
    put("bench/fr_long_2x2", lambda: spad.sample_histogram(fr_rates[:2, :2], fr_long, np.random.default_rng(3)))
    fr_ap = DetectorConfig(**{**fr.model_dump(), "afterpulse_probability": 0.01,
                              "afterpulse_time_constant": 50e-9})
    put("bench/fr_afterpulse", lambda: spad.sample_histogram(fr_rates, fr_ap, np.random.default_rng(4)))
    put("bench/fr_expected_histogram", lambda: spad.expected_histogram(fr_rates[0, :16], fr))

    # ---- every model on 8x8 pixels x 512 bins of the same kind of envelope ----
    mrng = np.random.default_rng(77)
    menv = _nlos_envelope((8, 8), 512, mrng, (60, 450)) * 5
    base = dict(repetition_rate="20MHz", n_cycles=200_000, bin_width="50ps", pde=0.3, ambient_rate="2MHz",
                dcr="100cps")
    models = {
        "poisson": dict(model="poisson"),
        "pile_up": dict(model="pile_up"),
        "pile_up_jitter_tail": dict(model="pile_up", jitter_fwhm="120ps", diffusion_tail="100ps",
                                    diffusion_fraction=0.2),
        "pile_up_gate_dnl": dict(model="pile_up", gate=["5ns", "22ns"],
                                 bin_widths=list(50e-12 * (1 + 0.05 * np.sin(np.arange(512))))),
        "pile_up_crosstalk": dict(model="pile_up", crosstalk_probability=0.01),
        "multi_stop": dict(model="multi_stop", dead_time="2ns"),
        "free_running": dict(model="free_running", dead_time="20ns"),
        "free_running_paralyzable": dict(model="free_running", dead_time="20ns", paralyzable=True),
        "free_running_afterpulse": dict(model="free_running", dead_time="20ns", afterpulse_probability=0.02,
                                        afterpulse_time_constant="10ns", n_cycles=20_000),
    }
    for i, (name, extra) in enumerate(models.items()):
        try:
            mcfg = DetectorConfig(**{**base, **extra})
        except Exception as exc:
            errors[f"models/{name}/config"] = f"{type(exc).__name__}: {exc}"
            continue
        mr = put(f"models/{name}/rates", lambda: spad.rates_from_envelope(menv, mcfg))
        if mr is None:
            continue
        put(f"models/{name}/sample_histogram",
            lambda: spad.sample_histogram(mr, mcfg, np.random.default_rng(100 + i)))
        if mcfg.crosstalk_probability == 0 and mcfg.afterpulse_probability == 0:
            put(f"models/{name}/expected_histogram", lambda: spad.expected_histogram(mr, mcfg))
    # low pixel count (< 64 pixels) and long histograms (> 4096 bins): the binary-tree sampler path
    tree_cfg = DetectorConfig(repetition_rate="5MHz", n_cycles=300_000, bin_width="20ps", pde=0.3,
                              ambient_rate="1MHz", dcr="100cps")
    tenv = _nlos_envelope((3,), 6000, np.random.default_rng(5), (500, 5500)) * 3
    tr = put("models/pile_up_tree_path/rates", lambda: spad.rates_from_envelope(tenv, tree_cfg))
    put("models/pile_up_tree_path/sample_histogram",
        lambda: spad.sample_histogram(tr, tree_cfg, np.random.default_rng(6)))
    counts = arrays.get("models/pile_up/sample_histogram")
    if counts is not None:
        put("models/pile_up/coates", lambda: spad.coates(counts, 200_000))

    # ---- the detector presets of configs/detectors (the tree's own files) ----
    for j, path in enumerate(sorted((tree / "configs" / "detectors").glob("*.yaml"))):
        name = path.stem
        try:
            pcfg = DetectorConfig.from_yaml(path)
        except Exception as exc:
            errors[f"presets/{name}/config"] = f"{type(exc).__name__}: {exc}"
            continue
        n_bins = min(2000, int(pcfg.period / pcfg.bin_width) - 1)
        shape = (8, 8) if pcfg.crosstalk_probability > 0 else (4,)
        penv = _nlos_envelope(shape, n_bins, np.random.default_rng(200 + j), (0.1 * n_bins, 0.9 * n_bins)) * 2
        pr = put(f"presets/{name}/rates", lambda: spad.rates_from_envelope(penv, pcfg))
        if pr is None:
            continue
        put(f"presets/{name}/sample_histogram", lambda: spad.sample_histogram(pr, pcfg, np.random.default_rng(300 + j)))
        if pcfg.crosstalk_probability == 0 and pcfg.afterpulse_probability == 0:
            put(f"presets/{name}/expected_histogram", lambda: spad.expected_histogram(pr, pcfg))
        put(f"presets/{name}/instrument_response", lambda: spad.instrument_response(pcfg, 256))
        put(f"presets/{name}/bin_edges", lambda: pcfg.bin_edges(n_bins))

    # ---- helpers ----
    edges = np.linspace(0.0, 50e-9, 1001)
    put("helpers/gate_fraction", lambda: spad.gate_fraction(edges, (3.3e-9, 21.7e-9)))
    put("helpers/rebin_envelope", lambda: spad.rebin_envelope(menv, np.linspace(0, 512 * 50e-12, 513),
                                                              np.linspace(0, 512 * 50e-12, 97)))
    put("helpers/gaussian_kernel", lambda: api("gaussian_kernel")(51e-12, 16e-12))
    put("helpers/exponential_kernel", lambda: api("exponential_kernel")(100e-12, 16e-12, 0.2))
    put("helpers/free_running_rate", lambda: api("free_running_rate")(
        arrays["models/free_running/rates"], DetectorConfig(**base, model="free_running", dead_time="20ns")))
    rate_grid = np.logspace(2, 8, 25)
    put("helpers/counter_rate", lambda: spad.counter_rate(rate_grid, 50e-9))
    put("helpers/counter_rate_paralyzable", lambda: spad.counter_rate(rate_grid, 50e-9, paralyzable=True))
    put("helpers/counter_variance", lambda: spad.counter_variance(rate_grid, 50e-9, 1e-3))
    put("helpers/sample_counter", lambda: spad.sample_counter(2e6, 50e-9, 1e-3, np.random.default_rng(9), size=200))
    put("helpers/sample_counter_paralyzable",
        lambda: spad.sample_counter(2e6, 50e-9, 1e-3, np.random.default_rng(9), size=200, paralyzable=True))

    np.savez_compressed(out_npz, **arrays)
    out_json.write_text(json.dumps({"errors": errors, "skipped": skipped, "private_functions_used": used},
                                   indent=1))
    if errors:
        sys.stderr.write("errors:\n" + "\n".join(f"  {k}: {v}" for k, v in errors.items()) + "\n")
        sys.exit(1)


# ------------------------------------------------------------------------------------------------------------
# dump
# ------------------------------------------------------------------------------------------------------------
def _sha256(arr: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()


def _run(cmd: list[str], tree: Path, log_stem: Path, timeout: float) -> tuple[int, float, str]:
    env = {**os.environ, "PYTHONPATH": str(tree), "COMPARE_OUTPUTS_TREE": str(tree)}
    t0 = time.perf_counter()
    with open(log_stem.with_suffix(".stdout"), "ab") as out, open(log_stem.with_suffix(".stderr"), "ab") as err:
        out.write(("$ " + " ".join(cmd) + "\n").encode())
        out.flush()
        try:
            rc = subprocess.run(cmd, cwd=tree, env=env, stdout=out, stderr=err, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = -999
    text = log_stem.with_suffix(".stderr").read_text(errors="replace")
    datagen_file = next((line.split("=", 1)[1] for line in text.splitlines() if line.startswith("datagen_file=")),
                        "")
    return rc, time.perf_counter() - t0, datagen_file


def _cli(args: list[str]) -> list[str]:
    return [sys.executable, "-c", CHECK_AND_RUN_CLI, *args]


def run_job(job: dict, tree: Path, out: Path, timeout: float) -> dict:
    """Run one job with the code of ``tree``; write arrays/<job>.npz; return its manifest entry."""
    name = job["name"]
    work = out / "_work" / name
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    log = out / "logs" / name
    for suffix in (".stdout", ".stderr"):
        log.with_suffix(suffix).unlink(missing_ok=True)
    entry = {"kind": job["kind"], "commands": [], "returncode": 0, "seconds": 0.0, "datagen_file": "",
             "arrays": {}, "meta": {}, "errors": {}, "skipped": {}}

    def step(cmd):
        rc, seconds, datagen_file = _run(cmd, tree, log, timeout)
        entry["commands"].append(" ".join("'<check datagen.__file__; from datagen.cli import main; main()>'"
                                          if c == CHECK_AND_RUN_CLI else c for c in cmd))
        entry["seconds"] += seconds
        entry["datagen_file"] = entry["datagen_file"] or datagen_file
        if rc != 0 and entry["returncode"] == 0:
            entry["returncode"] = rc
        return rc

    arrays, meta = {}, {}
    kind = job["kind"]
    if kind == "simulate":
        scene = SCENE
        if job.get("area_samples"):
            import yaml
            data = yaml.safe_load((tree / SCENE).read_text())
            data.setdefault("simulation", {})["area_samples"] = job["area_samples"]
            scene = str(work / "demo_room_area.yaml")
            Path(scene).write_text(yaml.safe_dump(data, sort_keys=False))
        res = work / "result"
        if step(_cli(["simulate", scene, "--out", str(res), "--quiet", *job["args"]])) == 0:
            for det in job.get("detect", []):
                step(_cli(["detect", str(res), "--detector", det, "--seed", "3"]))
            if (res / "result.zarr").exists():
                arrays, meta = read_zarr_store(res / "result.zarr")
    elif kind == "build":
        store = work / "dataset"
        if step(_cli(["build", *job["args"], "--out", str(store), "--workers", "2", "--quiet"])) == 0:
            arrays, meta = read_zarr_store(store)
    elif kind == "tal":
        h5 = work / "capture.hdf5"
        if step(_cli(["tal-render", *job["args"], "--out", str(h5), "--quiet"])) == 0:
            arrays, meta = read_hdf5(h5)
    elif kind == "spad":
        npz, info = work / "spad.npz", work / "spad.json"
        rc = step([sys.executable, str(Path(__file__).resolve()), "_spad-job", "--tree", str(tree),
                   "--out", str(npz), "--info", str(info)])
        if info.exists():
            extra = json.loads(info.read_text())
            entry["errors"], entry["skipped"] = extra["errors"], extra["skipped"]
            meta = {"private_functions_used": extra["private_functions_used"]}
        if rc == 0 or npz.exists():
            with np.load(npz) as z:
                arrays = {k: z[k] for k in z.files}
    else:
        raise ValueError(f"unknown job kind {kind!r}")

    replacements = sorted({(str(work), "<WORK>"), (os.path.realpath(work), "<WORK>"),
                           (str(tree), "<TREE>"), (os.path.realpath(tree), "<TREE>")}, key=lambda p: -len(p[0]))
    entry["meta"] = normalise_meta(_jsonable(meta), replacements)
    entry["arrays"] = {k: {"dtype": v.dtype.str, "shape": list(v.shape), "sha256": _sha256(v)}
                       for k, v in sorted(arrays.items())}
    np.savez_compressed(out / "arrays" / f"{name}.npz", **arrays)
    shutil.rmtree(work, ignore_errors=True)
    return entry


def _selected(only: str | None) -> list[dict]:
    if not only:
        return JOBS
    keys = [k.strip() for k in only.split(",") if k.strip()]
    jobs = [j for j in JOBS if any(k in j["name"] for k in keys)]
    if not jobs:
        sys.exit(f"--only {only!r} matches no job; jobs: {', '.join(j['name'] for j in JOBS)}")
    return jobs


def dump(src: Path, out: Path, only: str | None = None, timeout: float = 1200.0) -> Path:
    """Run the jobs with the code of ``src`` and write their arrays and manifest to ``out``."""
    src = src.resolve()
    if not (src / "datagen" / "__init__.py").is_file():
        sys.exit(f"{src} is not a datagen source tree (no datagen/__init__.py)")
    out = out.resolve()
    if (out / "manifest.json").exists():          # an earlier dump: start afresh (no stale arrays)
        for sub in ("arrays", "logs", "_work"):
            shutil.rmtree(out / sub, ignore_errors=True)
        (out / "manifest.json").unlink()
    for sub in ("arrays", "logs"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    manifest_path = out / "manifest.json"
    manifest = {"format": FORMAT, "src": str(src), "python": sys.version.split()[0], "jobs": {}}
    try:
        rev = subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run(["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True)
        manifest["git"] = {"head": rev.stdout.strip(), "modified_files": len(dirty.stdout.splitlines())}
    except OSError:
        pass
    t0 = time.perf_counter()
    for job in _selected(only):
        print(f"[{src.name}] {job['name']} …", end="", flush=True)
        entry = run_job(job, src, out, timeout)
        manifest["jobs"][job["name"]] = entry
        status = "ok" if entry["returncode"] == 0 and not entry["errors"] else f"FAILED (exit {entry['returncode']})"
        print(f" {status}, {len(entry['arrays'])} arrays, {entry['seconds']:.1f} s", flush=True)
        manifest_path.write_text(json.dumps(manifest, indent=1))
    manifest["seconds"] = time.perf_counter() - t0
    shutil.rmtree(out / "_work", ignore_errors=True)
    manifest_path.write_text(json.dumps(manifest, indent=1))
    print(f"dump of {src} -> {out}: {len(manifest['jobs'])} jobs in {manifest['seconds']:.1f} s")
    return out


# ------------------------------------------------------------------------------------------------------------
# compare
# ------------------------------------------------------------------------------------------------------------
def _differences(a: np.ndarray, b: np.ndarray) -> str:
    """Describe how two same-shape arrays differ: count of differing elements (bytewise), max abs / rel diff."""
    if a.size == 0:
        return "differs"
    if a.dtype.kind in "US" or b.dtype.kind in "US":
        n = int(np.count_nonzero(a.astype(str) != b.astype(str)))
        return f"{n} of {a.size} elements differ (strings)"
    if a.dtype == b.dtype:
        ab = np.ascontiguousarray(a).view(np.uint8).reshape(a.size, -1)
        bb = np.ascontiguousarray(b).view(np.uint8).reshape(b.size, -1)
        differ = np.any(ab != bb, axis=1).reshape(a.shape)
    else:
        differ = ~((a == b) | (np.isnan(a.astype(np.complex128)) & np.isnan(b.astype(np.complex128))))
    n = int(np.count_nonzero(differ))
    if n == 0:
        return "all values equal"
    if a.dtype.kind == "b" or b.dtype.kind == "b":
        return f"{n} of {a.size} elements differ"
    x, y = a[differ].astype(np.complex128 if "c" in (a.dtype.kind + b.dtype.kind) else np.float64), \
        b[differ].astype(np.complex128 if "c" in (a.dtype.kind + b.dtype.kind) else np.float64)
    finite = np.isfinite(x) & np.isfinite(y)
    nonfinite = int(np.count_nonzero(~finite))
    if finite.any():
        d = np.abs(x[finite] - y[finite])
        scale = np.maximum(np.abs(x[finite]), np.abs(y[finite]))
        rel = np.divide(d, scale, out=np.zeros_like(d), where=scale > 0)
        text = f"max abs diff {d.max():.3e}, max rel diff {rel.max():.3e}"
    else:
        text = "no finite pair"
    extra = f", {nonfinite} differ in NaN/inf" if nonfinite else ""
    zero = ", incl. -0.0 vs +0.0" if finite.any() and np.abs(x[finite] - y[finite]).max() == 0 else ""
    return f"{n} of {a.size} elements differ: {text}{extra}{zero}"


def _meta_diff(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            p = f"{path}.{k}" if path else str(k)
            if k not in a:
                out.append(f"{p}: only in B")
            elif k not in b:
                out.append(f"{p}: only in A")
            else:
                out += _meta_diff(a[k], b[k], p)
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _meta_diff(x, y, f"{path}[{i}]")]
    if a != b:
        sa, sb = json.dumps(a), json.dumps(b)
        return [f"{path}: {sa[:80]} != {sb[:80]}"]
    return []


def compare(dir_a: Path, dir_b: Path, check_attrs: bool = True, only: str | None = None) -> int:
    """Print one line per job/array and a summary; return 0 if every array is bit-identical, else 1."""
    ma = json.loads((dir_a / "manifest.json").read_text())
    mb = json.loads((dir_b / "manifest.json").read_text())
    print(f"A: {dir_a}  (src {ma.get('src')}, git {ma.get('git', {}).get('head', '?')[:10]})")
    print(f"B: {dir_b}  (src {mb.get('src')}, git {mb.get('git', {}).get('head', '?')[:10]})")
    counts = {"identical": 0, "different": 0, "missing": 0}
    failed_jobs, warnings, skipped = [], [], []
    names = list(ma["jobs"]) + [n for n in mb["jobs"] if n not in ma["jobs"]]
    if only:
        keys = [k.strip() for k in only.split(",") if k.strip()]
        names = [n for n in names if any(k in n for k in keys)]
    width = max([len(n) for n in names] + [10])
    for job in names:
        ja, jb = ma["jobs"].get(job), mb["jobs"].get(job)
        if ja is None or jb is None:
            print(f"{job:<{width}}  MISSING job in {'A' if ja is None else 'B'}")
            failed_jobs.append(job)
            continue
        for side, j in (("A", ja), ("B", jb)):
            if j["returncode"] != 0 or j["errors"]:
                print(f"{job:<{width}}  FAILED in {side}: exit {j['returncode']}"
                      + "".join(f"; {k}: {v}" for k, v in j["errors"].items()))
                failed_jobs.append(f"{job} ({side})")
        skip = set(ja.get("skipped", {})) | set(jb.get("skipped", {}))
        za, zb = np.load(dir_a / "arrays" / f"{job}.npz"), np.load(dir_b / "arrays" / f"{job}.npz")
        with za, zb:
            in_a, in_b = set(za.files), set(zb.files)
            arrays = sorted(in_a | in_b | skip)
            aw = max([len(a) for a in arrays] + [1])
            for arr in arrays:
                label = f"{job:<{width}}  {arr:<{aw}}"
                if arr in skip:
                    why = ja.get("skipped", {}).get(arr) or jb.get("skipped", {}).get(arr)
                    side = "A and B" if arr in ja.get("skipped", {}) and arr in jb.get("skipped", {}) else \
                        ("A" if arr in ja.get("skipped", {}) else "B")
                    print(f"{label}  SKIPPED in {side} ({why})")
                    skipped.append(f"{job}/{arr}")
                    continue
                if arr not in in_a or arr not in in_b:
                    print(f"{label}  MISSING in {'A' if arr not in in_a else 'B'}")
                    counts["missing"] += 1
                    continue
                a, b = za[arr], zb[arr]
                if a.dtype != b.dtype or a.shape != b.shape:
                    what = []
                    if a.dtype != b.dtype:
                        what.append(f"dtype {a.dtype} vs {b.dtype}")
                    if a.shape != b.shape:
                        what.append(f"shape {a.shape} vs {b.shape}")
                    elif a.dtype.kind not in "US" and b.dtype.kind not in "US":
                        what.append(_differences(a, b))
                    print(f"{label}  DIFFERENT: {'; '.join(what)}")
                    counts["different"] += 1
                elif np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes():
                    print(f"{label}  identical")
                    counts["identical"] += 1
                else:
                    print(f"{label}  DIFFERENT: {_differences(a, b)}")
                    counts["different"] += 1
        if check_attrs:
            diffs = _meta_diff(ja["meta"], jb["meta"])
            for d in diffs:
                print(f"{job:<{width}}  WARNING attrs differ: {d}")
            if diffs:
                warnings.append(f"{job}: {len(diffs)} attribute difference(s)")
    total = sum(counts.values())
    ok = counts["different"] == 0 and counts["missing"] == 0 and not failed_jobs and total > 0
    print(f"SUMMARY: {total} arrays in {len(names)} jobs: {counts['identical']} identical, {counts['different']} "
          f"different, {counts['missing']} missing; {len(failed_jobs)} failed job run(s)"
          f"{' (' + ', '.join(failed_jobs) + ')' if failed_jobs else ''}; {len(skipped)} skipped; "
          f"{len(warnings)} job(s) with attribute warnings{' (' + '; '.join(warnings) + ')' if warnings else ''}"
          f" -> {'ALL IDENTICAL' if ok else 'NOT IDENTICAL'}")
    return 0 if ok else 1


# ------------------------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------------------------
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("dump", help="run the jobs with the code of --src and write arrays + manifest to --out")
    p.add_argument("--src", type=Path, required=True, help="source tree (its datagen/ is imported)")
    p.add_argument("--out", type=Path, required=True, help="dump directory (created)")
    p.add_argument("--only", default=None, help="comma-separated job name substrings")
    p.add_argument("--timeout", type=float, default=1200.0, help="seconds per subprocess")
    p = sub.add_parser("compare", help="compare two dumps bit for bit (exit 0 only if all identical)")
    p.add_argument("dir_a", type=Path)
    p.add_argument("dir_b", type=Path)
    p.add_argument("--only", default=None, help="compare only these jobs (comma-separated name substrings)")
    p.add_argument("--no-attrs", action="store_true", help="do not compare the metadata (warnings only anyway)")
    p = sub.add_parser("run", help="dump --old and --new into temporary directories and compare them")
    p.add_argument("--old", type=Path, required=True)
    p.add_argument("--new", type=Path, required=True)
    p.add_argument("--only", default=None, help="comma-separated job name substrings")
    p.add_argument("--workdir", type=Path, default=None, help="where the two dumps go (default: a temp dir)")
    p.add_argument("--keep", action="store_true", help="keep the dumps")
    p.add_argument("--timeout", type=float, default=1200.0)
    sub.add_parser("list", help="list the jobs")
    p = sub.add_parser("_spad-job", help=argparse.SUPPRESS)
    p.add_argument("--tree", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--info", type=Path, required=True)
    args = parser.parse_args(argv)

    if args.command == "dump":
        dump(args.src, args.out, args.only, args.timeout)
        return 0
    if args.command == "compare":
        return compare(args.dir_a.resolve(), args.dir_b.resolve(), check_attrs=not args.no_attrs, only=args.only)
    if args.command == "list":
        for job in JOBS:
            extra = "".join(f"  [{k}: {v}]" for k, v in job.items() if k not in ("name", "kind", "args"))
            print(f"{job['name']:<28} {job['kind']:<9} {' '.join(job['args'])}{extra}")
        return 0
    if args.command == "_spad-job":
        spad_job(args.out, args.info, args.tree.resolve())
        return 0
    # run
    base = args.workdir or Path(tempfile.mkdtemp(prefix="compare_outputs_"))
    base.mkdir(parents=True, exist_ok=True)
    a, b = base / "old", base / "new"
    for d in (a, b):
        if d.exists():
            shutil.rmtree(d)
    try:
        dump(args.old, a, args.only, args.timeout)
        dump(args.new, b, args.only, args.timeout)
        rc = compare(a, b)
    finally:
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)
        else:
            print(f"dumps kept in {a} and {b}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
