"""Hostile input, round 5: no zero written with a false reason, every knob bounded, real files through
every command.

Each case exited 0 with a wrong or silent answer, or blamed the wrong thing; now it gives a right result or one
line naming the file, field or option, the value and what to do. The real Stanford files are read from
``$DATAGEN_REAL_CAPTURES`` or ``../shared/real`` (tests that need them skip, saying why, when they are absent); the
other tests make small synthetic files.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_hostile import cli
from conftest import REAL


def real_file(name: str) -> Path:
    path = REAL / name
    if not path.is_file():
        pytest.skip(f"{path} is absent: the Stanford LCT files are not shipped (set DATAGEN_REAL_CAPTURES to their folder)")
    return path


def lct_file(path: Path, peak: int | None = 20, n: int = 4, bins: int = 64, **fields) -> Path:
    """An LCT .mat of n × n transients: Poisson counts of a background of 2 per bin and, when ``peak`` is given, a
    return of 400 counts around bin ``peak`` (sigma 2 bins); ``fields`` replace or drop (None) width and
    bin_resolution."""
    from scipy.io import savemat
    rng = np.random.default_rng(5)
    mean = np.full(bins, 2.0)
    if peak is not None:
        mean += 400.0 * np.exp(-0.5 * ((np.arange(bins) - peak) / 2.0) ** 2)
    data = rng.poisson(np.broadcast_to(mean, (n, n, bins))).astype(np.float64)
    values = {"rect_data": data, "width": np.array([[0.4]]), "bin_resolution": np.array([[16e-12]]), **fields}
    savemat(path, {k: v for k, v in values.items() if v is not None})
    return path


# -- import-capture --bin-resolution: plausible, and blamed on the option ------------------------------------

@pytest.mark.parametrize("value, words", [
    ("4", "'4' is 4 s, not a TCSPC bin width (0.1 ps .. 100 ns); a number without a unit is seconds: write the unit"),
    ("4ms", "'4ms' is 4 ms, not a TCSPC bin width (0.1 ps .. 100 ns)"),
    ("1e9ps", "'1e9ps' is 1 ms, not a TCSPC bin width"),
    ("0.01ps", "'0.01ps' is 10 fs, not a TCSPC bin width"),
    ("-5ps", "'-5ps': a bin width is a duration > 0, e.g. 4ps"),
    ("0ps", "'0ps': a bin width is a duration > 0, e.g. 4ps"),
])
def test_import_capture_refuses_a_bin_resolution_no_tcspc_has_and_names_the_option(tmp_path, value, words):
    """Before: 4 / 4ms / 1e9ps were imported as bins of 4 s, 4 ms, 1 ms (exit 0); -5ps and 0ps read 'error: FILE:
    bin_resolution: expected one number > 0', a command-line value blamed on the file."""
    path = lct_file(tmp_path / "no_bins.mat", bin_resolution=None)
    out = cli(["import-capture", path, "--out", tmp_path / "o", "--bin-resolution", value], 2,
              "Invalid value for --bin-resolution", words)
    assert str(path) not in out and not (tmp_path / "o").exists()


def test_a_files_own_bin_resolution_and_width_are_checked_and_blamed_on_the_file(tmp_path):
    path = lct_file(tmp_path / "four_seconds.mat", bin_resolution=np.array([[4.0]]))
    cli(["import-capture", path, "--out", tmp_path / "a"], 2,
        f"error: {path}: bin_resolution: 4 s is not a TCSPC bin width (0.1 ps .. 100 ns); the field holds seconds "
        "(4 ps is 4e-12)")
    for width in ("-1", "nan", "1e9"):
        cli(["import-capture", lct_file(tmp_path / "w.mat", width=None), "--out", tmp_path / "b", "--width", width], 2,
            "Invalid value for --width", "the half width of the scanned wall in m, > 0 and at most 100")


