"""The detector of a real confocal capture (docs/detector.md "Direct light, gain and background maps", "Estimating
the detector of a capture"): the direct light gated by a stated factor, per-scan-point gain and background maps in
the detector, and ``datagen estimate-capture`` recovering known maps from a synthetic capture (and reading the
release's captures when they are at hand)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import datagen
from datagen.analysis.capture_detector import background_map, estimate_capture_detector, floor_bins, gain_exponent
from datagen.cli.main import main
from datagen.errors import ConfigError
from datagen.io import write_result
from datagen.scene import CaptureSpec, FieldOfView, Laser, Material, Scene, Sensor, WallGrid, quad
from datagen.spad import DetectorConfig, rates_from_envelope, sample_histogram
from datagen.spad.maps import read_map
from test_orientation import NEEDS_REAL, REAL

GRID = {"center": (2.0, 0.0, 1.0), "size": (0.6, 0.6), "points": (8, 8)}
DETECTOR = {"model": "poisson", "pde": 0.3, "repetition_rate": 1.0e7, "exposure": "8ms"}
OVER = {"estimator": "quadrature", "quadrature_edge": 0.05, "quadrature_fov": "edge", "secondary": "none",
        "count_sensor_leg": False, "time": {"t_start": 0.0, "bin_width": 16e-12, "n_bins": 300},
        "irf": {"fwhm": 60e-12}, "effects": {"first_bounce": True, "secondary": False}, "detector": DETECTOR}


def patch_scene() -> Scene:
    """A 0.4 m square patch 0.5 m behind the relay wall, scanned confocally at 8 x 8 points over 0.6 m."""
    wall = quad("relay_wall", (2.0, -1.05, -0.05), (0.0, 0.0, 2.1), (0.0, 2.1, 0.0), Material(albedo=0.8),
                label="relay_wall")
    patch = quad("patch", (1.5, -0.2, 0.8), (0.0, 0.4, 0.0), (0.0, 0.0, 0.4), Material(albedo=0.8))
    return Scene([wall, patch], Laser(emitter=(1.5, -3.0, 1.0), spot=(2.0, 0.0, 1.0)),
                 Sensor(position=(1.5, -3.0, 1.0), aperture_radius=0.02,
                        fov=FieldOfView(center=GRID["center"], size=GRID["size"])),
                 name="patch", capture=CaptureSpec(type="confocal", laser_grid=WallGrid(**GRID)))


@pytest.fixture(scope="module")
def scans():
    """The patch's scan (the direct light off each point at t = 0, its hidden return from 3.3 ns) without and with
    the direct light attenuated 1e-3 for 200 ps."""
    scene = patch_scene()
    plain = datagen.simulate(scene, datagen.resolve_config(scene, OVER))
    gated = {**OVER, "detector": {**DETECTOR, "direct": {"attenuation": 1e-3, "until": "200ps"}}}
    return plain, datagen.simulate(scene, datagen.resolve_config(scene, gated))


def test_direct_light_attenuated_by_the_stated_factor_until_the_stated_time(scans):
    plain, gated = scans
    edges = plain.time_edges
    before = edges[1:] <= 200e-12                       # bins wholly before the gate's end: the factor exactly
    after = edges[:-1] >= 200e-12
    np.testing.assert_allclose(gated.envelope[..., before], 1e-3 * plain.envelope[..., before], rtol=1e-12)
    np.testing.assert_array_equal(gated.envelope[..., after], plain.envelope[..., after])
    for name in plain.components:                       # every component as the detector sees it
        np.testing.assert_allclose(gated.components[name][..., before], 1e-3 * plain.components[name][..., before],
                                   rtol=1e-12)
    assert plain.envelope[..., before].sum() > 100 * plain.envelope[..., after].sum()   # the direct light is there
    assert "direct" not in plain.attrs["detector"] and gated.attrs["detector"]["direct"]["attenuation"] == 1e-3


def test_the_direct_component_attenuated_at_every_time_and_nothing_else():
    """``detector.direct`` without ``until``: the first_bounce component (laser spot → FoV point → sensor), its slow
    IRF tail included, times the attenuation in every bin; the hidden components untouched; the envelope their sum.
    A two-tail IRF (τ₂ = 280 ps) carries the direct light past 2 ns, into the hidden return, which a time gate
    (``until``) would leave unattenuated there."""
    scene = patch_scene()
    irf = {"kind": "two_tail", "sigma": 25e-12, "tail": 45e-12, "tail_weight": 0.15, "tail2": 280e-12,
           "tail2_weight": 0.3, "tail_delay": 0.0}
    over = {**OVER, "irf": irf}
    plain = datagen.simulate(scene, datagen.resolve_config(scene, over))
    attenuated = datagen.simulate(scene, datagen.resolve_config(
        scene, {**over, "detector": {**DETECTOR, "direct": {"attenuation": 1e-3}}}))
    late = plain.time_edges[:-1] >= 2e-9
    first = plain.components["first_bounce"]
    assert first[..., late].sum() > 0                                      # the direct light's tail reaches 2 ns
    np.testing.assert_allclose(attenuated.components["first_bounce"], 1e-3 * first, rtol=1e-12, atol=0)
    for name in plain.components:
        if name != "first_bounce":
            np.testing.assert_array_equal(attenuated.components[name], plain.components[name])
    total = sum(attenuated.components.values())
    np.testing.assert_allclose(attenuated.envelope, total, rtol=1e-12, atol=1e-12 * float(total.max()))
    assert attenuated.attrs["detector"]["direct"] == {"attenuation": 1e-3, "until": None}
    no_direct = {**over, "effects": {"first_bounce": False, "secondary": False},
                 "detector": {**DETECTOR, "direct": {"attenuation": 1e-3}}}
    named = dataclasses.replace(scene, source="patch.yaml")
    with pytest.raises(ConfigError) as err:
        datagen.simulate(named, datagen.resolve_config(named, no_direct))
    text = str(err.value)
    assert "\n" not in text and "detector.direct" in text and "first_bounce" in text and "until" in text
    assert "patch.yaml" in text and "attenuation: 0.001" in text


def test_the_direct_light_takes_its_own_map_and_the_hidden_light_the_gain(scans, tmp_path):
    """``detector.direct.counts_map`` M: what the detector sees of the direct light (first_bounce times the gain map
    G) follows M point by point (to 1e-9) with its scan total unchanged, while the hidden light keeps G; read from a
    detector file beside its .npy; one line when the map does not fit the scan or the direct light is not
    simulated."""
    scene = patch_scene()
    plain = scans[0]
    gain, _ = _known_maps()
    y, x = np.meshgrid(np.linspace(0, 1, 8), np.linspace(0, 1, 8), indexing="ij")
    counts_map = 16.0 ** (1 - x) * (1 + 0.5 * y)                  # the direct light brighter on the left, 16 x 1.5
    np.save(tmp_path / "direct_counts.npy", counts_map)
    (tmp_path / "det.yaml").write_text(yaml.safe_dump({"detector": {
        **DETECTOR, "bin_width": 16e-12, "gain_map": gain.tolist(),
        "direct": {"attenuation": 1.0, "counts_map": "direct_counts.npy"}}}))
    det = DetectorConfig.from_yaml(tmp_path / "det.yaml")
    np.testing.assert_array_equal(np.asarray(det.direct.counts_map), counts_map)
    over = {**OVER, "detector": {k: v for k, v in det.model_dump().items() if v is not None}}
    shaped = datagen.simulate(scene, datagen.resolve_config(scene, over))
    first, seen = plain.components["first_bounce"], shaped.components["first_bounce"]
    direct_seen = seen.sum(-1) * gain
    np.testing.assert_allclose(direct_seen / direct_seen.sum(), counts_map / counts_map.sum(), rtol=1e-9)
    assert direct_seen.sum() == pytest.approx(float((first.sum(-1) * gain).sum()), rel=1e-9)
    for name in plain.components:
        if name != "first_bounce":
            np.testing.assert_array_equal(shaped.components[name], plain.components[name])
    total = sum(shaped.components.values())
    np.testing.assert_allclose(shaped.envelope, total, rtol=1e-12, atol=1e-12 * float(total.max()))
    wrong = {**over, "detector": {**over["detector"], "direct": {"attenuation": 1.0, "counts_map": [[1.0] * 4] * 4}}}
    named = dataclasses.replace(scene, source="patch.yaml")
    with pytest.raises(ConfigError) as err:
        datagen.simulate(named, datagen.resolve_config(named, wrong))
    assert "\n" not in str(err.value) and "patch.yaml" in str(err.value)
    assert "direct.counts_map has shape (4, 4)" in str(err.value) and "(8, 8)" in str(err.value)
    dark = {**over, "effects": {"first_bounce": False, "secondary": False}}
    with pytest.raises(ConfigError) as err:
        datagen.simulate(named, datagen.resolve_config(named, dark))
    assert "\n" not in str(err.value) and "counts_map" in str(err.value) and "first_bounce" in str(err.value)


def _known_maps(shape=(8, 8)):
    """A smooth gain over a factor 10 and a background in two bands of columns 3.5x apart (mean 1 each)."""
    y, x = np.meshgrid(np.linspace(0, 1, shape[0]), np.linspace(0, 1, shape[1]), indexing="ij")
    gain = 10.0 ** (0.6 * x + 0.4 * y)
    background = np.where(np.arange(shape[1]) < 3, 3.5, 1.0)[None, :] * np.ones(shape)
    return gain / gain.mean(), background / background.mean()


def test_gain_and_background_maps_enter_the_rates(scans):
    env = scans[0].envelope
    gain, background = _known_maps()
    det = DetectorConfig(model="poisson", repetition_rate=1e7, n_cycles=1000, bin_width=16e-12, dcr=1e5,
                         gain_map=gain.tolist(), background_map=background.tolist())
    expected = gain[..., None] * env + 1e5 * background[..., None] * 16e-12
    np.testing.assert_allclose(rates_from_envelope(env, det), expected, rtol=1e-12)
    with pytest.raises(ValueError, match=r"gain_map has shape \(8, 8\) but the capture has \(4, 8\) scan points"):
        rates_from_envelope(env[:4], det)


def test_a_map_of_the_wrong_shape_in_a_scene_is_one_line_naming_file_field_and_shape(tmp_path):
    np.save(tmp_path / "gain.npy", np.ones((3, 3)))
    scene = dataclasses.replace(patch_scene(), source=str(tmp_path / "scene.yaml"))
    over = {**OVER, "detector": {**DETECTOR, "gain_map": str(tmp_path / "gain.npy")}}
    with pytest.raises(ConfigError) as err:
        datagen.simulate(scene, datagen.resolve_config(scene, over))
    text = str(err.value)
    assert "\n" not in text and "scene.yaml" in text and "gain_map has shape (3, 3)" in text and "(8, 8)" in text
    np.save(tmp_path / "cube.npy", np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match=r"gain_map \(.*cube.npy\): expected a \(ny, nx\) map .* shape \(2, 2, 2\)"):
        read_map(str(tmp_path / "cube.npy"), "gain_map")
    (tmp_path / "det.yaml").write_text(yaml.safe_dump({"detector": {**DETECTOR, "bin_width": 16e-12, "background_map": "gain.npy"}}))
    assert DetectorConfig.from_yaml(tmp_path / "det.yaml").scan_map("background_map").shape == (3, 3)


def test_a_scene_files_relative_map_is_read_from_the_scene_files_folder(tmp_path, monkeypatch):
    """A scene's detector block naming ``gain.npy`` beside it was read from the working directory (docs/detector.md:
    relative to the YAML that names it, as detector files and --detector files are)."""
    folder = tmp_path / "scenes"
    folder.mkdir()
    gain = np.linspace(0.5, 1.5, 64).reshape(8, 8)
    np.save(folder / "gain.npy", gain)
    scene = dataclasses.replace(patch_scene(), source=str(folder / "scene.yaml"),
                                defaults={"detector": {**DETECTOR, "gain_map": "gain.npy"}})
    monkeypatch.chdir(tmp_path)                                  # no gain.npy here
    config = datagen.resolve_config(scene, {k: v for k, v in OVER.items() if k != "detector"})
    np.testing.assert_array_equal(config.detector_config().scan_map("gain_map"), gain)


def _synthetic_capture(env: np.ndarray, seed: int = 1):
    """Poisson counts of ``env`` through a detector with the known maps: 1e10 cycles, a floor of 20 counts per bin
    at background factor 1 (dcr 125 Hz over 16 ps bins)."""
    gain, background = _known_maps(env.shape[:2])
    det = DetectorConfig(model="poisson", repetition_rate=1e7, n_cycles=10**10, bin_width=16e-12, dcr=125.0,
                         gain_map=gain.tolist(), background_map=background.tolist())
    counts = sample_histogram(rates_from_envelope(env, det), det, np.random.default_rng(seed))
    return counts, gain, background * 20.0


def test_estimators_recover_known_gain_and_background_maps(scans):
    """Gain: the estimate reads the light each point receives, the gain times the direct light's own variation over
    the scan (the wall's geometry: 1.7x here, which a capture alone cannot tell from the gain): correlation >= 0.95
    with the gain, >= 0.99 with that product and every point within 10 % of it; background: correlation >= 0.95
    with the true floor, mean within 5 %."""
    env = scans[0].envelope
    counts, gain, floor = _synthetic_capture(env)
    est = estimate_capture_detector(counts, 16e-12, fit_irf=False)
    seen = gain * env[..., :12].sum(-1)                            # the 0.2 ns gain window: 12 bins of 16 ps
    seen /= seen.mean()
    assert np.corrcoef(est.gain.ravel(), gain.ravel())[0, 1] >= 0.95
    assert np.corrcoef(est.gain.ravel(), seen.ravel())[0, 1] >= 0.99
    assert np.abs(est.gain / seen - 1).max() <= 0.10
    assert np.corrcoef(est.background.ravel(), floor.ravel())[0, 1] >= 0.95
    assert est.background.mean() == pytest.approx(floor.mean(), rel=0.05)
    assert est.direct_to_hidden > 100                               # datagen's unattenuated direct light
    assert est.gain_exponent == 1.0                   # the hidden counts within the floor's noise: the light as it is
    no_direct = counts.copy()                     # the direct light cut: its 0.2 ns hold each point's floor alone
    no_direct[..., :12] = np.random.default_rng(4).poisson(floor[..., None], (8, 8, 12))
    cut = estimate_capture_detector(no_direct, 16e-12, fit_irf=False)
    assert (cut.gain == 1.0).all() and any("not above its noise" in note for note in cut.notes)
    assert "not above its noise" in cut.gain_note and est.gain_note.startswith("the gain's power is 1")


def test_the_floor_is_read_where_no_light_returns():
    """A return that reaches the record's end (as the "S U"'s U does) is not taken for the floor: a known floor of
    0.5 counts per bin, a direct return, a near and a far return, the far one filling the last 15 % of the window:
    the floor within 1 % (the last 10 % of the window reads more than twice it). On a flat floor the runs within
    noise of the quietest are all taken, so the floor is not biased low as the quietest run alone is: within 0.6 %
    (3 standard errors of the estimate), where the quietest run alone reads about 1.2 % low."""
    rng = np.random.default_rng(0)
    t = np.arange(2000)
    light = 400.0 * np.exp(-t / 3.0) + 3.0 * np.exp(-0.5 * ((t - 600) / 60.0) ** 2) \
        + 3.0 * ((t > 1700) & (t < 1990))
    counts = rng.poisson(0.5 + np.broadcast_to(light, (16, 16, 2000))).astype(float)
    spans = floor_bins(counts, first=40)
    assert all(stop <= 1700 for _, stop in spans)
    assert background_map(counts, spans).mean() == pytest.approx(0.5, rel=0.01)
    assert background_map(counts).mean() > 1.0                       # the last 10 %: the far return's light
    flat = rng.poisson(0.5, (16, 16, 2000)).astype(float)
    assert background_map(flat, floor_bins(flat)).mean() == pytest.approx(0.5, rel=0.006)
    est = estimate_capture_detector(counts, 16e-12, direct_bins=40, fit_irf=False)
    assert est.floor_bins == spans and est.background.mean() == pytest.approx(0.5, rel=0.01)


def test_estimate_capture_writes_a_detector_a_simulation_loads(scans, tmp_path):
    counts, gain, _ = _synthetic_capture(scans[0].envelope, seed=2)
    write_result(dataclasses.replace(scans[0], counts=counts), tmp_path / "cap" / "result.zarr")
    out = CliRunner().invoke(main, ["estimate-capture", str(tmp_path / "cap"), "--out", str(tmp_path / "est"),
                                    "--no-irf"])
    assert out.exit_code == 0, out.output
    for name in ("detector.yaml", "gain.npy", "background.npy", "direct_counts.npy", "estimates.json", "maps.png"):
        assert (tmp_path / "est" / name).is_file()
    det = DetectorConfig.from_yaml(tmp_path / "est" / "detector.yaml")
    assert np.corrcoef(det.scan_map("gain_map").ravel(), gain.ravel())[0, 1] >= 0.95
    assert det.scan_map("background_map").mean() == pytest.approx(1.0, rel=1e-9)
    record = json.loads((tmp_path / "est" / "estimates.json").read_text())
    assert record["direct_to_hidden"] > 100 and record["irf"] is None


def test_gain_exponent_reads_the_power_the_hidden_counts_follow():
    """The hidden counts a power γ of the direct counts (0.4 over a direct light varying 14x, log-uniform per point)
    times a scene that varies 5x over the scan, Poisson noise on both: γ within 0.03 from the capture alone when the
    scene does not follow the direct light; a scene brighter where the direct light is (a gradient both share) reads
    too large a γ alone and the true one with the scene as model; hidden counts within their noise read 1."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:64, :64] / 63.0
    direct_gain = 14.0 ** rng.uniform(0, 1, (64, 64))
    direct = rng.poisson(2e4 * direct_gain).astype(float)
    scene = 1.0 + 4.0 * np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.05)
    hidden = rng.poisson(300.0 * scene * direct_gain ** 0.4).astype(float)
    noise = np.sqrt(hidden)
    assert gain_exponent(direct, hidden, noise) == pytest.approx(0.4, abs=0.03)
    sloped = 14.0 ** xx                                               # the scanner's gain: brighter to the right
    direct = rng.poisson(2e4 * sloped).astype(float)
    hidden = rng.poisson(300.0 * (1 + 2 * xx) * sloped ** 0.4).astype(float)   # and so is the scene
    assert gain_exponent(direct, hidden, np.sqrt(hidden)) > 0.5
    assert gain_exponent(direct, hidden, np.sqrt(hidden), model=1 + 2 * xx) == pytest.approx(0.4, abs=0.03)
    weak = rng.normal(0.0, 30.0, (64, 64))                            # net counts of a floor: no hidden light
    notes: list[str] = []
    assert gain_exponent(direct, weak, np.full((64, 64), 30.0), notes=notes) == 1.0
    assert len(notes) == 1 and "not 3 times their noise" in notes[0]
    assert gain_exponent(direct, hidden, np.sqrt(hidden), model=np.zeros((64, 64))) == 1.0


