"""Hostile input, round 4 (the capture and scoring commands): tracebacks turned into one-line errors.

Each case ran into a Python traceback before; now it is a one-line ``error:`` (exit 2) naming the option or the
file and the value.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import box_before_wall
from test_hostile import cli

from datagen.io import write_result
from datagen.simulation import resolve_config, simulate


@pytest.fixture(scope="module")
def scan_store(tmp_path_factory):
    """A 4 × 4 confocal scan result store (counts (4, 4, T))."""
    room = box_before_wall(4)
    config = resolve_config(room.scene, {"estimator": {"kind": "quadrature", "edge": 0.2}})
    path = tmp_path_factory.mktemp("scan") / "result.zarr"
    write_result(simulate(room.scene, config), path)
    return path


@pytest.mark.parametrize("pixel, words", [
    ("99,99", "--pixel 99,99: outside the scan of"),
    ("4,0", "whose points run 0..3, 0..3"),
    ("a,b", "--pixel 'a,b': give the scan point as integers 'i,j'"),
])
def test_fit_detector_pixel_outside_the_scan_is_one_line(scan_store, pixel, words):
    """Before: ``--pixel 99,99`` on a 16 × 16 store raised IndexError in the histogram read, ``--pixel a,b`` a
    ValueError traceback."""
    cli(["fit-detector", scan_store, "--repetition-rate", "20MHz", "--n-cycles", "1000", "--pixel", pixel], 2, words)


def test_a_truncated_predictions_archive_is_named(tmp_path):
    """Before: ``score`` of a truncated ``.npz`` ended in zipfile.BadZipFile (the file is read before the dataset)."""
    good = tmp_path / "pred.npz"
    np.savez(good, depth=np.ones((4, 16, 16)))
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    cli(["score", cut, "--dataset", tmp_path / "no_dataset", "--split", "train"], 2,
        f"error: {cut}: not a NumPy .npz archive, or a truncated one (BadZipFile")


# -- capture files: one validation layer (datagen/validate.py) ------------------------------------------------

def _lct(tmp_path, name: str, edit=None, n=(4, 4), t=32, tofgrid=None) -> str:
    from scipy.io import savemat
    rng = np.random.default_rng(4)
    data = rng.poisson(3.0, size=n + (t,)).astype(np.float64)
    if edit is not None:
        data = edit(data)
    fields = {"rect_data": data, "width": np.array([[0.4]]), "bin_resolution": np.array([[4e-12]])}
    if tofgrid is not None:
        fields["tofgrid"] = tofgrid
    path = tmp_path / name
    savemat(path, fields)
    return str(path)


def _nan(d):
    d[1, 2, 7] = np.nan
    return d


def _inf(d):
    d[0, 0, 3] = np.inf
    return d


def _negative(d):
    d[2, 1, 5:8] = -2.5
    return d


@pytest.mark.parametrize("name, edit, words", [
    ("nan.mat", _nan, "rect_data: 1 of 512 values are not finite (1 NaN, 0 ±inf), the first at index (1, 2, 7)"),
    ("inf.mat", _inf, "rect_data: 1 of 512 values are not finite (0 NaN, 1 ±inf), the first at index (0, 0, 3)"),
    ("neg.mat", _negative, "rect_data: 3 of 512 bins are negative (smallest -2.5, the first at index (2, 1, 5)); "
                           "photon counts are ≥ 0: a background-subtracted capture is read with --allow-negative"),
    ("imag.mat", lambda d: 1j * (d + 1), "rect_data: complex values (512 with an imaginary part; e.g. 4j at index "
                                         "(0, 0, 0)); photon counts and intensities are real"),
    ("one_bin.mat", lambda d: d[..., :1], "rect_data: 1 time bin(s) per transient (shape (4, 4, 1)); a transient "
                                          "needs at least 2"),
])
def test_import_capture_refuses_values_that_are_not_photon_counts(tmp_path, name, edit, words):
    """Before: NaN, inf, negative and complex transients were imported with exit 0 (complex: stored as zeros after
    numpy warnings), and compare-capture then printed 'relative L2 nan'; a 1-bin capture blamed the shape."""
    path = _lct(tmp_path, name, edit)
    cli(["import-capture", path, "--out", tmp_path / "out"], 2, f"error: {path}: {words}")
    assert not (tmp_path / "out").exists()                                   # nothing left behind


def test_a_background_subtracted_capture_is_read_with_allow_negative_and_detect_refuses_it(tmp_path):
    path = _lct(tmp_path, "neg.mat", _negative)
    out = cli(["import-capture", path, "--out", tmp_path / "out", "--allow-negative"], 0,
              "note: 3 of 512 bins are negative (--allow-negative")
    assert "wrote" in out
    cli(["detect", tmp_path / "out" / "result.zarr", "--detector", "configs/detectors/hwu_single_pixel.yaml"], 2,
        "envelope: 3 of 512 bins are negative", "cannot be negative")


def test_an_all_nan_tofgrid_is_refused_and_a_non_square_scan_says_what_it_is(tmp_path):
    """Before: an all-NaN tofgrid was stored ('per-point time offsets stored'); a 4 × 2 scan was imported as a
    confocal capture without a word."""
    path = _lct(tmp_path, "tof.mat", tofgrid=np.full((4, 4), np.nan))
    cli(["import-capture", path, "--out", tmp_path / "a"], 2,
        "tofgrid: 16 of 16 values are not finite (16 NaN, 0 ±inf), the first at index (0, 0)")
    path = _lct(tmp_path, "rect.mat", n=(4, 2))          # rect_data 4 x 2: datagen's (ny, nx) = (2, 4)
    cli(["import-capture", path, "--out", tmp_path / "b"], 0, "note: a 2 x 4 confocal scan, not square: LCT and f-k "
                                                               "need N x N points")


# -- detector histograms ------------------------------------------------------------------------------------

def _fit(path):
    return ["fit-detector", path, "--repetition-rate", "20MHz", "--n-cycles", "100000"]


def test_fit_detector_refuses_counts_that_overflow_and_time_columns_that_are_not_one_bin_width(tmp_path):
    """Before: counts of 1e302 were fitted with overflow warnings (a 1e306 Hz background written); a time column
    with uneven steps was fitted on its first step (background 50 % off); a decreasing one blamed the bin width;
    a CSV header line or a ragged row gave numpy's own advice."""
    t = np.arange(64) * 16e-12
    counts = np.full(64, 10.0)
    counts[20] = 1e302
    np.save(tmp_path / "huge.npy", counts)
    cli(_fit(tmp_path / "huge.npy"), 2, "counts: 1 bins exceed 9.01e+15 counts (largest 1e+302, the first at "
                                        "index (20,))")
    uneven = t.copy()
    uneven[32:] += 8e-12
    np.savetxt(tmp_path / "uneven.csv", np.c_[uneven, np.full(64, 10.0)], delimiter=",")
    cli(_fit(tmp_path / "uneven.csv"), 2, "time column: uneven steps from 1.6e-11 to 2.4e-11")
    np.savetxt(tmp_path / "down.csv", np.c_[t[::-1], np.full(64, 10.0)], delimiter=",")
    cli(_fit(tmp_path / "down.csv"), 2, "time column: not increasing: row 1")
    (tmp_path / "header.csv").write_text("time,counts\n" + "\n".join(f"{a},{b}" for a, b in zip(t, counts)))
    cli(_fit(tmp_path / "header.csv"), 2, f"{tmp_path / 'header.csv'}: cannot read it as columns of numbers "
                                          "(no header line, equal rows)")


