"""The LCT release's kind of data set (configs/datasets/lct_release.yaml, docs/datasets.md): the config loads, a smoke
build draws each sample's detector within the stated ranges, the planar cut-outs stand at their drawn depth and tilt,
and bad input is refused in one line naming the file, the field and the value."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from datagen.dataset.config import draw_room, load_dataset_config, make_sample
from datagen.dataset.cutouts import bar_chart_mask, cutout_mesh, dot_chart_mask, sign_mask
from datagen.dataset.detector_draws import DetectorDraws, draw_detector
from datagen.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
FULL = ROOT / "configs" / "datasets" / "lct_release.yaml"
SMOKE = ROOT / "configs" / "datasets" / "lct_release_smoke.yaml"


def test_the_config_and_its_smoke_variant_load():
    full, smoke = load_dataset_config(FULL), load_dataset_config(SMOKE)
    assert full.simulation_config("train").time.n_bins == 512
    assert full.simulation_config("train").time.bin_width == pytest.approx(16e-12)
    assert full.room_distribution("train").capture.scan.points == (64, 64)
    assert smoke.detector_draws == full.detector_draws            # the smoke variant draws the same detector


def test_the_every_order_variant_differs_only_in_the_orders_it_simulates():
    """configs/datasets/lct_release_every_order.yaml (the ablation of docs/real.md): lct_release.yaml's samples, seed,
    room, detector draws and labels, the simulation's orders 3 (the tracer's light) instead of 1 and nothing else."""
    full = load_dataset_config(FULL)
    every = load_dataset_config(ROOT / "configs" / "datasets" / "lct_release_every_order.yaml")
    skip = {"name", "simulation"}
    assert every.model_dump(exclude=skip) == full.model_dump(exclude=skip)
    a, b = full.simulation_config("train"), every.simulation_config("train")
    assert (a.orders_setting(), b.orders_setting()) == (1, 3)
    assert b.multibounce.paths == 512 and not b.effects["secondary"]
    assert b.model_dump(exclude={"orders", "multibounce", "secondary"}) == a.model_dump(
        exclude={"orders", "multibounce", "secondary"})


def test_a_smoke_sample_draws_its_detector_within_the_ranges():
    config = load_dataset_config(SMOKE)
    ranges = DetectorDraws.model_validate(config.detector_draws)
    sample = make_sample(config, "train", 0)
    drawn = json.loads(str(sample.arrays["params"]))["detector_draw"]
    for key, value in drawn["irf"].items():
        assert getattr(ranges.irf, key).contains(value), key
    assert ranges.dcr.contains(drawn["dcr"]) and ranges.gain_scale.contains(drawn["gain_scale"])
    assert ranges.gain_range.contains(drawn["gain_range"])
    assert ranges.background_bands.ratio.contains(drawn["background_bands"]["ratio"])
    assert ranges.direct.attenuation.contains(drawn["direct"]["attenuation"]) and "until" not in drawn["direct"]
    assert ranges.exposure.contains(drawn["exposure"])
    summed = sample.arrays["envelope"].sum(axis=(0, 1))           # the direct light from t = 0 (its slow tail
    assert np.all(np.diff(summed[:100]) < 0) and summed[0] > 0    # falling), the hidden light from 2 ns (bin 125)
    assert sample.arrays["counts"].shape == (16, 16, 512) and "wall_depth" in sample.arrays
    again = make_sample(config, "train", 0)                       # a pure function of (config, split, index)
    assert json.loads(str(again.arrays["params"]))["detector_draw"] == drawn
    np.testing.assert_array_equal(again.arrays["counts"], sample.arrays["counts"])


def test_the_light_level_is_drawn_as_hidden_counts(tmp_path):
    """``detector_draws.hidden_counts`` (instead of gain_scale): once simulated, the gain map is scaled so that the
    median over the scan of the expected hidden counts (the envelope less its first_bounce component, at the config's
    100 ms) is the drawn target, to 1e-9 (:func:`scale_to_hidden_counts` on a simulated scan with its components),
    and the counts are drawn with it: their net hidden sum within 4 % of the expected one at the drawn exposure
    (Poisson, thousands of counts); a target past what the detector counts is held where the brightest bin expects
    0.3 detections per cycle. In a build the record carries the target and the scale; gain_scale and hidden_counts
    together are one line."""
    import datagen
    from datagen.dataset.detector_draws import scale_to_hidden_counts
    from test_capture_detector import OVER, patch_scene
    scene = patch_scene()
    config = datagen.resolve_config(scene, {**OVER, "detector": {**OVER["detector"], "pde": 1.0, "exposure": "100ms",
                                                                 "dcr": 1e4}})
    result = datagen.simulate(scene, config)
    gain = np.linspace(0.5, 1.5, 64).reshape(8, 8)
    drawn_config = config.model_copy(update={"detector": {**config.detector, "gain_map": gain.tolist(),
                                                          "exposure": "20ms"}})
    drawn = {"hidden_counts": 100.0, "full_cycles": 1e6}
    out, cfg, record = scale_to_hidden_counts(result, drawn_config, drawn, np.random.default_rng(0))
    hidden = result.envelope - result.components["first_bounce"]
    seen = cfg.detector_config().scan_map("gain_map")
    assert np.median(1e6 * hidden.sum(-1) * seen) == pytest.approx(100.0, rel=1e-9)
    np.testing.assert_allclose(seen, gain * record["gain_scale"], rtol=1e-12)
    late = result.time_edges[:-1] >= 2.5e-9                                 # the patch's return, from 3.3 ns
    dark = (result.time_edges[:-1] >= 1e-9) & ~late                          # no light: the floor
    net = out.counts[..., late].sum() - out.counts[..., dark].mean(-1).sum() * late.sum()
    assert net == pytest.approx(0.2 * 1e6 * (hidden[..., late].sum(-1) * seen).sum(), rel=0.04)
    np.testing.assert_array_equal(out.envelope, result.envelope)
    assert out.attrs["detector"]["gain_map"][0][0] == pytest.approx(seen[0, 0]) and not record["held"]
    _, cfg, record = scale_to_hidden_counts(result, drawn_config, {**drawn, "hidden_counts": 1e12},
                                            np.random.default_rng(0))    # past what a SPAD counts: held there
    seen = cfg.detector_config().scan_map("gain_map")
    assert record["held"] and (result.envelope * seen[..., None]).max() == pytest.approx(0.3, rel=1e-12)
    raw = yaml.safe_load(SMOKE.read_text())
    draws = {k: v for k, v in raw["detector_draws"].items() if k != "gain_scale"}
    raw.update(detector_draws={**draws, "hidden_counts": [300, 3000]}, room=str((SMOKE.parent / raw["room"]).resolve()))
    (tmp_path / "lit.yaml").write_text(yaml.safe_dump(raw))
    sample = make_sample(load_dataset_config(tmp_path / "lit.yaml"), "train", 0)
    record = json.loads(str(sample.arrays["params"]))["detector_draw"]
    assert 300 <= record["hidden_counts"] <= 3000 and record["full_cycles"] == pytest.approx(1e6)
    assert record["gain_scale"] > 0 and "note" not in record
    with pytest.raises(ConfigError) as err:
        draw_detector({**draws, "hidden_counts": [300, 3000], "gain_scale": [0.5, 2.0]}, np.random.default_rng(0),
                      (16, 16), config)
    assert "\n" not in str(err.value) and "gain_scale or hidden_counts" in str(err.value)


def test_the_drawn_maps_and_irf_reach_the_simulation():
    config = load_dataset_config(SMOKE)
    from datagen.dataset.config import setup_sample
    room, sim, _ = setup_sample(config, "train", 1)
    out, record = draw_detector(config.detector_draws, np.random.default_rng(3), (16, 16), sim)
    det = out.detector_config()
    gain = det.scan_map("gain_map")
    assert gain.shape == (16, 16) and gain.mean() == pytest.approx(record["gain_scale"])
    assert gain.max() / gain.min() == pytest.approx(record["gain_range"])
    assert det.scan_map("background_map").mean() == pytest.approx(1.0)
    assert out.irf.kind == "two_tail" and out.irf.tail2 == pytest.approx(record["irf"]["tail2"])


def test_the_exposure_is_drawn_log_uniformly_down_to_a_hundredth():
    """``detector_draws.exposure: [1ms, 100ms]``: log-uniform, so its median is the geometric mean 10 ms (a uniform
    draw's would be 50 ms) and a quarter of the samples lie below 3.2 ms; each draw reaches the detector."""
    config = load_dataset_config(SMOKE)
    from datagen.dataset.config import setup_sample
    _, sim, _ = setup_sample(config, "train", 0)
    drawn = [draw_detector({"exposure": ["1ms", "100ms"]}, np.random.default_rng(i), None, sim) for i in range(400)]
    exposures = np.array([record["exposure"] for _, record in drawn])
    assert exposures.min() >= 1e-3 and exposures.max() <= 0.1
    assert np.median(exposures) == pytest.approx(1e-2, rel=0.25)            # 400 draws: the median's spread ~ 12 %
    assert np.mean(exposures < 10 ** -2.5) == pytest.approx(0.25, abs=0.07)
    assert all(out.detector_config().exposure == record["exposure"] for out, record in drawn[:5])


@pytest.mark.parametrize("index", range(8))
def test_cutouts_stand_flat_at_their_drawn_depth_and_tilt(index):
    data = yaml.safe_load(FULL.read_text())
    data["room"] = str(ROOT / "configs" / "rooms" / "lct_release.yaml")
    config = load_dataset_config(data)
    room, _ = draw_room(config, "train", index)
    (obj,) = room.objects
    mesh = next(o for o in room.scene.objects if o.name == obj["name"])
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centred = v - v.mean(0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    assert np.abs(centred @ normal).max() < 1e-6                 # one flat sheet
    tilt = np.degrees(np.arccos(abs(normal[0])))                  # against the wall's normal (x)
    assert tilt <= np.hypot(abs(obj["yaw_deg"]), obj["tilt_deg"]) + 1e-6 and tilt <= 17.0
    depth = -v[:, 0]                                              # the relay wall is x = 0, facing -x
    assert 0.3 - 1e-9 <= depth.min() and depth.max() <= 1.3 + 1e-9


def test_cutout_masks_are_what_they_say():
    dots = dot_chart_mask(3, 3, 0.4, cells=30)
    from scipy.ndimage import label
    assert label(dots)[1] == 9
    assert label(bar_chart_mask((2,), cells=40))[1] == 4          # 2 vertical + 2 horizontal bars
    exit_sign = sign_mask("exit")
    assert exit_sign.mean() > 0.6 and not exit_sign.all()         # a square with its text and arrow cut out
    vertices, faces = cutout_mesh(sign_mask("diamond", cells=20))
    assert np.allclose(vertices[:, 0], 0.0) and len(faces) > 0


def _write(tmp_path, **changes):
    data = yaml.safe_load(SMOKE.read_text())
    data["room"] = str(ROOT / "configs" / "rooms" / "lct_release.yaml")
    for key, value in changes.items():
        data["detector_draws"][key] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("change, words", [
    ({"gain_range": [0.5, 2.0]}, "detector_draws.gain_range: min must be >= 1"),
    ({"dcr": [-1.0, 5.0]}, "detector_draws.dcr: min must be >= 0"),
    ({"irf": {"sigma": "30ps", "tail": "40ps", "tail_weight": 0.7, "tail2": "280ps", "tail2_weight": 0.5}},
     "detector_draws.irf: tail_weight.max + tail2_weight.max must be <= 1"),
    ({"background_bands": {"ratio": [0.5, 2.0], "bands": 2}}, "detector_draws.background_bands: ratio must be >= 1"),
    ({"direct": {"attenuation": [0.0, 0.1], "until": "1ns"}}, "detector_draws.direct: attenuation must lie in (0, 1]"),
    ({"exposure": "soon"}, "detector_draws.exposure"),
    ({"colour": 3}, "detector_draws.colour: Extra inputs are not permitted (got 3)"),
])
def test_bad_draws_are_refused_in_one_line(tmp_path, change, words):
    path = _write(tmp_path, **change)
    with pytest.raises(ConfigError) as err:
        load_dataset_config(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and words in message and "\n" not in message