def test_a_znlos_delta_t_outside_a_tcspc_bin_is_named(tmp_path):
    from datagen.errors import DatasetError
    from datagen.io.lab_checks import check_znlos_fields
    from datagen.io.lab_formats import LabCapture
    grid = np.zeros((3, 2, 2))
    grid[2] = 1.0
    raw = {"data": np.ones((1, 8, 1, 2, 2)), "deltaT": np.array(1e6), "t0": np.array(0.0),
           "cameraPosition": np.zeros(3), "laserPosition": np.zeros(3), "cameraGridPositions": grid,
           "cameraGridNormals": grid}
    with pytest.raises(DatasetError, match=r"deltaT: 1e\+06 m of path \(3\.336 ms a bin\) is not a TCSPC bin width"):
        check_znlos_fields(LabCapture("znlos", raw, None, "z.hdf5"), Path("z.hdf5"))


# -- fit-detector reads the Stanford files as import-capture does ---------------------------------------------

FIT = ["--repetition-rate", "10MHz", "--n-cycles", "100000"]


def test_fit_detector_reads_a_mat_without_bin_resolution_with_the_same_options_as_import_capture(tmp_path):
    """Before: 'no bin_resolution field; give the bin width in s (--bin-resolution)', an option fit-detector did not
    have, and --bin-width was ignored."""
    path = lct_file(tmp_path / "no_bins.mat", bin_resolution=None)
    cli(["fit-detector", path, "--pixel", "1,2"] + FIT, 2,
        f"error: {path}: no 'bin_resolution' field; give the bin width in s (--bin-resolution)")
    a = cli(["fit-detector", path, "--pixel", "1,2", "--bin-resolution", "16ps"] + FIT, 0, "model pile_up")
    b = cli(["fit-detector", path, "--pixel", "1,2", "--bin-width", "16ps"] + FIT, 0, "model pile_up")
    cli(["import-capture", path, "--out", tmp_path / "store", "--bin-resolution", "16ps"], 0)
    c = cli(["fit-detector", tmp_path / "store", "--pixel", "1,2"] + FIT, 0, "model pile_up")
    assert a == b == c                                         # one reader, one histogram, one fit
    named = "Invalid value for --bin-width / --bin-resolution"                # one option, two names
    cli(["fit-detector", path, "--bin-resolution", "4"] + FIT, 2, f"{named}: '4' is 4 s")
    cli(["fit-detector", path, "--bin-width", "-4ps"] + FIT, 2, f"{named}: '-4ps'")


def test_fit_detector_refuses_negative_bins_of_a_file_without_suggesting_an_option_it_lacks(tmp_path):
    """Before: a .mat with negative bins was refused with 'a background-subtracted capture is read with
    --allow-negative', which fit-detector does not take."""
    from scipy.io import loadmat, savemat
    path = lct_file(tmp_path / "neg.mat")
    data = loadmat(path)
    data["rect_data"][0, 1, 3] = -2.0
    savemat(path, {k: v for k, v in data.items() if not k.startswith("__")})
    out = cli(["fit-detector", path, "--pixel", "1,2"] + FIT, 2, "a detector fit needs the raw histogram")
    assert "--allow-negative" not in out and str(path) in out
    cli(["import-capture", path, "--out", tmp_path / "s", "--bin-resolution", "16ps"], 2, "--allow-negative")


def test_fit_detector_refuses_a_return_cut_at_bin_0_instead_of_writing_a_degenerate_detector(tmp_path):
    """Before: on an imported Stanford store at (32, 32) it wrote a detector YAML with a jitter of 2.5e-82 s, saying
    only that 3 parameters were unidentifiable (the files start at the direct light: the return peaks in bin 0)."""
    path = lct_file(tmp_path / "cut.mat", peak=-1)
    cli(["import-capture", path, "--out", tmp_path / "store"], 0)
    out_yaml = tmp_path / "det.yaml"
    cli(["fit-detector", tmp_path / "store", "--pixel", "2,3", "--out", out_yaml] + FIT, 2,
        f"error: {tmp_path / 'store'} point (2, 3): the return peaks in bin 0 of 64 and every bin before it holds "
        "more than half its peak: the histogram starts after the return's rising edge, so its position and jitter "
        "cannot be fitted", "hold both with --fix position=... --fix jitter_sigma=...")
    assert not out_yaml.exists()
    cli(["fit-detector", tmp_path / "store", "--pixel", "2,3", "--fix", "position=0", "--fix", "jitter_sigma=20ps"]
        + FIT, 0, "model pile_up")                              # held: the rest is fitted