def test_messages_blame_the_option_not_the_file_or_the_model(tmp_path, scan_store):
    """Before: ``detect --exposure -5ms`` blamed the detector file ('hwu_single_pixel.yaml: exposure: …');
    ``--dead-time-bounds 10ns,2ns`` read 'needs model free_running (got free_running)'."""
    cli(["detect", scan_store, "--detector", "configs/detectors/hwu_single_pixel.yaml", "--exposure", "-5ms"], 2,
        "Invalid value for --exposure: '-5ms': an exposure is a duration > 0")
    np.savetxt(tmp_path / "h.txt", np.full(64, 10.0))
    cli(["fit-detector", tmp_path / "h.txt", "--bin-width", "16ps", "--repetition-rate", "20MHz", "--n-cycles", "1000",
         "--model", "free_running", "--dead-time-bounds", "10ns,2ns"], 2,
        "dead_time_bounds=(1e-08 s, 2e-09 s): LOW is not below HIGH; give LOW,HIGH with 0 < LOW < HIGH")


# -- scanned dataset configs -------------------------------------------------------------------------------

def test_the_confocal_configs_draw_square_scans_and_the_rest_of_the_stream_is_unchanged():
    """Before: confocal.yaml and confocal64.yaml drew the scan's width and height independently, so their samples
    were rectangles that ``export --format lct-mat`` refused. ``height: width`` draws a square and still spends
    the height's uniform, so everything else a sample draws is the same as with the room file's rectangles."""
    from datagen.dataset.config import load_dataset_config, sample_rngs
    from datagen.dataset.sampler import sample_room

    def drawn(config, i):
        room = sample_room(config.room_distribution("train"), sample_rngs(config.seed, "train", i))
        return room.params

    for name, points in (("confocal", 32), ("confocal64", 64), ("confocal_baseline", 16)):
        config = load_dataset_config(f"configs/datasets/{name}.yaml")
        for i in range(3):
            grid = drawn(config, i)["sensor"]["scan"]["laser_grid"]
            assert grid["size"][0] == grid["size"][1] and 1.2 <= grid["size"][0] <= 1.6, (name, i, grid)
            assert grid["points"] == [points, points]
    square = load_dataset_config("configs/datasets/confocal.yaml")
    rect = square.model_copy(update={"room_overrides": {}})
    a, b = drawn(square, 0), drawn(rect, 0)
    assert a["sensor"]["scan"]["laser_grid"]["size"][1] != b["sensor"]["scan"]["laser_grid"]["size"][1]
    assert a["sensor"]["scan"]["laser_grid"]["size"][0] == b["sensor"]["scan"]["laser_grid"]["size"][0]
    assert a["sensor"]["scan"]["laser_grid"]["center"][1] == b["sensor"]["scan"]["laser_grid"]["center"][1]
    assert a["objects"] == b["objects"] and a["materials"] == b["materials"]


