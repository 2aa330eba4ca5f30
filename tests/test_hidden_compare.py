"""compare-capture's hidden-signal comparison (datagen.analysis.hidden_compare): with the direct light excluded, the
floor subtracted and the scale fitted, a perfect simulation scores about 1x each metric's Poisson noise floor, and a
shifted or wider one many times it."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.analysis.hidden_compare import calibrated_gain, decay_time, hidden_comparison, leading_edges

N, T, DT = 24, 1024, 4e-12
EDGES = np.arange(T + 1) * DT
T_C = (np.arange(T) + 0.5) * DT
YY, XX = np.mgrid[:N, :N]
AMP = 2.0 * np.exp(-((YY - 12) ** 2 + (XX - 9) ** 2) / 40.0)       # hidden counts per bin at the peak


def capture(shift: float = 0.0, sigma: float = 30e-12, amp: float = 1.0) -> np.ndarray:
    """Expected counts (N, N, T): a direct return at t = 0 with a 50 ps tail, a hidden return whose round trip grows
    off-centre, and a floor of 0.02 per bin."""
    t0 = 2.0e-9 + 0.3e-9 * np.hypot(YY - 12, XX - 12) / 12 + shift
    hidden = amp * AMP[..., None] * np.exp(-0.5 * ((T_C - t0[..., None]) / sigma) ** 2)
    return hidden + 50.0 * np.exp(-T_C / 50e-12) + 0.02


@pytest.mark.parametrize("sim_is_counts", [False, True])
def test_a_perfect_simulation_scores_about_one_times_the_floor(sim_is_counts):
    rng = np.random.default_rng(7)
    mu = capture()
    real = rng.poisson(mu).astype(float)
    sim = rng.poisson(mu).astype(float) if sim_is_counts else 3.0 * mu          # any scale
    c = hidden_comparison(real, EDGES, None, sim, EDGES, None, sim_is_counts=sim_is_counts, draws=8, seed=1)
    f = c["floor"]
    assert 0.75 < c["rel_l2"] / f["rel_l2"] < 1.33, (c["rel_l2"], f["rel_l2"])          # tolerance: ±30 %
    assert 0.4 < c["map_decorrelation"] / f["map_decorrelation"] < 2.5
    assert abs(c["edge_median"]) < 4 * f["edge_median"] + 1e-12
    assert abs(c["fwhm_diff"]) < 4 * f["fwhm_diff"] + 2e-12
    assert c["trim_how"] == "auto" and 0.2e-9 < c["trim"] < 1.9e-9       # the direct light, not the hidden return
    # the floor read from the signal-free bins also holds the direct light's last tail: a few % low
    assert c["counts_real"] == pytest.approx(AMP.sum() * np.sqrt(2 * np.pi) * 30e-12 / DT, rel=0.06)


def test_a_shifted_or_wider_simulation_is_many_times_the_floor():
    rng = np.random.default_rng(8)
    real = rng.poisson(capture()).astype(float)
    c = hidden_comparison(real, EDGES, None, capture(shift=40e-12), EDGES, None, sim_is_counts=False, seed=1)
    assert c["edge_median"] == pytest.approx(40e-12, abs=5e-12)
    assert abs(c["edge_median"]) > 10 * c["floor"]["edge_median"]
    assert c["rel_l2"] > 1.5 * c["floor"]["rel_l2"]
    c = hidden_comparison(real, EDGES, None, capture(sigma=60e-12), EDGES, None, sim_is_counts=False, seed=1)
    assert c["fwhm_diff"] > 30e-12          # the return's own 71 ps more, added to its spread over the scan
    assert c["fwhm_diff"] > 3 * c["floor"]["fwhm_diff"]      # at 2 counts per bin the L2 hardly sees it


def test_gain_from_the_direct_light_restores_the_map():
    """A gain varying 4x across the scan scales the direct and the hidden light alike; estimated from the direct
    light it brings the simulation's map (no gain) back onto the measured one."""
    rng = np.random.default_rng(9)
    gain = np.linspace(0.5, 2.0, N)[None, :] * np.ones((N, 1))
    real = rng.poisson(capture(amp=10) * gain[..., None]).astype(float)
    plain = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, seed=1)
    fixed = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, gain="direct",
                              seed=1)
    assert fixed["gain"] == "direct" and fixed["gain_exponent"] == pytest.approx(1.0, abs=0.05)
    assert fixed["map_decorrelation"] < 2.5 * fixed["floor"]["map_decorrelation"]
    assert plain["map_decorrelation"] > 5 * plain["floor"]["map_decorrelation"]
    given = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, gain=gain, seed=1)
    assert given["gain"] == "map" and given["map_corr"] == pytest.approx(fixed["map_corr"], abs=0.01)


def test_gain_from_the_direct_light_follows_it_to_the_power_the_hidden_light_does():
    """Focus and alignment scale the direct light, a point on the wall, more than the hidden light: a gain over 4x
    (log-uniform per point, seeded) on the direct light and its square root on the hidden light. "direct" reads the
    power against the simulation (the slope of the log of the measured over the simulated mean hidden counts on log
    mean direct counts, over groups of points): 0.5 within 0.05, and its gain brings the map within 2.5x its noise
    floor; the direct light as it is (the power 1, given as a map) over-corrects it to more than 5x."""
    rng = np.random.default_rng(10)
    gain = 4.0 ** rng.uniform(-0.5, 0.5, (N, N))
    direct = capture(amp=0) - 0.02
    hidden = capture(amp=10) - direct - 0.02
    real = rng.poisson(direct * gain[..., None] + hidden * np.sqrt(gain)[..., None] + 0.02).astype(float)
    fixed = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, gain="direct",
                              seed=1)
    assert fixed["gain_exponent"] == pytest.approx(0.5, abs=0.05)
    assert fixed["map_decorrelation"] < 2.5 * fixed["floor"]["map_decorrelation"]
    linear = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, gain=gain,
                               seed=1)
    assert linear["map_decorrelation"] > 5 * linear["floor"]["map_decorrelation"]