def test_a_histogram_file_cut_at_its_first_bin_or_given_a_bin_width_in_seconds_is_refused(tmp_path):
    np.savetxt(tmp_path / "cut.txt", np.r_[np.linspace(500, 20, 30), np.full(34, 20.0)].round())
    cli(["fit-detector", tmp_path / "cut.txt", "--bin-width", "16ps"] + FIT, 2,
        f"error: {tmp_path / 'cut.txt'}: the return peaks in bin 0 of 64")
    cli(["fit-detector", tmp_path / "cut.txt", "--bin-width", "16"] + FIT, 2,
        "Invalid value for --bin-width / --bin-resolution: '16' is 16 s, not a TCSPC bin width")


def test_the_library_fit_refuses_the_same_histogram():
    from datagen.errors import ConfigError
    from datagen.spad.fit import fit_detector, rising_edge_missing
    h = np.r_[np.linspace(500, 20, 30), np.full(34, 20.0)].round()
    assert rising_edge_missing(h) == 0
    assert rising_edge_missing(np.r_[np.full(10, 20.0), h]) is None
    with pytest.raises(ConfigError, match=r"peaks in bin 0 of 64 .*\(its rising edge is before the first bin\)"):
        fit_detector(h, bin_width=16e-12, repetition_rate=1e7, n_cycles=100000)


def test_the_stanford_file_through_import_capture_and_fit_detector():
    """data_s_u.mat (no bin_resolution; 4 ps bins): both commands read it the same way and say what is wrong."""
    path = real_file("data_s_u.mat")
    cli(["import-capture", path, "--out", "/nonexistent/never", "--bin-resolution", "4"], 2,
        "Invalid value for --bin-resolution: '4' is 4 s")
    cli(["fit-detector", path, "--pixel", "32,32", "--bin-width", "4ps"] + FIT, 2,
        f"error: {path} point (32, 32): the return peaks in bin 0 of 2048")


# -- every command that reads a store checks its values ------------------------------------------------------

@pytest.fixture
def tampered_store(tmp_path):
    """An imported 4 × 4 capture store, and a function that writes values into its envelope."""
    import zarr
    path = lct_file(tmp_path / "c.mat")
    cli(["import-capture", path, "--out", tmp_path / "st"], 0)

    def put(index, value):
        group = zarr.open_group(str(tmp_path / "st" / "result.zarr"), mode="a")
        env = group["envelope"][...]
        env[index] = value
        group["envelope"][...] = env
        return tmp_path / "st"
    return path, put


def test_a_store_holding_nan_is_named_by_every_command_that_reads_it(tmp_path, tampered_store):
    """Before: compare-capture said 'real: no signal in the common time window'; export wrote the .mat without a
    word; export-tal wrote H with 'sum nan'."""
    mat, put = tampered_store
    store = put((1, 2, 5), np.nan)
    words = (f"error: store {store}: envelope: 1 of 1024 values are not finite (1 NaN, 0 ±inf), the first at index "
             "(1, 2, 5); no store datagen writes holds them: write it again")
    cli(["compare-capture", store, mat], 2, words)
    cli(["compare-capture", mat, store], 2, words)
    cli(["export", store, "--format", "lct-mat", "--out", tmp_path / "x.mat"], 2, words)
    cli(["export-tal", store, "--out", tmp_path / "x.hdf5"], 2, words)
    cli(["fit-detector", store] + FIT, 2, words)
    assert not (tmp_path / "x.mat").exists() and not (tmp_path / "x.hdf5").exists()


def test_a_store_holding_negative_values_is_named_and_read_with_allow_negative(tmp_path, tampered_store):
    mat, put = tampered_store
    store = put((0, 0, 3), -1.0)
    words = (f"error: store {store}: envelope: 1 of 1024 bins are negative (smallest -1, the first at index "
             "(0, 0, 3)); photon counts are ≥ 0: a background-subtracted capture is read with --allow-negative")
    cli(["compare-capture", store, mat], 2, words)
    cli(["export", store, "--format", "lct-mat", "--out", tmp_path / "x.mat"], 2, words)
    cli(["export", store, "--format", "lct-mat", "--out", tmp_path / "x.mat", "--allow-negative"], 0,
        "note: 1 of 1024 bins are negative (--allow-negative")
    cli(["compare-capture", store, mat, "--allow-negative"], 0, "relative L2")
    cli(["fit-detector", store] + FIT, 2, "bins are negative", "a detector fit needs the raw histogram")