def test_a_square_scan_too_tall_for_the_ceiling_names_the_width(tmp_path):
    from datagen.dataset.config import load_dataset_config
    from datagen.errors import ConfigError
    config = load_dataset_config("configs/datasets/confocal.yaml")
    bad = config.model_copy(update={"room_overrides": {"ceiling": {"min": 1.5, "max": 2.0},
                                                       "capture": {"scan": {"height": "width"}}}})
    with pytest.raises(ConfigError, match=r"capture\.scan\.width\.max \(height: width\): 1\.6 m does not fit under"):
        bad.room_distribution("train")


# -- files that are truncated, misfiled or empty ------------------------------------------------------------

def test_damaged_capture_files_name_the_file_and_the_cause(tmp_path):
    """Before: a truncated MAT v7.3 gave HDF5's 'truncated file: eof = …' without the file; a width stored as text
    passed through numpy's conversion; a 0-bin capture said 'expected (N, N, T)'."""
    import h5py
    d = np.random.default_rng(1).poisson(3.0, size=(4, 4, 16)).astype(float)
    whole = tmp_path / "v73.mat"
    with h5py.File(whole, "w") as f:
        f["rect_data"], f["width"], f["bin_resolution"] = d.T, np.array([[0.4]]), np.array([[4e-12]])
    cut = tmp_path / "cut.mat"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    cli(["import-capture", cut, "--out", tmp_path / "a"], 2,
        f"error: {cut}: cannot read the HDF5 (MAT v7.3) file: truncated (shorter than its header says)")
    from scipy.io import savemat
    text = tmp_path / "text.mat"
    savemat(text, {"rect_data": d, "width": "0.4", "bin_resolution": np.array([[4e-12]])})
    cli(["import-capture", text, "--out", tmp_path / "b"], 2,
        f"error: {text}: width: text ('0.4'), not a number; lengths and durations are stored as numbers")
    empty = _lct(tmp_path, "zero.mat", lambda x: x[..., :0])
    cli(["import-capture", empty, "--out", tmp_path / "c"], 2, "rect_data: 0 time bin(s) per transient (shape "
                                                               "(4, 4, 0)); a transient needs at least 2")
    assert not any((tmp_path / n).exists() for n in "abc")


