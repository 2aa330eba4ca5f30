"""The area sampler's compiled kernels (datagen/transport/area/kernels.py) against the numpy formulas they compile:
:class:`~datagen.scene.materials.MaterialTable`, :class:`~datagen.transport.physics.LegPhysics` and the pair weights
written here with physics.py's functions (the oracle). Same inputs → equal to 1e-12 relative."""
from __future__ import annotations

import numpy as np
import pytest

import datagen
from datagen.sampling import sample_surfaces
from datagen.scene import Material, Scene, SceneObject
from datagen.scene.brdf_kernel import on_arrays, retro_cos_h, retro_pdf
from datagen.scene.materials import MaterialTable
from datagen.transport import AreaSampler, AreaSettings
from datagen.transport.area.kernels import (brdf_value, connection_weights, fov_targets, material_arrays,
                                            partner_geometry, partner_irradiance, partner_rays, primary_impulses,
                                            secondary_pairs, sensor_collection, spot_irradiance)
from datagen.transport.physics import fov_connection_weight
from datagen.units import SPEED_OF_LIGHT

RTOL = 1e-12


def _unit(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape
    scale = np.maximum(np.abs(b), 1e-300)
    np.testing.assert_array_less(np.abs(a - b), rtol * scale + 1e-300 * (b == 0))


@pytest.fixture(scope="module")
def demo():
    """The demo room with a glossy box and a sin θ pillar, so that every BRDF kind is evaluated in full."""
    scene = datagen.load_scene("scene_library/demo_room.yaml")
    mats = {"box": Material(kind="phong", albedo=0.6, specular=0.4, exponent=17.3),
            "pillar": Material(kind="sin_theta", albedo=0.7, axis=(0.0, 0.0, 1.0))}
    objects = [SceneObject(o.name, o.label, mats.get(o.name, o.material), o.vertices, o.faces) for o in scene.objects]
    return Scene(objects, scene.laser, scene.sensor, scene.name, scene.source, scene.defaults)


def test_brdf_value_equals_material_table_evaluate():
    rng = np.random.default_rng(3)
    table = MaterialTable([Material(kind="lambertian", albedo=0.5),
                           Material(kind="phong", albedo=0.8, specular=0.3, exponent=12.5),
                           Material(kind="phong", albedo=0.4, specular=0.9, exponent=1.0),
                           Material(kind="sin_theta", albedo=0.9, axis=(1.0, 0.2, 0.0)),
                           Material(kind="sin_theta", albedo=0.9, axis=(0.0, 0.0, 1.0)),
                           Material(kind="retroreflective", albedo=0.7, specular=0.8, lobe_width=0.3)])
    n = 4000
    obj = rng.integers(0, 6, n)
    normals = _unit(rng.normal(size=(n, 3)))
    normals[:50] = [0.0, 0.0, 1.0]                       # axis ∥ normal: the tangent-frame fallback
    w_in, w_out = _unit(rng.normal(size=(n, 3))), _unit(rng.normal(size=(n, 3)))
    w_out[100:200] = 2 * np.einsum("ij,ij->i", normals[100:200], w_in[100:200])[:, None] * normals[100:200] \
        - w_in[100:200]                                  # mirror directions: the Phong lobe's peak
    w_out[200:300] = _unit(w_in[200:300] + 0.1 * rng.normal(size=(100, 3)))   # near ω_in: the retroreflective peak
    expected = table.evaluate(obj, normals, w_in, w_out)
    mat = (table.kind, table.albedo, table.specular, table.exponent, table.axis, np.full(6, np.nan), table.width)
    got = np.array([brdf_value(mat, obj[i], *normals[i], *w_in[i], *w_out[i]) for i in range(n)])
    assert (expected > 0).sum() > n // 5 and (expected == 0).sum() > n // 5
    _close(got, expected)


@pytest.mark.parametrize("brdf_angles", [False, True])
def test_irradiance_and_sensor_collection_equal_leg_physics(demo, brdf_angles):
    sampler = AreaSampler(demo, AreaSettings(brdf_angles=brdf_angles))
    physics, c = sampler.physics, sampler.capture
    rng = np.random.default_rng(5)
    pts, _ = sample_surfaces(sampler.caster, sampler.hidden_faces, 3000, "random", rng)
    e0, r0, w0, g0 = physics.irradiance(pts.points, pts.normals, 0)
    e1, r1, w1, g1 = spot_irradiance(physics, pts.points, pts.normals, 0)
    assert (e0 > 0).sum() > 500
    for a, b in ((e1, e0), (r1, r0), (w1, w0), (g1, g0)):
        _close(a, b)
    # FoV points on the wall, light arriving from the hidden points
    y = c.fov_points(rng.uniform(0, c.fov_pixels[0], 3000), rng.uniform(0, c.fov_pixels[1], 3000))
    w_in = _unit(pts.points - y)
    n_y = np.broadcast_to(c.fov_normal, y.shape)
    obj = np.full(len(y), physics.wall_object)
    out0, d0 = physics.sensor_collection(y, n_y, obj, w_in)
    out1, d1 = sensor_collection(physics, y, n_y, obj, w_in)
    assert (out0 > 0).sum() > 500
    _close(out1, out0)
    _close(d1, d0)


def test_fov_targets_equal_capture_geometry(demo):
    c = AreaSampler(demo).capture
    rng = np.random.default_rng(7)
    x = rng.uniform(-1, 1, (40, 3)) + c.fov_center + c.fov_normal
    n_x = _unit(rng.normal(size=(40, 3)))
    s = c.n_pixels * 4
    pix = np.repeat(np.arange(c.n_pixels), 4)
    iy, ix = np.divmod(pix, c.fov_pixels[0])
    corner = np.tile([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5], [0.5, 0.5]], (c.n_pixels, 1))
    jitter = rng.random((40, s, 2))
    fov = (c.fov_center, c.fov_u, c.fov_v, c.fov_normal, np.asarray(c.fov_size, float), np.asarray(c.fov_pixels, float))
    bi, si, y, w, r, cy = fov_targets(x, n_x, ix, iy, corner, jitter, (2.0, 2.0), fov)
    targets = c.fov_points(ix + (corner[None, :, 0] + jitter[..., 0] / 2),
                           iy + (corner[None, :, 1] + jitter[..., 1] / 2))
    to_y = targets - x[:, None]
    rr = np.linalg.norm(to_y, axis=-1)
    ww = to_y / rr[..., None]
    cos_y = -ww @ c.fov_normal
    b0, s0 = np.nonzero((np.einsum("bk,bsk->bs", n_x, ww) > 0) & (cos_y > 0))
    assert 0 < len(b0) < 40 * s
    np.testing.assert_array_equal(bi, b0)
    np.testing.assert_array_equal(si, s0)
    for a, b in ((y, targets[b0, s0]), (w, ww[b0, s0]), (r, rr[b0, s0]), (cy, cos_y[b0, s0])):
        _close(a, b, 1e-11)