@NEEDS_REAL
def test_estimate_capture_on_the_release_dot_chart(tmp_path):
    """The 40 cm dot chart: the direct counts vary over the scan by more than 10x (the issue measured 14x); the gain
    map is them to the power the hidden counts follow (0.50 on this chart: between 0.4 and 0.6, a span of 3-5x), and
    the hidden counts follow the gain better than the direct counts (correlation >= 0.5: the chart itself varies)."""
    out = CliRunner().invoke(main, ["estimate-capture", str(REAL / "data_dot_chart_40cm.mat"), "--bin-resolution",
                                    "4ps", "--out", str(tmp_path / "est"), "--no-irf"])
    assert out.exit_code == 0, out.output
    record = json.loads((tmp_path / "est" / "estimates.json").read_text())
    gain = np.load(tmp_path / "est" / "gain.npy")
    direct, hidden = np.asarray(record["direct_counts"]), np.asarray(record["hidden_counts"])
    direct_gain = np.asarray(record["direct_gain"])
    assert direct_gain.max() / direct_gain.min() > 10
    assert 0.4 < record["gain_exponent"] < 0.6 and 3 < gain.max() / gain.min() < 5
    powered = direct_gain ** record["gain_exponent"]
    np.testing.assert_allclose(gain, powered / powered.mean(), rtol=1e-12)
    assert np.corrcoef(direct_gain.ravel(), direct.ravel())[0, 1] >= 0.99
    assert np.corrcoef(gain.ravel(), hidden.ravel())[0, 1] >= 0.5
    assert np.corrcoef(gain.ravel(), hidden.ravel())[0, 1] > np.corrcoef(direct_gain.ravel(), hidden.ravel())[0, 1]
    assert 10 < record["direct_to_hidden"] < 200                    # suppressed: datagen's own is 1e5-1e6


