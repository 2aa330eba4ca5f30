"""Hidden-surface quadrature (datagen.transport.quadrature) and the exact tent deposits it relies on (datagen.timing.irf).

The tents are checked against closed forms computed independently (areas and centroids of a triangle clipped by
the level sets of a linear time map); the quadrature against the project's independent midpoint reference
(:func:`datagen.analysis.oracle.primary_area_quadrature`), the area sampler (occluder scene) and tal's point-radiance
integrand (tests/test_tal.py), and scans against single-spot captures.
"""
from __future__ import annotations

import numpy as np
import pytest
from test_tal import hidden_square, laser_scale, opl_edges, quadrature, rel_l2, run

from datagen.errors import ConfigError
from datagen.analysis import relative_l2
from datagen.sampling.surfaces import subdivide_triangles
from datagen.transport import AreaSampler, AreaSettings
from datagen.scene import Material
from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis, bin_impulses
from datagen.timing.tents import tent_curvature
from datagen.timing.curvature import deposit_curvature
from datagen.sampling.surfaces import subdivide_with_vertices
from datagen.transport import Quadrature, QuadratureSettings
from datagen.analysis.oracle import primary_area_quadrature
from datagen.scene import CaptureSpec, FieldOfView, Laser, Scene, Sensor, WallGrid, box, quad
from datagen.simulation import SimulationConfig, resolve_config, simulate
from datagen.io import tal_arrays

PS = 1e-12

# -- tents: closed forms ------------------------------------------------------------------------------------

TRI2D = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 0.9]])
"""A triangle in the plane; the time maps below are linear on it: τ(p) = τ0 + g·p (in cells)."""


def _clip(poly: np.ndarray, g: np.ndarray, c: float) -> np.ndarray:
    """The part of convex polygon ``poly`` (n, 2) where g·p < c (Sutherland–Hodgman, one half-plane)."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        da, db = g @ a - c, g @ b - c
        if da < 0:
            out.append(a)
        if (da < 0) != (db < 0):
            out.append(a + (b - a) * da / (da - db))
    return np.array(out).reshape(-1, 2)


def _moments(poly: np.ndarray) -> tuple[float, np.ndarray]:
    """Area and area-weighted centroid (shoelace) of a polygon (n, 2); (0, 0) when empty."""
    if len(poly) < 3:
        return 0.0, np.zeros(2)
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if area == 0:
        return 0.0, np.zeros(2)
    return area, np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def _below(tau0: float, g: np.ndarray, c: float) -> tuple[float, float]:
    """(∫ 1, ∫ τ) over the triangle where τ < c, divided by its area."""
    total, _ = _moments(TRI2D)
    area, centroid = _moments(_clip(TRI2D, g, c - tau0))
    return area / total, area / total * (tau0 + g @ centroid) if area else 0.0


def _vertex_times(tau0, g):
    return tau0 + TRI2D @ g


def test_tents_equal_the_impulse_limit_in_the_cell_modes():
    """Delta IRF: each cell gets the exact share of the triangle's area whose time falls in it; Gaussian IRF
    (fine grid, linear splatting): each node the exact integral of its splatting weight over the triangle (the
    limit of infinitely many impulses added with ``add``). Both from clipped-polygon areas and centroids."""
    maps = [(3.3, np.array([4.0, 1.5])),        # a generic tent over ~5 cells
            (7.6, np.array([-0.5, 2.5])),       # vertices 0 and 1 at one time: t0 = t1
            (12.25, np.array([0.37, 0.05])),    # narrower than a cell
            (20.0, np.array([-0.9, 0.3]))]      # vertices 0 and 2 at one time: t1 = t2
    for irf, kind in ((Irf(sigma=0.0), "cell"), (Irf(fwhm=50 * PS), "node")):
        axis = TimeAxis(t_start=0.0, bin_width=10 * PS, n_bins=40)
        acc = EnvelopeAccumulator(axis, irf, 1)
        step, shift = acc.fine_step, (acc.n_left if kind == "cell" else acc.n_left - 0.5)
        expect = np.zeros(acc.n_fine)
        for i, (tau0, g) in enumerate(maps):
            w = 1.0 + i
            acc.add_tents(((_vertex_times(tau0, g) - shift) * step)[None], [w], 0)
            for k in range(acc.n_fine):
                if kind == "cell":                                   # ∫ over [k, k+1)
                    expect[k] += w * (_below(tau0, g, k + 1)[0] - _below(tau0, g, k)[0])
                else:                                                 # ∫ max(0, 1 − |τ − k|)
                    (a0, m0), (a1, m1), (a2, m2) = (_below(tau0, g, c) for c in (k - 1, k, k + 1))
                    expect[k] += w * ((m1 - m0) - (k - 1) * (a1 - a0) + (k + 1) * (a2 - a1) - (m2 - m1))
        got = acc.fine_histogram()[0]
        assert np.abs(got - expect).max() < 1e-12 * expect.max(), kind
        assert acc.total_weight()[0] == pytest.approx(10.0, rel=1e-15)
        assert abs(acc.binned().sum() + acc.outside()[0] - 10.0) < 1e-12 * 10


def _tent_quadrature(t: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights of the unit tent (composite rule, sub-intervals ≤ ``step``)."""
    x, wq = np.polynomial.legendre.leggauss(10)
    t0, t1, t2 = np.sort(t)
    ts, ws = [], []
    for a, b, rising in ((t0, t1, True), (t1, t2, False)):
        if b <= a:
            continue
        ed = np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)
        lo, hi = ed[:-1, None], ed[1:, None]
        tt = (0.5 * (hi - lo) * x + 0.5 * (hi + lo)).ravel()
        dens = 2 / (t2 - t0) * ((tt - t0) / (t1 - t0) if rising else (t2 - tt) / (t2 - t1))
        ts.append(tt)
        ws.append(dens * (np.broadcast_to(wq, (len(lo), 10)) * 0.5 * (hi - lo)).ravel())
    return np.concatenate(ts), np.concatenate(ws)


