"""The retroreflective BRDF (datagen/scene/brdf_kernel.py, docs/physics.md §2 "BRDFs"): the Minimal Retroreflective
Microfacet model (Portsmouth, Raab, Belcour & Liu, JCGT 15(1), 2026), a GGX lobe at the back vector plus a diffuse
part.

- Energy: its hemispherical albedo, integrated by a quadrature centred on the incident direction (the lobe's axis,
  so that lobes 1° wide are resolved), is ≤ ρ at every incidence and width; it equals the albedo of the ordinary
  (forward) GGX reflection lobe written here from Walter et al. 2007 (the model's energy theorem: the reflection
  about the normal keeps solid angle and cosθ_out), ρ exactly without a lobe, and tends to ρ as the lobe narrows.
- Reciprocity to round-off, a peak at ω_out = ω_in, and the GGX distribution's normalisation ∫ D cosθ_h dω = 1.
- Sampling: the lobe sampler's directions (retro_sample) and the light tracer's continuation (continue_paths, the
  mixture k_s·lobe + (1 − k_s)·cosine) against their densities (retro_pdf, the returned ratio × cosθ/π) by a χ² test
  on a fixed seed; the same test rejects a density without its masking term G₁.
- The entrance-angle falloff (cosθ_i cosθ_o)^(m/2): the albedo falls as cos^m θ_i under ρ, reciprocity holds, and
  the compiled BRDF evaluates what the table does.
- Bad widths and falloffs are refused with the field and the value named.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from datagen.errors import SceneError
from datagen.scene import Material, scene_from_dict
from datagen.scene.brdf_kernel import ggx_ndf, on_arrays, retro_cos_h, retro_directions, retro_pdf
from datagen.scene.materials import MaterialTable

UP = np.array([0.0, 0.0, 1.0])


def incident(theta_deg: float, phi: float = 0.4) -> np.ndarray:
    t = np.deg2rad(theta_deg)
    return np.array([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])


def sphere_about(axis: np.ndarray, width: float, n_beta: int = 3000, n_phi: int = 720):
    """Directions (m, 3) and solid angles (m,) of a midpoint rule over the whole sphere in polar coordinates about
    ``axis``, the polar nodes packed near it (β = π s², s uniform): resolves a lobe ≪ 1° wide on its axis."""
    s = (np.arange(n_beta) + 0.5) / n_beta
    beta, d_beta = np.pi * s ** 2, 2 * np.pi * s / n_beta
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    b, p = np.meshgrid(beta, phi, indexing="ij")
    t = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    u = np.cross(axis, t)
    w = (np.cos(b)[..., None] * axis + (np.sin(b) * np.cos(p))[..., None] * t + (np.sin(b) * np.sin(p))[..., None] * u)
    d_omega = np.sin(b) * d_beta[:, None] * (2 * np.pi / n_phi)
    return w.reshape(-1, 3), d_omega.ravel()


def albedo(material: Material, w_in: np.ndarray) -> float:
    """∫ f(ω_in, ω) cosθ dω over the hemisphere above UP (the quadrature of :func:`sphere_about` about ω_in)."""
    w, d_omega = sphere_about(w_in, material.lobe_width)
    f = MaterialTable([material]).evaluate(np.zeros(len(w), dtype=int), UP, w_in, w)
    return float(np.sum(f * np.maximum(w[:, 2], 0.0) * d_omega))


def forward_ggx_albedo(alpha: float, w_in: np.ndarray) -> float:
    """The albedo of the ordinary GGX reflection lobe D(h) G₂ / (4 cosθ_i cosθ_o), h = unit(ω_i + ω_o), written
    from Walter et al. 2007 (D, eq. 33) and Heitz 2014 (height-correlated G₂, eqs. 72 and 99), about the mirror
    direction."""
    mirror = 2 * w_in[2] * UP - w_in
    w, d_omega = sphere_about(mirror, alpha)
    up = w[:, 2] > 0
    w, d_omega = w[up], d_omega[up]
    h = w + w_in
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    a2 = alpha ** 2
    d = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1) + 1) ** 2)
    lam = lambda c: (np.sqrt(1 + a2 * (1 - c ** 2) / c ** 2) - 1) / 2
    g2 = 1 / (1 + lam(w_in[2]) + lam(w[:, 2]))
    return float(np.sum(d * g2 / (4 * w_in[2] * w[:, 2]) * w[:, 2] * d_omega))


@pytest.mark.parametrize("alpha", [0.02, 0.1, 0.3, 1.0])
def test_the_albedo_never_exceeds_rho_and_is_the_forward_ggx_lobes(alpha):
    lobe = Material(kind="retroreflective", albedo=1.0, specular=1.0, lobe_width=alpha)
    mixed = Material(kind="retroreflective", albedo=0.8, specular=0.6, lobe_width=alpha)
    for theta in (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.0):
        w_in = incident(theta)
        a = albedo(lobe, w_in)
        assert 0.0 < a <= 1.0 + 1e-4, (theta, a)
        assert a == pytest.approx(forward_ggx_albedo(alpha, w_in), rel=2e-3, abs=1e-4), theta
        # the mixture: ρ[(1 − k_s) + k_s a_lobe] ≤ ρ
        assert albedo(mixed, w_in) == pytest.approx(0.8 * (0.4 + 0.6 * a), rel=1e-3, abs=1e-4)


def test_closed_forms_of_the_albedo():
    """No lobe (k_s = 0): exactly ρ, a Lambertian surface. A narrow lobe at normal incidence: → ρ (G₂ → 1, no mass
    below the surface). The GGX distribution is normalised: ∫ D cosθ_h dω_h = 1."""
    for theta in (0.0, 50.0, 85.0):
        assert albedo(Material(kind="retroreflective", albedo=0.7, specular=0.0), incident(theta)) == \
            pytest.approx(0.7, rel=1e-4)
    assert albedo(Material(kind="retroreflective", albedo=0.9, specular=1.0, lobe_width=0.02), UP) == \
        pytest.approx(0.9, rel=2e-3)
    for alpha in (0.02, 0.3, 1.0):
        w, d_omega = sphere_about(UP, alpha)
        up = w[:, 2] > 0
        assert np.sum(on_arrays(ggx_ndf)(alpha, w[up, 2]) * w[up, 2] * d_omega[up]) == pytest.approx(1.0, rel=1e-4)


def test_reciprocity_and_the_peak_back_toward_the_light(rng):
    table = MaterialTable([Material(kind="retroreflective", albedo=0.9, specular=0.8, lobe_width=w)
                           for w in (0.01, 0.1, 0.5, 1.0)])
    m = 20000
    v = rng.normal(size=(2, m, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    v[..., 2] = np.abs(v[..., 2])
    normals = rng.normal(size=(m, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    frame_ids = rng.integers(0, 4, m)
    # rotate each pair so that UP maps to its normal: any orientation of the surface
    t = np.cross(normals, [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    to_world = lambda x: x[:, :1] * t + x[:, 1:2] * b + x[:, 2:] * normals
    wi, wo = to_world(v[0]), to_world(v[1])
    f1, f2 = table.evaluate(frame_ids, normals, wi, wo), table.evaluate(frame_ids, normals, wo, wi)
    assert np.all(f1 > 0)
    np.testing.assert_allclose(f1, f2, rtol=1e-12, atol=0)
    # a narrow lobe (α = 0.01) away from grazing: f(ω, ω) above f(ω, ω') for ω' a degree away, and far above the
    # diffuse part (wide lobes peak off ω_in at grazing incidence: the 1/cosθ_out of the microfacet form)
    narrow = (frame_ids == 0) & (v[0, :, 2] > 0.3)
    peak = table.evaluate(frame_ids, normals, wi, wi)[narrow]
    off = wi[narrow] + np.radians(1.0) * t[narrow]
    off /= np.linalg.norm(off, axis=1, keepdims=True)
    assert np.all(peak > table.evaluate(0, normals[narrow], wi[narrow], off))
    assert np.all(peak > 100 * 0.9 * 0.2 / np.pi)


def test_the_separable_split_adds_up_to_the_brdf(rng):
    """The lookin secondary's split f = c + lobe (MaterialTable.separable_scale, lobe): c = (1 − k_s)ρ/π."""
    table = MaterialTable([Material(kind="retroreflective", albedo=0.8, specular=0.6, lobe_width=0.1)])
    v = rng.normal(size=(2, 3000, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    v[..., 2] = np.abs(v[..., 2])
    ids = np.zeros(3000, dtype=int)
    assert table.separable_scale(np.array([0]))[0] == pytest.approx(0.4 * 0.8 / np.pi, rel=1e-15)
    np.testing.assert_allclose(table.separable_scale(ids) + table.lobe(ids, UP, v[0], v[1]),
                               table.evaluate(ids, UP, v[0], v[1]), rtol=1e-12)


def hemisphere_bins(n_cos: int = 16, n_phi: int = 24):
    """Equal-solid-angle bins over the hemisphere above UP in (cosθ, φ), and a quadrature of each bin (k² midpoints):
    (nodes (n_bins, k², 3), solid angle per node)."""
    k = 24
    c = (np.arange(n_cos * k) + 0.5) / (n_cos * k)
    p = (np.arange(n_phi * k) + 0.5) * 2 * np.pi / (n_phi * k)
    cc, pp = np.meshgrid(c, p, indexing="ij")
    s = np.sqrt(1 - cc ** 2)
    w = np.stack([s * np.cos(pp), s * np.sin(pp), cc], -1)
    w = w.reshape(n_cos, k, n_phi, k, 3).transpose(0, 2, 1, 3, 4).reshape(n_cos * n_phi, k * k, 3)
    return w, 2 * np.pi / (n_cos * k * n_phi * k)


def bin_of(w: np.ndarray, n_cos: int = 16, n_phi: int = 24) -> np.ndarray:
    """The bin of :func:`hemisphere_bins` of each direction above UP (n,), n_cos·n_phi for one below it."""
    ic = np.minimum((w[:, 2] * n_cos).astype(int), n_cos - 1)
    ip = np.minimum((np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi) / (2 * np.pi) * n_phi).astype(int), n_phi - 1)
    return np.where(w[:, 2] > 0, ic * n_phi + ip, n_cos * n_phi)


def chi2_pvalue(counts: np.ndarray, expected: np.ndarray) -> float:
    """Pearson's χ² p-value of ``counts`` against ``expected`` counts (not rescaled: a density that does not
    integrate to one fails; bins below 5 expected merged into one; a count where nothing is expected gives 0)."""
    small = expected < 5
    obs = np.append(counts[~small], counts[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    if np.any((exp <= 0) & (obs > 0)):
        return 0.0
    keep = exp > 0
    chi2 = float(np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep]))
    return float(stats.chi2.sf(chi2, keep.sum() - 1))


def lobe_expectation(alpha: float, w_in: np.ndarray, n: int, masked: bool = True) -> np.ndarray:
    """Expected counts of n lobe draws per bin (and below the surface) from retro_pdf (or a density without G₁)."""
    nodes, d_omega = hemisphere_bins()
    cos_h = on_arrays(retro_cos_h)(w_in[2], nodes[..., 2], nodes @ w_in)
    p = on_arrays(retro_pdf)(alpha, w_in[2], cos_h)
    if not masked:
        p = on_arrays(ggx_ndf)(alpha, cos_h) / (4 * w_in[2])
    per_bin = p.sum(1) * d_omega
    return n * np.append(per_bin, max(0.0, 1.0 - per_bin.sum()))


@pytest.mark.parametrize("alpha,theta", [(0.15, 0.0), (0.15, 50.0), (0.5, 30.0), (0.5, 80.0), (1.0, 60.0)])
def test_the_lobe_samplers_histogram_matches_its_density(alpha, theta):
    n = 200_000
    rng = np.random.default_rng(int(100 * alpha + theta))
    w_in = incident(theta)
    w = retro_directions(alpha, np.tile(w_in, (n, 1)), rng.random(n), rng.random(n))
    counts = np.bincount(bin_of(w), minlength=16 * 24 + 1)
    assert chi2_pvalue(counts, lobe_expectation(alpha, w_in, n)) > 1e-3
    if theta >= 50.0:          # teeth: without the masking term G₁ (≠ 1 away from the normal) the test fails
        assert chi2_pvalue(counts, lobe_expectation(alpha, w_in, n, masked=False)) < 1e-6


def test_the_tracers_continuation_samples_the_mixture_it_weighs():
    """continue_paths at a retroreflective vertex: its directions follow ratio·cosθ/π (the density its flux and
    balance-heuristic weights use), and flux·f·π/(q·ratio) is f·cosθ/(q·p)."""
    from datagen.transport.multibounce.kernels import continue_paths
    table = MaterialTable([Material(kind="retroreflective", albedo=0.9, specular=0.6, lobe_width=0.3)])
    mat = (table.kind, table.albedo, table.specular, table.exponent, table.axis, np.full(1, np.nan), table.width)
    n = 200_000
    rng = np.random.default_rng(11)
    w_in = incident(40.0)
    u, v, r = rng.random(n), rng.random(n), np.zeros(n)
    w, flux, live, ratio = continue_paths(np.tile(UP, (n, 1)), np.zeros(n, np.int64), np.tile(w_in, (n, 1)), u, v, r,
                                          np.ones(n), np.array([0.9]), mat)
    counts = np.bincount(bin_of(w), minlength=16 * 24 + 1)
    nodes, d_omega = hemisphere_bins()
    cos_h = on_arrays(retro_cos_h)(w_in[2], nodes[..., 2], nodes @ w_in)
    p = 0.6 * on_arrays(retro_pdf)(0.3, w_in[2], cos_h) + 0.4 * nodes[..., 2] / np.pi
    per_bin = p.sum(1) * d_omega
    assert chi2_pvalue(counts, n * np.append(per_bin, 1.0 - per_bin.sum())) > 1e-3
    up = w[:, 2] > 0
    c = on_arrays(retro_cos_h)(w_in[2], w[up, 2], w[up] @ w_in)
    want = 0.6 * on_arrays(retro_pdf)(0.3, w_in[2], c) + 0.4 * w[up, 2] / np.pi
    np.testing.assert_allclose(ratio[up] * w[up, 2] / np.pi, want, rtol=1e-10)
    f = table.evaluate(np.zeros(up.sum(), dtype=int), UP, w_in, w[up])
    np.testing.assert_allclose(flux[up], f * w[up, 2] / (0.9 * want), rtol=1e-10)
    assert np.array_equal(live, flux > 0)


@pytest.mark.parametrize("field,width,words", [
    ("lobe_width", 0.0, "greater than 0"), ("lobe_width", -0.1, "greater than 0"),
    ("lobe_width", 2.5, "less than or equal to 1"), ("lobe_width", float("nan"), "finite"),
    ("entrance_falloff", -1.0, "greater than or equal to 0"), ("entrance_falloff", 80.0, "less than or equal to 50"),
    ("entrance_falloff", float("inf"), "finite")])
def test_a_bad_lobe_width_or_entrance_falloff_is_refused_naming_the_file_field_and_value(field, width, words):
    data = {"name": "retro", "objects": [
        {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [2.0, -1.0, 0.0],
         "edge_u": [0.0, 0.0, 2.0], "edge_v": [0.0, 2.0, 0.0], "material": {"kind": "lambertian"}},
        {"builder": "quad", "name": "sign", "corner": [1.0, -0.2, 0.8], "edge_u": [0.0, 0.4, 0.0],
         "edge_v": [0.0, 0.0, 0.4], "material": {"kind": "retroreflective", field: width}}],
        "laser": {"emitter": [0.0, 0.0, 1.0], "spot": [2.0, 0.0, 1.0]},
        "sensor": {"position": [0.0, 0.0, 1.0], "fov": {"center": [2.0, 0.0, 1.0], "size": [0.5, 0.5]}}}
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, source="sign.yaml")
    message = str(info.value)
    assert "sign.yaml" in message and field in message and repr(width) in message and words in message
    assert "\n" not in message.strip(), message