# ---- drawn per sample on the training device (datagen.SPADNoise, datagen.spad.map_draws) ---------------------

def test_gain_fields_and_background_bands_drawn_per_sample_have_their_stated_ranges():
    import torch

    from datagen.spad.map_draws import draw_background_bands, draw_gain_fields

    gen = torch.Generator().manual_seed(70)
    gain = draw_gain_fields((16, 16), 14.0, 32, gen)
    ratio = gain.amax(dim=(1, 2)) / gain.amin(dim=(1, 2))
    torch.testing.assert_close(ratio, torch.full((32,), 14.0, dtype=torch.float64), rtol=1e-12, atol=0)
    torch.testing.assert_close(gain.mean(dim=(1, 2)), torch.ones(32, dtype=torch.float64), rtol=1e-12, atol=0)
    assert float((gain[:, 1:] / gain[:, :-1]).max()) < 14.0 ** 0.5    # smooth: neighbours within a factor sqrt(R)
    bands = draw_background_bands((16, 16), 4.0, 3, 32, gen)
    assert bool((bands == bands[:, :1, :]).all())                    # constant down each column
    assert float((bands.amax(dim=(1, 2)) / bands.amin(dim=(1, 2))).max()) <= 4.0 + 1e-12
    assert max(len(torch.unique(b[0])) for b in bands) <= 3
    with pytest.raises(ValueError, match="gain_range must be a finite dynamic range >= 1"):
        draw_gain_fields((4, 4), 0.5, 1)


