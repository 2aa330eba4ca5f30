"""SPADNoise (datagen/spad/torch_noise.py) against the numpy detector model (datagen.spad).

Statistical tests use fixed seeds and state their tolerance: goodness-of-fit and two-sample tests require
p > 1e-3 (a correct sampler fails with probability 1e-3 for a random seed; never for the fixed seeds here);
mean tests require |z| < 4 with z from the exact standard error; variance ratios are checked against the
standard error of a sample variance, sqrt(2/(R−1)) (normal approximation), also at 4 standard errors.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

import datagen
from datagen import spad
from datagen.spad.torch_noise import RANDOMISED_FIELDS, first_photon, row_search

P_MIN = 1e-3
Z_MAX = 4.0


def detector(**kw) -> spad.DetectorConfig:
    base = dict(model="pile_up", pde=0.3, dcr=100.0, ambient_rate=1e4, repetition_rate=1e7, n_cycles=2000,
                bin_width=100e-12)
    base.update(kw)
    return spad.DetectorConfig(**base)


def envelope(peak: float, bins: int = 64) -> np.ndarray:
    """A return at bin 20 (Gaussian, σ = 3 bins) and a weaker one at bin 40; ``peak`` sets the flux."""
    t = np.arange(bins)
    return peak * (np.exp(-0.5 * ((t - 20) / 3.0) ** 2) + 0.3 * np.exp(-0.5 * ((t - 40) / 4.0) ** 2))


def torch_draws(det, env, rows, seed, **ranges):
    noise = datagen.SPADNoise(det, dtype=torch.float64, **ranges)
    batch = torch.as_tensor(env, dtype=torch.float32).expand(rows, -1).contiguous()
    return noise(batch, generator=torch.Generator().manual_seed(seed)).numpy()


def numpy_draws(det, env, rows, seed):
    rates = spad.rates_from_envelope(np.broadcast_to(env.astype(np.float32), (rows, env.size)), det)
    return spad.sample_histogram(rates, det, np.random.default_rng(seed)).astype(np.float64)


def pooled_chi2_p(observed, expected, min_expected=5.0):
    """Pearson χ² p-value of summed counts against expected sums, bins below min_expected pooled."""
    big = expected >= min_expected
    obs = np.append(observed[big], observed[~big].sum())
    exp = np.append(expected[big], expected[~big].sum())
    if exp[-1] < min_expected:
        obs, exp = obs[:-1], exp[:-1]
    return stats.chisquare(obs, exp * obs.sum() / exp.sum()).pvalue


# Λ (expected avalanches per cycle) ≈ 0.02, 0.4 and 4.2: low flux, pile-up, strong pile-up (e^{-4.2}: 1.5 % of
# cycles see no photon; the second return is recorded first in only ≈ e^{-3} of the cycles it reaches).
CASES = {"low_flux": 0.002, "pile_up": 0.04, "strong_pile_up": 0.4}


@pytest.mark.parametrize("case", list(CASES))
def test_pile_up_counts_match_the_multinomial_and_numpy(case):
    det, env = detector(), envelope(CASES[case])
    rows = 3000
    x = torch_draws(det, env, rows, seed=1)
    y = numpy_draws(det, env, rows, seed=2)
    expected = spad.expected_histogram(spad.rates_from_envelope(env.astype(np.float32), det), det)
    # χ² of the summed histograms against the model, and of torch against numpy (2 × bins contingency table)
    assert pooled_chi2_p(x.sum(0), rows * expected) > P_MIN
    keep = (x.sum(0) + y.sum(0)) > 20
    assert stats.chi2_contingency(np.stack([x.sum(0)[keep], y.sum(0)[keep]])).pvalue > P_MIN
    # each row is Multinomial(n; p): total detections ~ Binomial(n, 1 − e^{−Λ})
    p_det = expected.sum() / det.cycles
    total = x.sum(1)
    z = (total.mean() - det.cycles * p_det) / math.sqrt(det.cycles * p_det * (1 - p_det) / rows)
    assert abs(z) < Z_MAX
    var_ratio = total.var(ddof=1) / (det.cycles * p_det * (1 - p_det))
    assert abs(var_ratio - 1) < Z_MAX * math.sqrt(2 / (rows - 1))
    # multinomial covariance between the two returns (bins 10–29 and 30–53): Cov = −n p_A p_B
    a, b = x[:, 10:30].sum(1), x[:, 30:54].sum(1)
    pa, pb = expected[10:30].sum() / det.cycles, expected[30:54].sum() / det.cycles
    cov = np.cov(a, b)[0, 1]
    se = math.sqrt(det.cycles**2 * pa * pb * (1 + pa * pb) / rows)   # ≈ sd of the product's sample mean
    assert abs(cov - (-det.cycles * pa * pb)) < Z_MAX * se
    # the same moments from numpy's sampler agree with torch's (variance of totals: F test)
    f = total.var(ddof=1) / y.sum(1).var(ddof=1)
    assert stats.f.sf(max(f, 1 / f), rows - 1, rows - 1) * 2 > P_MIN


def test_strong_pile_up_suppresses_the_late_return():
    """At Λ ≈ 4.2 the second return's counts fall to ≈ e^{−3} of the flux it carries (the first return, 3
    avalanches per cycle, wins first)."""
    det, env = detector(), envelope(CASES["strong_pile_up"])
    x = torch_draws(det, env, 2000, seed=3)
    rates = spad.rates_from_envelope(env.astype(np.float32), det)
    late = x[:, 30:54].sum(1).mean()
    assert late < 0.1 * det.cycles * rates[30:54].sum()                  # far below the Poisson expectation
    z = (late - spad.expected_histogram(rates, det)[30:54].sum()) / (x[:, 30:54].sum(1).std(ddof=1) / math.sqrt(2000))
    assert abs(z) < Z_MAX


def test_poisson_model_mean_and_variance_per_bin():
    det = detector(model="poisson", n_cycles=500)
    env = envelope(0.01)
    x = torch_draws(det, env, 4000, seed=4)
    lam = det.cycles * spad.rates_from_envelope(env.astype(np.float32), det)
    z = (x.mean(0) - lam) / np.sqrt(lam / 4000)
    assert np.abs(z).max() < Z_MAX + 0.5      # 64 bins: the largest of 64 |z| stays below 4.5 at p ≈ 4e-4
    big = lam > 5
    ratio = x.var(0, ddof=1)[big] / lam[big]
    assert np.abs(ratio - 1).max() < (Z_MAX + 0.5) * math.sqrt(2 / 3999) * 1.2   # + kurtosis of Poisson(λ ≥ 5)


def test_rates_equal_rates_from_envelope_with_gate_and_dnl():
    widths = list(np.linspace(90e-12, 110e-12, 64))
    det = detector(gate=[1.05e-9, 5.0e-9], bin_widths=widths)
    env = envelope(0.05)[None].astype(np.float32)
    noise = datagen.SPADNoise(det)
    params = noise.draw_params(1, torch.Generator().manual_seed(0))
    ours = noise.rates(torch.as_tensor(env), params).numpy()
    np.testing.assert_allclose(ours, spad.rates_from_envelope(env, det), rtol=1e-12, atol=1e-18)
    assert ours[0, 5] == 0.0 and ours[0, 20] > 0   # outside / inside the gate


def test_detector_randomisation_draws_each_sample_and_keeps_the_physics():
    det = detector(n_cycles=None, exposure=2e-4)
    ranges = dict(exposure=("50us", "200us"), ambient_rate=(0.0, 2e6), pde=(0.1, 0.4), dcr=(0.0, 1e3))
    noise = datagen.SPADNoise(det, dtype=torch.float64, **ranges)
    env = envelope(0.04)
    rows = 4000
    counts, params = noise.sample(torch.as_tensor(env).expand(rows, -1).contiguous(),
                                  torch.Generator().manual_seed(5))
    for name, (lo, hi) in zip(RANDOMISED_FIELDS, [(5e-5, 2e-4), (0.0, 2e6), (0.0, 1e3), (0.1, 0.4)]):
        values = params[name].numpy()
        assert stats.kstest((values - lo) / (hi - lo), "uniform").pvalue > P_MIN, name
    np.testing.assert_array_equal(params["cycles"].numpy(), np.round(params["exposure"].numpy() * 1e7))
    # every row's total against its own detector's expectation (envelope rescaled by pde / 0.3)
    z_sum, var_sum = 0.0, 0.0
    for i in range(0, rows, 40):
        d = detector(n_cycles=int(params["cycles"][i]), pde=float(params["pde"][i]),
                     ambient_rate=float(params["ambient_rate"][i]), dcr=float(params["dcr"][i]))
        expected = spad.expected_histogram(spad.rates_from_envelope(env * d.pde / 0.3, d), d).sum()
        p = expected / d.cycles
        z_sum += counts[i].sum().item() - expected
        var_sum += d.cycles * p * (1 - p)
    assert abs(z_sum / math.sqrt(var_sum)) < Z_MAX


def test_pixels_share_their_sample_parameters_and_runs_repeat():
    det = detector()
    noise = datagen.SPADNoise(det, pde=(0.05, 0.5))
    env = torch.as_tensor(envelope(0.04), dtype=torch.float32).expand(8, 3, 2, -1).contiguous()
    a, params = noise.sample(env, torch.Generator().manual_seed(6))
    b = noise(env, torch.Generator().manual_seed(6))
    c = noise(env, torch.Generator().manual_seed(7))
    assert a.shape == env.shape and a.dtype == torch.float32 and params["pde"].shape == (8,)
    assert torch.equal(a, b) and not torch.equal(a, c)
    # per sample, the totals of its 6 pixels scale with that sample's PDE (same envelope everywhere)
    per_sample = a.sum(dim=(1, 2, 3)).numpy()
    assert stats.spearmanr(per_sample, params["pde"].numpy()).correlation > 0.9


def test_row_search_equals_searchsorted():
    gen = torch.Generator().manual_seed(8)
    for m in (1, 2, 3, 5, 7, 64, 1000, 1536):
        cum = torch.cumsum(torch.rand(4, m, generator=gen, dtype=torch.float64) *
                           (torch.rand(4, m, generator=gen) > 0.3), dim=-1)
        rows = torch.randint(0, 4, (3000,), generator=gen)
        target = torch.rand(3000, generator=gen, dtype=torch.float64) * cum[rows, -1]
        target[:50] = cum[rows[:50], -1]                        # at or past every entry: b = m − 1
        target[50:100] = cum[rows[50:100], torch.randint(0, m, (50,), generator=gen)]     # exactly on an entry
        expected = torch.searchsorted(cum[rows], target[:, None], right=True)[:, 0].clamp_max(m - 1)
        assert torch.equal(row_search(cum, rows, target), expected), m


def test_first_photon_rows_never_exceed_their_cycles():
    """The Poisson stage overshoots n in ≈ Φ(−2) ≈ 2.3 % of rows (module doc); those rows must be redrawn. At
    Λ = 5 (p_none = e^{−5}) a row keeps ≈ 99.3 % of its Poisson total as detections, so without the redraw
    ≈ 2 000 × 0.023 ≈ 46 rows would count more than n; with it, none may. The mean total is n(1 − e^{−5}) to
    1e-3 (≈ 40 standard errors: a gross check)."""
    gen = torch.Generator().manual_seed(13)
    rates = torch.full((2000, 16), 5.0 / 16, dtype=torch.float64)
    cycles = torch.full((2000,), 4000.0, dtype=torch.float64)
    counts = first_photon(rates, cycles, gen)
    assert float(counts.sum(dim=-1).max()) <= 4000.0
    assert abs(float(counts.sum(dim=-1).mean()) / (4000 * (1 - math.exp(-5.0))) - 1) < 1e-3


def test_first_photon_edge_cases():
    gen = torch.Generator().manual_seed(9)
    zero = first_photon(torch.zeros(3, 16, dtype=torch.float64), torch.tensor([0.0, 1.0, 50.0],
                                                                          dtype=torch.float64), gen)
    assert zero.sum() == 0
    certain = first_photon(torch.tensor([[50.0, 1.0, 1.0]], dtype=torch.float64),
                           torch.tensor([1000.0], dtype=torch.float64), gen)
    assert certain.tolist() == [[1000.0, 0.0, 0.0]]          # e^{-50}: every cycle detects in bin 0


@pytest.mark.parametrize("kw, exc, text", [
    (dict(model="multi_stop", dead_time=50e-9), NotImplementedError, "multi_stop"),
    (dict(jitter_sigma=30e-12), NotImplementedError, "jitter_sigma"),
])
def test_unsupported_detectors_are_refused(kw, exc, text):
    with pytest.raises(exc, match=text):
        datagen.SPADNoise(detector(**kw))


@pytest.mark.parametrize("kw, text", [
    (dict(pde=(0.5, 0.2)), "pde range must have low <= high"),
    (dict(pde=1.5), "pde"),
    (dict(exposure="3 parsecs"), "exposure"),
    (dict(ambient_rate=(1.0, 2.0, 3.0)), "ambient_rate must be a number or a \\(low, high\\) pair"),
])
def test_bad_ranges_give_one_line_errors(kw, text):
    with pytest.raises(ValueError, match=text) as info:
        datagen.SPADNoise(detector(), **kw)
    assert "\n" not in str(info.value)


def test_bad_envelopes_and_dtype_limits():
    noise = datagen.SPADNoise(detector())
    with pytest.raises(ValueError, match="batch, ..., bins"):
        noise(torch.zeros(16))
    bad = torch.ones(2, 16)
    bad[1, 3] = -1e-3
    with pytest.raises(ValueError, match="negative"):
        noise(bad)
    bad[1, 3] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        noise(bad)
    bad[1, 3] = -1e-14                  # FFT round-off: clamped to 0, as rates_from_envelope does
    assert noise(bad).shape == (2, 16)
    with pytest.raises(ValueError, match="float32"):
        datagen.SPADNoise(detector(n_cycles=None, exposure=10.0))
    assert datagen.SPADNoise(detector(n_cycles=None, exposure=10.0), dtype=torch.float64) is not None


def test_expected_counts_equal_expected_histogram():
    det = detector(gate=[0.5e-9, 6.0e-9])
    env = np.stack([envelope(0.04), envelope(0.4)]).astype(np.float32)
    ours = datagen.SPADNoise(det).expected(torch.as_tensor(env)).numpy()
    np.testing.assert_allclose(ours, spad.expected_histogram(spad.rates_from_envelope(env, det), det),
                               rtol=1e-9, atol=1e-9)
    poisson = detector(model="poisson")
    np.testing.assert_allclose(datagen.SPADNoise(poisson).expected(torch.as_tensor(env)).numpy(),
                               spad.expected_histogram(spad.rates_from_envelope(env, poisson), poisson), rtol=1e-12)
