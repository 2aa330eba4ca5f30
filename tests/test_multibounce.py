"""Light of every order (datagen/transport/multibounce, datagen/planner/orders.py, docs/physics.md §2 "Orders").

The tracer's orders 1 and 2 are checked against the area sampler's primary and secondary (an estimator that samples
those paths another way), the ``orders`` knob against its documented meaning, the planner's pilot against a bare
wall (nothing to add) and the demo room (most of its light), and the wrapped estimator for bit-identical orders 1–2
and worker counts. The closed-form rooms (sphere ratio ρ, mean chord, furnace) and the independent all-order
reference live in tests/test_multibounce_closed.py.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import patch_scene

import datagen
from datagen.cli.main import main
from datagen.errors import ConfigError
from datagen.simulation.run import prepare_transport
from datagen.transport.multibounce import MultibounceSettings, MultibounceTracer

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "scene_library" / "demo_room.yaml")


class Tally:
    """A sink that sums the weights it receives (the all-time energy of what a run deposits)."""

    def __init__(self):
        self.total = 0.0

    def add(self, times, weights, component):
        self.total += float(np.sum(weights))


def _order_energy(transport, order: int, paths: int, seed: int, window) -> float:
    tracer = MultibounceTracer(transport.capture, transport.caster, transport.physics,
                               MultibounceSettings(paths=paths, min_order=order, max_order=order), 0, window)
    sink = Tally()
    tracer.run(sink, np.random.default_rng(seed))
    return sink.total


def test_tracer_orders_one_and_two_agree_with_the_area_sampler_on_the_demo_room():
    """Order 1 of the tracer against the area sampler's primary (room + box + pillar), order 2 against its
    secondary: the same integrals sampled two ways. Tolerance: 4 standard errors of the difference, each side's
    standard error measured from its own independent runs (6 each)."""
    scene = datagen.load_scene(DEMO)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 16384}, "orders": 2,
                                         "time": {"t_start": 0, "bin_width": 1e-9, "n_bins": 1000}})
    transport, _ = prepare_transport(scene, cfg)
    window = (cfg.time.t_start, cfg.time.t_stop)
    area = {"primary": [], "secondary": []}
    for seed in range(6):
        sink = _ComponentTally(len(transport.component_names), transport.capture.n_channels)
        transport.run(sink, np.random.default_rng(100 + seed))
        area["primary"].append(sink.by_component[:-1].sum())
        area["secondary"].append(sink.by_component[-1])
    for order, name in ((1, "primary"), (2, "secondary")):
        traced = [_order_energy(transport, order, 20000, 200 + 10 * order + s, window) for s in range(6)]
        a, t = np.array(area[name]), np.array(traced)
        se = np.hypot(a.std(ddof=1) / np.sqrt(len(a)), t.std(ddof=1) / np.sqrt(len(t)))
        assert abs(a.mean() - t.mean()) < 4 * se, (order, a.mean(), t.mean(), se)
        assert se / a.mean() < 0.02                    # the test has teeth: 4 SE is at most 8 % of the order


class _ComponentTally:
    def __init__(self, n_components: int, n_channels: int):
        self.n_channels = n_channels
        self.by_component = np.zeros(n_components)

    def add(self, times, weights, component):
        np.add.at(self.by_component, np.asarray(component) // self.n_channels, weights)


def test_orders_one_and_two_are_bit_identical_with_the_tracer_beside_them_and_for_two_workers():
    scene = datagen.load_scene(DEMO)
    base = {"estimator": {"kind": "area", "samples": 2048}, "replicas": 2, "multibounce": {"paths": 2048}}
    two = datagen.simulate(scene, datagen.resolve_config(scene, {**base, "orders": 2}))
    four = datagen.simulate(scene, datagen.resolve_config(scene, {**base, "orders": 4}))
    four_w2 = datagen.simulate(scene, datagen.resolve_config(scene, {**base, "orders": 4, "workers": 2}))
    assert list(four.components) == list(two.components) + ["multibounce"]
    for name in two.components:
        assert np.array_equal(two.components[name], four.components[name]), name
    for name in four.components:
        assert np.array_equal(four.components[name], four_w2.components[name]), name
    assert four.components["multibounce"].sum() > 0.2 * four.envelope.sum()     # albedo 1: a large tail
    assert four.attrs["orders"]["simulated"] == "1..4"
    assert "orders" not in two.attrs
    energy = four.attrs["orders"]["energy_by_order"]
    assert energy["order_3"] > energy["order_4"] > 0 and energy["order_5"] == 0.0    # max_order 4 is honoured


def test_orders_one_is_secondary_none_and_the_old_spelling_still_means_it():
    scene = datagen.load_scene(DEMO)
    one = datagen.resolve_config(scene, {"orders": 1})
    assert one.secondary == "none" and one.orders_setting() == 1
    old = datagen.resolve_config(scene, {"secondary": "none"})
    assert old.orders_setting() == 1
    assert datagen.resolve_config(scene, {}).orders_setting() == 2
    # --orders beats the file's secondary: none (the old spelling of orders: 1)
    scan = datagen.load_scene(ROOT / "scene_library" / "confocal_scan.yaml")
    assert datagen.resolve_config(scan, {"orders": 2}).secondary == "full"


@pytest.mark.parametrize("overrides, words", [
    ({"orders": 0}, "orders must be an integer >= 1 or 'auto', got 0"),
    ({"orders": "many"}, "orders"),
    ({"orders": True}, "orders must be an integer >= 1 or 'auto', got True"),
    ({"orders": 3, "secondary": "none"}, "drop secondary: none, or write orders: 1"),
])
def test_bad_orders_are_refused_in_one_line_naming_the_field(overrides, words):
    scene = datagen.load_scene(DEMO)
    with pytest.raises(ConfigError) as exc:
        datagen.resolve_config(scene, overrides)
    assert words in str(exc.value) and "\n" not in str(exc.value).strip()


def test_cli_orders_option(tmp_path):
    runner = CliRunner()
    bad = runner.invoke(main, ["simulate", DEMO, "--out", str(tmp_path / "a"), "--orders", "0"])
    assert bad.exit_code == 2 and "--orders" in bad.output and "got '0'" in bad.output
    ok = runner.invoke(main, ["simulate", DEMO, "--out", str(tmp_path / "b"), "--estimator", "area",
                                  "--samples", "2048", "--orders", "auto", "--quiet"])
    assert ok.exit_code == 0, ok.output
    assert "multibounce" in ok.output and "orders simulated: 1..all (auto)" in ok.output


def test_planner_leaves_orders_3_up_out_before_a_bare_wall_and_counts_the_residual():
    """One patch before a bare relay wall: light returns to the patch only via the wall (the pilot rarely even samples it); the
    pilot leaves orders ≥ 3 out, records their share, and the stated error includes it."""
    scene = patch_scene()
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 4096}, "orders": "auto",
                                         "effect_threshold": 0.01,
                                         "detector": {"repetition_rate": 1e7, "n_cycles": 1000}})
    r = datagen.simulate(scene, cfg)
    orders = r.attrs["orders"]
    assert orders["simulated"] == "1..2" and "multibounce" not in r.components
    assert 0 <= orders["residual_share"] < 0.0025
    err = r.attrs["error"]
    assert err["omitted_orders"] == orders["residual_share"]
    assert err["rel_l2"] == pytest.approx(np.sqrt(err["monte_carlo"] ** 2 + err["omitted_orders"] ** 2))
    assert r.attrs["plan"]["multibounce"]["on"] is False


def test_planner_turns_orders_3_up_on_in_the_demo_room_and_the_pilot_matches_the_run():
    scene = datagen.load_scene(DEMO)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 8192}, "orders": "auto",
                                         "multibounce": {"paths": 16384}})
    r = datagen.simulate(scene, cfg)
    pilot = r.attrs["orders"]["pilot_shares"]
    pilot_beyond = sum(v for k, v in pilot.items() if k not in ("order_1", "order_2"))
    run_share = r.components["multibounce"].sum() / r.envelope.sum()
    # albedo 1, corridor open at one end: most of the in-window light (an independent tracer measured 60 %)
    assert 0.5 < run_share < 0.7
    assert pilot_beyond == pytest.approx(run_share, abs=0.05)
    assert r.attrs["plan"]["multibounce"]["on"] is True


def test_a_closed_albedo_one_room_ends_at_the_window(tmp_path):
    """Every albedo 1 and the corridor closed: light never leaves, roulette never ends a path (q = 1); every path
    that stays in the scene ends at the window's end, in bounded time."""
    text = (ROOT / "scene_library" / "closed_corridor.yaml").read_text()
    path = tmp_path / "furnace.yaml"
    path.write_text(re.sub(r"albedo: 0\.\d+", "albedo: 1.0", text))
    scene = datagen.load_scene(path)
    assert {o.material.albedo for o in scene.objects} == {1.0}
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 2048}, "orders": "auto",
                                         "multibounce": {"paths": 4096}, "time": {"t_start": 0, "bin_width": 1e-10,
                                                                            "n_bins": 600}})
    r = datagen.simulate(scene, cfg)
    st = r.attrs["stats"]
    assert st["multibounce_roulette"] == 0
    assert st["multibounce_escaped"] < 0.01 * st["multibounce_paths"]      # closed: only grazing leaks
    assert st["multibounce_window"] > 0.98 * st["multibounce_paths"]
    assert np.isfinite(r.attrs["error"]["rel_l2"]) and r.attrs["error"]["rel_l2"] > 0


