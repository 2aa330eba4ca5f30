"""Estimator settings as registered models (issue 24): ``SimulationConfig.estimator`` is the chosen estimator's own
pydantic model; the old flat keys (``lookins``, ``area_samples``, ``quadrature_edge``, …, ``tolerance``; the dataset
config's ``time_cap``) still load, translated once with one deprecation note, into an equal config."""
from __future__ import annotations

import copy
import warnings
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from datagen.errors import ConfigError, DatasetError
from datagen.cli.main import main
from datagen.dataset import load_dataset_config
from datagen.dataset.config import location_free_json
from datagen.dataset.legacy import canonical_json
from datagen.dataset.store import check_same_config
from datagen.scene import load_scene
from datagen.simulation import LegacyKeysWarning, SimulationConfig, resolve_config
from datagen.transport import estimator_names
from datagen.transport.area.estimator import AreaOptions
from datagen.transport.lookin.estimator import LookinOptions
from datagen.transport.quadrature.options import QuadratureOptions

DEMO = Path("scene_library/demo_room.yaml")
SMOKE = Path("configs/datasets/smoke.yaml")

OLD_AND_NEW = [
    ({"lookins": "4x4", "pixels": [8, 8], "top_k": 2, "conv_refine": 2, "batch": 7, "jitter": False},
     {"estimator": {"kind": "lookin", "lookins": "4x4", "pixels": [8, 8], "top_k": 2, "conv_refine": 2, "batch": 7,
                    "jitter": False}}),
    ({"estimator": "area", "area_samples": 2048, "lookins": "4x4"}, {"estimator": {"kind": "area", "samples": 2048}}),
    ({"estimator": "quadrature", "quadrature_edge": 0.1, "quadrature_fov": 2, "quadrature_grading": 0.5,
      "area_samples": 512, "tolerance": 0.05},
     {"estimator": {"kind": "quadrature", "edge": 0.1, "fov_cells": 2, "grading": 0.5, "secondary_samples": 512},
      "effect_threshold": 0.05}),
    ({"replicas": 3, "error_confidence": 0.9}, {"error": {"replicas": 3, "confidence": 0.9}}),
    ({"replicas": 5, "error": {"confidence": None}}, {"error": {"replicas": 5, "confidence": None}}),
]


