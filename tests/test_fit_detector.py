"""fit-detector (datagen.spad.fit): maximum-likelihood detector parameters recovered from histograms drawn by
datagen's own detector model (datagen.spad.sample_histogram) with known parameters, 25-200 seeds per regime."""
from __future__ import annotations

import math

import numpy as np
import pytest

from click.testing import CliRunner

from datagen.cli.main import main
from datagen.errors import ConfigError
from datagen.spad import DetectorConfig, rates_from_envelope, sample_histogram
from datagen.spad.fit import fit_detector, return_envelope
from datagen.spad.fit_numerics import sandwich_covariance

DT, BINS = 50e-12, 200
TRUE = {"position": 3.03e-9, "jitter_sigma": 80e-12, "diffusion_tail": 150e-12}


def draw(model: str, signal: float, background: float, n: int, rep: float, seed: int, dead_time: float = 0.0,
         afterpulse: tuple[float, float] = (0.0, 0.0), pixels: int = 1):
    """Histograms of a return at TRUE["position"] drawn by datagen's detector model (sample_histogram) with
    numpy.random.default_rng(seed): int64 (BINS,), or (pixels, BINS) independent ones from one call when pixels
    > 1 (the free-running event simulation with afterpulsing steps all pixels at once: ~0.3 s per histogram
    instead of 7.6 s one by one)."""
    extra = {"dead_time": dead_time, "afterpulse_probability": afterpulse[0],
             "afterpulse_time_constant": afterpulse[1]} if model == "free_running" else {}
    cfg = DetectorConfig(model=model, repetition_rate=rep, n_cycles=n, bin_width=DT, dcr=background,
                         jitter_sigma=TRUE["jitter_sigma"], diffusion_tail=TRUE["diffusion_tail"], **extra)
    rates = rates_from_envelope(return_envelope(BINS, DT, TRUE["position"], signal, 0.5 * DT), cfg)
    return sample_histogram(rates if pixels == 1 else np.tile(rates, (pixels, 1)), cfg, np.random.default_rng(seed))


REGIMES = {
    # low flux: 2 % of 10⁶ cycles (50 ms at 20 MHz) detect the return, the histogram is the IRF (Poisson-like)
    "pile_up low flux": dict(model="pile_up", signal=0.02, background=2e5, n=1_000_000, rep=20e6),
    # pile-up: one photon per cycle on average, 63 % of the cycles detect it, the histogram is skewed early
    "pile_up high flux": dict(model="pile_up", signal=1.0, background=2e5, n=100_000, rep=20e6),
    # free-running with a 4 ns dead time over a 10 ns period: the return blinds the SPAD, a dip follows it; the
    # datasheet's dead-time range (2–10 ns) as below: unbounded, τ + one period fits some draws within a likelihood
    # ratio of 20 and the fit says so (test_dead_time_one_period_off_is_named_in_one_line_...)
    "free_running": dict(model="free_running", signal=0.3, background=2e6, n=100_000, rep=100e6, dead_time=4e-9,
                         dead_time_bounds=(2e-9, 10e-9)),
    # the same with afterpulsing (P = 0.1, τ_ap = 2 ns known): an echo of the return one dead time later; the
    # datasheet's dead-time range (2–10 ns, below one period) excludes the alias τ + one period (14 ns), which fits
    # these histograms about as well (test_dead_time_one_period_off_is_named_in_one_line_...)
    "free_running afterpulsing": dict(model="free_running", signal=0.3, background=2e6, n=100_000, rep=100e6,
                                      dead_time=4e-9, afterpulse=(0.1, 2e-9), dead_time_bounds=(2e-9, 10e-9)),
}


# seeds per regime: enough to measure coverage to about ±2-4 % (a fit costs 0.25 s at low flux, 0.45 s in pile-up;
# a free-running seed, the fit and the refit with τ held, about 2 s, and 6 s with afterpulsing)
SEEDS = {"pile_up low flux": 200, "pile_up high flux": 200, "free_running": 50, "free_running afterpulsing": 25}
COVERAGE_RATE = 0.90          # "every parameter inside its 95 % interval in >= 9 of 10 seeds" (issue 26), as a rate
COVERAGE_SIGNIFICANCE = 0.01  # the test fails when the hits are below the 1 % quantile of Binomial(seeds, 0.90)