@pytest.mark.parametrize("mu", [0.0, 0.05])
def test_partner_and_pair_kernels_equal_the_numpy_formulas(demo, mu):
    """Partner geometry, MIS irradiance, secondary pairs and primary impulses against the formulas of the module
    docstring of datagen/transport/area/estimator.py written with physics.py (brdf, irradiance, attenuation)."""
    sampler = AreaSampler(demo, AreaSettings(attenuation=mu))
    physics, cst = sampler.physics, sampler.caster
    rng = np.random.default_rng(11)
    n, p = 300, 4
    xs, _ = sample_surfaces(cst, sampler.hidden_faces, n, "random", rng)
    xp, _ = sample_surfaces(cst, sampler.hidden_faces, n * p, "random", rng)
    pos, neg = rng.random(n) < 0.8, rng.random(n) < 0.5
    found = rng.random(n * p) < 0.9
    owner = np.repeat(np.arange(n), p)
    rp, wpx, cos_p, cos_x, on_pos, keep, n_px, n_xp = partner_geometry(
        xs.points, xs.normals, pos, neg, p, xp.points, xp.normals, found, 0.01)
    d = xs.points[owner] - xp.points
    r = np.linalg.norm(d, axis=-1)
    w = d / r[:, None]
    side_x = np.einsum("ij,ij->i", xs.normals[owner], w)
    side_p = np.einsum("ij,ij->i", xp.normals, w)
    _close(rp, r)
    _close(wpx, w)
    np.testing.assert_array_equal(on_pos, side_x < 0)
    np.testing.assert_array_equal(keep, found & (r > 0.01) & (np.abs(side_p) > 0) & (np.abs(side_x) > 0)
                                  & np.where(side_x < 0, pos[owner], neg[owner]))
    np.testing.assert_array_equal(n_px, np.where(side_p[:, None] < 0, -xp.normals, xp.normals))
    np.testing.assert_array_equal(n_xp, np.where(side_x[:, None] < 0, xs.normals[owner], -xs.normals[owner]))
    e_p, r_lp, w_sp, geo_p = physics.irradiance(xp.points, xp.normals, 0)
    rows = np.flatnonzero(keep)
    for a, b in zip(spot_irradiance(physics, xp.points, xp.normals, 0, rows),
                    physics.irradiance(xp.points[rows], xp.normals[rows], 0)):
        _close(a[rows], b)
    expected_keep = keep & (e_p > 0) & (np.einsum("ij,ij->i", n_px, w_sp) > 0)
    check = partner_rays(keep, e_p, n_px, w_sp, p, (2, 3))
    np.testing.assert_array_equal(keep, expected_keep)
    np.testing.assert_array_equal(check, np.flatnonzero(expected_keep & (np.arange(n * p) % p != 2)))
    keep = expected_keep & (e_p > 0)
    assert keep.sum() > 100
    n_sides = pos.astype(int) + neg.astype(int)
    hidden_w = sampler.is_hidden[xp.face] / sampler.hidden_area
    mat = material_arrays(physics)
    irr = partner_irradiance(keep, e_p, geo_p, cos_p, cos_x, rp, n_sides, p, hidden_w, (2, 1, 1), xp.object_id,
                             n_px, w_sp, wpx, mat)
    g = np.abs(side_p) * np.abs(side_x) / r ** 2
    f_p = physics.brdf(xp.object_id, n_px, w_sp, wpx)
    expected = np.where(keep, e_p * f_p * g / (2 * geo_p / np.pi + g / (np.pi * np.maximum(n_sides[owner], 1))
                                               + hidden_w), 0.0)
    _close(irr, expected)
    # FoV connections: two per hidden point, on random sides
    nc = 2 * n
    inv = np.repeat(np.arange(n), 2)
    side = rng.random(nc) < 0.6
    normal = np.where(side[:, None], xs.normals[inv], -xs.normals[inv])
    direction = _unit(normal + 0.8 * rng.normal(size=(nc, 3)))
    weight, phys, time = rng.random(nc), rng.uniform(1, 3, nc), rng.uniform(0, 1e-8, nc)
    channel = rng.integers(0, 5, nc)
    legs = (mu, 0.7, 0.0)
    t, wt, comp = secondary_pairs(inv, side, p, (irr, on_pos, wpx, r_lp, rp),
                                  (normal, direction, weight, phys, time, channel), xs.object_id[inv], mat, legs, 9)
    part = (inv[:, None] * p + np.arange(p)).ravel()
    ci = np.repeat(np.arange(nc), p)
    use = (irr[part] > 0) & (on_pos[part] == side[ci])
    part, ci = part[use], ci[use]
    f_x = physics.brdf(xs.object_id[inv[ci]], normal[ci], -wpx[part], direction[ci])
    w0 = np.maximum(np.einsum("ij,ij->i", normal, direction), 0)[ci] * weight[ci] * irr[part] * f_x
    w0 = w0 * physics.attenuation(0.7 + r_lp[part] + rp[part] + phys[ci])
    assert len(part) > 100 and np.any(np.isnan(physics.constant_brdf(xs.object_id)))
    _close(wt, w0)
    _close(t, (r_lp + rp)[part] / SPEED_OF_LIGHT + time[ci])
    np.testing.assert_array_equal(comp, 9 + channel[ci])
    # primary impulses of the same connections
    e_x, r_lx, w_spot, _ = physics.irradiance(xs.points, xs.normals, 0)
    primary = side
    t, wt, comp = primary_impulses(inv, primary, e_x, xs.object_id, w_spot, r_lx, normal, direction, weight, phys,
                                   time, channel, sampler.object_component, 5, mat, legs)
    u = primary & (e_x[inv] > 0)
    bu = inv[u]
    w0 = e_x[bu] * physics.brdf(xs.object_id[bu], normal[u], w_spot[bu], direction[u]) * \
        np.maximum(np.einsum("ij,ij->i", normal[u], direction[u]), 0) * weight[u]
    w0 = w0 * physics.attenuation(0.7 + r_lx[bu] + phys[u])
    assert u.sum() > 50
    _close(wt, w0)
    _close(t, r_lx[bu] / SPEED_OF_LIGHT + time[u])
    np.testing.assert_array_equal(comp, sampler.object_component[xs.object_id[bu]] * 5 + channel[u])


