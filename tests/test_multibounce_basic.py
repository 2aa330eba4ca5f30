"""The basic light tracer (datagen/transport/multibounce/basic.py) as an independent check of the fast one.

Both estimate the light of every order (docs/physics.md §2, "Light of every order") from the same leg weights; the
basic one samples it by next-event connections alone, in numpy, one laser point at a time, and the fast one
(``MultibounceTracer``, run unsmoothed: ``smooth_order=0``) combines next-event connections, direction hits and
eye vertices under the balance heuristic in compiled passes. Each order's in-window energy and the envelope on 1 ns
bins are compared on the demo room (albedo 1, a box 10 cm from the relay wall: the next-event weights' hardest
case) with and without the eye vertex, and on a confocal_smoke sample (an 8 × 8 scan, albedos 0.55–0.81: Russian
roulette at work; from order 2, as the confocal configs run the tracer), channel by channel too.

Tolerance: z = (mean_basic − mean_fast) / √(se_basic² + se_fast²), each standard error measured from that
estimator's own replicas (fixed seeds): |z| < 4 for each order's energy, and over the 1 ns bins (or the scan's
channels) that hold light, mean z² < 2 and |z| < 5 (the bins share paths, and next-event weights near the relay wall
have heavy tails). With these seeds: |z| ≤ 2.6 by order, mean z² 0.80–1.28 and |z| ≤ 3.1 by bin; on 8 other seed
sets (12 replicas on the scan) |z| ≤ 3.3 by order, mean z² ≤ 1.55 and |z| ≤ 4.1 by bin or channel. Each
comparison also asserts that its standard error is a small fraction of what it compares, so that a wrong weight
cannot hide in the noise: with every weight of the basic tracer 5 % too large all three comparisons fail (largest
z 6.3–10.8, mean z² 3.1–6.0); without the cosθ_x of its next-event weight, z = 26–120; without the roulette's 1/q,
z = −47 to −117 on the scan (the demo room's albedo 1 cannot see that one).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import datagen
from datagen.errors import ConfigError
from datagen.scene import Material, RayCaster, Scene, SceneObject, resolve_capture
from datagen.transport.multibounce import MultibounceSettings, build_tracer
from datagen.transport.multibounce.basic import trace_basic
from datagen.transport.physics import LegPhysics

ROOT = Path(__file__).resolve().parents[1]
BIN = 1e-9                                      # coarse time bins of the envelope comparison, s


class Binned:
    """A sink that bins impulses of component 0 on ``edges`` per channel: (n_channels, n_bins)."""

    def __init__(self, n_channels: int, edges: np.ndarray):
        self.edges = edges
        self.envelope = np.zeros((n_channels, len(edges) - 1))

    def add(self, times, weights, component):
        inside = (times >= self.edges[0]) & (times < self.edges[-1])
        bins = np.searchsorted(self.edges, times[inside], side="right") - 1
        np.add.at(self.envelope, (np.asarray(component)[inside], bins), weights[inside])


def legs(scene, config):
    """The capture, ray caster and leg weights of ``scene`` under ``config``'s physics (as a run builds them)."""
    caster = RayCaster(scene)
    capture = resolve_capture(scene, caster)
    return capture, caster, LegPhysics(scene, capture, caster, config.physics_settings())


def basic_runs(setup, paths, runs, seed, edges, min_order):
    """Per replica: each order's in-window energy (runs, 16) and the envelope (runs, n_channels, n_bins)."""
    out = [trace_basic(*setup, paths, np.random.default_rng(seed + r), edges, min_order=min_order)
           for r in range(runs)]
    return np.array([o.order_energy for o in out]), np.array([o.envelope for o in out])


def fast_runs(setup, paths, runs, seed, edges, min_order, eye):
    """The same for the fast tracer, unsmoothed."""
    capture = setup[0]
    energy, envelope = [], []
    for r in range(runs):
        tracer = build_tracer(*setup, MultibounceSettings(paths=paths, min_order=min_order, smooth_order=0, eye=eye),
                              window=(edges[0], edges[-1]))
        sink = Binned(capture.n_channels, edges)
        tracer.run(sink, np.random.default_rng(seed + r))
        energy.append(tracer.order_energy.copy())
        envelope.append(sink.envelope)
    return np.array(energy), np.array(envelope)


