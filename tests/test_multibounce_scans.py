"""Light of every order in scans and beside the quadrature (datagen/transport/multibounce, docs/physics.md §2).

The tracer traces the paths of every laser point of a scan in shared batches, each connecting to the pixel regions
its own laser point records; beside an estimator without its secondary (the confocal configs' quadrature) it carries
order 2 too, into the ``secondary`` component; its smoothing spreads a confocal scan's node masses over neighbouring
scan points with the bias estimated. Each piece is checked against an exact statement: the same targets as the area
sampler's kernel, a confocal point's light on its own pixel only, a plane kept and a parabola's bias found exactly,
the edge-cut tents deposited as add_tents deposits them, and order 2 of the tracer against the area sampler's
secondary.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import datagen
from datagen.simulation.run import prepare_transport
from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
from datagen.transport.area.kernels import fov_targets
from datagen.transport.multibounce import MultibounceSettings, build_tracer
from datagen.transport.multibounce.kernels import fov_targets_ranged
from datagen.transport.multibounce.scan_spread import spread_scan, tent_variance
from datagen.transport.multibounce.smoothing import DeepSmoothing

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "scene_library" / "demo_room.yaml")
SCAN = str(ROOT / "scene_library" / "confocal_scan.yaml")


def test_ranged_targets_are_the_area_samplers_targets_when_every_vertex_records_every_pixel():
    """One laser point that records every pixel: the ranged kernel gives the area sampler's targets to the bit (the
    same uniforms), so a single capture traces what it traced before scans shared the batches."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (50, 3)) + np.array([2.0, 0.0, 0.0])
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    ix, iy = np.tile(np.arange(4), 3), np.repeat(np.arange(3), 4)
    jitter = rng.random((50, 12, 2))
    fov = (np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]),
           np.array([2.0, 1.5]), np.array([4.0, 3.0]))
    want = fov_targets(x, n, ix, iy, np.zeros((12, 2)), jitter, (1.0, 1.0), fov)
    got = fov_targets_ranged(x, n, np.zeros(50, np.int64), np.full(50, 12, np.int64), ix, iy, jitter, fov)
    assert len(want[0]) > 100                       # pairs that face each other exist
    for a, b in zip(want, got):
        assert np.array_equal(a, b)