@pytest.mark.parametrize("irf", [Irf(sigma=1 * PS), Irf(sigma=0.5 * PS, kind="exgaussian", tail=0.2 * PS)],
                         ids=["gaussian", "exgaussian"])
def test_tents_in_direct_mode_are_the_exact_bin_integrals(irf):
    """Narrow IRF (direct mode): bins hold ∫ tent(t) P(e_b ≤ t + X < e_b+1) dt exactly (partial moments of the
    IRF), against a composite Gauss–Legendre rule over the tent with the per-impulse reference bin_impulses."""
    axis = TimeAxis(t_start=0.0, bin_width=20 * PS, n_bins=120)
    acc = EnvelopeAccumulator(axis, irf, 1)
    assert acc.direct
    tents = np.array([[100, 190, 700], [1000, 1000, 1050], [1500, 1533, 1533], [1200, 1200.01, 1200.03],
                      [-25, 10, 40], [2380, 2395, 2600]]) * PS
    weights = np.array([1.0, 2.0, 0.5, 1.1, 1.3, 0.9])
    acc.add_tents(tents, weights, 0)
    exact = np.zeros(axis.n_bins)
    for t, w in zip(tents, weights):
        ts, ws = _tent_quadrature(t, irf.sigma / 4)
        exact += w * bin_impulses(ts, ws, axis, irf)
    got = acc.binned()[0]
    assert np.abs(got - exact).max() < 1e-9 * exact.max()
    assert abs(got.sum() + acc.outside()[0] - weights.sum()) < 1e-12 * weights.sum()