# -- a full disk names the store ----------------------------------------------------------------------------

def multizone_config(tmp_path: Path) -> Path:
    """configs/datasets/multizone_smoke.yaml cut to one sample per split."""
    import yaml
    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import SplitSpec
    config = load_dataset_config(Path(__file__).resolve().parents[1] / "configs" / "datasets" / "multizone_smoke.yaml")
    config = config.model_copy(update={"splits": {"train": SplitSpec(count=1), "val": SplitSpec(count=1)}})
    path = tmp_path / "mz.yaml"
    path.write_text(yaml.safe_dump(config.to_json()))
    return path


def test_a_full_disk_while_creating_a_multizone_store_names_the_store(tmp_path, monkeypatch):
    """Before: 'error: [Errno 28] No space left on device', no path (shard writes named theirs; creating the store's
    arrays and card did not)."""
    import errno

    import zarr

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(zarr.Group, "create_array", full)
    out = tmp_path / "ds"
    cli(["build", multizone_config(tmp_path), "--out", out, "--workers", "0", "--quiet"], 2,
        f"No space left on device while creating the dataset store {out}; free space, then run again")
    assert not out.exists()                                   # nothing half-made is left to block the next build


# -- builds say when their samples miss the tolerance, --quiet or not ---------------------------------------

def test_a_quiet_build_whose_samples_miss_the_tolerance_says_so(tmp_path, monkeypatch):
    """Before: ``build --quiet`` of smoke.yaml at tolerance 0.01 % printed 'status complete' and nothing else, while
    the card recorded that every sample missed it; the projection of a long build was printed only with the bar."""
    import yaml
    import datagen.dataset.build as build_module
    from test_hostile_build import tiny
    monkeypatch.setattr(build_module, "PROJECTION_NOTE_S", 0.0)       # project even this small build
    data = tiny(train=2, val=0).to_json()
    data["tolerance"] = 1e-4
    config = tmp_path / "tight.yaml"
    config.write_text(yaml.safe_dump(data))
    out = cli(["build", config, "--out", tmp_path / "ds", "--workers", "0", "--quiet"], 0,
              "status complete",
              "build smoke: the probe took",                              # the projection, without the bar
              "build smoke: the probe sample (train, 0) reached an estimated error of",
              "above the tolerance 0.01%",
              "warning: 2 of 2 samples missed the tolerance 0.01% (estimated envelope errors",
              "they are stored with their error and listed in the card (accuracy.missed): raise cost_cap (0.5 s) or "
              "loosen the tolerance")
    assert out.count("warning:") == 1 and "replicas" not in out          # one line; no bar, no rounds
    met = cli(["build", config_file_at(tmp_path, tiny(train=1, val=0)), "--out", tmp_path / "ok", "--workers", "0",
               "--quiet"], 0, "status complete")
    assert "missed" not in met and "warning" not in met


def test_a_quiet_lookin_build_at_a_tiny_cost_cap_and_no_tolerance_says_what_it_missed(tmp_path):
    """Before: a lookin dataset with ``cost_cap: 0.1s`` and no tolerance printed nothing with --quiet."""
    import yaml
    from test_hostile_build import tiny
    data = tiny(train=2, val=0).to_json()
    data["simulation"]["estimator"] = {"kind": "lookin", "lookins": [4, 4], "pixels": [16, 16]}
    data["cost_cap"] = "0.1s"
    data.pop("tolerance", None)
    config = tmp_path / "lookin.yaml"
    config.write_text(yaml.safe_dump(data))
    cli(["build", config, "--out", tmp_path / "ds", "--workers", "0", "--quiet"], 0,
        "above the tolerance 1.00% (the default: the config sets none)",
        "warning: 2 of 2 samples missed the tolerance 1% (estimated envelope errors",
        "raise cost_cap (0.1 s) or loosen the tolerance")