def test_a_confocal_point_deposits_on_its_own_pixel_only():
    scene = datagen.load_scene(SCAN)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 256}})
    transport, _ = prepare_transport(scene, cfg)
    capture = transport.capture
    assert capture.kind == "confocal" and capture.n_lasers > 4

    class Channels:
        seen: set = set()

        def add(self, times, weights, component):
            self.seen |= set(np.asarray(component).tolist())

    for laser in (0, capture.n_lasers // 2 + 3):
        tracer = build_tracer(capture, transport.caster, transport.physics, MultibounceSettings(paths=4000, min_order=1),
                              window=(cfg.time.t_start, 1e-6))
        sink = Channels()
        sink.seen = set()
        tracer.run_lasers(sink, np.random.default_rng(laser), np.array([laser]))
        assert sink.seen == {laser}


def test_the_scan_spread_keeps_a_plane_and_estimates_a_parabolas_bias_exactly():
    """A separable tent keeps a linear field (at the grid's edges too: the point reflection there; a one-sided mean
    would move an edge point of this plane by 0.17–0.5) and moves a quadratic one by var_h · curvature: the estimate
    (S_2h − S_h) · var_h / (var_2h − var_h) of DeepSmoothing.bias is then exact."""
    ny, nx, h = 12, 14, 2
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    inner = (slice(2 * h, ny - 2 * h), slice(2 * h, nx - 2 * h))
    plane = (3.0 + 0.5 * x - 0.25 * y).reshape(-1, 1)
    for width in (2, 3, 4):
        assert np.allclose(spread_scan(plane, (ny, nx, width)), plane, rtol=0, atol=1e-12)
    bowl = (x ** 2 + 2.0 * y ** 2).reshape(-1, 1)
    s_h = spread_scan(bowl, (ny, nx, h)).reshape(ny, nx)
    s_2h = spread_scan(bowl, (ny, nx, 2 * h)).reshape(ny, nx)
    true_bias = s_h - bowl.reshape(ny, nx)
    estimate = (s_2h - s_h) * tent_variance(h) / (tent_variance(2 * h) - tent_variance(h))
    assert np.allclose(estimate[inner], true_bias[inner]) and np.allclose(true_bias[inner], 3 * tent_variance(h))


def test_the_smoothing_correction_on_a_scan_is_spread_as_the_masses_are():
    """An 8 × 8 scan whose channels hold a Gaussian of σ = 5 ns (200 000 impulses each) with an amplitude linear across
    the scan (the spread over 2 pitches keeps it), smoothed at Δ = 2 ns: the plain deposit is 2.3 % from the density,
    the corrected one (its correction spread over the scan with the masses) 0.8 %; the bias estimate reads the
    corrected deposit's bias within [1, 1.5] × and every deposited mass is ≥ 0."""
    edges = np.linspace(0, 100e-9, 2001)
    c = 0.5 * (edges[1:] + edges[:-1])
    ny = nx = 8
    amp = (1.0 + 0.05 * np.arange(nx)[None, :] + 0.03 * np.arange(ny)[:, None]).ravel()
    exact = amp[:, None] * (np.exp(-0.5 * ((c - 50e-9) / 5e-9) ** 2) / (5e-9 * np.sqrt(2 * np.pi)) * np.diff(edges))
    errors = {}
    for correct in (False, True):
        rng = np.random.default_rng(1)
        sm = DeepSmoothing(2e-9, 0.0, 100e-9, ny * nx, scan=(ny, nx, 2), correct=correct)
        for ch in range(ny * nx):
            t = rng.normal(50e-9, 5e-9, 200_000)
            t = t[sm.covers(t)]
            sm.add(t, np.full(t.size, amp[ch] / 200_000), np.full(t.size, ch, dtype=np.int64))
        deposited = np.maximum(spread_scan(sm.pending - (sm.applied_now() if correct else 0.0), (ny, nx, 2)), 0.0)
        sm.end_run()
        nodes = sm.t_start + sm.width * np.arange(sm.nodes)
        density = np.stack([np.interp(c, nodes, row / sm.width) * np.diff(edges) for row in deposited])
        errors[correct] = np.linalg.norm(density - exact) / np.linalg.norm(exact)
        estimate = np.linalg.norm(sm.bias(edges, 1)) / np.linalg.norm(exact)
        assert deposited.min() >= 0.0
    assert errors[False] == pytest.approx(0.023, rel=0.05) and errors[True] < 0.4 * errors[False]
    assert errors[True] <= estimate <= 1.5 * errors[True]


def _nodes_and_their_tents():
    """16 channels of 5000 impulses over a 30 ns window and 3.9 ns past both ends (the nodes reach 2Δ), smoothed at
    Δ = 2 ns (before its flush), an empty accumulator of 2 × 16 components on that window and IRF, and every node's
    tent deposited into component 16 + channel of one of its spawns by add_tents (the reference)."""
    axis = TimeAxis(t_start=0.0, bin_width=100e-12, n_bins=300)
    rng = np.random.default_rng(0)
    smooth = DeepSmoothing(2e-9, axis.t_start, axis.t_stop, 16)
    smooth.add(rng.uniform(-3.9e-9, axis.t_stop + 3.9e-9, 5000), rng.random(5000), rng.integers(0, 16, 5000))
    acc = EnvelopeAccumulator(axis, Irf(fwhm=100e-12), 2 * 16)
    ch, j = np.nonzero(smooth.pending)
    t = smooth.t_start + j * smooth.width
    slow = acc.spawn()
    slow.add_tents(np.stack([t - smooth.width, t, t + smooth.width], 1), smooth.pending[ch, j], 16 + ch)
    return smooth, acc, slow


def test_tents_cut_by_the_grid_ends_are_deposited_as_add_tents_deposits_them():
    """DeepSmoothing.flush sends the nodes whose tents cross an end of the fine grid as one shape per node times each
    channel's mass (EnvelopeAccumulator.add_fine): the binned envelope, what lies outside and the total weight are
    those of add_tents for every tent (the binned arrays to 1e-12 of their peak)."""
    smooth, acc, slow = _nodes_and_their_tents()
    pending = smooth.pending.copy()
    fast = acc.spawn()
    smooth.flush(fast, 1)
    assert len(smooth.edge_shapes(fast)) >= 2                                # the grid's end cuts some tents
    assert np.abs(fast.binned() - slow.binned()).max() <= 1e-12 * slow.binned().max()
    assert np.allclose(fast.outside(), slow.outside(), rtol=1e-12, atol=1e-12 * pending.sum())
    assert np.allclose(fast.total_weight(), slow.total_weight(), rtol=1e-12)
    with pytest.raises(ValueError, match="distinct"):
        fast.add_fine(np.ones((2, 3)), np.array([1, 1]), 0, np.ones(2), np.zeros(2))


def test_the_quadrature_carries_the_tracer_from_order_2_when_its_secondary_is_off():
    """A quadrature without its secondary and orders: auto: the tracer runs from order 2 (into ``secondary``) and
    up (``multibounce``), nothing is left out, the replicas of the tracer give the Monte Carlo part of the stated
    error, and its order 2 carries what the area sampler's secondary carries (demo room; within 6 %: the two
    estimators' standard errors here are about 1.5 % each)."""
    scene = datagen.load_scene(DEMO)
    cfg = datagen.resolve_config(scene, {"estimator": {"kind": "quadrature", "edge": 0.2}, "orders": "auto",
                                         "effects": {"secondary": False}, "multibounce": {"paths": 16384}})
    r = datagen.simulate(scene, cfg)
    d = r.attrs["plan"]["multibounce"]
    assert d["on"] and d["numbers"]["min_order"] == 2 and d["numbers"]["residual"] == 0.0
    assert r.attrs["error"]["omitted_orders"] == 0.0 and r.attrs["error"]["tracer_replicas"] == 2
    assert r.attrs["error"]["monte_carlo"] > 0 and "order ≥ 2 tracer" in r.attrs["error"]["method"]
    area = datagen.simulate(scene, datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 65536},
                                                                  "replicas": 4}))
    second, reference = r.components["secondary"].sum(), area.components["secondary"].sum()
    assert abs(second / reference - 1) < 0.06, (second, reference)
    # the demo room's albedo-1 walls: orders >= 3 carry most of the light (docs/physics.md)
    assert r.components["multibounce"].sum() > r.components["secondary"].sum()
    # orders: 2 is the same light with every estimator: the tracer carries order 2 alone, into `secondary` (no
    # multibounce component), and the orders above it are the residual in the stated error
    two = datagen.simulate(scene, cfg.model_copy(update={"orders": 2}))
    assert list(two.components) == [n for n in r.components if n != "multibounce"]
    assert two.attrs["orders"]["simulated"] == "1..2" and 0.5 < two.attrs["error"]["omitted_orders"] < 0.7
    assert abs(two.components["secondary"].sum() / reference - 1) < 0.06, (two.components["secondary"].sum(), reference)


