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
    path = _lct(tmp_path, "rect.mat", n=(4, 2))
    cli(["import-capture", path, "--out", tmp_path / "b"], 0, "note: a 4 x 2 confocal scan, not square: LCT and f-k "
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