def test_no_gain_from_a_direct_light_within_its_noise():
    """A capture whose direct light was cut (here: none at all, the floor's 0.02 counts per bin alone in its first
    0.2 ns): a gain read off it would be counting noise (zero at most points, huge at a few), so "direct" applies
    none and says why; the comparison is the plain one. The same capture with its direct light gets the gain."""
    rng = np.random.default_rng(11)
    direct = capture(amp=0) - 0.02
    real = rng.poisson(capture(amp=10) - direct).astype(float)
    plain = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, seed=1)
    asked = hidden_comparison(real, EDGES, None, capture(amp=10), EDGES, None, sim_is_counts=False, gain="direct",
                              seed=1)
    assert asked["gain"].startswith("none (direct: ") and asked["gain_exponent"] is None
    assert asked["map_corr"] == plain["map_corr"] and asked["rel_l2"] == plain["rel_l2"]
    lit = hidden_comparison(rng.poisson(capture(amp=10)).astype(float), EDGES, None, capture(amp=10), EDGES, None,
                            sim_is_counts=False, gain="direct", seed=1)
    assert lit["gain"] == "direct"


def test_a_gain_calibrated_on_one_capture_restores_another_of_the_same_scanner():
    """A scanner's gain, 4x across the scan times a per-point factor of ±20 %, on two captures: a calibration
    target (100 counts per bin at the peak) and a dimmer scene whose return comes 30 ps later. calibrated_gain of the
    calibration's comparison (no gain applied) is the true gain up to one factor where the target sends light (its
    ratio to the truth within 4 % rms over the points at 25 % of the peak counts or more, whose 900–14 000 hidden
    counts hold 1–3 % of counting noise); given to the other
    capture's comparison it brings the map within 2.5x of its noise floor, where without it the map is over 5x
    off; read off a comparison that already applied it, it gives it back (2 %); a simulation without hidden counts
    is refused."""
    rng = np.random.default_rng(11)
    gain = np.linspace(0.5, 2.0, N)[None, :] * rng.uniform(0.8, 1.2, (N, N))
    calibration = rng.poisson(capture(amp=100) * gain[..., None]).astype(float)
    c = hidden_comparison(calibration, EDGES, None, capture(amp=100), EDGES, None, sim_is_counts=False, seed=1)
    g = calibrated_gain(c)
    assert g.shape == (N, N) and g.mean() == pytest.approx(1.0)
    strong = AMP >= 0.25 * AMP.max()
    ratio = g[strong] / gain[strong]
    assert ratio.std() / ratio.mean() < 0.04, ratio.std() / ratio.mean()
    scene = rng.poisson(capture(amp=10, shift=30e-12) * gain[..., None]).astype(float)
    sim = capture(amp=10, shift=30e-12)
    plain = hidden_comparison(scene, EDGES, None, sim, EDGES, None, sim_is_counts=False, seed=1)
    fixed = hidden_comparison(scene, EDGES, None, sim, EDGES, None, sim_is_counts=False, gain=g, seed=1)
    assert fixed["map_decorrelation"] < 2.5 * fixed["floor"]["map_decorrelation"], fixed["map_corr"]
    assert plain["map_decorrelation"] > 5 * plain["floor"]["map_decorrelation"], plain["map_corr"]
    again = calibrated_gain(hidden_comparison(calibration, EDGES, None, capture(amp=100), EDGES, None,
                                              sim_is_counts=False, gain=g, seed=1))
    np.testing.assert_allclose(again[strong] / again[strong].mean(), g[strong] / g[strong].mean(), rtol=0.02)
    with pytest.raises(ValueError, match="no hidden counts to calibrate a gain against"):
        calibrated_gain({"model_map": np.zeros((N, N)), "real_map": np.ones((N, N)), "gain_map": np.ones((N, N))})


def test_leading_edge_and_decay_of_known_shapes():
    t = (np.arange(2000) + 0.5) * 1e-12
    step = (t > 500e-12).astype(float)[None]
    assert leading_edges(step, t, smoothing=1e-12)[0] == pytest.approx(500e-12, abs=1e-12)
    y = np.where(t > 300e-12, np.exp(-(t - 300e-12) / 200e-12), 0.0)
    assert decay_time(t, y) == pytest.approx(200e-12, abs=2e-12)


def test_bad_input_is_named():
    mu = capture()
    with pytest.raises(ValueError, match=r"grids differ: real \(24, 24\), sim \(12, 24\)"):
        hidden_comparison(mu, EDGES, None, mu[::2], EDGES, None, sim_is_counts=False)
    with pytest.raises(ValueError, match=r"gain map must have the scan's shape \(24, 24\), got shape \(3, 3\)"):
        hidden_comparison(mu, EDGES, None, mu, EDGES, None, sim_is_counts=False, gain=np.ones((3, 3)))
    g = np.ones((24, 24))
    g[2, 5], g[7, 1] = np.nan, -1.0
    with pytest.raises(ValueError, match=r"finite values >= 0; 2 do not, the first at \(2, 5\): nan"):
        hidden_comparison(mu, EDGES, None, mu, EDGES, None, sim_is_counts=False, gain=g)
    with pytest.raises(ValueError, match="bins left after the direct light"):
        hidden_comparison(mu, EDGES, None, mu, EDGES, None, sim_is_counts=False, trim=4.09e-9)