def z_scores(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z, combined standard error) of the replica means of a (R_a, ...) and b (R_b, ...), elementwise."""
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    return np.divide(a.mean(0) - b.mean(0), se, out=np.zeros_like(se), where=se > 0), se


def by_order(energy: np.ndarray, orders: range) -> np.ndarray:
    """(runs, len(orders) + 1): each order of ``orders`` alone and every higher order summed."""
    return np.concatenate([energy[:, orders.start - 1:orders.stop - 1], energy[:, orders.stop - 1:].sum(1)[:, None]],
                          axis=1)


def assert_agree(basic, fast, orders: range, channels: bool = False):
    """The test's tolerance (module doc) for (energy, envelope) replicas of both tracers."""
    e_b, e_f = by_order(basic[0], orders), by_order(fast[0], orders)
    z, se = z_scores(e_b, e_f)
    assert np.all(se < 0.025 * e_f.mean(0)), se / e_f.mean(0)     # teeth: a 10 % error of any order gives |z| > 4
    assert np.all(np.abs(z) < 4), (e_b.mean(0), e_f.mean(0), z)
    series = [(basic[1].sum(1), fast[1].sum(1))]                               # the envelope over all channels
    if channels:
        series.append((basic[1].sum(2), fast[1].sum(2)))                      # each channel's energy
    for b, f in series:
        z, se = z_scores(b, f)
        lit = se > 0
        assert lit.sum() > 10 and se.sum() < 0.05 * f.mean(0).sum()           # teeth: se ~5 % of a bin or less
        assert (z[lit] ** 2).mean() < 2 and np.abs(z[lit]).max() < 5, ((z[lit] ** 2).mean(), z[lit])


@pytest.fixture(scope="module")
def demo_room():
    scene = datagen.load_scene(ROOT / "scene_library" / "demo_room.yaml")
    setup = legs(scene, datagen.resolve_config(scene, {}))
    edges = np.arange(101) * BIN                                               # the room's 0–100 ns window
    return setup, edges, basic_runs(setup, 40000, 16, 1000, edges, 3)


def test_the_demo_rooms_orders_agree_with_the_fast_tracer(demo_room):
    setup, edges, basic = demo_room
    assert_agree(basic, fast_runs(setup, 10000, 16, 2000, edges, 3, eye=True), range(3, 9))


def test_the_demo_rooms_orders_agree_with_the_fast_tracer_without_its_eye_vertex(demo_room):
    setup, edges, basic = demo_room
    assert_agree(basic, fast_runs(setup, 10000, 16, 3000, edges, 3, eye=False), range(3, 9))


def test_retroreflective_objects_orders_agree_with_the_fast_tracer():
    """The demo room with a retroreflective box and pillar (k_s 0.8, lobe width 0.2): the fast tracer draws their
    continuations from the lobe (flux f cosθ / (q p), the balance heuristic's densities with p), the basic one
    cosine directions; both must give every order. With these seeds |z| ≤ 1.5 by order, mean z² 1.6 and |z| ≤ 3.4
    by 1 ns bin; without the lobe's density in the fast tracer's flux (f π / q instead of f π / (q s)), z = −3 to −20
    by order."""
    retro = Material(kind="retroreflective", albedo=0.9, specular=0.8, lobe_width=0.2)
    scene = datagen.load_scene(ROOT / "scene_library" / "demo_room.yaml")
    objects = [SceneObject(o.name, o.label, retro if o.name in ("box", "pillar") else o.material, o.vertices, o.faces)
               for o in scene.objects]
    scene = Scene(objects, scene.laser, scene.sensor, scene.name, scene.source, scene.defaults)
    setup = legs(scene, datagen.resolve_config(scene, {}))
    edges = np.arange(101) * BIN
    basic = basic_runs(setup, 40000, 16, 6000, edges, 3)
    assert_agree(basic, fast_runs(setup, 10000, 16, 7000, edges, 3, eye=True), range(3, 7))


def test_a_confocal_scans_orders_agree_with_the_fast_tracer_channel_by_channel():
    scene, config = datagen.sample_setup(ROOT / "configs" / "datasets" / "confocal_smoke.yaml", "train", 0)
    setup = legs(scene, config)
    assert setup[0].kind == "confocal" and setup[0].n_channels == 64
    edges = config.time.t_start + np.arange(round((config.time.t_stop - config.time.t_start) / BIN) + 1) * BIN
    basic = basic_runs(setup, 500, 16, 4000, edges, 2)
    assert_agree(basic, fast_runs(setup, 500, 16, 5000, edges, 2, eye=True), range(2, 5), channels=True)


def test_the_basic_tracer_refuses_what_it_cannot_trace(demo_room):
    setup, edges, _ = demo_room
    for kwargs, words in (({"paths": 0}, "paths"), ({"min_order": 0}, "min_order"),
                          ({"min_order": 4, "max_order": 3}, "max_order 3 is below"),
                          ({"edges": edges[::-1]}, "edges")):
        args = {"paths": 10, "rng": np.random.default_rng(0), "edges": edges, **kwargs}
        with pytest.raises(ConfigError, match=words):
            trace_basic(*setup, **args)


def test_the_basic_tracer_deposits_the_orders_asked_for_only(demo_room):
    setup, edges, _ = demo_room
    traced = trace_basic(*setup, 2000, np.random.default_rng(1), edges, min_order=4, max_order=5)
    assert np.all(traced.order_energy[[3, 4]] > 0) and traced.order_energy.sum() == traced.order_energy[[3, 4]].sum()
    assert traced.envelope.shape == (1, 100) and np.isclose(traced.envelope.sum(), traced.order_energy.sum())
