"""docs/architecture.md, "Adding an estimator", followed from a test file: a toy estimator registered here runs
through ``simulate``, ``simulate_to_tolerance`` (``--tolerance``), the accuracy benchmark and a dataset build, with
no edit to any module of datagen (the registry is the only place that knows it).

The toy is the area sampler under another name, with its own settings model, replica rule, description, memory
estimate and accuracy ladder, so every result must equal the area sampler's bit for bit: the plumbing is what is
tested, and any place that still branched on the estimator's name (or ignored the toy's settings) would break the
equality or raise.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
import pytest
from pydantic import Field

from conftest import patch_scene
from test_hostile_build import tiny
from test_reference import config
from datagen.analysis import converged_reference, run_accuracy
from datagen.dataset import NLOSDataset, build_dataset
from datagen.simulation import simulate, simulate_to_tolerance, simulation_memory
from datagen.transport import AccuracyLadder, AreaSampler, AreaSettings, EstimatorOptions, estimator_names, register
from datagen.transport.base import unregister

SAMPLES = 2048


class ToyOptions(EstimatorOptions):
    """The toy's settings (``estimator: {kind: toy, samples: M}``)."""

    kind: Literal["toy"] = "toy"
    samples: int = Field(SAMPLES, ge=16)

    def replica(self, replicas: int) -> dict:
        return {"samples": max(16, -(-self.samples // replicas))}     # the area sampler's rule

    def describe(self) -> str:
        return f"toy with {self.samples} samples"


def toy_memory(scene, config, lasers: int, sensors: int) -> list[tuple[str, str, float]]:
    return [("estimator.samples", f"{config.estimator.samples} (toy)", 500.0 * config.estimator.samples)]


TOY_LADDER = AccuracyLadder("toy sampler", tuple({"samples": 1 << k} for k in range(9, 16)),
                            lambda s: float(s["samples"]), lambda s: f"toy M={s['samples']}")


@pytest.fixture(scope="module", autouse=True)
def toy():
    """Register the toy for this module's tests only (the other tests see the three shipped estimators)."""

    @register("toy", AreaSettings, "a toy: the area sampler under another name", options=ToyOptions,
              replica=ToyOptions.replica, describe=ToyOptions.describe, memory=toy_memory, ladder=TOY_LADDER)
    class ToySampler(AreaSampler):
        pass

    yield ToySampler
    unregister("toy")
    assert "toy" not in estimator_names()


def both(scene):
    """(toy config, area config) with the same samples and shared settings (tests/test_reference.py's axis, IRF
    and detector)."""
    return tuple(config(secondary="full", estimator={"kind": kind, "samples": SAMPLES}) for kind in ("toy", "area"))


def test_simulate_runs_the_toy_and_records_its_settings():
    scene = patch_scene(with_occluder=True)
    toy, area = both(scene)
    a, b = simulate(scene, toy), simulate(scene, area)
    assert b.envelope.any()
    np.testing.assert_array_equal(a.envelope, b.envelope)
    np.testing.assert_array_equal(a.counts, b.counts)
    assert a.attrs["effects"]["estimator"] == "toy"
    assert a.attrs["config"]["estimator"] == {"kind": "toy", "samples": SAMPLES}
    assert a.attrs["error"]["rel_l2"] == b.attrs["error"]["rel_l2"]
    assert ("estimator.samples", f"{SAMPLES} (toy)", 500.0 * SAMPLES) in simulation_memory(scene, toy)


def test_simulate_to_tolerance_adds_the_toys_replicas():
    scene = patch_scene(with_occluder=True)
    toy, area = both(scene)
    a = simulate_to_tolerance(scene, toy, 0.05)
    b = simulate_to_tolerance(scene, area, 0.05)
    assert a.attrs["tolerance"]["met"] and a.attrs["tolerance"]["estimate"] <= 0.05
    assert a.attrs["error"]["replica_setting"] == f"toy with {SAMPLES // toy.error.replicas} samples"
    np.testing.assert_array_equal(a.envelope, b.envelope)


def test_the_accuracy_benchmark_takes_the_toys_ladder():
    scene = patch_scene(with_occluder=True)
    toy, _ = both(scene)
    ref = converged_reference(scene, toy, rel_tol=3e-2, samples=1 << 10)
    rows = run_accuracy(scene, ref, toy, budget=1.0, estimators=("toy",))
    assert rows and {r.estimator for r in rows} == {"toy"}
    assert [r.setting for r in rows] == [TOY_LADDER.setting(s) for s in TOY_LADDER.steps[:len(rows)]]
    assert all(np.isfinite(r.rel_l2) for r in rows)


def test_a_dataset_of_the_toy_builds_and_equals_the_area_samplers(tmp_path):
    base = tiny(train=2, val=1)
    out = {}
    for kind in ("toy", "area"):
        sim = {**base.simulation, "estimator": {"kind": kind, "samples": 512}}
        sim.pop("area_samples", None)
        config = base.model_copy(update={"simulation": sim})
        out[kind] = tmp_path / kind
        build_dataset(config, out[kind], workers=0, progress=False)   # in process: the toy is registered here
    for split in ("train", "val"):
        a, b = (NLOSDataset(out[k], split=split, fields=["envelope", "counts"]) for k in ("toy", "area"))
        for i in range(len(a)):
            np.testing.assert_array_equal(a.read(i)["envelope"], b.read(i)["envelope"])
            np.testing.assert_array_equal(a.read(i)["counts"], b.read(i)["counts"])
