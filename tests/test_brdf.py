"""BRDFs: reciprocity and energy conservation (hemispherical albedo ≤ albedo ≤ 1)."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.scene import Material
from datagen.scene.materials import MaterialTable
from datagen.sampling import square_to_hemisphere
from datagen.sampling.directions import stratified_grid

MATERIALS = [Material(kind="lambertian", albedo=0.7), Material(kind="sin_theta", albedo=0.9),
             Material(kind="phong", albedo=1.0, specular=0.6, exponent=20.0),
             Material(kind="phong", albedo=1.0, specular=1.0, exponent=2000.0),   # near-mirror
             Material(kind="retroreflective", albedo=0.8, specular=0.7, lobe_width=0.2)]


def random_hemisphere(rng, n):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


@pytest.mark.parametrize("mat_id", range(len(MATERIALS)))
def test_reciprocity(mat_id, rng):
    table = MaterialTable(MATERIALS)
    n = np.array([0.0, 0.0, 1.0])
    wi, wo = random_hemisphere(rng, 10000), random_hemisphere(rng, 10000)
    f1 = table.evaluate(np.full(10000, mat_id), n, wi, wo)
    f2 = table.evaluate(np.full(10000, mat_id), n, wo, wi)
    assert np.all(f1 >= 0)
    np.testing.assert_allclose(f1, f2, rtol=1e-12, atol=0)


def albedo(table, mat_id, w_in, n_side=600):
    """∫ f(ω_in, ω) cos θ dω by the equal-area midpoint rule on an n_side² hemisphere grid."""
    uv = stratified_grid(n_side, n_side, None)[0]
    w, _ = square_to_hemisphere(uv[:, 0], uv[:, 1], "uniform")
    f = table.evaluate(np.full(len(w), mat_id), np.array([0.0, 0.0, 1.0]), w_in, w)
    return float(np.sum(f * w[:, 2]) * 2 * np.pi / len(w))


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 85.0])
def test_hemispherical_albedo(theta_deg):
    table = MaterialTable(MATERIALS)
    t = np.deg2rad(theta_deg)
    phi = 0.3                                       # azimuth from the sin θ lobe's reference axis (+z → x)
    w_in = np.array([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])
    # Lambertian: exactly its albedo (quadrature error of the midpoint rule ~1e-5)
    assert albedo(table, 0, w_in) == pytest.approx(0.7, rel=2e-4)
    # sin θ lobe: never above its albedo (closed form checked in test_sin_theta_albedo_closed_form)
    assert albedo(table, 1, w_in) <= 0.9 * (1 + 1e-3)
    # Phong lobes: ≤ ρ for every incidence, = ρ at normal incidence (the lobe integrates to 1 there)
    for mat_id in (2, 3):
        a = albedo(table, mat_id, w_in, n_side=1200 if mat_id == 3 else 600)
        assert a <= 1.0 + 2e-3
        if theta_deg == 0.0 and mat_id == 2:
            assert a == pytest.approx(1.0, rel=2e-3)


def test_sin_theta_albedo_closed_form():
    """On a vertical face (normal −x, axis +z) the albedo is ρ·|sin θ_in|, θ_in the azimuth from +z."""
    table = MaterialTable([Material(kind="sin_theta", albedo=0.8, axis=(0, 0, 1))])
    n = np.array([-1.0, 0.0, 0.0])
    uv = stratified_grid(800, 800, None)[0]
    local, _ = square_to_hemisphere(uv[:, 0], uv[:, 1], "uniform")
    # local frame: z → n, x → +z (axis), y → n × axis
    w = local[:, 2:3] * n + local[:, 0:1] * np.array([0, 0, 1.0]) + local[:, 1:2] * np.cross(n, [0, 0, 1.0])
    for az in (0.2, 0.9, 1.5707963):
        polar = 0.7
        w_in = (np.cos(polar) * n + np.sin(polar) * (np.cos(az) * np.array([0, 0, 1.0])
                                                      + np.sin(az) * np.cross(n, [0, 0, 1.0])))
        f = table.evaluate(np.zeros(len(w), dtype=int), n, w_in, w)
        a = float(np.sum(f * local[:, 2]) * 2 * np.pi / len(w))
        assert a == pytest.approx(0.8 * abs(np.sin(az)), rel=2e-3, abs=1e-4)


def test_material_validation_names_field():
    with pytest.raises(ValueError, match="albedo"):
        Material(albedo=-0.1)
    with pytest.raises(ValueError, match="kind"):
        Material(kind="velvet")
