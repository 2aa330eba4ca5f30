"""The detector-model registry (datagen/spad/models.py): every model a config may name is registered by its module,
the histogram functions dispatch through it, and what it says a model supports is what the code does."""
from __future__ import annotations

from typing import get_args

import numpy as np
import pytest

from datagen.errors import ConfigError
from datagen.spad import DetectorConfig, expected_histogram, sample_histogram
from datagen.spad.config import ModelName
from datagen.spad.models import DetectorModel, detector_model, model_names, register_model


def test_every_model_a_config_may_name_is_registered_and_nothing_else():
    assert model_names() == get_args(ModelName) == ("poisson", "pile_up", "multi_stop", "free_running")
    assert model_names(torch_noise=True) == ("poisson", "pile_up")
    assert model_names(fittable=True) == ("poisson", "pile_up", "free_running")
    assert {m: detector_model(m).dead_time for m in model_names()} == {
        "poisson": "none", "pile_up": "synchronous", "multi_stop": "synchronous", "free_running": "free_running"}


@pytest.mark.parametrize("model", get_args(ModelName))
def test_a_config_asks_a_model_only_for_the_effects_its_entry_says_it_simulates(model):
    """DetectorConfig reads the registry's effect flags: each effect is accepted exactly by the models whose entry
    has it (paralyzable: free_running; afterpulsing: free_running, non-paralyzable; crosstalk: pile_up)."""
    base = dict(model=model, bin_width=1e-9, repetition_rate=2e7, exposure=1e-5, dead_time=3e-9)
    entry = detector_model(model)
    for effect, field in (("paralyzable", {"paralyzable": True}), ("afterpulsing", {"afterpulse_probability": 0.01}),
                          ("crosstalk", {"crosstalk_probability": 0.01})):
        if getattr(entry, effect):
            DetectorConfig(**base, **field)
        else:
            supported = " or ".join(f"model={m!r}" for m in model_names(**{effect: True}))
            with pytest.raises(ValueError, match=supported):
                DetectorConfig(**base, **field)
    assert (model_names(paralyzable=True), model_names(afterpulsing=True), model_names(crosstalk=True)) == (
        ("free_running",), ("free_running",), ("pile_up",))


def test_an_unknown_model_and_a_second_registration_are_refused():
    with pytest.raises(ConfigError, match=r"detector model 'nope' is not registered \(registered: poisson, pile_up, "
                                          r"multi_stop, free_running\)"):
        detector_model("nope")
    with pytest.raises(ValueError, match="detector model 'pile_up' is registered twice"):
        register_model(DetectorModel("pile_up", detector_model("poisson").expected, detector_model("poisson").sample,
                                     dead_time="none"))


@pytest.mark.parametrize("model", get_args(ModelName))
def test_each_models_draws_average_to_its_expected_histogram(model):
    """The registry's two functions for one model agree: the mean of 400 exposures is the expected histogram
    within 5 standard errors in every bin (fixed seed), for (2, 3, T) rates, shape kept."""
    t = np.arange(24)
    rates = 0.02 + 0.3 * np.exp(-0.5 * ((t - 8) / 2.0) ** 2)
    rates = np.stack([rates, 0.5 * rates, 2 * rates])[None].repeat(2, axis=0) * 0.5   # (2, 3, 24)
    config = DetectorConfig(model=model, bin_width=1e-9, repetition_rate=2e7, exposure=1e-5, dead_time=3e-9,
                            dcr=0.0, ambient_rate=0.0, pde=1.0)
    expected = expected_histogram(rates, config)
    rng = np.random.default_rng(20261125)
    draws = np.stack([sample_histogram(rates, config, rng) for _ in range(400)])
    assert draws.shape == (400, 2, 3, 24) and draws.dtype == np.int64
    sem = draws.std(axis=0) / np.sqrt(len(draws)) + 1e-9
    assert np.all(np.abs(draws.mean(axis=0) - expected) < 5 * sem + 1e-6 * expected.max()), model


def test_the_fit_command_offers_the_fittable_models():
    from datagen.cli.capture import fit_detector_cmd
    choice = next(p for p in fit_detector_cmd.params if p.name == "model").type
    assert sorted(choice.choices) == sorted(model_names(fittable=True))         # the default, pile_up, listed first