def test_spad_noise_draws_the_maps_per_sample_and_applies_fixed_ones():
    import torch

    det = {"model": "poisson", "repetition_rate": 1e7, "n_cycles": 10**6, "bin_width": 16e-12, "dcr": 1e5}
    env = torch.full((4, 8, 8, 20), 1e-3, dtype=torch.float64)
    noise = datagen.SPADNoise(det, gain_range=10.0, background_bands=(3.0, 2), dtype=torch.float64)
    gen = torch.Generator().manual_seed(1)
    params = noise.draw_params(4, gen)
    params.update(noise.draw_maps((8, 8), 4, gen))
    rates = noise.rates(env, params)
    expected = 1e-3 * params["gain"][..., None] + 1e5 * 16e-12 * params["background"][..., None]
    torch.testing.assert_close(rates, expected.expand_as(rates), rtol=1e-12, atol=0)
    counts = noise(env, generator=3)
    assert counts.shape == env.shape
    gain, _ = _known_maps()
    fixed = datagen.SPADNoise({**det, "gain_map": gain.tolist()}, dtype=torch.float64)
    mean = fixed.expected(env)
    torch.testing.assert_close(mean[0, ..., 0], torch.as_tensor(gain) * 1e-3 * 1e6 + 1e5 * 16e-12 * 1e6,
                               rtol=1e-12, atol=0)
    with pytest.raises(ValueError, match=r"gain_map has shape \(8, 8\) but the capture has \(4, 4\)"):
        fixed(env[:, :4, :4])