@pytest.mark.parametrize("falloff", [2.0, 5.0])
def test_the_entrance_falloff_scales_the_lobe_by_cos_to_the_m_and_stays_below_rho(falloff):
    """``entrance_falloff`` m: the lobe times (cosθ_i cosθ_o)^(m/2). A narrow lobe (α = 0.02) keeps ω_out within a
    degree of ω_in, so its albedo is cos^m θ_i times the lobe's without the falloff (to 1 % up to 60°, 3 % at 80°,
    where cosθ_o varies across the lobe), the diffuse part untouched; ρ bounds it at every incidence."""
    plain = Material(kind="retroreflective", albedo=0.8, specular=0.9, lobe_width=0.02)
    steep = Material(kind="retroreflective", albedo=0.8, specular=0.9, lobe_width=0.02, entrance_falloff=falloff)
    for theta in (0.0, 20.0, 40.0, 60.0, 80.0):
        w_in = incident(theta)
        lobe = (albedo(plain, w_in) / 0.8 - 0.1) / 0.9
        expected = 0.8 * (0.1 + 0.9 * lobe * np.cos(np.radians(theta)) ** falloff)
        a = albedo(steep, w_in)
        assert a == pytest.approx(expected, rel=0.01 if theta <= 60 else 0.03), theta
        assert a <= 0.8 * (1 + 1e-4)