@pytest.mark.parametrize("irf", [Irf(sigma=0.0), Irf(fwhm=60 * PS), Irf(sigma=1 * PS)], ids=["delta", "fine", "direct"])
def test_zero_span_tents_are_impulses_and_mass_is_conserved(irf):
    axis = TimeAxis(t_start=0.0, bin_width=20 * PS, n_bins=50)
    times = np.array([37.0, 200.0, 640.3, -5.0, 995.0, 5000.0]) * PS        # two straddle or leave the window
    a, b = EnvelopeAccumulator(axis, irf, 2), EnvelopeAccumulator(axis, irf, 2)
    a.add(times, np.arange(1.0, 7.0), np.array([0, 1, 0, 1, 0, 1]))
    b.add_tents(np.repeat(times[:, None], 3, axis=1), np.arange(1.0, 7.0), np.array([0, 1, 0, 1, 0, 1]))
    np.testing.assert_allclose(b.fine_histogram(), a.fine_histogram(), rtol=0, atol=1e-12 * 6)
    np.testing.assert_allclose(b.outside(), a.outside(), rtol=0, atol=1e-12 * 21)
    # wide tents across both ends of the window and wholly outside: binned + outside = total
    c = EnvelopeAccumulator(axis, irf, 1)
    c.add_tents(np.array([[-300, 20, 400], [900, 1100, 1300], [-900, -800, -700], [10, 10, 2e6]]) * PS,
                [1.0, 2.0, 3.0, 4.0], 0)
    assert abs(c.binned().sum() + c.outside()[0] - 10.0) < 1e-12 * 10
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        c.add_tents(np.zeros((2, 2)), [1.0, 1.0])
    with pytest.raises(ValueError, match="negative"):
        c.add_tents(np.zeros((1, 3)), [-1.0])


def test_wide_tents_by_curvature_equal_the_per_node_closed_form():
    """Fine-grid mode: tents of >= CURVATURE_MIN_NODES nodes go through their second differences
    (tent_curvature, summed twice when read); the same fine histogram as the per-node closed form (the
    threshold set to inf) to 1e-9 of its maximum, over widths from 4 nodes to hundreds, sides from 0 (flat
    sides) to 1e-7 nodes and both sides narrower than a node, in several components."""
    axis = TimeAxis(t_start=0.0, bin_width=20 * PS, n_bins=400)
    irf = Irf(fwhm=60 * PS)
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(100, 7800, (3000, 3)), axis=1)
    t[:3000:4] = t[:3000:4, :1] + np.sort(rng.uniform(0, 40, (750, 3)), axis=1)      # 0–40 ps: a few nodes
    t[1::50, 1] = t[1::50, 0]                                       # flat rising side
    t[2::50, 1] = t[2::50, 2] - 1e-7                                  # side of 1e-7 ps
    t[3::50] = t[3::50, :1] + np.array([0.0, 0.3, 25.0])              # one side below a node
    t = t * PS
    w = rng.uniform(0.1, 2.0, len(t))
    comp = rng.integers(0, 3, len(t))
    fast, exact = EnvelopeAccumulator(axis, irf, 3), EnvelopeAccumulator(axis, irf, 3)
    exact.curvature_min_nodes = np.inf
    span = (t[:, 2] - t[:, 0]) / fast.fine_step
    assert (span >= fast.curvature_min_nodes).mean() > 0.5 and (span < fast.curvature_min_nodes).any()
    for part in np.array_split(rng.permutation(len(t)), 3):            # several calls, folded once
        fast.add_tents(t[part], w[part], comp[part])
        exact.add_tents(t[part], w[part], comp[part])
    ref = exact.fine_histogram()
    assert np.abs(fast.fine_histogram() - ref).max() < 1e-9 * ref.max()
    np.testing.assert_allclose(fast.binned(), exact.binned(), rtol=0, atol=1e-9 * exact.binned().max())
    np.testing.assert_allclose(fast.outside(), exact.outside(), rtol=0, atol=1e-9 * w.sum())


def test_compiled_curvature_deposit_equals_tent_curvature():
    """deposit_curvature (numba) adds the same values as tent_curvature (numpy), weighted, to 1e-12."""
    rng = np.random.default_rng(3)
    c = np.sort(rng.uniform(5, 60, (500, 3)), axis=1)
    c[::7, 1] = c[::7, 0] + rng.uniform(0, 1, len(c[::7]))            # sides narrower than a node
    c[1::9, 1] = c[1::9, 2]
    w, comp = rng.uniform(0.5, 2.0, len(c)), rng.integers(0, 2, len(c))
    node, value = tent_curvature(c)
    ref = np.zeros(2 * 80)
    np.add.at(ref, (comp[:, None] * 80 + node).ravel(), (value * w[:, None]).ravel())
    got = np.zeros(2 * 80)
    deposit_curvature(c, w, comp, 80, got)
    assert np.abs(got - ref).max() < 1e-12 * np.abs(ref).max()