def validate(data: dict) -> tuple[SimulationConfig, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        config = SimulationConfig.model_validate(data)
    return config, [str(w.message) for w in caught if issubclass(w.category, LegacyKeysWarning)]


@pytest.mark.parametrize("old, new", OLD_AND_NEW)
def test_old_keys_load_with_one_note_into_an_equal_config(old, new):
    before, notes = validate(old)
    after, none = validate(new)
    assert before == after and none == []
    assert len(notes) == 1 and "\n" not in notes[0]
    for key in old:
        if key != "estimator":
            assert key in notes[0]
    if "lookins" in old and old.get("estimator") == "area":
        assert "lookins dropped (not used by the area estimator)" in notes[0]


@pytest.mark.parametrize("kind", ["lookin", "area", "quadrature"])
def test_the_new_form_round_trips(kind):
    config, notes = validate({"estimator": kind, "secondary": "none"})
    dumped = config.model_dump(mode="json")
    assert dumped["estimator"]["kind"] == kind and notes == []
    again, notes = validate(dumped)
    assert again == config and notes == [] and type(again.estimator) is type(config.estimator)
    assert len(SimulationConfig.model_fields) <= 16      # the 15 before `orders`; its tracer knobs are one block


def test_each_estimator_owns_its_model():
    assert estimator_names() == ("lookin", "area", "quadrature")
    config = SimulationConfig(estimator={"kind": "quadrature", "edge": 0.05})
    assert isinstance(config.estimator, QuadratureOptions) and config.estimator.edge == 0.05
    assert isinstance(SimulationConfig().estimator, LookinOptions)
    assert isinstance(SimulationConfig(estimator="area").estimator, AreaOptions)


@pytest.mark.parametrize("data, expected", [
    ({"estimator": {"kind": "montecarlo"}}, "unknown estimator kind 'montecarlo'; known: lookin, area, quadrature"),
    ({"estimator": {"samples": 3}}, "give kind; known: lookin, area, quadrature"),
    ({"estimator": {"kind": "area", "edge": 0.1}}, "estimator.edge: Extra inputs are not permitted"),
    ({"estimator": {"kind": "lookin", "lookins": "4x4"}, "lookins": "8x8"},
     "lookins '8x8' and estimator.lookins '4x4' are both given"),
])
def test_bad_estimator_settings_get_one_line(tmp_path, data, expected):
    scene = yaml.safe_load(DEMO.read_text())
    scene["simulation"].update(data)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    with pytest.raises(ConfigError) as info:
        resolve_config(load_scene(path))
    assert expected in str(info.value) and "\n" not in str(info.value)


def test_scene_knobs_of_another_estimator_are_dropped_under_a_command_line_estimator(tmp_path):
    """A scene with lookin settings (old or new form) under --estimator area: the area sampler with its own
    defaults, or the command line's --samples; a scene's old flat area_samples still applies, as before."""
    scene = load_scene(DEMO)
    assert resolve_config(scene, {"estimator": "area"}).estimator == AreaOptions()
    assert resolve_config(scene, {"estimator": "area", "area_samples": 64}).estimator == AreaOptions(samples=64)
    quad = resolve_config(scene, {"estimator": "quadrature", "quadrature_edge": 0.3, "area_samples": 64})
    assert quad.estimator == QuadratureOptions(edge=0.3, secondary_samples=64)
    lookin = resolve_config(scene, {"lookins": "2x2"}).estimator       # merged into the scene's own block
    assert lookin.lookins == (2, 2) and lookin.pixels == (60, 60)
    data = yaml.safe_load(DEMO.read_text())
    data["simulation"] = {**{k: v for k, v in data["simulation"].items() if k != "estimator"},
                          "lookins": "10x10", "area_samples": 128}
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.warns(LegacyKeysWarning, match="old.yaml"):
        assert resolve_config(load_scene(path), {"estimator": "area"}).estimator == AreaOptions(samples=128)


def test_the_command_line_prints_one_note_for_old_keys(tmp_path):
    data = yaml.safe_load(DEMO.read_text())
    data["simulation"].pop("estimator")
    data["simulation"].update(lookins="2x2", pixels="4x4", secondary="none")
    data["simulation"]["time"]["n_bins"] = 500
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(data))
    res = CliRunner().invoke(main, ["simulate", str(old), "--out", str(tmp_path / "a"), "--quiet"])
    assert res.exit_code == 0, res.output
    notes = [line for line in res.output.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and "lookins -> estimator.lookins" in notes[0] and "Traceback" not in res.output
    res = CliRunner().invoke(main, ["simulate", str(old), "--out", str(tmp_path / "b"), "--quiet", "--estimator",
                                    "area", "--samples", "64"])
    assert res.exit_code == 0, res.output


def test_old_dataset_keys_load_with_one_note_and_resume_into_the_new_form():
    old = yaml.safe_load(SMOKE.read_text())
    old["time_cap"] = old.pop("cost_cap")
    est = old["simulation"].pop("estimator")
    old["simulation"].update(estimator=est["kind"], area_samples=est["samples"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        before = load_dataset_config(copy.deepcopy(old), base_dir=SMOKE.parent)
    notes = [str(w.message) for w in caught if issubclass(w.category, LegacyKeysWarning)]
    assert len(notes) == 1 and "time_cap -> cost_cap" in notes[0] and "area_samples -> estimator.samples" in notes[0]
    after = load_dataset_config(SMOKE)
    assert before.cost_cap == after.cost_cap
    assert all(before.simulation_config(s) == after.simulation_config(s) for s in after.splits)
    card = {"config": before.to_json(), "config_sha256": before.fingerprint()}
    card["config"]["time_cap"] = card["config"].pop("cost_cap")        # as a card written before issue 24
    assert before.fingerprint() != after.fingerprint()
    assert canonical_json(location_free_json(card["config"])) == canonical_json(location_free_json(after.to_json()))
    check_same_config(Path("old"), card, after)                          # accepted: the same dataset
    changed = after.model_copy(update={"cost_cap": 1.0})
    with pytest.raises(DatasetError, match="cost_cap"):
        check_same_config(Path("old"), card, changed)


def test_an_unchanged_dataset_yaml_keeps_its_fingerprint():
    """The fingerprint hashes renamed keys under their old names: a dataset YAML written before issue 24 (time_cap)
    has the fingerprint its cards recorded."""
    import hashlib
    import json
    config = load_dataset_config(SMOKE)
    data = location_free_json(config.to_json())
    data["time_cap"] = data.pop("cost_cap")
    assert config.fingerprint() == hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def test_a_flat_key_of_the_command_line_estimator_applies_beside_a_new_form_block(tmp_path):
    """benchmarks/compare_outputs.py's demo_area job: the demo room (a lookin block) with a flat area_samples and
    --estimator area: the area sampler takes the scene's samples, as the old flat merge did (one note)."""
    data = yaml.safe_load(DEMO.read_text())
    data["simulation"]["area_samples"] = 16384
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.warns(LegacyKeysWarning, match="area_samples -> estimator.samples"):
        assert resolve_config(load_scene(path), {"estimator": "area"}).estimator == AreaOptions(samples=16384)


def test_the_stated_error_settings_are_one_block_and_an_old_key_beside_it_is_one_line(tmp_path):
    config = SimulationConfig(error={"confidence": None})
    assert config.error.replicas == 8 and config.error.confidence is None
    assert SimulationConfig().error.confidence == 0.95
    with pytest.raises(ValueError, match="error.replicas"):
        SimulationConfig(error={"replicas": 1})
    data = yaml.safe_load(SMOKE.read_text())
    assert data["simulation"]["error"] == {"replicas": 4}
    data["simulation"]["replicas"] = 3                        # the old key beside its new home, at another value
    path = tmp_path / "both.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_dataset_config(path, base_dir=SMOKE.parent)
    line = str(err.value)
    assert "\n" not in line and str(path) in line and "replicas 3 and error.replicas 4 are both given" in line
