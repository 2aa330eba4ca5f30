"""Causality of the light of every order: the geometric onset bound (datagen/transport/multibounce/onset.py) and the
tracer's smoothing that keeps its kernels after it (datagen/transport/multibounce/smoothing.py, "Causal")."""
from __future__ import annotations

import numpy as np
import pytest

import datagen
from datagen.dataset import load_dataset_config
from datagen.scene import RayCaster, resolve_capture
from datagen.transport.multibounce.onset import ONSET_GAP, channel_pairs, earliest_arrival
from datagen.transport.physics import LegPhysics
from datagen.units import SPEED_OF_LIGHT

DEMO = "scene_library/demo_room.yaml"


def _setup(scene, config):
    caster = RayCaster(scene)
    capture = resolve_capture(scene, caster)
    return caster, capture, LegPhysics(scene, capture, caster, config.physics_settings())


def _surface_points(caster, n, rng):
    tris = caster.vertices[caster.faces]
    k = rng.choice(len(tris), n, p=caster.face_area / caster.face_area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    return tris[k, 0] + u[:, None] * (tris[k, 1] - tris[k, 0]) + v[:, None] * (tris[k, 2] - tris[k, 0])


@pytest.mark.parametrize("source", ["demo", "confocal"])
def test_the_onset_lies_below_every_sampled_path_and_within_a_tenth_of_a_nanosecond(source):
    """Brute force: 400 000 uniform surface points ahead of each spot, |s − x| + d(x, pixel) computed directly; the
    bound must lie below their minimum (it is a lower bound) and within ONSET_GAP + the sampling's own slack of it."""
    if source == "demo":
        scene = datagen.load_scene(DEMO)
        config = datagen.resolve_config(scene, {})
    else:
        scene, config = datagen.sample_setup(load_dataset_config("configs/datasets/confocal_smoke.yaml"), "train", 0)
    caster, capture, legs = _setup(scene, config)
    onset = earliest_arrival(capture, caster, legs)
    x = _surface_points(caster, 400_000, np.random.default_rng(1))
    laser, pix, chan = channel_pairs(capture)
    nx, ny = capture.fov_pixels
    hw, hh = 0.5 * capture.fov_size[0] / nx, 0.5 * capture.fov_size[1] / ny
    tail = legs.sensor_leg(capture.fov_sensor_distance())
    for i in np.linspace(0, len(laser) - 1, 5).astype(int):
        s, n = capture.spots[laser[i]], capture.spot_normals[laser[i]]
        centre = capture.fov_points(np.array(pix[i] % nx) + 0.5, np.array(pix[i] // nx) + 0.5)
        rel = x - centre
        a = np.clip(rel @ capture.fov_u, -hw, hw)
        b = np.clip(rel @ capture.fov_v, -hh, hh)
        d = np.linalg.norm(rel - a[:, None] * capture.fov_u - b[:, None] * capture.fov_v, axis=1)
        ahead = (x - s) @ n > 1e-6
        brute = (np.linalg.norm(x - s, axis=1) + d)[ahead].min()
        brute_t = (legs.laser_leg(laser[i]) + brute + tail) / SPEED_OF_LIGHT
        assert onset[chan[i]] <= brute_t
        assert brute_t - onset[chan[i]] < (ONSET_GAP + 0.01) / SPEED_OF_LIGHT + 0.02e-9


def _first_ns(result, onset, span=1e-9):
    e = result.time_edges
    inside = (e[:-1] >= onset) & (e[1:] <= onset + span)
    return float(result.components["multibounce"][..., inside].sum())


def test_the_demo_room_has_no_deep_light_before_its_onset_nor_piled_just_after_it():
    """Orders ≥ 3 of the demo room (albedo 1, 60 % of its light), smoothed at Δ = 2 ns, with a 50 ps IRF: nothing
    before the onset, and in the first nanoseconds after it about what an unsmoothed tracer (every order as
    impulses, an unbiased reference) finds there. Measured (seeds 0, 1; reference seed 7, 4 M paths): first 2 ns
    6.8–9.1·10⁻⁵ photons per pulse against the reference's 5.9·10⁻⁵ (fixed-width kernels: 1.8–3.0·10⁻⁴); first
    nanosecond 2.4–2.7·10⁻⁷, where the reference has none (fixed-width kernels: 1.5·10⁻⁶–2.1·10⁻⁵)."""
    scene = datagen.load_scene(DEMO)
    base = {"estimator": {"kind": "area", "samples": 8192}, "orders": "auto", "replicas": 4,
            "time": {"t_start": "15ns", "bin_width": "100ps", "n_bins": 450}, "irf": {"fwhm": "50ps"}}
    config = datagen.resolve_config(scene, base)
    caster, capture, legs = _setup(scene, config)
    onset = float(earliest_arrival(capture, caster, legs).min())
    assert 22.0e-9 < onset < 22.2e-9                       # ~ 6.63 m of path: the spot, the floor's edge, the FoV
    smoothed = [datagen.simulate(scene, config.model_copy(update={"seed": seed})) for seed in (0, 1)]
    reach = config.irf.support[0]
    for result in smoothed:
        assert result.attrs["orders"]["simulated"] == "1..all"
        for name, comp in result.components.items():
            before = comp[..., result.time_edges[1:] <= onset - reach].sum()
            assert before <= 1e-12 * comp.sum(), name
    reference = datagen.simulate(scene, datagen.resolve_config(scene, {
        **base, "seed": 7, "multibounce": {"smoothing": False, "paths": 1_000_000}}))
    ref = _first_ns(reference, onset, 2e-9)
    assert 3e-5 < ref < 1.2e-4                             # 5.9e-5 (photons per pulse in the first 2 ns)
    mean = np.mean([_first_ns(r, onset, 2e-9) for r in smoothed])
    assert mean < 2 * ref                                  # 1.35 × (fixed-width kernels: 4 ×)
    first = np.mean([_first_ns(r, onset, 1e-9) for r in smoothed])
    assert first < 0.02 * ref                              # 0.004 × (fixed-width kernels: 0.19 ×)


def test_a_confocal_scan_has_no_deep_light_before_any_points_onset():
    """confocal.yaml train 0 (32 × 32 points, 100 ps bins): the tracer carries orders ≥ 2 (secondary and
    multibounce), smoothed in time and across the scan; per scan point nothing before that point's own onset (the
    fixed-width kernels put up to 8.7·10⁻⁴ of the envelope's peak into a bin there)."""
    dataset = load_dataset_config("configs/datasets/confocal.yaml")
    scene, config = datagen.sample_setup(dataset, "train", 0)
    config = config.model_copy(update={"split_components": True})
    result = datagen.simulate(scene, config)
    caster, capture, legs = _setup(scene, config)
    onset = earliest_arrival(capture, caster, legs).reshape(result.envelope.shape[:-1] + (1,))
    assert np.ptp(onset) > 1e-9                            # the points' onsets differ (2.3–8.9 ns)
    before = result.time_edges[None, None, 1:] <= onset - config.irf.support[0]
    for name in ("secondary", "multibounce"):
        comp = result.components[name]
        assert comp.sum() > 0
        assert np.where(before, comp, 0.0).sum() <= 1e-12 * comp.sum(), name


def test_the_point_totriangle_distance_is_the_nearest_of_a_dense_sampling():
    """triangle_distance (Ericson's closest point) against the minimum over 200 000 points of the triangle, for points
    in every Voronoi region of 50 random triangles: never above it, and within the sampling's spacing."""
    from datagen.transport.multibounce.onset import triangle_distance
    rng = np.random.default_rng(3)
    u, v = rng.random(200_000), rng.random(200_000)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    for _ in range(50):
        t = rng.normal(size=(3, 3))
        p = rng.normal(size=3) * 2.0
        x = t[0] + u[:, None] * (t[1] - t[0]) + v[:, None] * (t[2] - t[0])
        brute = np.linalg.norm(x - p, axis=1).min()
        d = triangle_distance(p, t)
        assert d <= brute + 1e-12 and brute - d < 0.02
