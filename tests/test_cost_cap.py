"""Every cap caps (issue 69): a dataset's ``cost_cap`` (nominal seconds) and ``simulate --time-cap`` (wall seconds)
bound the lookin sampler, the area sampler and the quadrature, alone and beside the order ≥ 3 tracer; a build whose
probe sample misses its tolerance says so in one line before it spends."""
from __future__ import annotations

import json
import re
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from datagen.cli import main
from datagen.dataset import load_dataset_config, make_sample
from datagen.dataset.probe import probe_notice
from datagen.dataset.store import read_card, zarr_module
from datagen.dataset.config import setup_sample
from datagen.simulation import ToleranceOutOfReach, resolve_config, simulate_to_tolerance
from datagen.simulation.config import STREAM_SAMPLING, stream_rng
from datagen.simulation.run import Replicas

ROOT = Path(__file__).resolve().parents[1]
DATASETS = ROOT / "configs" / "datasets"
WINDOW_12NS = {"t_start": "15ns", "bin_width": "200ps", "n_bins": 60}
FIRST_ROUND = 0.3
"""Nominal seconds of a first round of the lookin config at most (4 replicas of 2 × 2 lookins and the tracer's two:
0.26 s on train 0), which always runs."""
CONFOCAL_TRACER = {"orders": "auto", "secondary": "full",    # the tracer carries orders >= 2 beside the quadrature
                   "effects": {"first_bounce": False, "secondary": False, "attenuation": False, "shadow_spot": True,
                               "shadow_sensor": True, "pile_up": True}}


def lookin_yaml(tmp_path: Path, **simulation) -> Path:
    """configs/datasets/smoke.yaml with the lookin estimator, a 12 ns window, 8 train samples and no tolerance (the
    issue's config: 1 % by default, cost_cap 0.5 s), ``simulation`` merged in."""
    data = yaml.safe_load((DATASETS / "smoke.yaml").read_text())
    data.update(name="smoke_lookin", room=str(DATASETS / data["room"]), splits={"train": {"count": 8}})
    del data["tolerance"]
    data["simulation"].update(estimator={"kind": "lookin"}, time=WINDOW_12NS, **simulation)
    path = tmp_path / "smoke_lookin.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def capped_run(name: str, tolerance: float, cap: float, overrides: dict, index: int = 0, **kwargs):
    """``simulate_to_tolerance`` of sample ``index`` of dataset config ``name`` with ``overrides`` on its simulation
    block, capped at ``cap`` nominal seconds."""
    config = load_dataset_config(DATASETS / f"{name}.yaml")
    config = config.model_copy(update={"simulation": {**config.simulation, **overrides}})
    room, sim, rngs = setup_sample(config, "train", index)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")           # orders: 2 names the orders it leaves out
        return simulate_to_tolerance(room.scene, sim, tolerance, max_cost=cap, sampling_rng=rngs["sampling"],
                                     noise_rng=rngs["noise"], **kwargs)


@pytest.mark.parametrize("label, name, tolerance, cap, overrides, index", [
    ("lookin", "smoke", 0.01, 0.5, {"estimator": {"kind": "lookin"}, "time": WINDOW_12NS, "orders": 2}, 0),
    ("lookin + tracer", "smoke", 0.01, 0.3, {"estimator": {"kind": "lookin"}, "time": WINDOW_12NS}, 0),
    ("area + tracer", "smoke", 0.005, 0.5, {}, 0),
    ("quadrature", "wall_smoke", 0.001, 0.3, {}, 0),
    ("quadrature + tracer", "confocal_smoke", 0.01, 4.0, CONFOCAL_TRACER, 1),
], ids=["lookin", "lookin+tracer", "area+tracer", "quadrature", "quadrature+tracer"])
def test_the_cost_cap_bounds_every_estimators_nominal_seconds(label, name, tolerance, cap, overrides, index):
    """Each stops at the cap (``capped: cost``) having spent at most the cap plus its first round (the first round,
    or the quadrature's first level with the tracer's first replicas, always runs): no later round or level is
    planned beyond it. The lookin sampler, uncapped before, ran its probe for 106 s in the issue."""
    result = capped_run(name, tolerance, cap, overrides, index)
    tol = result.attrs["tolerance"]
    rounds = tol["rounds"]
    spent = rounds[-1]["nominal_seconds"]
    assert tol["met"] is False and tol["capped"] == "cost", label
    assert 0 < spent <= cap + rounds[0]["nominal_seconds"], label
    if tol["unreachable"]:                         # the orders left out / the smoothing bias alone exceed it
        assert tol["projected_nominal_seconds"] is None
    else:                                          # meeting it projects beyond the cap
        assert tol["projected_nominal_seconds"] > cap
    assert result.attrs["error"]["rel_l2"] == tol["estimate"]


def test_the_time_cap_bounds_the_tracers_replicas_beside_the_quadrature():
    """The quadrature's level is not refined, nor its tracer topped up, beyond ``max_seconds`` (the wall-time cap of
    ``simulate --time-cap``): at 1 ms the first level with the tracer's first two replicas is all."""
    result = capped_run("confocal_smoke", 0.01, None, CONFOCAL_TRACER, index=1, max_seconds=1e-3)
    tol = result.attrs["tolerance"]
    assert tol["capped"] == "time" and len(tol["rounds"]) == 1 and result.attrs["error"]["tracer_replicas"] == 2


