"""Transport: the lookin estimator against closed forms and an independent area quadrature."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import patch_scene

from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
from datagen.analysis.oracle import primary_area_quadrature
from datagen.transport import LookinSampler, LookinSettings

AXIS = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=1000)
IRF = Irf(fwhm=100e-12)


def run_primary(scene, lookins, pixels, seed=0, **kw):
    tr = LookinSampler(scene, LookinSettings(lookins=lookins, pixels=pixels, secondary="none", **kw))
    acc = EnvelopeAccumulator(AXIS, IRF, len(scene.component_names()) + 1)
    tr.run(acc, np.random.default_rng(seed))
    return acc.binned().sum(0), tr


def patch_closed_form(n=24):
    """Primary total for the patch scene from the closed-form integrand (no occluders in that scene):
    a tensor Gauss–Legendre rule over patch × FoV, every factor of docs/physics.md §2 written out."""
    xg, wg = np.polynomial.legendre.leggauss(n)
    spot, n_l = np.array([2.0, 0, 0]), np.array([-1.0, 0, 0])
    sensor = np.array([0.0, 0, -0.5])
    rho_w, rho_p, s = 0.9, 0.8, 0.4
    # patch points (x = 1, y, z), normal +x; FoV points (x = 2, y, z), normal −x
    py, pz = 0.5 * s * xg, 0.5 + 0.5 * s * xg
    pw = np.outer(wg, wg).ravel() * (0.5 * s) ** 2
    P = np.stack(np.broadcast_arrays(1.0, *np.meshgrid(py, pz, indexing="ij")), -1).reshape(-1, 3)
    fy, fz = 0.4 * xg, -0.6 + 0.4 * xg
    fw = np.outer(wg, wg).ravel() * 0.4 ** 2
    F = np.stack(np.broadcast_arrays(2.0, *np.meshgrid(fy, fz, indexing="ij")), -1).reshape(-1, 3)
    d_lp = P - spot
    r_lp = np.linalg.norm(d_lp, axis=1)
    cos_l = (d_lp @ n_l) / r_lp
    cos_p_in = -(d_lp @ np.array([1.0, 0, 0])) / r_lp
    leg1 = rho_w / np.pi * cos_l * cos_p_in / r_lp ** 2
    d_pf = F[None] - P[:, None]
    r_pf = np.linalg.norm(d_pf, axis=-1)
    cos_p_out = d_pf[..., 0] / r_pf
    cos_f_in = d_pf[..., 0] / r_pf
    leg2 = rho_p / np.pi * cos_p_out * cos_f_in / r_pf ** 2
    d_fs = sensor - F
    r_fs = np.linalg.norm(d_fs, axis=1)
    cos_f_out = (d_fs @ np.array([-1.0, 0, 0])) / r_fs          # relay-wall normal −x · unit(sensor − F)
    a_ap = np.pi * 0.02 ** 2
    aim = np.array([2.0, 0, -0.6]) - sensor
    aim /= np.linalg.norm(aim)
    cos_ap = -(d_fs / r_fs[:, None]) @ aim
    leg3 = rho_w / np.pi * cos_f_out * a_ap * cos_ap / r_fs ** 2
    assert np.all(cos_l > 0) and np.all(cos_p_out > 0)
    return float(np.sum(pw[:, None] * fw[None] * leg1[:, None] * leg2 * leg3[None]))


def test_patch_facing_spot_matches_closed_form_total():
    scene = patch_scene()
    exact = patch_closed_form()
    env, tr = run_primary(scene, (96, 96), (24, 24))
    assert tr.capture.photons == 1.0
    # the whole transient lies inside the window, so the binned total is the path-integral total
    assert env.sum() == pytest.approx(exact, rel=0.03)
    assert patch_closed_form(n=12) == pytest.approx(exact, rel=1e-6)   # the rule has converged


def rel_l2(a, b):
    m = b > 0.01 * b.max()
    return float(np.linalg.norm(a[m] - b[m]) / np.linalg.norm(b[m]))


def test_lookin_estimator_converges_to_area_quadrature_with_occlusion():
    scene = patch_scene(with_occluder=True)
    ref, ref_total = primary_area_quadrature(scene, AXIS, IRF, h_hidden=0.02, h_fov=0.02)
    ref_coarse, _ = primary_area_quadrature(scene, AXIS, IRF, h_hidden=0.04, h_fov=0.04)
    assert rel_l2(ref_coarse, ref) < 0.01          # the reference's own error is far below the tested ones
    errors = {}
    for n in (12, 24, 48, 96):
        env = np.mean([run_primary(scene, (n, n), (24, 24), seed=s)[0] for s in range(2)], axis=0)
        errors[n] = rel_l2(env, ref)
    print("relative L2 error vs area quadrature:", errors)
    assert errors[96] < 0.05
    assert errors[96] < errors[12] / 3
    assert errors[48] < errors[12]


# -- exact factorised secondary, parallel batches, next-event sensor connections ---------------------------

def demo_like_scene(pillar_kind="sin_theta", pixels=(1, 1)):
    import yaml

    from datagen.scene import scene_from_dict
    data = yaml.safe_load(open("scene_library/demo_room.yaml"))
    data["objects"][2]["material"] = ({"kind": "phong", "albedo": 0.9, "specular": 0.7, "exponent": 30}
                                      if pillar_kind == "phong" else {"kind": pillar_kind, "albedo": 1.0})
    data["sensor"]["fov"]["pixels"] = list(pixels)
    return scene_from_dict(data)


def secondary(scene, mode, lookins=(8, 8), pixels=(24, 24), seed=3, **kw):
    tr = LookinSampler(scene, LookinSettings(lookins=lookins, pixels=pixels, secondary=mode, **kw))
    acc = EnvelopeAccumulator(TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=5000), Irf(fwhm=600e-12),
                              len(tr.component_names) * tr.capture.n_channels)
    tr.run(acc, np.random.default_rng(seed))
    per = acc.binned().reshape(len(tr.component_names), tr.capture.n_channels, -1)
    return per[tr.n_primary], tr


@pytest.mark.parametrize("kind", ["lambertian", "sin_theta", "phong", "retroreflective"])
def test_exact_secondary_equals_full_pairs(kind):
    """The factorised O(N) secondary (docs/physics.md §3) sums the same pairs as the O(Ñ²) one: identical up to
    time binning of its profiles (measured 1e-5 relative L2 on the demo room at 30×30×30×30)."""
    scene = demo_like_scene(kind)
    full, tr = secondary(scene, "full")
    exact, _ = secondary(scene, "exact")
    assert full.sum() > 0
    assert exact.sum() == pytest.approx(full.sum(), rel=1e-9)       # binning moves mass, never loses it
    assert rel_l2(exact, full) < 1e-4


def test_exact_secondary_per_pixel_of_a_spad_array():
    scene = demo_like_scene("lambertian", pixels=(3, 2))
    full, tr = secondary(scene, "full", lookins=(6, 6), pixels=(20, 20))
    exact, _ = secondary(scene, "exact", lookins=(6, 6), pixels=(20, 20))
    assert tr.capture.n_channels == 6
    for ch in range(6):
        assert exact[ch].sum() == pytest.approx(full[ch].sum(), rel=1e-9)
        if full[ch].sum() > 0:
            assert rel_l2(exact[ch], full[ch]) < 1e-4


def test_workers_do_not_change_the_result():
    scene = demo_like_scene("sin_theta")
    one, _ = secondary(scene, "exact", lookins=(8, 8), pixels=(16, 16), batch=8)
    two, _ = secondary(scene, "exact", lookins=(8, 8), pixels=(16, 16), batch=8, workers=2)
    np.testing.assert_array_equal(one, two)


@pytest.mark.parametrize("replicas", [2, 5])
def test_area_replicas_do_not_depend_on_the_worker_count(replicas, monkeypatch):
    """The area sampler's replicas on 1, 2 and 3 workers (this process runs every W-th replica itself, W − 1 forked
    processes the others, so never more than W at once): bit-identical envelopes, components, error estimates and
    hidden-sample counts."""
    from pathlib import Path

    import datagen
    import datagen.transport.area.estimator as area

    from datagen.processes import ForkedCall

    forks = []

    def counted(*args):
        forks.append(args)
        return ForkedCall(*args)

    monkeypatch.setattr(area, "ForkedCall", counted)
    scene = datagen.load_scene(Path(__file__).resolve().parents[1] / "scene_library" / "demo_room.yaml")
    runs = []
    for w in (1, 2, 3):
        forks.clear()
        runs.append(datagen.simulate(scene, datagen.resolve_config(
            scene, {"estimator": "area", "area_samples": 1024 * replicas, "replicas": replicas, "workers": w})))
        assert len(forks) == min(w, replicas) - 1
    for r in runs[1:]:
        np.testing.assert_array_equal(r.envelope, runs[0].envelope)
        assert r.components.keys() == runs[0].components.keys()
        for name in r.components:
            np.testing.assert_array_equal(r.components[name], runs[0].components[name])
        assert r.attrs["error"] == runs[0].attrs["error"]
        assert r.attrs["stats"] == runs[0].attrs["stats"] and r.attrs["stats"]["secondary_pairs"] > 0


def test_connect_sensor_sampling_converges_to_the_same_primary():
    """Next-event connections to stratified FoV points estimate the same integral as the camera pixels."""
    scene = patch_scene(with_occluder=True)
    ref, _ = primary_area_quadrature(scene, AXIS, IRF, h_hidden=0.02, h_fov=0.02)
    # measured at 48×48 lookins: camera 0.996 of the total, 1.4 % L2; connect (24×24 per FoV) 0.995, 1.6 %
    cam, _ = run_primary(scene, (48, 48), (48, 48))
    con, _ = run_primary(scene, (48, 48), (2, 2), sensor_sampling="connect", connect_samples=(24, 24))
    for est in (cam, con):
        assert est.sum() == pytest.approx(ref.sum(), rel=0.02)
        assert rel_l2(est, ref) < 0.04


def _secondary_total(scene, seed, **kw):
    tr = LookinSampler(scene, LookinSettings(secondary="exact", **kw))
    acc = EnvelopeAccumulator(AXIS, IRF, len(tr.component_names))
    tr.run(acc, np.random.default_rng(seed))
    return dict(zip(tr.component_names, acc.total_weight()))["secondary"], tr.stats


def test_secondary_through_laser_shadowed_middle_vertices_is_counted():
    """The occluder scene's only secondary paths go spot → lit patch → an occluder side the spot cannot see →
    FoV: the middle vertex is dark, so the paper's lookin secondary (no lookin there) gives exactly 0 and the
    dark-middle connections must supply all of it. Their mean over 6 seeds (48×48 lookins, 64×64 pixels) equals
    the area sampler's (which samples middle vertices anywhere; 6 seeds of 2^14) within 4 combined standard
    errors (measured: lookin 1.83e-11 ± 0.03e-11 at 96², area 1.80e-11 ± 0.04e-11 at 2^16)."""
    from datagen.transport import AreaSampler, AreaSettings

    scene = patch_scene(with_occluder=True)
    paper, stats = _secondary_total(scene, 0, lookins=(32, 32), pixels=(32, 32), dark_middle=False)
    assert paper == 0.0 and stats.dark_points == 0
    ours = np.array([_secondary_total(scene, s, lookins=(48, 48), pixels=(64, 64))[0] for s in range(6)])
    area = []
    for s in range(6):
        sampler = AreaSampler(scene, AreaSettings(samples=1 << 14))
        acc = EnvelopeAccumulator(AXIS, IRF, len(sampler.component_names))
        sampler.run(acc, np.random.default_rng(100 + s))
        area.append(dict(zip(sampler.component_names, acc.total_weight()))["secondary"])
    area = np.array(area)
    se = np.hypot(ours.std(ddof=1), area.std(ddof=1)) / np.sqrt(6)
    assert ours.mean() > 0
    assert abs(ours.mean() - area.mean()) < 4 * se, (ours.mean(), area.mean(), se)
    assert se < 0.1 * area.mean()


def test_skipping_unblockable_shadow_rays_changes_nothing():
    """Laser and sensor shadow rays whose segment misses every blocker's bounding sphere (the planner's complete
    lists of faces that can cross a spot → hidden point or FoV point → sensor segment) are skipped: on the demo
    room (box and pillar block) the envelope is bit-identical to casting every ray, with well under half the
    shadow rays."""
    import datagen
    from datagen.planner import plan_effects
    from datagen.scene import RayCaster
    from datagen.scene import resolve_capture

    scene = datagen.load_scene("scene_library/demo_room.yaml")
    config = datagen.resolve_config(scene, {"lookins": "12x12", "pixels": "32x32", "secondary": "exact"})
    caster = RayCaster(scene)
    plan = plan_effects(scene, config, resolve_capture(scene, caster), caster)
    blockers, sensor_blockers = plan["shadow_spot"].blockers, plan["shadow_sensor"].blockers
    assert blockers and set(caster.face_object[list(blockers)]) == {
        i for i, o in enumerate(scene.objects) if o.name in ("box", "pillar")}
    assert sensor_blockers and {scene.objects[i].name for i in caster.face_object[list(sensor_blockers)]} == {"box"}
    out = []
    for listed, sensor_listed in ((blockers, sensor_blockers), (None, None)):
        tr = LookinSampler(scene, LookinSettings(lookins=(12, 12), pixels=(32, 32), secondary="exact",
                                                spot_blockers=listed, sensor_blockers=sensor_listed), caster)
        acc = EnvelopeAccumulator(AXIS, IRF, len(tr.component_names))
        tr.run(acc, np.random.default_rng(3))
        out.append((acc.binned(), tr.stats.shadow_rays))
    assert np.array_equal(out[0][0], out[1][0])
    assert out[0][1] < 0.5 * out[1][1]