def test_a_confocal_scan_to_tolerance_with_every_order():
    """confocal_scan.yaml (quadrature, orders 1 as shipped) with orders 1–4 at 5 %: the tolerance loop refines the
    edge for its part and adds tracer replicas for theirs; the stated error holds every part and meets 5 %. (Orders
    fixed: this scene's orders >= 2 carry 0.5 % of its light, so orders: auto leaves them out at 5 %.)"""
    from datagen.simulation.tolerance import simulate_to_tolerance
    scene = datagen.load_scene(SCAN)
    cfg = datagen.resolve_config(scene, {"orders": 4})
    r = simulate_to_tolerance(scene, cfg, 0.05)
    e = r.attrs["error"]
    assert r.attrs["tolerance"]["met"] and e["rel_l2"] <= 0.05
    assert e["tracer_replicas"] >= 2 and e["refinement"] is not None and e["monte_carlo"] > 0
    parts = np.sqrt(e["monte_carlo"] ** 2 + e["refinement"] ** 2 + (e["smoothing"] or 0) ** 2)
    assert e["rel_l2"] == pytest.approx(parts, rel=1e-9)
    # a convex box before a bare wall: no order 2 (docs/physics.md), the light of orders >= 3 passes the relay wall
    assert r.components["secondary"].sum() == 0 and r.components["multibounce"].sum() > 0