def test_narrow_tent_sides_by_their_two_ends_equal_the_divided_difference(monkeypatch):
    """A side from NARROW_SIDE (1e-3 node) to a node wide takes the B3 values at its two ends over the side; the
    same second differences as the divided difference without cancellation (NARROW_SIDE raised to a node) to
    1e-12 of their largest value, for sides from 1e-3 to 1 node on either side of the tent, in numpy and
    compiled; a side below NARROW_SIDE keeps the divided difference."""
    import datagen.timing.tents as tents

    rng = np.random.default_rng(11)
    gap = np.geomspace(tents.NARROW_SIDE, 1.0, 400)
    c0 = rng.uniform(5.0, 6.0, len(gap))
    span = rng.uniform(4.0, 40.0, len(gap))
    c = np.stack([c0, c0 + gap, c0 + span], axis=1)
    c[1::2, 1] = c[1::2, 2] - gap[1::2]                                # the narrow side on the falling end
    c = np.concatenate([c, [[5.2, 5.2 + 0.5 * tents.NARROW_SIDE, 9.0]]])  # below NARROW_SIDE

    def summed(values_of):
        node, value = values_of(c)
        out = np.zeros((len(c), 64))
        np.add.at(out, (np.repeat(np.arange(len(c)), node.shape[1]), node.ravel()), value.ravel())
        return out

    two_ends = summed(tents.tent_curvature)
    compiled = np.zeros(len(c) * 64)
    deposit_curvature(c, np.ones(len(c)), np.arange(len(c)), 64, compiled)
    monkeypatch.setattr(tents, "NARROW_SIDE", 1.0)
    divided = summed(tents.tent_curvature)
    scale = np.abs(divided).max(axis=1, keepdims=True)
    assert (np.abs(two_ends - divided) / scale).max() < 1e-12
    assert (np.abs(compiled.reshape(len(c), 64) - divided) / scale).max() < 1e-12
    assert np.abs(two_ends[-1] - divided[-1]).max() == 0.0           # the divided difference itself


def test_confocal_scan_shares_the_laser_legs_visibility():
    """A confocal room scan (one FoV cell per pixel: each target is its laser point) casts no hidden → FoV rays:
    the laser leg's visibility is the same segment's. Same envelope as with those rays forced, about half the rays."""
    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import draw_room

    config = load_dataset_config("configs/datasets/confocal_smoke.yaml")
    scene = draw_room(config, "train", 0)[0].scene
    sim = resolve_config(scene, config.simulation_overrides())
    runs = {}
    for forced in (None, True):
        q = Quadrature(scene, QuadratureSettings(edge=0.4, fov_cells=1, shadow_spot=True, shadow_fov=forced))
        acc = EnvelopeAccumulator(sim.time, sim.irf, len(q.component_names) * q.capture.n_channels)
        q.run(acc)
        runs[forced] = (acc.binned(), q.stats.shadow_rays, q.settings.shadow_fov)
    (shared, rays, fov), (ref, forced_rays, forced_fov) = runs[None], runs[True]
    assert not fov and forced_fov and rays < 0.51 * forced_rays and ref.max() > 0
    np.testing.assert_allclose(shared, ref, rtol=0, atol=1e-12 * ref.max())


# -- quadrature: scenes -------------------------------------------------------------------------------------

AXIS = TimeAxis(t_start=0.0, bin_width=20 * PS, n_bins=700)
IRF = Irf(fwhm=100 * PS)


def small_scene(occluder: bool = False, capture: CaptureSpec | None = None) -> Scene:
    """A 1.2 m relay wall x = 2 facing −x, laser spot (2, 0, 0); a 0.2 m Lambertian patch at (1, 0, 0.3) facing
    the wall; sensor and emitter at (0, 0, −0.5); 0.4 m FoV centred (2, 0, −0.3). Optionally a box in front of
    the patch that shadows part of it from the spot and from the FoV."""
    s = 0.2
    objects = [quad("relay_wall", (2.0, -0.6, -0.8), (0.0, 1.2, 0.0), (0.0, 0.0, 1.2), Material(albedo=0.9),
                    label="relay_wall"),
               quad("patch", (1.0, -s / 2, 0.3 - s / 2), (0.0, s, 0.0), (0.0, 0.0, s), Material(albedo=0.8))]
    if occluder:
        objects.append(box("occluder", (1.5, 0.05, 0.0), (0.1, 0.15, 0.15), material=Material(albedo=0.5)))
    sensor = Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02,
                    fov=FieldOfView(center=(2.0, 0.0, -0.3), size=(0.4, 0.4)) if capture is None else None)
    return Scene(objects, Laser(emitter=(0.0, 0.0, -0.5), spot=(2.0, 0.0, 0.0)), sensor, capture=capture)