def config_file_at(tmp_path: Path, config) -> Path:
    import yaml
    path = tmp_path / f"config_{len(list(tmp_path.glob('config_*')))}.yaml"
    path.write_text(yaml.safe_dump(config.to_json()))
    return path


# -- zero results state the true reason; zones the sampling cannot resolve are refused up front --------------

def multizone_scene(tmp_path: Path, zones: list[int], size: float = 20.0) -> Path:
    """scene_library/multizone_room.yaml with a 2 × 2 node flood and ``zones`` zones over a size × size m grid."""
    import yaml
    data = yaml.safe_load((Path(__file__).resolve().parents[1] / "scene_library" / "multizone_room.yaml").read_text())
    data["multizone"]["flood"]["nodes"] = [2, 2]
    data["multizone"]["zones"].update(size=[size, size], zones=zones)
    path = tmp_path / "mz.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_zones_whose_only_sample_points_miss_the_wall_are_refused_before_the_work(tmp_path):
    """Before: 4 × 4 zones of a 20 m grid around the 1.4 m flood: exit 0, an all-zero envelope and 'no path from the
    laser reaches the sensor grid' (false: 16 × 16 zones of the same grid collect light). The quadrature samples a
    flood's zone at its centre, and every centre was off the 2 m-high wall."""
    scene = multizone_scene(tmp_path, [4, 4])
    out = cli(["multizone", scene, "--out", tmp_path / "o", "--quiet"], 2,
              f"error: {scene}: multizone.zones: 4 x 4 zones of 5 x 5 m sampled at 1 x 1 point(s) each (the "
              "quadrature's FoV cells at their centres): none of the 16 points lies on a surface the sensor sees, "
              "while 4 zones hold one (4% .. 9% of their area): the envelope would be zero though light reaches them; "
              "set simulation.estimator.fov_cells: 16")
    assert "no path" not in out and not (tmp_path / "o").exists()


def test_zones_the_sampling_resolves_badly_are_warned_about_and_the_run_goes_on(tmp_path):
    """3 × 3 zones of the same grid: the middle zone's centre is on the wall, which covers a tenth of it; the
    quadrature counts the whole zone as wall."""
    out = cli(["multizone", multizone_scene(tmp_path, [3, 3]), "--out", tmp_path / "o", "--quiet"], 0,
              "warning: multizone.zones: 3 x 3 zones of 6.67 x 6.67 m sampled at 1 x 1 point(s) each",
              "in 1 of 9 zones the share of the points on a surface the sensor sees is off that of the zone's area "
              "by more than 50% of it", "set simulation.estimator.fov_cells")
    assert out.index("warning: multizone.zones") < out.index("3×3 zones, flood")     # before the work
    quiet = cli(["multizone", multizone_scene(tmp_path, [4, 4], size=1.4), "--out", tmp_path / "p", "--quiet"], 0)
    assert "warning" not in quiet                        # the shipped zones tile the wall: nothing to say


def glossy_box(tmp_path: Path, exponent: float = 1e6) -> Path:
    """A closed 3 × 2 × 2.5 m box whose every wall is a Phong lobe (specular 1) of ``exponent``."""
    import yaml
    m = {"kind": "phong", "albedo": 0.9, "specular": 1.0, "exponent": exponent}
    walls = [("relay_wall", [3, -1, 0], [0, 2, 0], [0, 0, 2.5]), ("back", [0, -1, 0], [0, 2, 0], [0, 0, 2.5]),
             ("left", [0, -1, 0], [3, 0, 0], [0, 0, 2.5]), ("right", [0, 1, 0], [3, 0, 0], [0, 0, 2.5]),
             ("floor", [0, -1, 0], [3, 0, 0], [0, 2, 0]), ("ceiling", [0, -1, 2.5], [3, 0, 0], [0, 2, 0])]
    objects = [{"builder": "quad", "name": n, "corner": c, "edge_u": u, "edge_v": v, "material": m,
                **({"label": "relay_wall"} if n == "relay_wall" else {})} for n, c, u, v in walls]
    scene = {"name": "glossy_box", "objects": objects,
             "laser": {"emitter": [1.5, 0, 1.25], "spot": [3, 0.3, 1.6], "photons_per_pulse": 1.0},
             "sensor": {"position": [1.5, 0, 1.25], "aperture_radius": "10mm",
                        "fov": {"center": [3, -0.2, 1.0], "size": [0.4, 0.4]}},
             "simulation": {"time": {"t_start": "0ns", "bin_width": "100ps", "n_bins": 200}, "irf": {"fwhm": "200ps"},
                            "detector": {"model": "poisson", "repetition_rate": "10MHz", "n_cycles": 1000}}}
    path = tmp_path / "glossy_box.yaml"
    path.write_text(yaml.safe_dump(scene))
    return path