def test_histogram_files_that_are_cut_ragged_or_empty_name_the_file(tmp_path):
    np.save(tmp_path / "h.npy", np.full(64, 10.0))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "h.npy").read_bytes()[:150])
    cli(_fit(tmp_path / "cut.npy") + ["--bin-width", "16ps"], 2,
        f"{tmp_path / 'cut.npy'}: cannot read it as a NumPy .npy array: truncated (Failed to read all data")
    (tmp_path / "ragged.csv").write_text("1e-11,3\n2e-11,4,5\n3e-11,5\n")
    out = cli(_fit(tmp_path / "ragged.csv"), 2, "the number of columns changed from 2 to 3 at row 2")
    assert "usecols" not in out                                              # numpy's advice is not ours
    (tmp_path / "empty.txt").write_text("")
    cli(_fit(tmp_path / "empty.txt") + ["--bin-width", "16ps"], 2,
        "empty.txt: counts: shape (0,); a histogram is one axis of at least 8 bins")
    np.savetxt(tmp_path / "frac.txt", np.full(16, 2.5))
    cli(_fit(tmp_path / "frac.txt") + ["--bin-width", "16ps"], 2,
        "frac.txt: counts: 16 of 16 bins are not whole numbers (e.g. 2.5 at index (0,))")


def test_export_into_a_folder_suggests_the_formats_file(tmp_path, scan_store):
    """Before: ``export --format lct-mat --out FOLDER`` suggested FOLDER/capture.hdf5."""
    (tmp_path / "folder").mkdir()
    cli(["export", scan_store, "--format", "lct-mat", "--out", tmp_path / "folder"], 2,
        f"--out {tmp_path / 'folder'} is a directory; give the .mat file to write, e.g. "
        f"{tmp_path / 'folder' / 'capture.mat'}")
    cli(["export", scan_store, "--format", "znlos", "--out", tmp_path / "folder"], 2, "capture.hdf5")


# -- compare-capture ------------------------------------------------------------------------------------------

def test_compare_capture_names_the_empty_capture_and_both_windows_and_notes_a_grid_mismatch(tmp_path, scan_store):
    """Before: 'a capture has no signal in the common time window' (which? which windows?); an 8 x 8 scan against a
    4 x 4 one was compared without a word (the per-point metric silently dropped)."""
    early = _lct(tmp_path, "early.mat")                  # 32 bins of 4 ps: 0..0.128 ns, before any return
    cli(["compare-capture", early, scan_store], 2,
        f"error: real {early}, sim {scan_store}: sim: no signal in the common time window 0..0.128 ns of hidden "
        "time (real 0..0.128 ns, sim")
    room = box_before_wall(2)
    config = resolve_config(room.scene, {"estimator": {"kind": "quadrature", "edge": 0.2}})
    small = tmp_path / "scan2.zarr"
    write_result(simulate(room.scene, config), small)
    out = cli(["compare-capture", small, scan_store], 0,
              "note: real is a confocal scan of 2 x 2 points, sim a confocal scan of 4 x 4 points: compared on the "
              "scan-summed transients only (no per-point metric)")
    assert "per scan point" not in out


@pytest.fixture(scope="module")
def flood_store(tmp_path_factory):
    """A multi-zone result of scene_library/multizone_room.yaml with a 2 x 2 node flood and a coarse quadrature."""
    from test_multizone import small_scene_file
    tmp = tmp_path_factory.mktemp("flood")
    cli(["multizone", small_scene_file(tmp), "--out", tmp / "mz", "--edge", "0.3", "--quiet"], 0)
    return tmp / "mz" / "result.zarr"


def test_a_flood_is_not_compared_with_a_spot_nor_exported_to_a_capture_file(tmp_path, flood_store, scan_store):
    """Before: a confocal capture against a multi-zone result was compared without a word; export of a multi-zone
    result to znlos / tal said 'cannot reshape array of size 192 into shape (1,1,3)'."""
    cli(["compare-capture", scan_store, flood_store], 2,
        f"error: {scan_store} is a confocal scan of 4 x 4 points, {flood_store} is a multi-zone result of 4 x 4 "
        "zones (a flood): a flood's zones and a laser spot's transients are different measurements")
    for fmt in ("znlos", "tal", "lct-mat"):
        cli(["export", flood_store, "--format", fmt, "--out", tmp_path / f"x.{fmt}"], 2,
            f"error: a multi-zone result (4 x 4 zones lit by a flood) has no single laser point per transient, which "
            f"{fmt} files hold; keep it as a datagen store (docs/multizone.md)")
    assert not list(tmp_path.iterdir())


