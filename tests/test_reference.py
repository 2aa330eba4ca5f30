"""Converged reference: its error estimate is honest against a closed form, it stops at its tolerance, and it
caches and resumes."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import patch_scene
from test_transport import patch_closed_form

from datagen.errors import ConfigError
from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
from datagen.scene import RayCaster
from datagen.analysis import converged_reference
from datagen.analysis.reference import peak_time
from datagen.scene import FieldOfView, Scene, Sensor
from datagen.simulation import SimulationConfig
from datagen.units import SPEED_OF_LIGHT

AXIS = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=1000)
IRF = Irf(fwhm=100e-12)
DETECTOR = {"repetition_rate": 1e7, "n_cycles": 1000}      # pde 1: the closed form has q = 1


def config(**kw) -> SimulationConfig:
    return SimulationConfig(time=kw.pop("time", AXIS), irf=kw.pop("irf", IRF), detector=DETECTOR, **kw)


def patch_impulses(n: int = 32, s: float = 0.4, rho_w: float = 0.9, rho_p: float = 0.8):
    """Tensor Gauss–Legendre nodes of the patch scene's primary (conftest.patch_scene, no occluder): times (s)
    and weights (photons), every factor of docs/physics.md §2 written out, as in test_transport.patch_closed_form."""
    xg, wg = np.polynomial.legendre.leggauss(n)
    spot, n_l, sensor = np.array([2.0, 0, 0]), np.array([-1.0, 0, 0]), np.array([0.0, 0, -0.5])
    P = np.stack(np.broadcast_arrays(1.0, *np.meshgrid(0.5 * s * xg, 0.5 + 0.5 * s * xg, indexing="ij")),
                 -1).reshape(-1, 3)
    pw = np.outer(wg, wg).ravel() * (0.5 * s) ** 2
    F = np.stack(np.broadcast_arrays(2.0, *np.meshgrid(0.4 * xg, -0.6 + 0.4 * xg, indexing="ij")), -1).reshape(-1, 3)
    fw = np.outer(wg, wg).ravel() * 0.4 ** 2
    d_lp = P - spot
    r_lp = np.linalg.norm(d_lp, axis=1)
    leg1 = rho_w / np.pi * ((d_lp @ n_l) / r_lp) * (-d_lp[:, 0] / r_lp) / r_lp ** 2
    d_pf = F[None] - P[:, None]
    r_pf = np.linalg.norm(d_pf, axis=-1)
    leg2 = rho_p / np.pi * (d_pf[..., 0] / r_pf) ** 2 / r_pf ** 2
    d_fs = sensor - F
    r_fs = np.linalg.norm(d_fs, axis=1)
    aim = (np.array([2.0, 0, -0.6]) - sensor) / np.linalg.norm(np.array([2.0, 0, -0.6]) - sensor)
    leg3 = rho_w / np.pi * (-d_fs[:, 0] / r_fs) * np.pi * 0.02 ** 2 * (-(d_fs / r_fs[:, None]) @ aim) / r_fs ** 2
    weights = pw[:, None] * fw[None] * leg1[:, None] * leg2 * leg3[None]
    return ((r_lp[:, None] + r_pf + r_fs[None]) / SPEED_OF_LIGHT).ravel(), weights.ravel()


def patch_envelope(axis: TimeAxis, irf: Irf, n: int = 32) -> np.ndarray:
    """Closed-form binned primary envelope of the patch scene (the rule's own error: 3e-5 relative L2 at n = 32
    against n = 48 for a 100 ps IRF)."""
    acc = EnvelopeAccumulator(axis, irf, 1)
    acc.add(*patch_impulses(n), 0)
    return acc.binned()[0]


def rel_l2(a, b):
    m = b > 0.01 * b.max()
    return float(np.linalg.norm(a[m] - b[m]) / np.linalg.norm(b[m]))


@pytest.fixture(scope="module")
def exact():
    env = patch_envelope(AXIS, IRF)
    assert env.sum() == pytest.approx(patch_closed_form(), rel=1e-9)     # window holds the whole transient
    return env


def test_error_estimate_is_honest_against_closed_form(exact):
    """Six independent loose references (rel_tol 1 %, ≥ 8 replicas): the actual errors against the closed form
    scatter as the estimates say: RMS(actual)/RMS(estimated) near 1 for the envelope's relative L2 and the
    total, and no single relative L2 beyond 4 estimates."""
    scene = patch_scene()
    caster = RayCaster(scene)
    est_l2, act_l2, est_tot, act_tot = [], [], [], []
    for seed in range(6):
        ref = converged_reference(scene, config(), rel_tol=1e-2, samples=1 << 11, min_replicas=8, seed=seed,
                                  caster=caster)
        assert ref.converged and ref.error_estimate["rel_l2"] <= 1e-2
        est_l2.append(ref.error_estimate["rel_l2"])
        act_l2.append(rel_l2(ref.envelope, exact))
        est_tot.append(ref.error_estimate["total"])
        act_tot.append(abs(ref.envelope.sum() / exact.sum() - 1))
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))
    print("rel L2 actual/estimate", np.round(np.array(act_l2) / est_l2, 2), "total", np.round(np.array(act_tot) / est_tot, 2))
    print("RMS ratios", rms(act_l2) / rms(est_l2), rms(act_tot) / rms(est_tot))
    assert 0.5 < rms(act_l2) / rms(est_l2) < 2.0          # measured 0.93–1.10 over four blocks of seeds
    assert 0.25 < rms(act_tot) / rms(est_tot) < 4.0        # a sum of 6 |errors| scatters more: 0.41–1.66
    assert np.all(np.array(act_l2) < 4 * np.array(est_l2) + 3e-5)


def test_reference_reaches_its_tolerance_and_the_closed_form(exact):
    ref = converged_reference(patch_scene(), config(orders=2), rel_tol=2e-3, samples=1 << 13)   # the closed form's
    assert ref.converged and ref.error_estimate["rel_l2"] <= 2e-3 and ref.replicas >= 8
    assert rel_l2(ref.envelope, exact) < 3 * 2e-3
    assert ref.envelope.sum() == pytest.approx(exact.sum(), rel=1e-3)
    t_exact = peak_time(exact, AXIS.edges)
    assert abs(peak_time(ref.envelope, AXIS.edges) - t_exact) < max(4 * ref.error_estimate["peak_time"], 2e-12)
    assert set(ref.components) == {"room", "patch", "secondary"}
    assert np.allclose(sum(ref.components.values()), ref.envelope)
    assert ref.envelope.shape == (AXIS.n_bins,) and np.array_equal(ref.time_edges, AXIS.edges)


def test_cache_returns_resumes_and_is_keyed_by_config(tmp_path):
    scene = patch_scene(with_occluder=True)
    cfg = config(secondary="full")
    first = converged_reference(scene, cfg, rel_tol=3e-2, samples=1 << 10, cache_dir=tmp_path)
    files = list(tmp_path.glob("reference_*.npz"))
    assert len(files) == 1 and first.settings["cache_file"] == str(files[0])
    again = converged_reference(scene, cfg, rel_tol=3e-2, samples=1 << 10, cache_dir=tmp_path)
    assert again.replicas == first.replicas and np.array_equal(again.envelope, first.envelope)
    assert again.settings["seconds_this_call"] < 0.5 * first.seconds + 0.05     # nothing recomputed
    tighter = converged_reference(scene, cfg, rel_tol=1e-2, samples=1 << 10, cache_dir=tmp_path)
    assert tighter.replicas > first.replicas and tighter.error_estimate["rel_l2"] <= 1e-2
    fresh = converged_reference(scene, cfg, rel_tol=1e-6, samples=1 << 10, min_replicas=tighter.replicas,
                                max_replicas=tighter.replicas)
    assert np.allclose(fresh.envelope, tighter.envelope, rtol=1e-12, atol=0)     # resuming = running straight
    converged_reference(scene, config(secondary="full", irf=Irf(fwhm=200e-12)), rel_tol=3e-2, samples=1 << 10,
                        cache_dir=tmp_path)
    converged_reference(scene, config(secondary="none"), rel_tol=3e-2, samples=1 << 10, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("reference_*.npz"))) == 3


def test_budget_stops_early_and_says_so():
    ref = converged_reference(patch_scene(), config(), rel_tol=1e-6, samples=1 << 10, max_seconds=0.0)
    assert not ref.converged and ref.replicas == 2 and ref.error_estimate["rel_l2"] > 1e-6


def test_sensor_array_reference_has_pixel_shape():
    base = patch_scene()
    scene = Scene(base.objects, base.laser, Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02,
                                                   fov=FieldOfView(center=(2.0, 0.0, -0.6), size=(0.8, 0.8),
                                                                   pixels=(2, 2))))
    ref = converged_reference(scene, config(), rel_tol=5e-2, samples=1 << 10, min_replicas=2)
    assert ref.envelope.shape == (2, 2, AXIS.n_bins)
    assert ref.envelope.sum() == pytest.approx(patch_closed_form(), rel=0.02)
    # the upper pixels (v > 0, closer to the patch above) collect more than the lower ones
    assert ref.envelope[1].sum() > ref.envelope[0].sum()


def test_bad_tolerances_are_clear_errors():
    with pytest.raises(ConfigError, match="rel_tol"):
        converged_reference(patch_scene(), config(), rel_tol=0.0)
    with pytest.raises(ConfigError, match="min_replicas"):
        converged_reference(patch_scene(), config(), min_replicas=1)