def test_a_zero_of_lobes_too_narrow_to_sample_says_so_not_that_no_path_exists(tmp_path):
    """Before: a closed box of Phong walls (exponent 1e6, specular 1), --orders auto: exit 0, all-zero envelope and
    'no path from the laser reaches the sensor grid'; paths exist, no sample found one."""
    out = cli(["simulate", glossy_box(tmp_path), "--out", tmp_path / "o", "--lookins", "2x2", "--pixels", "16x16",
               "--orders", "auto", "--quiet"], 0,
              "warning: the envelope of the FoV is zero: no sample (lookins 2x2, pixels 16x16) found a path; the "
              "glossy lobes of back, ceiling, floor, left (+2 more) (phong exponent up to 1e+06, about 0.001 rad "
              "wide) may be narrower than the sampling resolves, so paths may exist that it missed")
    assert "no path from the laser reaches" not in out


def test_a_scene_where_nothing_reaches_the_fov_says_what_was_sampled(tmp_path):
    scene = Path(__file__).resolve().parents[1] / "scene_library" / "hard" / "nothing_reaches_fov.yaml"
    cli(["simulate", scene, "--out", tmp_path / "o", "--lookins", "4x4", "--pixels", "16x16", "--quiet"], 0,
        "warning: the envelope of the FoV is zero: no sampled path (lookins 4x4, pixels 16x16) from the laser reached "
        "the sensor grid: the surfaces the laser lights face away from it or are blocked from it, or the sampling is "
        "too coarse to find the paths; counts hold background only")


# -- every numeric knob has an upper bound, checked before the work --------------------------------------------

def test_light_paths_beyond_their_bound_are_refused_before_the_work_and_long_work_is_projected(tmp_path):
    """Before: ``multibounce: {paths: 1e12}`` was accepted; ``simulate --quiet`` ran silent until killed at 600 s."""
    import yaml
    data = bounded_scene()
    data["simulation"].update(orders=3, secondary="full", multibounce={"paths": 1e12})
    path = tmp_path / "paths.yaml"
    path.write_text(yaml.safe_dump(data))
    cli(["simulate", path, "--out", tmp_path / "o", "--quiet"], 2,
        f"error: {path} (simulation): multibounce.paths 1000000000000 is above its bound of 1.074e+09 light paths "
        "(10-20 min of tracing at about 1 µs a path): lower multibounce.paths")
    data["simulation"]["multibounce"]["paths"] = 10**9
    path.write_text(yaml.safe_dump(data))
    out = stopped_at_the_work(["simulate", path, "--out", tmp_path / "p", "--quiet"])
    assert "note: multibounce.paths 1e+09 project about 17min of transport on one core" in out


def test_build_options_beyond_their_bounds_are_refused(tmp_path):
    from datagen.dataset.workers import check_build_options
    for option, args, words in (("--workers", (10**15, None, 2, 4), "--workers 1000000000000000 is above its bound "
                                                                     "of 1024: give at most 1024"),
                                ("--retries", (0, None, 10**15, 4), "--retries 1000000000000000 is above its bound"),
                                ("--tasks-per-worker", (0, None, 2, 10**15), "--tasks-per-worker 1000000000000000 is")):
        with pytest.raises(ValueError, match=words):
            check_build_options(*args)
    from datagen.dataset.dask_engine import check_worker_timeout
    with pytest.raises(ValueError, match=r"--worker-timeout 1e\+15 is above its bound of 86400 s"):
        check_worker_timeout(1e15)
    cli(["simulate", "scene_library/demo_room.yaml", "--out", tmp_path / "o", "--tolerance", "1%", "--time-cap",
         "1e15"], 2, "Invalid value for --time-cap: must be a duration > 0 and at most 86400 s (a day)")