def _cropped_direct_returns(seed: int = 7, centre_bin: int = 0) -> tuple[np.ndarray, dict]:
    """(4, 4, 600) counts of 4 ps bins: each point's direct return, a two-tail IRF whose core is centred in the middle
    of bin ``centre_bin`` (at 0 its rise cropped, as the LCT release's files are at their direct peak), 2e5 photons
    per point, on a floor of 0.5 counts per bin."""
    from datagen.timing.irf import Irf

    true = {"sigma": 23e-12, "tail": 60e-12, "tail_weight": 0.2, "tail2": 290e-12, "tail2_weight": 0.35,
            "tail_delay": 40e-12}
    edges = np.arange(601) * 4e-12 - (centre_bin + 0.5) * 4e-12   # the core's centre mid-bin: edges less it
    mass = Irf(kind="two_tail", **true).interval_mass(edges[:-1], edges[1:])
    lam = np.broadcast_to(2e5 * mass + 0.5, (4, 4, 600))
    return np.random.default_rng(seed).poisson(lam).astype(float), true


def test_the_irf_fit_holds_the_core_where_the_aligned_axis_puts_the_direct_light():
    """Held at the middle of the first bin (`aligned`, the default), the two-tail fit of a return cropped at its peak
    recovers the core within 5 % and the slow tail within 10 %. `free` fits the position too (on a return of the
    model's own shape it finds it; on the release's summed returns it does not, docs/detector.md); an unknown mode
    is refused."""
    counts, true = _cropped_direct_returns()
    held = estimate_capture_detector(counts, 4e-12)
    assert held.irf_position == "aligned"
    irf = held.fit.irf_model
    assert irf.sigma == pytest.approx(true["sigma"], rel=0.05)
    assert irf.tail2 == pytest.approx(true["tail2"], rel=0.10)
    assert irf.tail2_weight == pytest.approx(true["tail2_weight"], rel=0.10)
    free = estimate_capture_detector(counts, 4e-12, irf_position="free")
    assert free.irf_position == "free" and free.fit is not None
    with pytest.raises(ValueError, match="irf_position must be one of aligned, free, got 'peak'"):
        estimate_capture_detector(counts, 4e-12, irf_position="peak")


def test_the_aligned_irf_fit_follows_a_direct_peak_that_is_not_in_the_first_bin():
    """A capture whose time zero is off by 40 ps (its direct return peaking in bin 10, its rise in the record):
    `aligned` holds the core at that peak, not at the first bin, and recovers the core within 5 %."""
    counts, true = _cropped_direct_returns(centre_bin=10)
    irf = estimate_capture_detector(counts, 4e-12).fit.irf_model
    assert irf.sigma == pytest.approx(true["sigma"], rel=0.05)
    assert irf.tail2 == pytest.approx(true["tail2"], rel=0.10)