def test_a_finer_quadrature_level_continues_the_tracers_replicas():
    """The tracer does not depend on the quadrature's edge: a finer level adopts the replicas of the one before
    (Replicas.adopt_tracer) and its tracer components are those replicas' mean, to round-off, with no new run."""
    from datagen.simulation.run import Replicas
    scene = datagen.load_scene(SCAN)
    # orders fixed (no pilot): this scene's orders >= 2 carry 0.5 %, near what orders: auto leaves out
    cfg = datagen.resolve_config(scene, {"orders": 4, "multibounce": {"paths": 64}})
    coarse = Replicas(scene, cfg, np.random.default_rng(1))
    coarse.run(cfg.error.replicas)
    finer = cfg.with_estimator(**cfg.estimator.at_edge(cfg.estimator.edge / 2))
    fine = Replicas(scene, finer, np.random.default_rng(2), planned=coarse.planned)
    fine.adopt_tracer(coarse)
    fine.run(cfg.error.replicas)
    assert fine.tracer is coarse.tracer and fine.tracer_sums.count == coarse.tracer_sums.count == 2
    a, b = coarse.transported(), fine.transported()
    for name in ("secondary", "multibounce"):
        i = a.names.index(name)
        assert np.allclose(b.binned[i], a.binned[i], rtol=1e-12, atol=1e-12 * a.binned[i].max())
        assert np.allclose(b.outside[i], a.outside[i], rtol=1e-9, atol=1e-12)
    base = [i for i, n in enumerate(a.names) if n not in ("secondary", "multibounce")]
    assert not np.array_equal(a.binned[base].sum(0), b.binned[base].sum(0))    # the quadrature did run again


def test_the_reference_of_a_quadrature_config_runs_the_quadrature_once_and_the_tracer_on_every_core():
    """converged_reference of a scan config: the quadrature at a quarter of the edge once (its own refinement error
    counted), the unsmoothed tracer as replicas; the same numbers on one core and on two; a result at 5 % lies
    within twice its stated error of it."""
    scene = datagen.load_scene(SCAN)
    # orders fixed (no pilot): the light of orders >= 2 in this scene is 0.5 %, near what orders: auto leaves out
    cfg = datagen.resolve_config(scene, {"orders": 4, "estimator": {"kind": "quadrature", "edge": 0.2}})
    kw = dict(rel_tol=0.05, min_replicas=2, max_replicas=2)
    one = datagen.converged_reference(scene, cfg, workers=1, **kw)
    two = datagen.converged_reference(scene, cfg, workers=2, **kw)
    assert one.settings["sampler"] == "quadrature + tracer" and one.settings["estimator"]["edge"] == pytest.approx(
        cfg.estimator.edge / 4)
    assert np.array_equal(one.envelope, two.envelope)
    e = one.error_estimate
    assert e["refinement"] is not None and e["monte_carlo"] > 0
    assert e["rel_l2"] == pytest.approx(np.hypot(e["monte_carlo"], e["refinement"]))
    assert one.components["multibounce"].sum() > 0
    from datagen.simulation.replicas import relative_difference
    from datagen.simulation.tolerance import simulate_to_tolerance
    r = simulate_to_tolerance(scene, cfg, 0.05)
    actual = relative_difference(r.envelope, one.envelope, one.envelope)
    assert actual <= 2 * np.hypot(r.attrs["error"]["rel_l2"], e["rel_l2"]), (actual, r.attrs["error"]["rel_l2"])