# the afterpulsing regime (about 3 minutes) runs from tests/test_fit_coverage_afterpulsing.py: CI gives each file
# one worker (--dist loadfile), so it runs beside this file's regimes instead of after them
SEPARATE = ("free_running afterpulsing",)


@pytest.mark.slow
@pytest.mark.parametrize("regime", [r for r in REGIMES if r not in SEPARATE])
def test_fit_recovers_every_parameter_within_its_95_percent_interval(regime):
    check_coverage(regime)


def check_coverage(regime: str) -> None:
    """Issue 26's acceptance as a coverage rate: fitted to histograms drawn by datagen's own detector model with
    known parameters, each parameter's 95 % interval (and the simultaneous intervals, all parameters at once) holds
    the true value in at least 9 of 10 seeds. Ten seeds cannot show that: an exact 95 % interval has 9 or 10 hits
    in 10 with probability 0.91 only, so over the 25-30 parameters of the four regimes some would miss by chance.
    So each regime runs SEEDS histograms and fails when a parameter's hits (or the joint hits) fall below the 1 %
    quantile of Binomial(seeds, 0.90), i.e. when the data say its coverage is below 90 %. The calibration is also
    checked both ways: z = (estimate − truth) / σ has a standard deviation within 0.75-1.3 (too narrow or too wide
    intervals fail) and a mean within ±3 / √seeds + 0.2. The dead time's interval is a likelihood-ratio set (its
    likelihood is far from quadratic, its estimate heavy-tailed: (τ̂ − τ) / σ reached −7 in 50 draws), so its z is
    the signed root of the likelihood ratio at the truth, sign(τ̂ − τ)·√(2 Δ(−log L)), Δ from a refit with τ held
    at the truth (N(0, 1) when that set is calibrated). Every fit must converge and raise no identifiability line.
    The free-running fit starts from a datasheet dead time 25 % off; with afterpulsing it also fits the afterpulse
    probability (τ_ap known) with sandwich intervals (docs/capture_io.md)."""
    from scipy.stats import binom

    spec = dict(REGIMES[regime])
    truth = {**TRUE, "signal": spec["signal"], "background_rate": spec["background"]}
    initial, tau_ap = None, None
    if spec["model"] == "free_running":
        truth["dead_time"] = spec["dead_time"]
        initial = {"dead_time": 5e-9}
    if "afterpulse" in spec:
        truth["afterpulse_probability"], tau_ap = spec["afterpulse"]
    n_seeds = SEEDS[regime]
    inside = {k: 0 for k in truth}
    z = {k: [] for k in truth}
    joint = 0
    histograms = draw(spec["model"], spec["signal"], spec["background"], spec["n"], spec["rep"], 26,
                      spec.get("dead_time", 0.0), spec.get("afterpulse", (0.0, 0.0)), pixels=n_seeds)
    for i, h in enumerate(histograms):
        fit = fit_detector(h, bin_width=DT, repetition_rate=spec["rep"], n_cycles=spec["n"], model=spec["model"],
                           irf="exgauss", initial=initial, afterpulse_time_constant=tau_ap, seed=1000 + i,
                           dead_time_bounds=spec.get("dead_time_bounds"))
        assert fit.messages == [] and fit.settings["converged"], (i, fit.summary(), fit.messages)
        for k in truth:
            lo, hi = fit.intervals[k]
            inside[k] += lo <= truth[k] <= hi
            z[k].append((fit.values[k] - truth[k]) / fit.errors[k])
        if "dead_time" in truth:
            held = fit_detector(h, bin_width=DT, repetition_rate=spec["rep"], n_cycles=spec["n"], model=spec["model"],
                                irf="exgauss", initial=fit.values, afterpulse_time_constant=tau_ap,
                                covariance="fisher", fixed={"dead_time": truth["dead_time"]})
            rise = max(held.deviance - fit.deviance, 0.0)          # 2 Δ(−log L): Poisson deviances
            z["dead_time"][-1] = math.copysign(math.sqrt(rise), fit.values["dead_time"] - truth["dead_time"])
        joint += all(fit.joint_intervals[k][0] <= truth[k] <= fit.joint_intervals[k][1] for k in truth)
    need = int(binom.ppf(COVERAGE_SIGNIFICANCE, n_seeds, COVERAGE_RATE))
    report = {k: (f"{inside[k] / n_seeds:.1%}", round(float(np.std(z[k])), 2), round(float(np.mean(z[k])), 2))
              for k in truth}
    report["joint"] = f"{joint / n_seeds:.1%}"
    print(regime, n_seeds, "seeds, need", need, report)
    assert all(v >= need for v in inside.values()) and joint >= need, (need, report)
    assert all(0.75 < np.std(v) < 1.3 and abs(np.mean(v)) < 3 / np.sqrt(n_seeds) + 0.2 for v in z.values()), report