@pytest.mark.parametrize("count_sensor", [1.0, 0.0])
def test_connection_weights_equal_the_balance_heuristic_with_fov_connection_weight(count_sensor):
    rng = np.random.default_rng(13)
    n, m = 500, 2000
    b = rng.integers(0, n, m)
    n_x = _unit(rng.normal(size=(n, 3)))
    rho_x = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.1, 50, n))
    w = _unit(n_x[b] + rng.normal(size=(m, 3)))
    r, cos_y = rng.uniform(0.05, 4, m), rng.uniform(0, 1, m)
    collect, d_ys = rng.uniform(0, 1e-3, m), rng.uniform(1, 3, m)
    rho_a, n_dir, fov_density = 900.0, 1.0, 12.5
    # half the points retroreflective: their direction rays follow the BRDF's sampler (density p_d × its ratio s)
    table = MaterialTable([Material(kind="lambertian", albedo=0.5),
                           Material(kind="retroreflective", albedo=0.9, specular=0.7, lobe_width=0.2)])
    mat = (table.kind, table.albedo, table.specular, table.exponent, table.axis, np.full(2, np.nan), table.width)
    obj = rng.integers(0, 2, n)
    w_in = _unit(n_x + rng.normal(size=(n, 3)))
    weight, time, phys = connection_weights(b, n_x, rho_x, w, r, cos_y, collect, d_ys,
                                            (rho_a, n_dir, fov_density, count_sensor), obj, w_in, mat)
    cos_x = np.einsum("ij,ij->i", n_x[b], w)
    p_d = cos_x * cos_y / (np.pi * r ** 2)
    cos_in = np.einsum("ij,ij->i", n_x[b], w_in[b])
    lobe = (obj[b] == 1) & (cos_in > 0) & (cos_x > 0)
    cos_h = on_arrays(retro_cos_h)(cos_in[lobe], cos_x[lobe], np.einsum("ij,ij->i", w_in[b][lobe], w[lobe]))
    s = np.ones(m)
    s[lobe] = 0.3 + 0.7 * on_arrays(retro_pdf)(0.2, cos_in[lobe], cos_h) * np.pi / cos_x[lobe]
    assert lobe.sum() > 100
    density = rho_x[b] * (rho_a + n_dir * p_d * s) + fov_density * p_d
    expected = np.divide(1.0, density, out=np.zeros(m), where=density > 0) * fov_connection_weight(cos_y, r, collect)
    assert (density <= 0).sum() > 10
    _close(weight, expected)
    _close(time, (r + count_sensor * d_ys) / SPEED_OF_LIGHT)
    _close(phys, r + d_ys)