def test_converged_reference_holds_every_order_and_does_not_depend_on_the_worker_count():
    from datagen.analysis.reference import converged_reference
    scene = datagen.load_scene(ROOT / "scene_library" / "office_room.yaml")
    two = converged_reference(scene, datagen.resolve_config(scene, {"orders": 2}), rel_tol=0.5, samples=2048,
                              min_replicas=3, max_replicas=3, workers=1)
    one = converged_reference(scene, datagen.resolve_config(scene, {"orders": "auto"}), rel_tol=0.5, samples=2048,
                              min_replicas=3, max_replicas=3, workers=1)
    both = converged_reference(scene, datagen.resolve_config(scene, {"orders": "auto"}), rel_tol=0.5, samples=2048,
                               min_replicas=3, max_replicas=3, workers=2)
    assert "multibounce" not in two.components and one.components["multibounce"].sum() > 0
    for name in two.components:                       # orders 1–2 unchanged by the tracer beside them
        assert np.array_equal(two.components[name], one.components[name]), name
    for name in one.components:
        assert np.array_equal(one.components[name], both.components[name]), name
    # painted-office albedos: orders >= 3 carry about a quarter of the light
    assert 0.15 < one.components["multibounce"].sum() / one.envelope.sum() < 0.35


def test_a_deterministic_estimator_leaves_orders_3_up_out_and_counts_them():
    """The quadrature runs its primary once: no replicas would measure the tracer's noise, so with orders: auto the
    pilot's share of orders >= 3 is left out and counted in the stated error (with the order-2 share when the
    secondary is off), rather than simulated with an unmeasured error."""
    scene = datagen.load_scene(DEMO)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "quadrature", "edge": 0.2}, "orders": "auto",
                                         "effects": {"secondary": False}})
    assert cfg.orders_setting() == "auto"
    r = datagen.simulate(scene, cfg)
    d = r.attrs["plan"]["multibounce"]
    assert d["on"] is False and "multibounce" not in r.components
    shares = d["numbers"]["pilot_shares"]
    beyond = sum(v for k, v in shares.items() if k not in ("order_1", "order_2"))
    assert d["numbers"]["residual"] == pytest.approx(beyond + shares["order_2"])
    assert r.attrs["error"]["omitted_orders"] == d["numbers"]["residual"] > 0.5     # demo room: most of the light
    assert r.attrs["error"]["rel_l2"] >= r.attrs["error"]["omitted_orders"]