def test_joint_z_is_bonferroni():
    from datagen.spad.fit import joint_z

    assert joint_z(1) == pytest.approx(1.959964, abs=1e-6)
    assert joint_z(5) == pytest.approx(2.575829, abs=1e-6)           # each at 99 %
    assert joint_z(7) == pytest.approx(2.690110, abs=1e-6)


def test_profile_walk_refits_the_others_along_a_curved_ridge():
    """−log L = 50 (y − x²)² + x²/2: the others' optimum y = x² is curved (the Hessian's ridge direction at the
    optimum, y = 0, is wrong away from it), the profile along x is exactly x²/2. The walk refits y at each point,
    stops a side three points above its stop level, or at the bound (reported)."""
    from datagen.spad.fit_numerics import profile_walk

    def f(p):
        return 50.0 * (p[1] - p[0] ** 2) ** 2 + 0.5 * p[0] ** 2

    x = np.zeros(2)
    hess = np.array([[1.0, 0.0], [0.0, 100.0]])
    grid, delta, at_bound = profile_walk(f, x, 0, hess, [1e-3, 1e-3], 0.25, 2.0, (-1.1, 10.0))
    assert grid[0] == pytest.approx(-1.0) and grid[-1] == pytest.approx(2.75)     # 2.25, 2.5, 2.75 above 2
    np.testing.assert_allclose(delta, 0.5 * grid ** 2, atol=2e-3)
    assert at_bound == (True, False)
    held = np.array([f(np.array([g, 0.0])) for g in grid])                          # the others held instead
    assert held[-1] - delta[-1] > 100


def test_fitted_detector_yaml_loads_and_reproduces_the_fit(tmp_path):
    h = draw("pile_up", 1.0, 2e5, 100_000, 20e6, 0)
    fit = fit_detector(h, bin_width=DT, repetition_rate=20e6, n_cycles=100_000)
    cfg = DetectorConfig.from_yaml(fit.write_yaml(tmp_path / "fitted.yaml"))
    assert cfg == fit.config
    assert cfg.model == "pile_up" and cfg.cycles == 100_000 and cfg.diffusion_fraction == 1.0
    assert cfg.jitter == pytest.approx(80e-12, rel=0.05) and cfg.dcr == pytest.approx(2e5, rel=0.3)
    assert 0.5 < fit.p_value and fit.dof == BINS - 5
    # simultaneous intervals: the same centre, the Bonferroni quantile of the 5 fitted parameters instead of 1.96
    from datagen.spad.fit import joint_z

    for name, (lo, hi) in fit.intervals.items():
        jlo, jhi = fit.joint_intervals[name]
        assert jlo < lo < fit.values[name] < hi < jhi
        if name in ("jitter_sigma", "signal"):                        # log scale: log(hi/lo) ∝ the quantile (1.96)
            assert np.log(jhi / jlo) / np.log(hi / lo) == pytest.approx(joint_z(5) / 1.96, rel=1e-9)
    assert "all jointly:" in fit.summary() and "simultaneous 95 % interval" in fit.detector_yaml()