def test_smoothed_nodes_deposited_binned_are_the_tents_add_tents_deposits():
    """DeepSmoothing.flush into a BinnedSink: the node masses times the binned unit tents (binned_shapes) give the
    binned envelope of add_tents for every tent (to 1e-12 of its peak) and the same light outside the window, tents cut
    by the grid's ends included, without touching the sink's fine grid; impulses beyond the grid's reach are tallied
    as outside; binned + outside = total for every component."""
    from datagen.timing.binned_sink import BinnedSink
    smooth, acc, slow = _nodes_and_their_tents()
    pending = smooth.pending.copy()
    sink = BinnedSink(acc.spawn())
    smooth.flush(sink, 1)
    assert not sink.holds_fine()
    assert np.abs(sink.binned_rows - slow.binned()).max() <= 1e-12 * slow.binned().max()
    assert np.allclose(sink.outside, slow.outside(), rtol=1e-12, atol=1e-12 * pending.sum())
    assert np.allclose(sink.binned_rows.sum(axis=1) + sink.outside, slow.total_weight(), rtol=1e-12)
    assert np.abs(sink.binned_total(16) - slow.binned_total(16)).max() <= 1e-12 * slow.binned().max()
    far = np.array([-5e-9, acc.axis.t_stop + 5e-9])                     # beyond the fine grid's reach
    sink.add(far, np.array([2.0, 3.0]), np.array([0, 5]))
    sink.add(np.array([10e-9]), np.array([1.0]), np.array([3]))     # within it: on the fine grid
    assert sink.holds_fine() and sink.outside[0] == 2.0 and sink.outside[5] == 3.0
    binned = sink.binned_rows + sink.fine.binned()
    outside = sink.outside + sink.fine.outside()
    added = slow.total_weight() + np.bincount([0, 5, 3], weights=[2.0, 3.0, 1.0], minlength=32)
    assert np.allclose(binned.sum(axis=1) + outside, added, rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="distinct"):
        sink.add_binned(np.ones((2, 300)), np.array([1, 1]), np.ones(2))
    with pytest.raises(ValueError, match="non-finite"):                 # beyond the reach too: never tallied silently
        sink.add(np.array([np.nan]), np.array([1.0]), np.array([0]))
    with pytest.raises(ValueError, match="component ids"):
        sink.add(far, np.array([1.0, 1.0]), np.array([0, 99]))


class _ScriptedRuns:
    """A stand-in for :class:`~datagen.simulation.run.Replicas` beside the quadrature: the tracer's spread is
    σ/√runs, and its smoothing bias reads 0.75 × the tolerance from fewer than NARROW_RUNS runs (two runs' noisy
    reading) and 0.2 × from more (what more runs show); ``settle_smoothing`` runs up to NARROW_RUNS while the bias
    reads above NARROW_SHARE × the tolerance."""

    def __init__(self, tolerance: float, sigma: float):
        from datagen.simulation.run import NARROW_RUNS, NARROW_SHARE
        self.tolerance, self.sigma, self.narrow_runs, self.share = tolerance, sigma, NARROW_RUNS, NARROW_SHARE
        self.tracer_sums = type("Sums", (), {"count": 2})()
        self.counts = [2]

    def narrow_smoothing(self, tolerance):
        return False

    def fixed_error(self):
        return (0.75 if self.tracer_sums.count < self.narrow_runs else 0.2) * self.tolerance

    def settle_smoothing(self, tolerance):
        if self.fixed_error() <= self.share * tolerance:     # as Replicas.settle_smoothing
            return False
        more = self.narrow_runs - self.tracer_sums.count
        if more > 0:
            self.run(more)
        return more > 0

    def error(self):
        return self.sigma / np.sqrt(self.tracer_sums.count)

    def run(self, n):
        self.tracer_sums.count += n
        self.counts.append(self.tracer_sums.count)

    transport = None                             # no coarse rule of its own: the level's attrs are error_attrs'

    def transported(self):
        return None

    def error_attrs(self, tr, rng):
        return {}


def test_beside_the_quadrature_a_smoothing_bias_read_from_two_runs_is_read_again_before_replicas_are_planned(
        monkeypatch):
    """Tolerance 2 %, σ = 1.6 × it: planned on the two runs' reading (0.75 × the tolerance, leaving √(1 − 0.75²) =
    0.66 × it) the tracer would run to ⌈2 · (1.6/√2 / 0.66)² · 1.1⌉ = 7; read again on NARROW_RUNS = 4 runs (0.2 ×),
    its spread there, 0.8 × the tolerance, is within what is left (0.98 ×), and the loop stops at 4."""
    from datagen.simulation.tolerance import top_up_tracer
    runs = _ScriptedRuns(0.02, 1.6 * 0.02)
    top_up_tracer(runs, 0.02, 0.0, None, None, 1.0, None)
    assert runs.counts == [2, runs.narrow_runs]
    # the same loop without the second reading (the bias stays at two runs' reading) plans 7
    stuck = _ScriptedRuns(0.02, 1.6 * 0.02)
    monkeypatch.setattr(stuck, "settle_smoothing", lambda tolerance: False)
    monkeypatch.setattr(stuck, "fixed_error", lambda: 0.75 * 0.02)
    top_up_tracer(stuck, 0.02, 0.0, None, None, 1.0, None)
    assert stuck.counts == [2, 7]
