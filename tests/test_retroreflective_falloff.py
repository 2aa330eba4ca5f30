"""A small patch's confocal return against distance (docs/physics.md §2, "Retroreflective"): why the Stanford LCT
release models its retroreflective scenes with a t² falloff and its diffuse one with t⁴ (O'Toole, Lindell &
Wetzstein, Nature 2018).

A 2 cm square patch faces a Lambertian relay wall at distance r from the one scanned point of a confocal capture
(its pixel region a 10 cm square about the point), simulated by datagen's area sampler with orders 1. In area measure
the return is

    L(r) = Φ (ρ_w/π) A/r² · coll · ∫_pixel f(ω_l, ω_y) cosθ_o cosθ_y / r_y² dA_y,

coll = q (ρ_w/π) cosθ_s A_ap / d² the FoV point's collection (d the wall point's distance to the sensor; its
variation over the pixel is < 1e-4 here). For a Lambertian patch (f = ρ/π) the last integral is π·4F(a/r, a/r),
F(X, Y) = [X/√(1+X²) atan(Y/√(1+X²)) + Y/√(1+Y²) atan(X/√(1+Y²))]/(2π) the form factor from a point to a
parallel X·r × Y·r rectangle at one corner (a = 5 cm the pixel's half side): ≈ (2a)²/r², so L ∝ 1/r⁴. For a
retroreflective patch whose lobe (α = 0.002: half maximum 0.15° from ω_l) lands inside the pixel, the integral is the
lobe's albedo ρ a(0), a(0) = 1 − O(α²), so L ∝ 1/r²: the retroreflector returns all its light to the pixel however
far it is, the Lambertian patch a share (2a/r)²/π that falls with r². Both are checked to 2 % at 0.25–1 m (the GGX
tail outside the pixel is < 0.6 % of the lobe there), which tells 1/r² from 1/r⁴ by a factor 16 over the range.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import datagen
from datagen.scene import scene_from_dict

WALL_X, SPOT = 2.0, np.array([2.0, 0.0, 1.0])
SENSOR = np.array([1.5, -3.0, 1.0])
HALF = 0.05                      # the pixel region's half side, m
PATCH = 0.02                     # the patch's side, m
RHO_WALL, RHO = 0.8, 0.9
DISTANCES = (0.25, 0.4, 0.65, 1.0)


def patch_scene(r: float, material: dict, corner=None, edge_u=(0.0, PATCH, 0.0), edge_v=(0.0, 0.0, PATCH)):
    """The wall, and the patch (by default straight ahead of the spot at distance r, facing it)."""
    corner = [WALL_X - r, -PATCH / 2, 1.0 - PATCH / 2] if corner is None else list(corner)
    data = {"name": "falloff", "objects": [
        {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [WALL_X, -1.05, -0.05],
         "edge_u": [0.0, 0.0, 2.1], "edge_v": [0.0, 2.1, 0.0], "material": {"kind": "lambertian", "albedo": RHO_WALL}},
        {"builder": "quad", "name": "patch", "corner": corner, "edge_u": list(edge_u), "edge_v": list(edge_v),
         "material": material}],
        "laser": {"emitter": SENSOR.tolist(), "spot": SPOT.tolist(), "photons_per_pulse": 1.0e6},
        "sensor": {"position": SENSOR.tolist(), "aperture_radius": 0.02},
        "capture": {"type": "confocal", "laser_grid": {"center": SPOT.tolist(), "size": [2 * HALF, 2 * HALF],
                                                       "points": [1, 1]}},
        "simulation": {"secondary": "none", "effects": {"first_bounce": False}, "count_laser_leg": False,
                       "count_sensor_leg": False, "time": {"t_start": "0ns", "bin_width": "32ps", "n_bins": 512},
                       "irf": {"fwhm": "70ps"},
                       "detector": {"model": "poisson", "pde": 0.3, "repetition_rate": 1.0e7, "exposure": "1ms"}}}
    return scene_from_dict(data, source="falloff.yaml")


def scene_return(scene, estimator: dict) -> float:
    """Photons per pulse of a scene's one scan point, summed over the time bins (orders 1; fixed seeds)."""
    config = datagen.resolve_config(scene, {"estimator": estimator})
    result = datagen.simulate(scene, config, sampling_rng=np.random.default_rng(7), noise_rng=np.random.default_rng(8))
    return float(np.asarray(result.envelope).sum())


def simulated_return(r: float, material: dict) -> float:
    """Photons per pulse of the patch facing the spot at r (area sampler)."""
    return scene_return(patch_scene(r, material), {"kind": "area", "samples": 8192})