def test_a_parameter_the_data_cannot_fix_is_named_in_one_line():
    """A free-running fit of a low-flux histogram: nothing blinds the SPAD long enough to show its dead time."""
    h = draw("free_running", 0.002, 1e4, 100_000, 100e6, 3, dead_time=4e-9)
    fit = fit_detector(h, bin_width=DT, repetition_rate=100e6, n_cycles=100_000, model="free_running", irf="gauss",
                       initial={"dead_time": 5e-9})
    assert not fit.identifiable["dead_time"]
    lines = [m for m in fit.messages if m.startswith("dead_time")]
    assert len(lines) == 1 and "\n" not in lines[0]
    assert "dead_time is not identifiable from this histogram" in lines[0] and "--fix dead_time=" in lines[0]
    assert fit.identifiable["jitter_sigma"]


def test_bad_input_is_a_one_line_error():
    with pytest.raises(ConfigError, match=r"histogram must hold counts"):
        fit_detector(np.full(20, 0.5), bin_width=DT, repetition_rate=20e6, n_cycles=10)
    with pytest.raises(ConfigError, match=r"model must be one of poisson, pile_up, free_running, got 'gated'"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, model="gated")
    with pytest.raises(ConfigError, match=r"fixed: unknown parameter 'dead_time' for model 'pile_up'"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, fixed={"dead_time": 1e-9})
    with pytest.raises(ConfigError, match=r"afterpulse_time_constant=2e-09: needs model 'free_running' "
                                          r"\(got 'pile_up'\)"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, afterpulse_time_constant=2e-9)
    with pytest.raises(ConfigError, match=r"covariance='sandwich': must be one of fisher, sandwich, and 'sandwich' "
                                          r"needs model 'free_running' \(got 'pile_up'"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, covariance="sandwich")
    with pytest.raises(ConfigError, match=r"covariance='bootstrap': must be one of fisher, sandwich"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, covariance="bootstrap")
    with pytest.raises(ConfigError, match=r"seed must be an integer >= 0, got -1"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, seed=-1)
    with pytest.raises(ConfigError, match=r"dead_time_bounds=\(8e-09 s, 2e-09 s\): LOW is not below HIGH; give "
                                          r"LOW,HIGH with 0 < LOW < HIGH <= 2e-07 s"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, model="free_running",
                     dead_time_bounds=(8e-9, 2e-9))
    with pytest.raises(ConfigError, match=r"dead_time_bounds=\(2e-09, 8e-09\): a dead time is fitted by model "
                                          r"'free_running' only \(got 'pile_up'\)"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, dead_time_bounds=(2e-9, 8e-9))
    with pytest.raises(ConfigError, match=r"fixed dead_time=1e-08 s is outside dead_time_bounds=\(2e-09, 8e-09\)"):
        fit_detector(np.ones(20), bin_width=DT, repetition_rate=20e6, n_cycles=10, model="free_running",
                     dead_time_bounds=(2e-9, 8e-9), fixed={"dead_time": 1e-8})
    with pytest.raises(ConfigError, match=r"longer than the laser period"):
        fit_detector(np.ones(4000), bin_width=DT, repetition_rate=20e6, n_cycles=10)


@pytest.mark.parametrize("dispersion", [1.0, 2.0])
def test_sandwich_covariance_is_the_inverse_information_scaled_by_the_counts_dispersion(dispersion):
    """Replicates of m = n/10 cycles whose bins have variance dispersion × mean (Poisson, or twice a Poisson count
    of half the mean): the sandwich of a linear two-parameter model is dispersion × F⁻¹ (F the Fisher information
    of n cycles), the variance of the score scaled from m to n cycles."""
    n, m, bins = 100_000, 10_000, 50
    shape = np.exp(-0.5 * ((np.arange(bins) - 20) / 3.0) ** 2)

    def mean(x):                                  # expected counts of n cycles: a peak on a flat background
        return n * (np.exp(x[0]) * shape / shape.sum() + np.exp(x[1]) / bins)

    x = np.log([0.3, 0.1])
    mu = mean(x)
    jac = np.column_stack([n * 0.3 * shape / shape.sum(), np.full(bins, n * 0.1 / bins)])
    fisher_inv = np.linalg.inv(jac.T @ (jac / mu[:, None]))
    rng = np.random.default_rng(5)
    reps = dispersion * rng.poisson(mu * m / n / dispersion, size=(4000, bins))
    cov = sandwich_covariance(fisher_inv, x, [1e-3, 1e-3], mean, reps, n, m)
    ratio = np.diag(cov) / np.diag(fisher_inv)
    assert ratio == pytest.approx([dispersion, dispersion], rel=0.1)      # 4000 replicates: ≈ 2 % sd