def bounded_scene() -> dict:
    """tests/test_hostile.py's patch scene with a small lookin sampling and a 26 ns window."""
    import copy
    from test_hostile import PATCH
    data = copy.deepcopy(PATCH)
    data["simulation"] = {"estimator": {"kind": "lookin", "lookins": [4, 4], "pixels": [8, 8]}, "secondary": "none",
                          "error": {"replicas": 4}, "time": {"t_start": 0.0, "bin_width": "100ps", "n_bins": 256},
                          "irf": {"fwhm": "200ps"},
                          "detector": {"model": "poisson", "repetition_rate": "10MHz", "n_cycles": 1000}}
    return data


class StopBeforeWork(Exception):
    """Raised where the transport would start: the command accepted every knob."""


def invoke_stopping_at_the_work(args):
    """``datagen args`` run in process with the transport replaced by :class:`StopBeforeWork` (click's Result)."""
    from click.testing import CliRunner

    from datagen.cli import main
    from datagen.simulation.run import Replicas

    def stop(self, *args, **kwargs):
        raise StopBeforeWork

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Replicas, "run", stop)
        return CliRunner().invoke(main, [str(a) for a in args])


def stopped_at_the_work(args) -> str:
    """Run ``datagen args`` up to the transport's start (:func:`invoke_stopping_at_the_work`); the command must get
    there (no refusal). Returns its output."""
    res = invoke_stopping_at_the_work(args)
    assert isinstance(res.exception, StopBeforeWork), res.output
    return res.output


def _sim(key, value):
    def edit(data):
        data["simulation"][key] = value
    return edit


def _estimator(block):
    def edit(data):
        data["simulation"]["estimator"] = block
        data["simulation"]["secondary"] = "full" if "secondary_samples" in block or "top_k" in block else "none"
    return edit


KNOBS = {   # knob → (scene edit for value v, the largest v run to the end here; beyond it the run stops at the work)
    "multibounce.paths": (lambda v: lambda d: d["simulation"].update(orders=3, secondary="full",
                                                                      multibounce={"paths": v}), 10**6),
    "error.replicas": (lambda v: _sim("error", {"replicas": v}), 64),
    "time.n_bins": (lambda v: lambda d: d["simulation"]["time"].update(n_bins=v), 10**5),
    "orders": (lambda v: lambda d: d["simulation"].update(orders=v, secondary="full"), 10**15),
    "workers": (lambda v: _sim("workers", v), 1),
    "estimator.samples": (lambda v: _estimator({"kind": "area", "samples": v}), 10**5),
    "estimator.secondary_samples": (lambda v: _estimator({"kind": "quadrature", "edge": 0.2,
                                                           "secondary_samples": v}), 10**5),
    "estimator.fov_cells": (lambda v: _estimator({"kind": "quadrature", "edge": 0.2, "fov_cells": v}), 8),
    "estimator.lookins": (lambda v: _estimator({"kind": "lookin", "lookins": [v, 1], "pixels": [8, 8]}), 256),
    "estimator.pixels": (lambda v: _estimator({"kind": "lookin", "lookins": [2, 2], "pixels": [v, 1]}), 1024),
    "estimator.top_k": (lambda v: _estimator({"kind": "lookin", "lookins": [2, 2], "pixels": [8, 8], "top_k": v}),
                        10**15),
    "estimator.batch": (lambda v: _estimator({"kind": "lookin", "lookins": [2, 2], "pixels": [8, 8], "batch": v}),
                        10**15),
    "estimator.connect_samples": (lambda v: _estimator({"kind": "lookin", "lookins": [2, 2], "pixels": [8, 8],
                                                        "sensor_sampling": "connect", "connect_samples": [v, 1]}), 16),
    "sensor.fov.pixels": (lambda v: lambda d: d["sensor"]["fov"].update(pixels=[v, 1]), 64),
}
"""The bounded knobs of a simulation the property test draws (multi-zone zones and nodes are drawn apart)."""

