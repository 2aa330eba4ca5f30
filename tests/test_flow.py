"""The simulation flow reads in one direction (docs/architecture.md, "One estimator, end to end"): resolve the
capture → plan the effects on the capture and the physics (estimator-neutral) → build the chosen estimator from
those → run → bin → detector. No lookin object exists unless the lookin estimator runs, no estimator undoes a
planner decision (its registry entry says which planned switches it follows), and the pile-up decision is the
detector stage's, made from the envelope without the planner.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
import pytest

from conftest import patch_scene
import datagen
from datagen.planner import EFFECTS, Decision, Plan
from datagen.simulation.run import prepare_transport
from datagen.simulation.detection import detector_model, make_result
from datagen.simulation.run import Replicas
from datagen.spad.pileup import pile_up_from_envelope
from datagen.transport import (AreaSampler, AreaSettings, EstimatorOptions, LookinSampler, LookinSettings, estimator,
                               estimator_names)
from datagen.transport.base import PLANNED_SWITCHES, register, unregister

SETTINGS = {"lookins": "4x4", "pixels": "12x12", "secondary": "full", "tolerance": 0.01,
            "time": {"t_start": 0.0, "bin_width": 40e-12, "n_bins": 600}, "irf": {"fwhm": "100ps"},
            "detector": {"repetition_rate": 1e7, "n_cycles": 1000}}
KINDS = {"lookin": {"kind": "lookin", "lookins": "4x4", "pixels": "12x12"},
         "area": {"kind": "area", "samples": 1024},
         "quadrature": {"kind": "quadrature", "edge": 0.2, "secondary_samples": 1024}}


def config(scene, kind: str, **over):
    return datagen.resolve_config(scene, {**SETTINGS, "estimator": KINDS[kind], **over})


@pytest.fixture
def no_lookins(monkeypatch):
    """Constructing lookin settings or a lookin sampler raises."""
    def boom(self, *args, **kwargs):
        raise AssertionError(f"{type(self).__name__} constructed")
    monkeypatch.setattr(LookinSettings, "__init__", boom)
    monkeypatch.setattr(LookinSampler, "__init__", boom)


@pytest.mark.parametrize("kind", ["area", "quadrature"])
def test_planning_and_building_another_estimator_never_constructs_a_lookin_object(kind, no_lookins):
    scene = patch_scene(with_occluder=True)
    transport, plan = prepare_transport(scene, config(scene, kind))
    assert type(getattr(transport, "base", transport)) is estimator(kind).cls      # (beside the tracer: orders auto)
    assert set(EFFECTS) <= set(plan.decisions) <= set(EFFECTS) | {"multibounce"}
    assert not isinstance(transport.settings, LookinSettings)


def test_the_lookin_estimator_is_the_one_that_builds_lookin_settings(no_lookins):
    """The check above is not vacuous: the lookin estimator's factory is where lookin settings are made."""
    scene = patch_scene(with_occluder=True)
    with pytest.raises(AssertionError, match="LookinSettings constructed"):
        prepare_transport(scene, config(scene, "lookin"))


def test_each_estimator_follows_the_planned_switches_its_entry_declares():
    """The planner says shadow_spot off (it concerns the laser leg of secondary paths, and the secondary is off);
    the lookin sampler follows it, the area sampler and the quadrature do not (their primary needs the laser
    leg's visibility) and keep their own rule, without undoing anything."""
    scene = patch_scene(with_occluder=True)
    assert estimator("lookin").follows_plan == PLANNED_SWITCHES
    for kind in ("area", "quadrature"):
        assert set(PLANNED_SWITCHES) - set(estimator(kind).follows_plan) == {"shadow_spot"}
    built = {kind: prepare_transport(scene, config(scene, kind, secondary="none")) for kind in KINDS}
    plan = built["lookin"][1]
    assert not plan.on("shadow_spot") and "it is off" in plan["shadow_spot"].reason
    assert built["lookin"][0].settings.shadow_spot is False
    assert built["area"][0].settings.shadow_spot is True                     # cast unless the user forces off
    assert built["quadrature"][0].settings.shadow_spot is True               # its occluder test: the box blocks
    assert built["quadrature"][0].visibility["shadow_spot"].startswith("a triangle may cross")
    # the switches every one follows are the plan's, and the secondary mode is the plan's
    for transport, _ in built.values():
        assert transport.settings.shadow_sensor == plan.on("shadow_sensor")
        assert transport.settings.secondary == "none"
    forced = prepare_transport(scene, config(scene, "area", effects={"shadow_spot": False}))[0]
    assert forced.settings.shadow_spot is False


def test_a_subclass_keeps_its_base_estimators_rule_and_register_refuses_an_unplanned_switch():
    """The entry takes ``follows_plan`` from the class unless ``register`` gives it: an estimator built on the
    area sampler keeps the area sampler's own laser-leg rule (tests/test_toy_estimator.py relies on it)."""
    class Sub(AreaSampler):
        pass

    class Options(EstimatorOptions):
        kind: Literal["sub"] = "sub"

    try:
        register("sub", AreaSettings, "x", options=Options, replica=lambda o, r: {})(Sub)
        assert estimator("sub").follows_plan == estimator("area").follows_plan
    finally:
        unregister("sub")
    with pytest.raises(ValueError, match=r"follows_plan \['pile_up'\] are not planned switches"):
        register("sub", AreaSettings, "x", options=Options, replica=lambda o, r: {},
                 follows_plan=("attenuation", "pile_up"))(Sub)
    assert "sub" not in estimator_names()


def test_the_pile_up_decision_is_the_detector_stages_and_needs_no_planner():
    scene = patch_scene()
    cfg = config(scene, "area")
    runs = Replicas(scene, cfg, np.random.default_rng(0))
    runs.run(cfg.error.replicas)
    tr = runs.transported()
    envelope = tr.binned.sum(axis=0).reshape(tr.transport.capture.channel_shape() + (cfg.time.n_bins,))
    # without any plan: the detector stage decides from the envelope (low flux: Poisson counts)
    detector, record = detector_model(envelope, cfg, {})
    decision = pile_up_from_envelope(envelope, cfg.detector_config(), cfg.effect_threshold)
    assert detector.model == "poisson" and not decision.on
    assert record == {"pile_up": {"on": False, "forced": False, "reason": decision.reason,
                                  "numbers": decision.numbers}}
    # a plan whose preview says "on" is not consulted after transport: the envelope decides
    tr.plan = Plan({**tr.plan.decisions, "pile_up": Decision(True, "a preview that said on")}, tr.plan.tolerance)
    result = make_result(scene, cfg, tr, np.random.default_rng(1), 0.0)
    assert result.attrs["effects"]["detector_model"] == "poisson"
    assert result.attrs["plan"]["pile_up"]["reason"] == decision.reason
    assert result.attrs["plan"]["secondary"] == tr.plan.to_attrs()["secondary"]