def form_factor(x: float, y: float) -> float:
    """Point → parallel rectangle x·r × y·r with one corner above the point (Howell's catalogue, B-3)."""
    a, b = math.sqrt(1 + x * x), math.sqrt(1 + y * y)
    return (x / a * math.atan(y / a) + y / b * math.atan(x / b)) / (2 * math.pi)


def common(r: float, pde: float) -> float:
    """Φ (ρ_w/π) cosθ_l A/r² · coll: the laser leg at the patch (straight ahead of the spot: cosθ_l = 1; the
    Lambertian spot's f does not depend on where the beam comes from) times the collection of the scanned point."""
    d = SENSOR - SPOT
    dist = float(np.linalg.norm(d))
    cos_s = -d[0] / dist                               # the wall's normal is −x
    coll = pde * (RHO_WALL / math.pi) * cos_s * math.pi * 0.02 ** 2 / dist ** 2
    return 1.0e6 * (RHO_WALL / math.pi) * PATCH ** 2 / r ** 2 * coll


@pytest.fixture(scope="module")
def returns():
    lamb = {"kind": "lambertian", "albedo": RHO}
    retro = {"kind": "retroreflective", "albedo": RHO, "specular": 1.0, "lobe_width": 0.002}
    pde = datagen.resolve_config(patch_scene(0.5, lamb), {}).physics_settings().pde
    return {r: (simulated_return(r, lamb), simulated_return(r, retro), common(r, pde)) for r in DISTANCES}


def test_a_lambertian_patch_falls_as_one_over_r_to_the_fourth(returns):
    for r, (lamb, _, c) in returns.items():
        closed = c * (RHO / math.pi) * math.pi * 4 * form_factor(HALF / r, HALF / r)
        assert lamb == pytest.approx(closed, rel=0.02), r
    r0, r1 = DISTANCES[0], DISTANCES[-1]
    assert returns[r0][0] / returns[r1][0] == pytest.approx((r1 / r0) ** 4, rel=0.06)


def test_a_retroreflective_patch_falls_as_one_over_r_squared(returns):
    for r, (_, retro, c) in returns.items():
        assert retro == pytest.approx(c * RHO, rel=0.02), r
    r0, r1 = DISTANCES[0], DISTANCES[-1]
    assert returns[r0][1] / returns[r1][1] == pytest.approx((r1 / r0) ** 2, rel=0.03)


def tilted_patch_return(estimator: dict, falloff: float, tilt_deg: float = 40.0) -> float:
    """Photons per pulse of the retroreflective patch at 0.5 m, turned by ``tilt_deg`` about the vertical so that the
    laser spot lies ``tilt_deg`` off its normal (the entrance angle), with the lobe's entrance falloff ``falloff``."""
    t = math.radians(tilt_deg)
    centre = np.array([WALL_X - 0.5, 0.0, 1.0])
    edge_u, edge_v = PATCH * np.array([math.sin(t), math.cos(t), 0.0]), np.array([0.0, 0.0, PATCH])
    material = {"kind": "retroreflective", "albedo": RHO, "specular": 1.0, "lobe_width": 0.002,
                "entrance_falloff": falloff}
    return scene_return(patch_scene(0.5, material, centre - edge_u / 2 - edge_v / 2, edge_u, edge_v), estimator)


@pytest.mark.parametrize("estimator", [{"kind": "area", "samples": 8192}, {"kind": "quadrature"}],
                         ids=["area", "quadrature"])
def test_the_entrance_falloff_scales_a_tilted_patchs_return_by_cos_to_the_m(estimator):
    """Real sheeting returns less at a slant (docs/physics.md, "Retroreflective"): a patch 40° off the scanned
    point returns cos⁵ 40° = 0.263 of its return without the falloff (the lobe, 0.15° wide, keeps ω_out = ω_in to
    O(α)), through every estimator's path weight (the area sampler's connections, the quadrature's cells); and
    facing the point (0°) the falloff changes it by the patch's own spread of angles only (≤ 1.6°: cos⁵ ≥ 0.998)."""
    ratio = tilted_patch_return(estimator, 5.0) / tilted_patch_return(estimator, 0.0)
    assert ratio == pytest.approx(math.cos(math.radians(40.0)) ** 5, rel=0.01)
    assert tilted_patch_return(estimator, 5.0, 0.0) == pytest.approx(tilted_patch_return(estimator, 0.0, 0.0),
                                                                     rel=2e-3)