def run_quadrature(scene, **kw):
    q = Quadrature(scene, QuadratureSettings(**kw))
    acc = EnvelopeAccumulator(AXIS, IRF, len(q.component_names) * q.capture.n_channels)
    q.run(acc)
    return acc, q


def test_subdivision_keeps_the_area_samplers_split_with_shared_vertices():
    tri = np.array([[[0.0, 0, 0], [2.0, 0, 0], [0.0, 1.0, 0]], [[0.0, 0, 1], [0.3, 0, 1], [0.0, 0.3, 1]]])
    verts, cells, area, parent = subdivide_with_vertices(tri, 0.25)
    pts, area_ref, parent_ref = subdivide_triangles(tri, 0.25)
    assert len(cells) == 9 ** 2 + 2 ** 2 and len(verts) == 10 * 11 // 2 + 3 * 4 // 2
    np.testing.assert_allclose(verts[cells].mean(axis=1), pts, atol=1e-15)   # same cells, same order
    np.testing.assert_array_equal(parent, parent_ref)
    np.testing.assert_allclose(area, area_ref, rtol=1e-12)
    np.testing.assert_allclose(0.5 * np.linalg.norm(np.cross(verts[cells[:, 1]] - verts[cells[:, 0]],
                                                             verts[cells[:, 2]] - verts[cells[:, 0]]), axis=1),
                               area, rtol=1e-9)


def test_quadrature_converges_at_second_order_to_the_midpoint_reference():
    """Aperture capture (one 0.4 m pixel; FoV cells no larger than h), no occluder. The error is O(h²) (module
    doc): measured relative L2 5.2e-3, 1.1e-3, 2.3e-4 at h = 8, 4, 2 cm (fitted slope 2.2; against a reference
    twice as fine 2.1: this reference's own error, 9e-5, steepens the last step), totals −2.4e-3, −6.4e-4,
    −1.9e-4. The reference: sub-triangles of 5 mm, FoV squares of 1 cm, an impulse per pair. Asserted: the
    fitted slope in [1.8, 2.5] and each halving gains ≥ 3.5×."""
    scene = small_scene()
    ref, _ = primary_area_quadrature(scene, AXIS, IRF, h_hidden=0.005, h_fov=0.01)
    errors, totals = [], []
    for h in (0.08, 0.04, 0.02):
        acc, q = run_quadrature(scene, edge=h)
        env = acc.binned().sum(0)
        assert q.fov_cells == int(np.ceil(0.4 / h)) and "no shadow rays" in q.visibility["shadow_spot"]
        errors.append(relative_l2(env, ref))
        totals.append(abs(env.sum() / ref.sum() - 1))
    slope = np.polyfit(np.log([0.08, 0.04, 0.02]), np.log(errors), 1)[0]       # error ∝ h^slope
    assert 1.8 < slope < 2.5, (errors, slope)
    assert errors[0] / errors[1] > 3.5 and errors[1] / errors[2] > 3.5
    assert errors[2] < 5e-4 and totals[2] < 5e-4 and totals[0] / totals[2] > 9


