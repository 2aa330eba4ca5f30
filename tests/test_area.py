"""Area sampler: closed forms for the primary and the secondary, every BRDF, and its convergence rates."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import patch_scene
from test_transport import patch_closed_form

from datagen.errors import ConfigError
from datagen.sampling import sample_surfaces
from datagen.sampling.surfaces import subdivide_triangles
from datagen.transport import AreaSampler, AreaSettings
from datagen.scene import Material
from datagen.scene.materials import MaterialTable
from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
from datagen.scene import RayCaster
from datagen.scene import FieldOfView, Laser, Scene, Sensor, quad
from datagen.units import SPEED_OF_LIGHT

AXIS = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=1000)
IRF = Irf(fwhm=100e-12)

# -- closed forms -------------------------------------------------------------------------------------------

SPOT, N_WALL, SENSOR = np.array([2.0, 0, 0]), np.array([-1.0, 0, 0]), np.array([0.0, 0, -0.5])
FOV_C, FOV, R_AP, RHO_WALL = np.array([2.0, 0, -0.6]), 0.8, 0.02, 0.9
TWO_PATCHES = [((1.0, -0.4, 0.5), (1.0, 0.6, 0.0), 0.3), ((1.0, 0.4, 0.5), (1.0, -0.6, 0.0), 0.3)]
"""Two tilted 0.3 m squares facing the relay wall and each other (centre, normal, side): both lit, both see
the FoV and each other, nothing occludes, so primary and secondary have closed forms."""


def _frame(center, normal, size):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross([0, 0, 1.0], n)
    u /= np.linalg.norm(u)
    return np.asarray(center, float), n, u * size, np.cross(n, u) * size


def two_patch_scene(materials):
    objects = [quad("relay_wall", (2.0, -2.0, -2.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0), Material(albedo=RHO_WALL),
                    label="relay_wall")]
    for i, ((c, n, s), m) in enumerate(zip(TWO_PATCHES, materials)):
        c, n, u, v = _frame(c, n, s)
        objects.append(quad(f"patch{i}", tuple(c - u / 2 - v / 2), tuple(u), tuple(v), m))
    return Scene(objects, Laser(emitter=tuple(SENSOR), spot=tuple(SPOT)),
                 Sensor(position=tuple(SENSOR), aperture_radius=R_AP,
                        fov=FieldOfView(center=tuple(FOV_C), size=(FOV, FOV))))


def _gl_rect(center, u, v, n):
    x, w = np.polynomial.legendre.leggauss(n)
    a, b = np.meshgrid(0.5 * x, 0.5 * x, indexing="ij")
    return center + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v, np.outer(w, w).ravel() * np.linalg.norm(
        np.cross(u, v)) / 4


def two_patch_closed_form(materials, n=8):
    """(primary of patch 0, primary of patch 1, secondary) totals by tensor Gauss–Legendre rules over the
    patches and the FoV (the secondary is a 6-D rule over patch × patch × FoV), every factor of docs/physics.md §2
    written out; BRDF values from MaterialTable (tested in test_brdf.py)."""
    mt = MaterialTable([Material(albedo=RHO_WALL)] + list(materials))
    F, wF = _gl_rect(FOV_C, np.array([0, FOV, 0.0]), np.array([0, 0, FOV]), n)
    d = SENSOR - F
    r_s = np.linalg.norm(d, axis=1)
    ws = d / r_s[:, None]
    aim = (FOV_C - SENSOR) / np.linalg.norm(FOV_C - SENSOR)

    def collect(w_in):          # (..., n_F, 3) unit directions from the FoV point toward the previous vertex
        f = mt.evaluate(np.zeros(w_in.shape[:-1], int), np.broadcast_to(N_WALL, w_in.shape), w_in,
                        np.broadcast_to(ws, w_in.shape))
        return f * (ws @ N_WALL) * np.pi * R_AP ** 2 * (-(ws @ aim)) / r_s ** 2

    w_e = (SENSOR - SPOT) / np.linalg.norm(SENSOR - SPOT)
    patches, E, out = [], [], []
    for i, (c, nn, s) in enumerate(TWO_PATCHES):
        c, nrm, u, v = _frame(c, nn, s)
        pts, wts = _gl_rect(c, u, v, n)
        wl = (pts - SPOT) / np.linalg.norm(pts - SPOT, axis=1)[:, None]
        f_l = mt.evaluate(np.zeros(len(pts), int), np.broadcast_to(N_WALL, pts.shape), np.broadcast_to(w_e, pts.shape), wl)
        E.append(f_l * (wl @ N_WALL) * (-(wl @ nrm)) / np.linalg.norm(pts - SPOT, axis=1) ** 2)
        dy = F[None] - pts[:, None]
        ry = np.linalg.norm(dy, axis=-1)
        wy = dy / ry[..., None]
        out.append((wy, (wy @ nrm) * (-(wy @ N_WALL)) / ry ** 2 * collect(-wy) * wF[None]))   # (P, F)
        patches.append((pts, wts, nrm, i + 1, -wl))
    primary = []
    for (pts, wts, nrm, oid, w_to_spot), e, (wy, g2) in zip(patches, E, out):
        fx = mt.evaluate(np.full(g2.shape, oid), np.broadcast_to(nrm, wy.shape),
                         np.broadcast_to(w_to_spot[:, None], wy.shape), wy)
        primary.append(float(np.einsum("i,ij->", wts * e, fx * g2)))
    secondary = 0.0
    for a in range(2):
        pa, wa, na, oa, wsa = patches[a]
        pb, wb, nb, ob, _ = patches[1 - a]
        wy, g2 = out[1 - a]
        dab = pb[None] - pa[:, None]
        rab = np.linalg.norm(dab, axis=-1)
        wab = dab / rab[..., None]
        fa = mt.evaluate(np.full(rab.shape, oa), np.broadcast_to(na, wab.shape),
                         np.broadcast_to(wsa[:, None], wab.shape), wab)
        inc = wa[:, None] * E[a][:, None] * fa * (wab @ na) * (-(wab @ nb)) / rab ** 2          # (A, B)
        shape = (len(pa), len(pb), len(F))
        fb = mt.evaluate(np.full(shape, ob), np.broadcast_to(nb, shape + (3,)),
                         np.broadcast_to(-wab[:, :, None], shape + (3,)), np.broadcast_to(wy[None], shape + (3,)))
        secondary += float(np.einsum("ab,abf,bf,b->", inc, fb, g2, wb))
    return primary[0], primary[1], secondary


def run_area(scene, seed=0, caster=None, **kw):
    sampler = AreaSampler(scene, AreaSettings(**kw), caster)
    acc = EnvelopeAccumulator(AXIS, IRF, len(sampler.component_names) * sampler.capture.n_channels)
    sampler.run(acc, np.random.default_rng(seed))
    return acc, sampler


# -- tests --------------------------------------------------------------------------------------------------

def test_subdivision_tiles_each_triangle_and_jitter_stays_inside():
    tri = np.array([[[0.0, 0, 0], [2.0, 0, 0], [0.0, 1.0, 0]]])
    pts, area, _ = subdivide_triangles(tri, 0.25, np.random.default_rng(0))
    k = 9                                              # ceil(√5 / 0.25)
    assert len(pts) == k * k and area.sum() == pytest.approx(1.0, rel=1e-12)
    assert np.all(pts[:, 0] >= 0) and np.all(pts[:, 1] >= 0) and np.all(pts[:, 0] / 2 + pts[:, 1] <= 1 + 1e-12)
    cents, _, _ = subdivide_triangles(tri, 0.25)      # midpoint rule: centroids average to the centroid
    assert cents.mean(0) == pytest.approx([2 / 3, 1 / 3, 0.0], abs=1e-12)


@pytest.mark.parametrize("method", ["stratified", "sobol", "random"])
def test_surface_samples_weights_sum_to_the_area(method):
    scene = patch_scene(with_occluder=True)
    caster = RayCaster(scene)
    faces = np.arange(2, len(caster.faces))            # the patch and the occluder box
    xs, density = sample_surfaces(caster, faces, 1000, method, np.random.default_rng(1))
    total = caster.face_area[faces].sum()
    assert xs.area.sum() == pytest.approx(total, rel=1e-12)
    assert np.allclose(1.0 / density[xs.face], xs.area)
    on_patch = np.isin(xs.face, [2, 3])
    assert total == pytest.approx(0.16 + 2 * 0.25 ** 2 + 4 * 0.1 * 0.25)
    if method == "stratified":      # whole sub-triangles: the patch's weights sum to its area exactly
        assert xs.area[on_patch].sum() == pytest.approx(0.16, rel=1e-12)
    else:                           # by area: the share of points on the patch is its area share
        assert on_patch.mean() == pytest.approx(0.16 / total, abs=0.05 if method == "random" else 0.01)


def test_primary_matches_closed_form_patch():
    exact = patch_closed_form()
    caster = RayCaster(patch_scene())
    totals = [run_area(patch_scene(), seed, caster, samples=1 << 14, secondary="none")[0].total_weight().sum()
              for seed in range(3)]
    # scrambled-Sobol replicas: spread ~1e-4 (measured); 1e-3 is a 5σ bound on the mean
    assert np.mean(totals) == pytest.approx(exact, rel=1e-3)
    assert np.std(totals) / exact < 1e-3


@pytest.mark.parametrize("materials", [
    (Material(albedo=0.8), Material(albedo=0.7)),
    (Material(kind="phong", albedo=0.8, specular=0.7, exponent=10.0),
     Material(kind="phong", albedo=0.7, specular=0.5, exponent=5.0)),
    (Material(kind="retroreflective", albedo=0.8, specular=0.8, lobe_width=0.4),
     Material(kind="retroreflective", albedo=0.7, specular=0.6, lobe_width=0.6)),
], ids=["lambertian", "phong", "retroreflective"])
def test_primary_and_secondary_match_closed_form_two_patches(materials):
    p0, p1, sec = two_patch_closed_form(materials)
    assert two_patch_closed_form(materials, n=10)[2] == pytest.approx(sec, rel=1e-9)     # the rule has converged
    scene = two_patch_scene(materials)
    caster = RayCaster(scene)
    runs = np.array([run_area(scene, seed, caster, samples=1 << 13)[0].total_weight() for seed in range(4)])
    mean, sem = runs.mean(0), runs.std(0, ddof=1) / 2
    # per-run spread measured: primary 0.1 %, secondary 1 %; assert within 4 standard errors + 0.1 %
    for i, exact in ((1, p0), (2, p1), (3, sec)):
        assert abs(mean[i] - exact) < 4 * sem[i] + 1e-3 * exact, (i, mean[i] / exact - 1, sem[i] / exact)
    assert sem[3] / sec < 0.01


@pytest.mark.parametrize("spot_fraction, fov_fraction", [(0.05, 0.9), (0.5, 0.0)])
def test_fov_paths_in_any_share_keep_primary_and_secondary_unbiased(spot_fraction, fov_fraction):
    """Hidden points drawn mostly as FoV paths (x the first hit of a cosine ray from a uniform FoV point; the pair
    (x, y) weighed by the balance heuristic with the connections' densities), or not at all: the primary of each
    patch and the secondary agree with the closed form within 4 standard errors + 0.2 %."""
    mats = (Material(albedo=0.8), Material(albedo=0.7))
    p0, p1, sec = two_patch_closed_form(mats)
    scene = two_patch_scene(mats)
    caster = RayCaster(scene)
    runs = np.array([run_area(scene, seed, caster, samples=1 << 12, spot_fraction=spot_fraction,
                              fov_fraction=fov_fraction)[0].total_weight() for seed in range(6)])
    mean, sem = runs.mean(0), runs.std(0, ddof=1) / np.sqrt(len(runs))
    for i, exact in ((1, p0), (2, p1), (3, sec)):
        assert abs(mean[i] - exact) < 4 * sem[i] + 2e-3 * exact, (i, mean[i] / exact - 1, sem[i] / exact)


def test_secondary_partner_strategies_each_unbiased():
    """Every partner strategy alone and their MIS mix estimate the same secondary (closed form)."""
    mats = (Material(albedo=0.8), Material(albedo=0.7))
    sec = two_patch_closed_form(mats)[2]
    scene = two_patch_scene(mats)
    caster = RayCaster(scene)
    for parts in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
        runs = [run_area(scene, seed, caster, samples=1 << 12, spot_partners=parts[0], direction_partners=parts[1],
                         area_partners=parts[2], fov_samples=(2, 2))[0].total_weight()[3] for seed in range(6)]
        sem = np.std(runs, ddof=1) / np.sqrt(len(runs))
        assert abs(np.mean(runs) - sec) < 4 * sem + 0.01 * sec, (parts, np.mean(runs) / sec - 1, sem / sec)


def test_time_of_flight_of_the_primary_is_the_path_length():
    """Every primary impulse arrives at (|x−x_l| + |y−x| + |x_s−y|)/c: with a delta IRF the envelope lies
    between the shortest and the longest such path of the patch scene."""
    class Sink:
        times, weights = [], []

        def add(self, t, w, c):
            self.times.append(np.asarray(t))
            self.weights.append(np.asarray(w))

    sink = Sink()
    AreaSampler(patch_scene(), AreaSettings(samples=2048, secondary="none")).run(sink, np.random.default_rng(0))
    t = np.concatenate(sink.times) * SPEED_OF_LIGHT
    # patch x=1, |y|,|z-0.5| <= 0.2; FoV x=2, |y| <= 0.4, z in [-1, -0.2]; spot (2,0,0); sensor (0,0,-0.5)
    assert t.min() > 1.0 + 1.0 + 2.0 - 1e-9 and t.max() < 1.1 + 1.9 + 2.4
    assert np.all(np.concatenate(sink.weights) >= 0)


@pytest.mark.parametrize("method,slope_range", [("random", (-0.65, -0.38)), ("sobol", (-0.95, -0.6))])
def test_error_falls_at_the_expected_rate(method, slope_range):
    """RMS relative L2 error of the envelope (against the closed form) over 3 seeds at M = 2^9 … 2^15: the
    fitted slope of log error vs log M is −1/2 for independent samples (measured −0.53) and steeper for
    scrambled Sobol points with padded FoV grids (measured −0.71); the total falls faster still for Sobol."""
    from test_reference import patch_envelope

    ref = patch_envelope(AXIS, IRF)
    scene = patch_scene()
    caster = RayCaster(scene)
    ms = [1 << 9, 1 << 11, 1 << 13, 1 << 15]
    errs, tots = [], []
    for m in ms:
        e, tot = [], []
        for seed in range(3):
            acc, _ = run_area(scene, seed, caster, samples=m, sampling=method, secondary="none", spot_fraction=0.0,
                              fov_fraction=0.0, fov_samples=(4, 4), fov_directions=0)
            env = acc.binned().sum(0)
            mask = ref > 0.01 * ref.max()
            e.append(np.linalg.norm(env[mask] - ref[mask]) / np.linalg.norm(ref[mask]))
            tot.append(abs(env.sum() / ref.sum() - 1))
        errs.append(np.sqrt(np.mean(np.square(e))))
        tots.append(np.sqrt(np.mean(np.square(tot))))
    slope = np.polyfit(np.log(ms), np.log(errs), 1)[0]
    print(method, "rel L2", np.round(errs, 5), "slope", round(slope, 3), "total", np.round(tots, 6))
    assert slope_range[0] < slope < slope_range[1]
    assert errs[-1] < 0.012
    if method == "sobol":
        assert np.polyfit(np.log(ms), np.log(tots), 1)[0] < -0.9          # measured −1.23


def test_settings_errors_name_the_field():
    with pytest.raises(ConfigError, match="samples"):
        AreaSettings(samples=0)
    with pytest.raises(ConfigError, match="fov_fraction"):
        AreaSettings(spot_fraction=0.5, fov_fraction=0.5)
    with pytest.raises(ConfigError, match="spot_fraction"):
        AreaSettings(spot_fraction=1.0)
    with pytest.raises(ConfigError, match="sampling"):
        AreaSettings(sampling="halton")
    with pytest.raises(ConfigError, match="partners"):
        AreaSettings(spot_partners=0, direction_partners=0, area_partners=0)
    with pytest.raises(ConfigError, match="fov_samples"):
        AreaSettings(fov_samples=(0, 4))


def test_components_and_secondary_only_through_visible_pairs():
    """The occluder scene: primary goes to patch and occluder components; the secondary (patch ↔ occluder)
    is positive and far below the primary; the room (relay wall) gets nothing."""
    scene = patch_scene(with_occluder=True)
    acc, sampler = run_area(scene, 0, samples=1 << 12)
    names = sampler.component_names
    tw = dict(zip(names, acc.total_weight()))
    assert names == ["room", "patch", "occluder", "secondary"]
    assert tw["room"] == 0.0 and tw["patch"] > 0 and tw["occluder"] > 0
    assert 0 < tw["secondary"] < 1e-2 * (tw["patch"] + tw["occluder"])


@pytest.mark.parametrize("convention", ["aperture", "point_radiance"])
def test_scans_match_the_lookin_estimator_per_channel(convention):
    """An exhaustive scan (2 laser points × 2×2 sensor points): every channel's total agrees with the lookin
    estimator at 64²×32² lookins (its own noise is a few per cent here; tolerance 8 %)."""
    from datagen.scene import CaptureSpec, WallGrid
    from datagen.transport import LookinSampler, LookinSettings

    base = patch_scene()
    capture = CaptureSpec(type="exhaustive", convention=convention,
                          laser_grid=WallGrid(center=(2.0, 0.0, 0.0), size=(0.4, 0.0), points=(2, 1)),
                          sensor_grid=WallGrid(center=(2.0, 0.0, -0.6), size=(0.8, 0.8), points=(2, 2)))
    scene = Scene(base.objects, base.laser, Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02),
                  capture=capture)
    acc, sampler = run_area(scene, 0, samples=1 << 13, secondary="none")
    n_ch = sampler.capture.n_channels
    assert n_ch == 8 and sampler.capture.channel_shape() == (1, 2, 2, 2)
    area = acc.total_weight().reshape(-1, n_ch).sum(0)
    tr = LookinSampler(scene, LookinSettings(lookins=(64, 64), pixels=(32, 32), secondary="none"))
    acc2 = EnvelopeAccumulator(AXIS, IRF, len(tr.component_names) * n_ch)
    tr.run(acc2, np.random.default_rng(0))
    lookin = acc2.total_weight().reshape(-1, n_ch).sum(0)
    assert np.all(area > 0)
    assert np.allclose(area, lookin, rtol=0.08), area / lookin - 1


def test_simulate_selects_the_area_estimator_by_name():
    """``estimator: area`` through simulate(): same integral as the primary quadrature (patch scene)."""
    from datagen.timing import Irf, TimeAxis
    from datagen.analysis.oracle import primary_area_quadrature
    from datagen.simulation import SimulationConfig, simulate
    from conftest import patch_scene
    scene = patch_scene(with_occluder=True)
    axis, irf = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=1000), Irf(fwhm=100e-12)
    ref, _ = primary_area_quadrature(scene, axis, irf, h_hidden=0.02, h_fov=0.02)
    r = simulate(scene, SimulationConfig(time=axis, irf=irf, secondary="none", estimator="area",
                                         area_samples=16384, detector={"repetition_rate": 1e7, "exposure": 1e-3}))
    assert r.attrs["effects"]["estimator"] == "area"
    assert r.envelope.sum() == pytest.approx(ref.sum(), rel=0.02)


def thin_panel_scene() -> Scene:
    """A two-sided panel in the plane y = 0 that cuts the FoV, lit on its +y side, and a patch facing the wall that
    straddles the panel's plane: secondary paths patch → panel → FoV exist on both sides of the panel."""
    objects = [
        quad("relay_wall", (2.0, -2.0, -2.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0), Material(albedo=0.9),
             label="relay_wall"),
        quad("panel", (1.2, 0.0, -0.8), (0.7, 0.0, 0.0), (0.0, 0.0, 1.6), Material(albedo=0.8)),
        quad("patch", (1.0, -0.3, -0.3), (0.0, 0.6, 0.0), (0.0, 0.0, 0.6), Material(albedo=0.8)),
    ]
    return Scene(objects, Laser(emitter=(0.0, 0.4, -0.5), spot=(2.0, 0.5, 0.0)),
                 Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02,
                        fov=FieldOfView(center=(2.0, 0.0, -0.6), size=(0.8, 0.8))))


def test_no_light_passes_through_a_thin_panel():
    """The Lambertian shortcut (``brdf_angles`` off) weighs exactly the pairs the full BRDF does: a partner lit on one
    side of the panel never feeds a FoV connection leaving its other side (before the fix the shortcut gave a
    secondary 50 % above the full evaluation on such a panel)."""
    scene = thin_panel_scene()
    out = {}
    for angles in (False, True):
        sink = EnvelopeAccumulator(AXIS, IRF, 4)
        sampler = AreaSampler(scene, AreaSettings(samples=1 << 12, brdf_angles=angles))
        sampler.run(sink, np.random.default_rng(5))
        out[angles] = sink.binned()
    secondary = sampler.component_names.index("secondary")
    assert out[True][secondary].sum() > 0
    assert np.array_equal(out[False], out[True])