def test_the_time_cap_refuses_a_lookin_run_it_cannot_afford():
    """A lookin run whose first round projects beyond ten times ``max_seconds`` is refused with its projection (it
    ran without any cap before: the loop's rounds grow ×8 each)."""
    config = load_dataset_config(DATASETS / "smoke.yaml")
    config = config.model_copy(update={"simulation": {**config.simulation, "estimator": {"kind": "lookin"},
                                                      "time": WINDOW_12NS, "orders": 2}})
    room, sim, rngs = setup_sample(config, "train", 0)
    with warnings.catch_warnings(), pytest.raises(ToleranceOutOfReach, match=r"projects .* s to reach 0\.02, beyond "
                                                                             r"the time cap of 0\.01 s"):
        warnings.simplefilter("ignore")
        simulate_to_tolerance(room.scene, sim, 0.02, max_seconds=0.01, sampling_rng=rngs["sampling"])


def test_lookin_nominal_seconds_follow_its_cpu_time():
    """The lookin sampler's nominal seconds (counted work at the rates fitted by ``benchmarks/fit_nominal.py
    lookin``: 72 runs within 0.5–1.35× of their CPU time on the machine it was fitted on) follow the CPU time of
    small replicas (per-run work), large cameras with the full secondary (per-pair work) and without it (per-ray
    work): their ratios to it agree within 2.5× of each other, whatever the machine's speed (a 2-core machine of this
    project's CI ran all three at 0.32–0.44), and each lies within 6× of 1 (the rates are of a
    machine of this kind, in seconds)."""
    config = load_dataset_config(DATASETS / "smoke.yaml")
    room, _, _ = setup_sample(config, "train", 0)
    base = {**config.simulation_overrides(), "time": WINDOW_12NS, "replicas": 4, "workers": 1}
    ratios = {}
    for side, pixels, secondary, n in ((4, 16, "full", 60), (6, 60, "full", 3), (10, 60, "none", 4)):
        over = {**base, "estimator": {"kind": "lookin", "lookins": [side, side], "pixels": [pixels, pixels]},
                "secondary": secondary, "orders": 2 if secondary != "none" else 1,
                "effects": {**base["effects"], "secondary": secondary != "none"}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            runs = Replicas(room.scene, resolve_config(room.scene, over), stream_rng(0, STREAM_SAMPLING))
            runs.run(1)
            before, t0 = runs.transport.nominal_seconds(), time.process_time()
            runs.run(n)
            cpu = time.process_time() - t0
        ratios[side, pixels, secondary] = (runs.transport.nominal_seconds() - before) / cpu
    assert max(ratios.values()) / min(ratios.values()) < 2.5, ratios
    assert all(1 / 6 < ratio < 6 for ratio in ratios.values()), ratios


def test_a_lookin_build_stays_within_its_cost_cap_and_says_so_once(tmp_path):
    """The issue's config (lookin, 12 ns window, no tolerance: 1 %, cost_cap 0.5 s) builds its 8 samples, each within
    the cap plus its first round; before it spends, one line says the probe missed the tolerance within the cap and
    what meeting it projects per sample."""
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["build", str(lookin_yaml(tmp_path)), "--out", str(out), "--workers", "0",
                                       "--quiet"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stderr.splitlines() if "the probe sample" in line]
    assert len(lines) == 1, result.stderr
    pattern = (r"build smoke_lookin: the probe sample \(train, 0\) reached an estimated error of ([0-9.]+)% within "
               r"cost_cap 0\.5 s \(nominal, ([0-9.]+) s spent\), above the tolerance 1\.00% \(the default: the config "
               r"sets none\); meeting it projects about ([0-9.e+]+) nominal s per sample: samples that miss it are "
               r"built and listed in the card \(raise cost_cap or the tolerance to meet it\)")
    found = re.fullmatch(pattern, lines[0])
    assert found, lines[0]
    error, spent, projected = map(float, found.groups())
    # the planned round lands within 12 % of the cap (0.559 s on train 0: the 95 % bound plans a larger second
    # round, whose tracer costs more per replica than the first round's mean); the samples' bound is the same
    assert error > 1 and spent <= 0.5 + FIRST_ROUND and projected > 0.5
    params = zarr_module().open_group(str(out), mode="r")["train"]["params"][...]
    accuracy = [json.loads(str(p))["accuracy"] for p in params]
    assert len(accuracy) == 8 and all(not a["met"] and 0 < a["nominal_seconds"] <= 0.5 + FIRST_ROUND for a in accuracy)
    assert read_card(out)["accuracy"]["n_missed"] == 8


@pytest.mark.parametrize("name, simulation, expected", [
    ("smoke.yaml", None, None),                                        # the smoke probe meets 5 %: nothing to say
    ("lookin", {"orders": 2}, r"build smoke_lookin: the probe sample \(train, 0\) reached an estimated error of "
                              r"[0-9.]+% and cannot meet the tolerance 1\.00% \(the default: the config sets none\): "
                              r"the orders left out carry 2\.[0-9]+% and the smoothing bias 0\.00% of the envelope, "
                              r"which no sampling brings down"),
], ids=["met", "orders-left-out"])
def test_a_probe_that_cannot_meet_its_tolerance_says_why_in_one_line(tmp_path, name, simulation, expected):
    """orders: 2 leaves out 2.2 % of the 12 ns window's light, beyond what a 1 % tolerance can hold: the line says so
    instead of projecting replicas (the sample still stops at its cap); a probe that met its tolerance says nothing."""
    config = load_dataset_config(DATASETS / name if simulation is None else lookin_yaml(tmp_path, **simulation))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        probe = make_sample(config, "train", 0)
    line = probe_notice(config, "train", probe)
    if expected is None:
        assert line is None and probe.accuracy["met"]
        return
    assert "\n" not in line and re.match(expected, line), line
    assert probe.accuracy["unreachable"] and probe.accuracy["nominal_seconds"] <= config.cost_cap + 0.1
    assert np.isfinite(probe.arrays["envelope_error"])