def test_occluder_shadow_rays_match_the_area_sampler():
    """A box shadows part of the patch from the spot and from the FoV: the occluder test turns both legs' shadow
    rays on, and the quadrature (h = 2 cm) equals the mean of 6 area-sampler runs (2^14 samples) within their
    noise plus its own O(h²) error: measured relative L2 7.4e-4 against a noise of 9.2e-4 (the quadrature
    moves by 4.4e-4 from h = 2 to 1 cm), total 2.7e-4 against a standard error of 3.4e-4. Without shadow rays
    it is 66 % off."""
    scene = small_scene(occluder=True)
    acc, q = run_quadrature(scene, edge=0.02)
    assert q.settings.shadow_spot and q.settings.shadow_fov and q.stats.shadow_rays > 0
    env = acc.binned().sum(0)
    names = dict(zip(q.component_names, acc.total_weight()))
    assert names["room"] == 0 and names["patch"] > 0 and names["occluder"] > 0 and names["secondary"] == 0
    envs = []
    for seed in range(6):
        sampler = AreaSampler(scene, AreaSettings(samples=1 << 14, secondary="none"))
        a = EnvelopeAccumulator(AXIS, IRF, len(sampler.component_names))
        sampler.run(a, np.random.default_rng(seed))
        envs.append(a.binned().sum(0))
    envs = np.array(envs)
    mean, se = envs.mean(0), envs.std(0, ddof=1) / np.sqrt(len(envs))
    mask = mean > 0.01 * mean.max()
    noise = np.sqrt((se[mask] ** 2).sum()) / np.linalg.norm(mean[mask])
    total_se = envs.sum(1).std(ddof=1) / np.sqrt(len(envs)) / mean.sum()
    assert relative_l2(env, mean) < 3 * noise + 1e-3
    assert abs(env.sum() / mean.sum() - 1) < 4 * total_se + 5e-4
    off, _ = run_quadrature(scene, edge=0.02, shadow_spot=False, shadow_fov=False)
    assert off.total_weight().sum() > 1.5 * acc.total_weight().sum()      # the shadows matter


@pytest.mark.parametrize("convention", ["aperture", "point_radiance"])
def test_scans_equal_single_spot_captures_per_laser_point(convention):
    """Exhaustive (2 laser points × 2×2 sensor points) and confocal (2×1 points) scans: every channel equals a
    single-spot capture with the laser at that point (one subdivision serves every laser point; FoV cells by the
    edge rule in both, ``fov_cells="edge"``: a scan's default is one per pixel)."""
    lasers = WallGrid(center=(2.0, 0.0, 0.0), size=(0.4, 0.2), points=(2, 1))
    sensors = WallGrid(center=(2.0, 0.0, -0.3), size=(0.4, 0.4), points=(2, 2))
    ex, qe = run_quadrature(small_scene(capture=CaptureSpec(type="exhaustive", convention=convention,
                                                            laser_grid=lasers, sensor_grid=sensors)), edge=0.04,
                            fov_cells="edge")
    co, qc = run_quadrature(small_scene(capture=CaptureSpec(type="confocal", convention=convention,
                                                            laser_grid=lasers)), edge=0.04, fov_cells="edge")
    assert qc.target_is_laser == (convention == "point_radiance")
    ex_env = ex.binned().reshape(len(qe.component_names), 2, 4, -1).sum(0)        # (laser, pixel, T)
    co_env = co.binned().reshape(len(qc.component_names), 2, -1).sum(0)           # (point, T)
    for i, spot in enumerate(qe.capture.spots):
        single = small_scene(capture=CaptureSpec(type="single", convention=convention, sensor_grid=sensors))
        single = Scene(single.objects, Laser(emitter=(0.0, 0.0, -0.5), spot=tuple(spot)), single.sensor,
                       capture=single.capture)
        one, q1 = run_quadrature(single, edge=0.04)
        env = one.binned().reshape(len(q1.component_names), 4, -1).sum(0)
        assert env.sum() > 0
        np.testing.assert_allclose(ex_env[i], env, rtol=1e-10, atol=1e-12 * env.max())
        # confocal channel i: the laser at point i, the sensor grid pixel i's region alone (a confocal aperture
        # follows the laser: it faces point i, as a single capture faces its grid's centre)
        pixel = WallGrid(center=tuple(spot), size=(0.2, 0.2), points=(1, 1))
        conf1 = Scene(single.objects, single.laser, single.sensor,
                      capture=CaptureSpec(type="single", convention=convention, sensor_grid=pixel))
        one, q1 = run_quadrature(conf1, edge=0.04)
        one_env = one.binned().reshape(len(q1.component_names), -1).sum(0)
        assert one_env.sum() > 0
        np.testing.assert_allclose(co_env[i], one_env, rtol=1e-10, atol=1e-12 * co_env.max())