def test_free_running_sandwich_intervals_are_named_and_deterministic_in_the_seed():
    """The sandwich for a free-running fit without afterpulsing (opt in; the default there stays the Fisher
    intervals): the same seed gives the same intervals, the summary names the method."""
    h = draw("free_running", 0.3, 2e6, 100_000, 100e6, 0, dead_time=4e-9)
    kw = dict(bin_width=DT, repetition_rate=100e6, n_cycles=100_000, model="free_running",
              initial={"dead_time": 5e-9})
    fisher = fit_detector(h, **kw)
    a = fit_detector(h, covariance="sandwich", seed=3, **kw)
    b = fit_detector(h, covariance="sandwich", seed=3, **kw)
    assert fisher.settings["covariance"] == "fisher" and a.values == fisher.values
    assert a.errors == b.errors and a.errors != fisher.errors
    assert a.settings["sandwich_replicates"] == 1000 and a.settings["sandwich_cycles"] == 2000
    assert "intervals: sandwich" in a.summary() and "sandwich" not in fisher.summary()
    assert "sandwich covariance" in a.detector_yaml()
    ratio = {k: a.errors[k] / fisher.errors[k] for k in a.errors}
    assert all(0.7 < r < 1.1 for r in ratio.values()), ratio      # dead time: sub-Poissonian bins


@pytest.mark.slow
def test_dead_time_one_period_off_is_named_in_one_line_and_a_datasheet_range_excludes_it():
    """Afterpulsing, 10⁵ cycles: τ = 4 ns and τ + one period (14 ns) fit the histogram within a likelihood ratio
    of 20 (the detection-phase chain depends on τ modulo the period); bounds below one period remove the alias."""
    spec = REGIMES["free_running afterpulsing"]
    h = draw("free_running", spec["signal"], spec["background"], spec["n"], spec["rep"], 0, spec["dead_time"],
             spec["afterpulse"])
    kw = dict(bin_width=DT, repetition_rate=spec["rep"], n_cycles=spec["n"], model="free_running",
              initial={"dead_time": 5e-9}, afterpulse_time_constant=2e-9)
    fit = fit_detector(h, **kw)
    assert fit.messages and len(fit.messages) == 1 and "\n" not in fit.messages[0], fit.messages
    assert fit.messages[0].startswith("dead_time is not identifiable modulo the laser period from this histogram")
    assert "--dead-time-bounds" in fit.messages[0] and not fit.identifiable["dead_time"]
    alias = fit.settings["dead_time_alias"]
    assert sorted([fit.values["dead_time"], alias["dead_time"]]) == pytest.approx([4e-9, 14e-9], rel=0.02)
    assert 0 <= alias["delta_log_likelihood"] < 3.0
    bounded = fit_detector(h, dead_time_bounds=(2e-9, 10e-9), **kw)
    assert bounded.messages == [] and "dead_time_alias" not in bounded.settings
    assert bounded.values["dead_time"] == pytest.approx(4e-9, rel=0.01)


def test_cli_dead_time_bounds_need_two_durations(tmp_path):
    np.savetxt(tmp_path / "h.csv", np.ones(20))
    res = CliRunner().invoke(main, ["fit-detector", str(tmp_path / "h.csv"), "--repetition-rate", "100MHz",
                                    "--n-cycles", "10", "--bin-width", "50ps", "--model", "free_running",
                                    "--dead-time-bounds", "2ns"])
    assert res.exit_code == 2 and "expected LOW,HIGH, got '2ns'" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(main, ["fit-detector", str(tmp_path / "h.csv"), "--repetition-rate", "100MHz",
                                    "--n-cycles", "10", "--bin-width", "50ps", "--dead-time-bounds", "2ns,8ns"])
    assert res.exit_code == 2 and res.output.startswith("error: dead_time_bounds=(2e-09, 8e-09): a dead time is "
                                                        "fitted by model 'free_running' only (got 'pile_up')")
