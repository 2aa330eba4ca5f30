"""compare-capture (datagen.analysis.compare_capture, datagen cli): a measured capture against its simulation on
the hidden time axis — the per-point offsets of each (LCT tofgrid; datagen's counted wall legs) removed."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import special
from scipy.io import savemat

from datagen.analysis.compare_capture import compare_captures, fwhm, peak_time
from datagen.cli.main import main
from datagen.io import write_result
from datagen.io.orientation import scan_to_lct
from datagen.simulation import Result
from datagen.units import SPEED_OF_LIGHT

N, DT = 4, 16e-12


def pulse(edges, t0, sigma, amp):
    return amp * np.diff(special.ndtr((edges - t0) / sigma))


def test_peak_and_width_of_a_gaussian():
    edges = np.arange(401) * DT
    t = 0.5 * (edges[1:] + edges[:-1])
    y = pulse(edges, 3.0e-9, 100e-12, 1.0)
    assert peak_time(t, y) == pytest.approx(3.0e-9, abs=0.5e-12)
    assert fwhm(t, y) == pytest.approx(2.3548 * 100e-12, rel=0.01)


def scene(tmp_path, shift=0.0, sigma=100e-12):
    """A 4 × 4 LCT capture (counts, tofgrid per point) and a datagen result store of the same hidden transients
    whose time axis counts the sensor leg, optionally shifted by ``shift`` s and of width ``sigma``."""
    rng = np.random.default_rng(5)
    ys = xs = np.linspace(-0.3, 0.3, N)
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    pts = np.stack([gx, gy, np.zeros_like(gx)], -1)
    hidden = np.full((N, N), 5e-9)                  # a hidden shell centred on the wall: one round trip everywhere
    tof_ps = 16.0 * rng.integers(125, 190, (N, N))   # whole bins: the real is shifted without rebinning its noise
    edges = np.arange(1025) * DT
    real = np.stack([[pulse(edges, tof_ps[i, j] * 1e-12 + hidden[i, j], 100e-12, 2000.0) for j in range(N)]
                     for i in range(N)])
    counts = rng.poisson(real).astype(np.float64)
    savemat(tmp_path / "real.mat", {"rect_data": scan_to_lct(counts), "width": 0.3, "bin_resolution": DT,
                                    "tofgrid": scan_to_lct(tof_ps)})      # the release's order (datagen.io.orientation)
    sensor = np.array([0.0, -1.0, -1.5])
    legs = np.linalg.norm(pts - sensor, axis=-1) / SPEED_OF_LIGHT
    sedges = 9e-9 + np.arange(601) * 8e-12
    env = np.stack([[pulse(sedges, legs[i, j] + hidden[i, j] + shift, sigma, 1e-3) for j in range(N)]
                    for i in range(N)])
    attrs = {"capture": {"type": "confocal", "convention": "aperture", "emitter_position": [0.0, -1.0, -1.5],
                         "sensor_position": sensor.tolist()},
             "config": {"count_laser_leg": False, "count_sensor_leg": True}}
    write_result(Result(sedges, env, {}, np.zeros(env.shape, np.int64), attrs, laser_points=pts,
                        sensor_points=pts, wall_normal=np.array([0.0, 0.0, 1.0])), tmp_path / "sim" / "result.zarr")
    return counts, edges, tof_ps * 1e-12, env, sedges, legs


def test_a_simulation_of_the_same_transients_is_close_and_a_shifted_one_is_measured(tmp_path):
    counts, edges, tof, env, sedges, legs = scene(tmp_path)
    m = compare_captures(counts, edges, tof, env, sedges, legs)
    assert abs(m["peak_time_diff"]) < DT and abs(m["width_diff"]) < DT          # within one bin of the real
    assert m["rel_l2"] < 0.05 and m["rel_l2_points"] < 0.2
    assert 0.7 < m["chi2_per_bin"] < 1.4                       # counting noise only
    counts, edges, tof, env, sedges, legs = scene(tmp_path, shift=120e-12, sigma=150e-12)
    m = compare_captures(counts, edges, tof, env, sedges, legs)
    assert m["peak_time_diff"] == pytest.approx(120e-12, abs=DT)
    assert m["width_diff"] == pytest.approx(2.3548 * 50e-12, abs=15e-12)
    assert m["rel_l2"] > 0.3 and m["chi2_per_bin"] > 10


def test_cli_import_fit_compare_and_draw(tmp_path):
    scene(tmp_path)
    runner = CliRunner()
    res = runner.invoke(main, ["import-capture", str(tmp_path / "real.mat"), "--out", str(tmp_path / "imp")])
    assert res.exit_code == 0, res.output
    assert "lct-mat (MAT v5) confocal capture (4, 4) x 1024 bins of 16 ps" in res.output
    assert "per-point time offsets stored" in res.output
    res = runner.invoke(main, ["compare-capture", str(tmp_path / "imp"), str(tmp_path / "sim"),
                               "--png", str(tmp_path / "side.png")])
    assert res.exit_code == 0, res.output
    assert "relative L2 (normalised, scan-summed) 0.0" in res.output and "wrote" in res.output
    assert (tmp_path / "side.png").stat().st_size > 10_000
    res = runner.invoke(main, ["compare-capture", str(tmp_path / "imp"), str(tmp_path / "sim"),
                               "--write-gain", str(tmp_path / "gain.npy")])      # this pair has no hidden signal
    assert res.exit_code == 2 and "error: --write-gain" in res.output and "the note above says why" in res.output
    assert "no hidden signal above the background" in res.output and not (tmp_path / "gain.npy").exists()
    res = runner.invoke(main, ["compare-capture", str(tmp_path / "imp"), str(tmp_path / "sim"),
                               "--write-gain", str(tmp_path / "gain.txt")])
    assert res.exit_code == 2 and "--write-gain" in res.output and "expected a .npy file" in res.output
    res = runner.invoke(main, ["compare-capture", str(tmp_path / "nothing"), str(tmp_path / "sim")])
    assert res.exit_code == 2 and res.output.startswith("error: no capture file at")


def test_cli_fit_detector_writes_a_detector_yaml(tmp_path):
    from datagen.spad import DetectorConfig, rates_from_envelope, sample_histogram
    from datagen.spad.fit import return_envelope

    cfg = DetectorConfig(model="pile_up", repetition_rate=20e6, n_cycles=100_000, bin_width=50e-12, dcr=2e5,
                         jitter_sigma=80e-12, diffusion_tail=150e-12)
    h = sample_histogram(rates_from_envelope(return_envelope(200, 50e-12, 3.03e-9, 0.5, 25e-12), cfg), cfg,
                         np.random.default_rng(0))
    np.savetxt(tmp_path / "h.csv", np.column_stack([np.arange(200) * 50e-12, h]), delimiter=",")
    res = CliRunner().invoke(main, ["fit-detector", str(tmp_path / "h.csv"), "--repetition-rate", "20MHz",
                                    "--n-cycles", "100000", "--out", str(tmp_path / "det.yaml")])
    assert res.exit_code == 0, res.output
    assert "jitter_sigma" in res.output and "goodness of fit" in res.output
    fitted = DetectorConfig.from_yaml(tmp_path / "det.yaml")
    assert fitted.jitter == pytest.approx(80e-12, rel=0.05)
    res = CliRunner().invoke(main, ["fit-detector", str(tmp_path / "h.csv"), "--repetition-rate", "20MHz",
                                    "--n-cycles", "100000", "--fix", "dead_time=4ns"])
    assert res.exit_code == 2 and "error: fixed: unknown parameter 'dead_time' for model 'pile_up'" in res.output


def test_cli_export_writes_each_format_and_refuses_what_a_format_cannot_hold(tmp_path):
    from datagen.io.lab_formats import read_lab_capture

    *_, legs = scene(tmp_path)                       # tmp_path/sim: a confocal 4 × 4 store counting the sensor leg
    runner = CliRunner()
    for fmt, name in (("lct-mat", "s.mat"), ("fk-mat", "f.mat")):
        res = runner.invoke(main, ["export", str(tmp_path / "sim"), "--format", fmt, "--out", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
    lct = read_lab_capture(tmp_path / "s.mat")
    assert lct.format == "lct-mat" and lct.data().shape == (4, 4, 600)
    assert float(np.squeeze(lct.raw["width"])) == pytest.approx(0.3)          # pitch·(N−1)/2 = the grid's half width
    np.testing.assert_allclose(lct.time_offsets(), legs - 9e-9, rtol=0, atol=1e-18)   # sensor leg − t_start (< 0)
    res = runner.invoke(main, ["export", str(tmp_path / "sim"), "--format", "tal", "--out", str(tmp_path / "t.h5")])
    assert res.exit_code == 2 and "t_accounts_first_and_last_bounces needs count_laser_leg == count_sensor_leg" \
        in res.output                                  # tal's own rule (datagen.io.tal_hdf5), one line
    res = runner.invoke(main, ["export", str(tmp_path / "sim"), "--format", "znlos", "--out", str(tmp_path / "z.h5")])
    assert res.exit_code == 2
    assert "error: ZNLOS time axes count both wall legs; the result counts laser leg False, sensor leg True" in res.output