# -- multi-zone runs that are slow or empty --------------------------------------------------------------------

def _multizone_scene(tmp_path, edit) -> str:
    import yaml
    from test_multizone import small_scene_file
    path = small_scene_file(tmp_path)
    data = yaml.safe_load(path.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_a_zone_grid_the_flood_barely_lights_is_warned_about_before_the_work(tmp_path):
    """Before: zones of 20 m around a 1.4 m flood ran 18x the shipped scene's time with no word and no progress."""
    def big(d):
        d["multizone"]["zones"]["size"] = [1.4, 7.0]                # 5x the flood: 20 % of it lit
    out = cli(["multizone", _multizone_scene(tmp_path, big), "--out", tmp_path / "o", "--edge", "0.3"], 0,
              "warning: multizone.flood (1.4 x 1.4 m) lights 20.0% of multizone.zones (1.4 x 7 m, 5x its area): a "
              "multi-zone sensor's zones tile its flood", "transport:")
    assert out.index("warning: multizone.flood") < out.index("transport:")   # before the work starts
    assert out.count("lights 20.0%") == 1


def test_zone_coverage_is_the_overlap_of_two_rectangles():
    from datagen.scene import RayCaster
    from datagen.scene.capture import resolve_capture
    from datagen.scene.flood import load_multizone_scene, zone_coverage
    scene, spec = load_multizone_scene("scene_library/multizone_room.yaml")
    capture = resolve_capture(scene, RayCaster(scene))
    assert zone_coverage(capture, spec) == pytest.approx(1.0)
    for size, shift, expected in (([20.0, 20.0], 0.0, 1.96 / 400), ([1.4, 1.4], 0.7, 0.5), ([1.4, 1.4], 1.5, 0.0)):
        zones = spec.zones.model_copy(update={"size": tuple(size),
                                              "center": tuple(np.add(spec.zones.center, shift * capture.fov_u))})
        assert zone_coverage(capture, spec.model_copy(update={"zones": zones})) == pytest.approx(expected, abs=1e-12)


def test_a_window_that_ends_before_the_light_says_so(tmp_path):
    """Before: ``n_bins: 1`` in a multi-zone scene said 'no light path reaches the zones' (it arrives later)."""
    def one_bin(d):
        d["simulation"]["time"]["n_bins"] = 1
    out = cli(["multizone", _multizone_scene(tmp_path, one_bin), "--out", tmp_path / "o", "--edge", "0.3",
               "--quiet"], 0, "warning: the envelope is zero: the light that reaches the zones arrives outside the "
                              "time window 0..0.26 ns; widen simulation.time (t_start, bin_width, n_bins)")
    assert "no light path" not in out and "Warning" not in out       # nor matplotlib's log-scale warning


def test_a_build_says_its_probe_runs_shows_its_bar_and_projects_its_time(tmp_path, monkeypatch):
    """Before: a build printed nothing while its probe sample ran to the tolerance (over 120 s with the lookin
    estimator). Now one line says the probe runs, its tolerance loop reports each round, and the projected time
    follows."""
    import datagen.dataset.build as build_module
    from test_hostile_build import config_file
    monkeypatch.setattr(build_module, "PROJECTION_NOTE_S", 0.0)      # project even this small build
    out = cli(["build", config_file(tmp_path), "--out", tmp_path / "ds", "--workers", "0"], 0,
              "build smoke: probe sample (train, 0) first: its arrays fix the dataset's shapes",
              "4 replicas (512 hidden samples per laser point each): estimated error",   # the probe's rounds
              "build smoke: the probe took", "3 samples project to about", "on 1 process (samples differ")
    assert out.index("probe sample (train, 0) first") < out.index("the probe took")
    quiet = cli(["build", config_file(tmp_path), "--out", tmp_path / "ds2", "--workers", "0", "--quiet"], 0)
    assert "probe sample" not in quiet and "replicas" not in quiet


def test_verify_shows_a_bar_over_the_shards_unless_quiet(tmp_path):
    from test_hostile_build import config_file
    cli(["build", config_file(tmp_path), "--out", tmp_path / "ds", "--workers", "0", "--quiet"], 0)
    assert "verify ds" in cli(["verify", tmp_path / "ds"], 0, "ok, 3 shards")
    assert "verify ds" not in cli(["verify", tmp_path / "ds", "--quiet"], 0, "ok, 3 shards")