@pytest.mark.parametrize("scan", ["single", "confocal", "exhaustive"])
def test_tal_captures_match_the_point_radiance_quadrature(tmp_path, scan):
    """tal's hidden square (point radiance, 1 cm bins) at the default edge against tests/test_tal.py's
    independent 200×200 midpoint integrand, in datagen's and tal's layouts: per-point totals within 0.1 %
    (measured ≤ 0.011 %), relative L2 below 0.6 % (measured 0.20–0.34 %, the same at h = 1 cm: it is the
    integrand's own binning of 40 000 impulses into 1 cm bins)."""
    scene, tal, result = run(hidden_square(tmp_path, scan), estimator="quadrature")
    assert result.attrs["effects"]["estimator"] == "quadrature"
    assert result.attrs["quadrature"]["settings"]["edge"] == 0.02
    edges = opl_edges(result)
    lasers = result.laser_points.reshape(-1, 3)
    sensors = result.sensor_points.reshape(-1, 3)
    if scan == "confocal":
        ref = np.concatenate([quadrature(p, p[None], edges) for p in sensors])
        scale = np.array([laser_scale(p) for p in tal.sensor_grid_xyz.reshape(-1, 3)])
    else:
        ref = np.stack([quadrature(p, sensors, edges) for p in lasers])
    env = result.envelope.reshape(ref.shape)
    np.testing.assert_allclose(env.sum(-1), ref.sum(-1), rtol=1e-3)
    assert rel_l2(env, ref) < 6e-3
    if scan == "confocal":                    # tal layout and K per laser point
        H = tal_arrays(result, tal)["H"]
        ref_tal = np.concatenate([quadrature(p, p[None], edges) for p in tal.sensor_grid_xyz.reshape(-1, 3)])
        ref_tal = (ref_tal * scale[:, None]).reshape(4, 3, -1).transpose(2, 0, 1)
        assert rel_l2(H, ref_tal) < 6e-3


def test_simulate_records_the_quadrature_and_keeps_a_planned_secondary():
    """estimator: quadrature through simulate(): the settings are recorded; with the secondary planned the area
    sampler adds it (secondary_only) and the primary components are unchanged (to FFT round-off: the primary is
    added to each of the secondary's replicas and averaged, ~1e-16 of the component's peak)."""
    scene = small_scene(occluder=True)
    base = dict(time=AXIS, irf=IRF, estimator="quadrature", quadrature_edge=0.04, area_samples=4096,
                detector={"repetition_rate": 1e7, "exposure": 1e-3})
    with_sec = simulate(scene, SimulationConfig(**base, secondary="full", effects={"secondary": True}))
    without = simulate(scene, SimulationConfig(**base, secondary="none"))
    attrs = with_sec.attrs
    assert attrs["effects"]["estimator"] == "quadrature" and attrs["effects"]["secondary"] == "full"
    assert attrs["quadrature"]["settings"]["edge"] == 0.04 and attrs["quadrature"]["sub_triangles"] > 0
    assert attrs["quadrature"]["visibility"]["shadow_spot"].startswith("a triangle may cross")
    for name in ("patch", "occluder"):
        ref = without.components[name]
        np.testing.assert_allclose(with_sec.components[name], ref, rtol=1e-12, atol=1e-13 * ref.max())
    assert with_sec.attrs["error"]["replicas"] == 8 and without.attrs["error"]["replicas"] == 1
    assert without.attrs["error"]["monte_carlo"] == 0 and without.attrs["error"]["refinement"] > 0
    assert with_sec.components["secondary"].sum() > 0 and without.components["secondary"].sum() == 0


def test_bad_settings_name_the_field():
    for kw, field in (({"edge": 0.0}, "edge"), ({"edge": float("nan")}, "edge"), ({"fov_cells": 0}, "fov_cells"),
                      ({"secondary": "exact"}, "secondary"), ({"batch": 0}, "batch"),
                      ({"shadow_spot": "yes"}, "shadow_spot"), ({"split": "odd"}, "split")):
        with pytest.raises(ConfigError, match=field):
            QuadratureSettings(**kw)
    scene = small_scene()
    for value, field, new in ((-0.01, "quadrature_edge", "estimator.edge"), (0, "quadrature_fov", "estimator.fov_cells")):
        with pytest.raises(ConfigError, match=new):
            resolve_config(scene, {"estimator": "quadrature", field: value})
    with pytest.raises(ConfigError, match="secondary_only"):
        AreaSampler(scene, AreaSettings(secondary="none"), secondary_only=True)