RUN_S = 60.0
"""Wall seconds an accepted run of the small scene must end within (this shared 2-core machine; runs take 1–5 s)."""

REFUSE_S = 30.0
"""Wall seconds a refusal must take at most (it comes before the transport)."""


def one_line_error(output: str) -> str:
    lines = [line for line in output.splitlines() if line.startswith(("error:", "Error:"))]
    assert len(lines) == 1 and "Traceback" not in output, output
    return lines[0]


@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
@given(knob=st.sampled_from(sorted(KNOBS)), exponent=st.floats(0.0, 15.0))
@example(knob="multibounce.paths", exponent=9.0)           # accepted, 17 min projected: stopped at the work
@example(knob="estimator.samples", exponent=8.0)           # accepted, 7 min projected
@example(knob="estimator.lookins", exponent=3.5)           # accepted, no projection worth printing
@example(knob="workers", exponent=2.0)                     # accepted: 100 processes would start; stopped
@example(knob="time.n_bins", exponent=7.0)                 # 2e7 fine nodes: refused by the bound, not the accumulator
def test_every_bounded_knob_drawn_up_to_1e15_is_refused_in_one_line_or_runs_in_a_stated_time(tmp_path_factory, knob,
                                                                                           exponent):
    """A value drawn log-uniformly from 1 to 1e15: a one-line refusal naming the knob, before the work (within
    REFUSE_S), or an accepted run. Accepted values up to the knob's run limit run to the end within RUN_S; larger
    ones are stopped where the transport starts (so this test stays short), after every check passed and, when the
    work projects beyond LONG_WORK_S, the projection was printed: the bounds keep that projection within about an
    hour (docs/reliability.md, "Bounds")."""
    import time

    import yaml
    from click.testing import CliRunner

    from datagen.cli import main
    from datagen.scene import load_scene
    from datagen.simulation import resolve_config
    from datagen.simulation.bounds import LONG_WORK_S, projected_work

    value = max(1, int(round(10 ** exponent)))
    edit, run_limit = KNOBS[knob]
    data = bounded_scene()
    edit(value)(data)
    tmp = tmp_path_factory.mktemp("knob")
    path = tmp / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    args = ["simulate", path, "--out", tmp / "o", "--quiet"]
    t0 = time.perf_counter()
    if value > run_limit:
        res = invoke_stopping_at_the_work(args)
        if isinstance(res.exception, StopBeforeWork):       # accepted: the projection was said when it is long
            seconds, _ = projected_work(load_scene(path), resolve_config(load_scene(path)))
            assert seconds <= 4 * 3600, (knob, value, seconds)
            assert (seconds > LONG_WORK_S) == ("project about" in res.output), res.output
            return
    else:
        res = CliRunner().invoke(main, [str(a) for a in args])
    elapsed = time.perf_counter() - t0
    assert res.exception is None or isinstance(res.exception, SystemExit), (knob, value, res.exception)
    if res.exit_code == 2:
        line = one_line_error(res.output)
        field = knob.split(".")[-1]
        assert field in line or knob.split(".")[0] in line, (knob, value, line)
        assert elapsed < REFUSE_S, (knob, value, elapsed)
    else:
        assert res.exit_code == 0 and elapsed < RUN_S, (knob, value, elapsed, res.output)


@pytest.mark.parametrize("exponent", [2, 6, 15])
def test_multizone_zones_and_nodes_up_to_1e15_are_refused_in_one_line(tmp_path, exponent):
    import yaml
    path = multizone_scene(tmp_path, [4, 4], size=1.4)
    n = 10 ** exponent
    line = one_line_error(cli(["multizone", path, "--out", tmp_path / "a", "--nodes", f"{n}x2", "--quiet"], 2))
    assert "--nodes" in line and "64" in line, line
    data = yaml.safe_load(path.read_text())
    data["multizone"]["zones"]["zones"] = [n, 4]
    path.write_text(yaml.safe_dump(data))
    line = one_line_error(cli(["multizone", path, "--out", tmp_path / "b", "--quiet"], 2))
    assert "multizone.zones.zones" in line and "16" in line, line