def test_the_entrance_falloff_is_reciprocal_and_the_compiled_brdf_is_the_tables(rng):
    from datagen.scene.brdf_kernel import brdf_value
    table = MaterialTable([Material(kind="retroreflective", albedo=0.9, specular=0.8, lobe_width=w, entrance_falloff=m)
                           for w, m in ((0.01, 4.0), (0.3, 6.0), (1.0, 0.5))])
    n = 5000
    v = rng.normal(size=(2, n, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    v[..., 2] = np.abs(v[..., 2])
    ids = rng.integers(0, 3, n)
    f1, f2 = table.evaluate(ids, UP, v[0], v[1]), table.evaluate(ids, UP, v[1], v[0])
    np.testing.assert_allclose(f1, f2, rtol=1e-12, atol=0)
    mat = (table.kind, table.albedo, table.specular, table.exponent, table.axis, np.full(3, np.nan), table.width)
    compiled = np.array([brdf_value(mat, ids[i], 0.0, 0.0, 1.0, *v[0, i], *v[1, i]) for i in range(200)])
    np.testing.assert_allclose(compiled, f1[:200], rtol=1e-12, atol=0)
    # the falloff only lowers the lobe: against the same widths without it
    flat = MaterialTable([Material(kind="retroreflective", albedo=0.9, specular=0.8, lobe_width=w)
                          for w in (0.01, 0.3, 1.0)])
    assert np.all(f1 <= flat.evaluate(ids, UP, v[0], v[1]) * (1 + 1e-12))