def test_accuracy_ladder_halves_the_edge():
    """``datagen bench accuracy``'s quadrature ladder: h halves at every step and the error against a fine
    quadrature (h = 2 cm, itself 2.3e-4 from the reference) falls by ≥ 3× per step (measured 0.082, 0.010,
    0.0017 at h = 20, 10, 5 cm on the small scene: the first step is pre-asymptotic, 2 sub-triangles per side)."""
    from datagen.analysis.accuracy import LADDERS, run_estimator
    from datagen.scene import RayCaster

    est = LADDERS["quadrature"]
    edges = [s["edge"] for s in est.ladder]
    assert all(a == 2 * b for a, b in zip(edges, edges[1:])) and est.describe(est.ladder[0]).startswith("h=1.6 m")
    scene = small_scene()
    cfg = SimulationConfig(time=AXIS, irf=IRF, secondary="none", detector={"repetition_rate": 1e7, "exposure": 1e-3})
    caster = RayCaster(scene)
    fine, _ = run_estimator(scene, cfg, est, {"edge": 0.02, "secondary_samples": 16}, caster)
    errors = [relative_l2(run_estimator(scene, cfg, est, step, caster)[0], fine) for step in est.ladder[3:6]]
    assert errors[0] / errors[1] > 3 and errors[1] / errors[2] > 3, errors


def test_distinct_rows_is_numpy_unique_and_a_split_shares_its_mesh_vertices():
    from datagen.vectors import distinct_rows

    rng = np.random.default_rng(7)
    base = rng.random((500, 3))
    base[::7, 1], base[::11, 1] = 0.0, -0.0                  # signed zeros are one coordinate
    points = base[rng.integers(0, 500, 2000)]
    distinct, index = distinct_rows(points)
    unique, inverse = np.unique(points, axis=0, return_inverse=True)
    assert np.array_equal(distinct, unique) and np.array_equal(index, inverse.reshape(-1))
    assert np.array_equal(distinct[index], points)
    # two triangles sharing an edge, split one cell per face: 4 distinct corners, not 6
    from datagen.sampling.surfaces import subdivide_with_vertices

    tri = np.array([[[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
                    [[1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]]])
    vertices, cells, _, _ = subdivide_with_vertices(tri, 2.0)
    distinct, index = distinct_rows(vertices)
    assert len(vertices) == 6 and len(distinct) == 4
    assert np.array_equal(distinct[index[cells]], vertices[cells])


def test_aperture_cells_per_pixel_side():
    """FoV cells per pixel side of a scan: one at every edge by default; "edge": ceil(pixel side / edge) clamped to
    1 … MAX_FOV_CELLS; a forced value as given; none for a point-radiance capture; the quadrature takes the same
    number at the edge it runs."""
    from dataclasses import replace

    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import draw_room
    from datagen.scene import RayCaster, resolve_capture
    from datagen.transport import Quadrature, QuadratureSettings

    scene = draw_room(load_dataset_config("configs/datasets/wall_smoke.yaml"), "train", 0)[0].scene
    c = resolve_capture(scene, RayCaster(scene))
    side = max(c.fov_size[0] / c.fov_pixels[0], c.fov_size[1] / c.fov_pixels[1])    # 2 m / 16 = 0.125 m
    assert c.convention == "aperture" and side == pytest.approx(0.125)
    cells = Quadrature.aperture_cells
    assert [cells(c, e, "edge") for e in (1.0, 0.125, 0.1249, 0.06, 0.03, 1e-5)] == [1, 1, 2, 3, 5, 64]
    assert [cells(c, e) for e in (1.0, 0.06, 1e-5)] == [1, 1, 1]
    assert cells(c, 0.06, 2) == 2 and cells(replace(c, convention="point_radiance"), 0.06) is None
    assert Quadrature(scene, QuadratureSettings(edge=0.06, secondary="none", fov_cells="edge")).fov_cells == 3
    assert Quadrature(scene, QuadratureSettings(edge=0.06, secondary="none")).fov_cells == 1
