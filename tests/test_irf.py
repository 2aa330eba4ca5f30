"""Tests of datagen.timing.irf: bin integrals of the IRF, fine-grid splatting + FFT, energy conservation (docs/physics.md §5).

Tolerances are stated next to each assertion. "rel" means relative to the total weight (or to the largest
bin where stated).
"""
from __future__ import annotations

import math
import time
import tracemalloc

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import ndtr

from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis, bin_impulses
from datagen.timing.accumulator import MAX_FINE_NODES
from datagen.timing.irf import fwhm_to_sigma, sigma_to_fwhm
from datagen.units import SPEED_OF_LIGHT

PS = 1e-12
NS = 1e-9


def _conservation_error(acc: EnvelopeAccumulator) -> np.ndarray:
    total = acc.total_weight()
    return np.abs(acc.binned().sum(-1) + acc.outside() - total) / total


# --------------------------------------------------------------------------------------------- models


def test_fwhm_sigma_conversion():
    # docs/physics.md §4: FWHM 600 ps <-> sigma ~ 254.8 ps.
    assert fwhm_to_sigma(600 * PS) == pytest.approx(254.80e-12, rel=1e-4)
    assert sigma_to_fwhm(fwhm_to_sigma(123 * PS)) == pytest.approx(123 * PS, rel=1e-15)
    irf = Irf(fwhm="600ps")
    assert irf.sigma == pytest.approx(600 * PS / (2 * math.sqrt(2 * math.log(2))), rel=1e-15)
    assert irf.fwhm == pytest.approx(600 * PS, rel=1e-15)
    assert Irf.model_validate(irf.model_dump()) == irf  # round-trips through its dump
    with pytest.raises(ValueError, match="fwhm"):
        fwhm_to_sigma(-1.0)


def test_time_axis_parses_durations_and_builds_edges():
    axis = TimeAxis(t_start="-1ns", bin_width="20ps", n_bins=100)
    assert axis.t_start == pytest.approx(-1 * NS)
    assert axis.bin_width == pytest.approx(20 * PS)
    assert axis.edges.shape == (101,) and axis.edges.dtype == np.float64
    assert axis.centers.shape == (100,)
    assert axis.t_stop == pytest.approx(1 * NS, rel=1e-12)
    np.testing.assert_allclose(np.diff(axis.edges), 20 * PS, rtol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "field", "value"),
    [
        (dict(t_start=0.0, bin_width=-1, n_bins=10), "bin_width", "-1"),
        (dict(t_start=0.0, bin_width=0.0, n_bins=10), "bin_width", "0.0"),
        (dict(t_start=0.0, bin_width=1e-12, n_bins=0), "n_bins", "0"),
        (dict(t_start=float("nan"), bin_width=1e-12, n_bins=5), "t_start", "nan"),
        (dict(t_start="3 parsecs", bin_width=1e-12, n_bins=5), "t_start", "parsecs"),
        (dict(t_start=0.0, bin_width=1e-12, n_bins=5, width=3), "width", "3"),
    ],
)
def test_invalid_axis_names_field_and_value(kwargs, field, value):
    with pytest.raises(ValueError) as info:
        TimeAxis(**kwargs)
    assert field in str(info.value) and value in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        (dict(), "exactly one of sigma or fwhm"),
        (dict(sigma=1e-12, fwhm=2e-12), "exactly one of sigma or fwhm"),
        (dict(sigma=-1e-12), "sigma"),
        (dict(fwhm="-600ps"), "fwhm"),
        (dict(sigma=1e-12, tail=5e-11), "tail"),
        (dict(sigma=1e-12, kind="exgaussian"), "tail"),
        (dict(sigma=0.0, kind="exgaussian", tail=5e-11), "sigma"),
        (dict(sigma=1e-12, kind="lorentzian"), "kind"),
    ],
)
def test_invalid_irf_rejected(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        Irf(**kwargs)


# ----------------------------------------------------------------------------------- exact reference


def test_bin_impulses_matches_quadrature_of_density():
    # Independent check of the erf-difference formula: Simpson-free adaptive quadrature of the density.
    axis = TimeAxis(t_start=0.0, bin_width=30 * PS, n_bins=40)
    irf = Irf(sigma=45 * PS)
    tau, w = 0.5 * NS + 7 * PS, 2.5
    got = bin_impulses([tau], [w], axis, irf)
    pdf = lambda t: w * math.exp(-0.5 * ((t - tau) / irf.sigma) ** 2) / (irf.sigma * math.sqrt(2 * math.pi))
    e = axis.edges
    want = np.array([quad(pdf, e[b], e[b + 1], epsabs=0, epsrel=1e-12)[0] for b in range(axis.n_bins)])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-14 * w)


def test_tail_bins_keep_relative_accuracy():
    # A 1-sigma-wide bin starting 20..35 sigma from the impulse: Phi(b) - Phi(a) cancels to exactly 0 in
    # float64, the survival-function difference keeps ~1e-12 relative accuracy. Reference: quadrature of
    # phi(a) * int_0^{b-a} exp(-a y - y^2/2) dy, which is O(1)-scaled.
    sigma = 10 * PS
    irf = Irf(sigma=sigma)
    for a in (20.0, 27.0, 35.0):
        b = a + 1.0
        ref = math.exp(-0.5 * a * a) / math.sqrt(2 * math.pi) * quad(
            lambda y: math.exp(-a * y - 0.5 * y * y), 0.0, b - a, epsabs=0, epsrel=1e-13
        )[0]
        assert ndtr(b) - ndtr(a) == 0.0  # the naive form loses it entirely
        right = irf.interval_mass(a * sigma, b * sigma)
        left = irf.interval_mass(-b * sigma, -a * sigma)
        assert right == pytest.approx(ref, rel=1e-10)
        assert left == pytest.approx(ref, rel=1e-10)
        axis = TimeAxis(t_start=a * sigma, bin_width=sigma, n_bins=1)
        assert bin_impulses([0.0], [1.0], axis, irf)[0] == pytest.approx(ref, rel=1e-10)


# ------------------------------------------------------------------------------- energy conservation


def test_narrow_irf_conserves_energy_and_fills_own_bin():
    # sigma = 1 ps << bin = 100 ps. Each impulse (>= 10 ps = 10 sigma from an edge) must put its whole
    # weight in the bin that contains it; Phi(-10) ~ 8e-24, so to 1e-12 relative.
    axis = TimeAxis(t_start=0.0, bin_width=100 * PS, n_bins=50)
    irf = Irf(sigma=1 * PS)
    rng = np.random.default_rng(11)
    n = 40
    bins = rng.integers(0, axis.n_bins, n)
    tau = axis.edges[bins] + rng.uniform(10 * PS, 90 * PS, n)
    w = rng.uniform(0.1, 3.0, n)
    acc = EnvelopeAccumulator(axis, irf, n_components=n)
    acc.add(tau, w, np.arange(n))
    out = acc.binned()
    np.testing.assert_allclose(out[np.arange(n), bins], w, rtol=1e-12)
    assert np.all(out.sum(-1) - out[np.arange(n), bins] <= 1e-12 * w)
    assert np.all(_conservation_error(acc) <= 1e-12)

    # Whole set in one component, including impulses before, across and after the window edges.
    acc1 = EnvelopeAccumulator(axis, irf, n_components=1)
    t_all = rng.uniform(-0.5 * NS, 5.5 * NS, 5000)
    t_all[:4] = [0.0, 1 * PS, axis.t_stop - 0.5 * PS, axis.t_stop]  # on / near the edges
    w_all = rng.exponential(1.0, t_all.size)
    acc1.add(t_all, w_all)
    assert _conservation_error(acc1)[0] <= 1e-12
    # Naive sampling of the density at bin centres loses or invents energy per impulse (docs/physics.md §5):
    # an impulse 40 ps from the centre gets ~exp(-800) of its weight, one 0.1 ps from it 40x its weight.
    centre = axis.centers[7]
    for offset, lo, hi in ((40 * PS, 0.0, 1e-300), (0.1 * PS, 39.0, 40.0)):
        naive = axis.bin_width * np.exp(-0.5 * ((axis.centers - centre - offset) / irf.sigma) ** 2).sum()
        naive /= irf.sigma * math.sqrt(2 * math.pi)
        assert lo <= naive <= hi
        assert bin_impulses([centre + offset], [1.0], axis, irf).sum() == pytest.approx(1.0, rel=1e-12)


def test_wide_irf_conserves_energy_and_matches_reference():
    # sigma = 1 ns >> bin = 10 ps: impulses scattered well beyond the 5 ns window on both sides.
    axis = TimeAxis(t_start=0.0, bin_width=10 * PS, n_bins=500)
    irf = Irf(sigma=1 * NS)
    rng = np.random.default_rng(12)
    tau = rng.uniform(-12 * NS, 17 * NS, 3000)
    w = rng.uniform(0.0, 2.0, tau.size)
    acc = EnvelopeAccumulator(axis, irf, n_components=1)
    assert acc.oversample == 1  # fine step 10 ps <= sigma / 4
    acc.add(tau, w)
    assert _conservation_error(acc)[0] <= 1e-12
    assert acc.outside()[0] > 0.3 * acc.total_weight()[0]
    ref = bin_impulses(tau, w, axis, irf)
    # (delta/sigma)^2 = 1e-4, times the measured 0.115 constant -> ~1e-5 worst case relative to the max.
    np.testing.assert_allclose(acc.binned()[0], ref, rtol=0, atol=2e-5 * ref.max())


def test_sigma_much_larger_than_window_gives_analytic_mass():
    # sigma = 10 ns, window 200 ps: the inside mass of each impulse is Phi((t1-tau)/s) - Phi((t0-tau)/s).
    axis = TimeAxis(t_start="1ns", bin_width="10ps", n_bins=20)
    irf = Irf(sigma="10ns")
    tau = np.array([1.1 * NS, -25 * NS, 30 * NS, 1.0 * NS, 1.234567 * NS])
    w = np.array([1.0, 2.0, 0.5, 3.0, 1.5])
    acc = EnvelopeAccumulator(axis, irf, n_components=1)
    acc.add(tau, w)
    s = irf.sigma
    analytic = float(np.sum(w * (ndtr((axis.t_stop - tau) / s) - ndtr((axis.t_start - tau) / s))))
    # Off-node impulses: linear-splatting error ~ (delta/sigma)^2 = 1e-6 relative (measured 8.5e-8).
    assert acc.binned().sum() == pytest.approx(analytic, rel=1e-6)
    assert _conservation_error(acc)[0] <= 1e-12
    # On fine nodes the result is exact: same check to 1e-12.
    on_nodes = EnvelopeAccumulator(axis, irf, n_components=1)
    nodes = on_nodes.fine_times[[0, 5000, on_nodes.n_left + 3, on_nodes.n_fine - 1]]
    on_nodes.add(nodes, w[:4])
    analytic = float(np.sum(w[:4] * (ndtr((axis.t_stop - nodes) / s) - ndtr((axis.t_start - nodes) / s))))
    assert on_nodes.binned().sum() == pytest.approx(analytic, rel=1e-12)
    assert _conservation_error(on_nodes)[0] <= 1e-12


# ---------------------------------------------------------------------------- splatting error vs step


def test_splatting_error_falls_as_step_over_sigma_squared():
    """Accumulator vs exact per-impulse erf differences, impulses at random (non-node) times.

    64 single impulses (one per component), sigma = bin = 40 ps. Error metric: max over bins and impulses
    of |acc - exact| / max(exact) for that impulse. Measured (seed 7):
        oversample  delta/sigma  max error   error/(delta/sigma)^2
           1          1          8.5e-2        0.085
           2          1/2        2.8e-2        0.113
           4          1/4        7.2e-3        0.115
           8          1/8        1.8e-3        0.115
          16          1/16       4.5e-4        0.115
    i.e. ~ (delta/sigma)^2 / 8.7: linear splatting adds variance u(1-u) delta^2 <= delta^2/4, so the peak
    drops by at most delta^2/(8 sigma^2). Asserted: error <= 0.125 (delta/sigma)^2 and each halving of the
    step divides the error by 3.5..4.5 (for delta <= sigma/2).
    """
    sigma = 40 * PS
    axis = TimeAxis(t_start=0.0, bin_width=40 * PS, n_bins=100)
    irf = Irf(sigma=sigma)
    rng = np.random.default_rng(7)
    n = 64
    tau = rng.uniform(1 * NS, 3 * NS, n)
    w = rng.uniform(0.5, 1.5, n)
    exact = np.stack([bin_impulses(tau[i : i + 1], w[i : i + 1], axis, irf) for i in range(n)])
    errors = {}
    for oversample in (1, 2, 4, 8, 16):
        acc = EnvelopeAccumulator(axis, irf, n_components=n, oversample=oversample)
        acc.add(tau, w, np.arange(n))
        errors[oversample] = float((np.abs(acc.binned() - exact).max(1) / exact.max(1)).max())
        ratio = axis.bin_width / oversample / sigma
        assert errors[oversample] <= 0.125 * ratio**2, (oversample, errors[oversample])
    for o in (2, 4, 8):
        assert 3.5 <= errors[o] / errors[2 * o] <= 4.5, errors
    # Default oversample targets fine_step <= sigma / 4, i.e. <= 0.8 % worst-case single-impulse error.
    assert EnvelopeAccumulator.default_oversample(axis, irf) == 4
    assert errors[4] < 8e-3

    # Impulses exactly on fine nodes are binned exactly (to float round-off).
    acc = EnvelopeAccumulator(axis, irf, n_components=1, oversample=4)
    nodes = acc.fine_times[rng.integers(acc.n_left, acc.n_left + acc.n_cells, 50)]
    acc.add(nodes, w[:50])
    ref = bin_impulses(nodes, w[:50], axis, irf)
    np.testing.assert_allclose(acc.binned()[0], ref, rtol=0, atol=1e-13 * ref.max())


def test_single_impulse_mean_time_preserved():
    # sigma = 50 ps, bin = 10 ps: the first moment over bin centres equals tau (+ tail for the
    # ex-Gaussian) to 1e-3 of the fine step (linear splatting and the convolution preserve it exactly;
    # the midpoint rule's error cancels for an envelope well inside the window).
    axis = TimeAxis(t_start=0.0, bin_width=10 * PS, n_bins=600)
    rng = np.random.default_rng(3)
    for irf in (Irf(sigma=50 * PS), Irf(sigma=50 * PS, kind="exgaussian", tail=30 * PS)):
        acc = EnvelopeAccumulator(axis, irf, n_components=1)
        tau = 1.5 * NS + rng.uniform(0, 10 * PS)
        acc.add([tau], [1.0])
        env = acc.binned()[0]
        mean = float(env @ axis.centers / env.sum())
        assert abs(mean - (tau + irf.mean)) <= 1e-3 * acc.fine_step, (irf.kind, mean - tau - irf.mean)
        assert _conservation_error(acc)[0] <= 1e-12


# -------------------------------------------------------------------------------- special cases


def test_delta_irf_bins_by_membership():
    axis = TimeAxis(t_start="-100ps", bin_width="25ps", n_bins=80)
    irf = Irf(sigma=0.0)
    rng = np.random.default_rng(5)
    tau = rng.uniform(-0.3 * NS, 2.1 * NS, 2000)
    w = rng.uniform(0.0, 1.0, tau.size)
    acc = EnvelopeAccumulator(axis, irf, n_components=1)
    assert acc.oversample == 1 and acc.n_fine == axis.n_bins
    acc.add(tau, w)
    hist, _ = np.histogram(tau, bins=axis.edges, weights=w)
    np.testing.assert_allclose(acc.binned()[0], hist, rtol=1e-12)
    np.testing.assert_allclose(bin_impulses(tau, w, axis, irf), hist, rtol=1e-12)
    inside = (tau >= axis.t_start) & (tau < axis.t_stop)
    assert acc.outside()[0] == pytest.approx(w[~inside].sum(), rel=1e-12)
    assert _conservation_error(acc)[0] <= 1e-12


def test_non_finite_and_negative_inputs_rejected_without_side_effects():
    axis = TimeAxis(t_start=0.0, bin_width=10 * PS, n_bins=10)
    irf = Irf(sigma=5 * PS)
    acc = EnvelopeAccumulator(axis, irf, n_components=2)
    acc.add([20 * PS], [1.0], 0)
    before = acc.fine_histogram()
    with pytest.raises(ValueError, match=r"times contain 1 non-finite.*index 2"):
        acc.add([1e-11, 2e-11, np.nan], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"weights contain 1 non-finite.*index 0"):
        acc.add([1e-11, 2e-11], [np.inf, 1.0])
    with pytest.raises(ValueError, match=r"weights must be >= 0"):
        acc.add([1e-11], [-1.0])
    with pytest.raises(ValueError, match="component"):
        acc.add([1e-11], [1.0], 2)
    with pytest.raises(ValueError, match="component"):
        acc.add([1e-11, 2e-11], [1.0, 1.0], np.array([0, 5]))
    with pytest.raises(ValueError, match="same length"):
        acc.add([1e-11, 2e-11], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="times contain"):
        bin_impulses([np.nan], [1.0], axis, irf)
    np.testing.assert_array_equal(acc.fine_histogram(), before)
    assert acc.total_weight().tolist() == [1.0, 0.0]
    # Zero weights are ignored; empty input is a no-op.
    acc.add([30 * PS, 40 * PS], [0.0, 0.0], 1)
    acc.add([], [])
    assert acc.total_weight().tolist() == [1.0, 0.0]


def test_components_kept_separate_and_sum_to_single():
    axis = TimeAxis(t_start=0.0, bin_width=20 * PS, n_bins=300)
    irf = Irf(fwhm="120ps")
    rng = np.random.default_rng(9)
    tau = rng.normal(3 * NS, 1 * NS, 20000)
    w = rng.exponential(1e-3, tau.size)
    comp = rng.integers(0, 4, tau.size)
    multi = EnvelopeAccumulator(axis, irf, n_components=4)
    multi.add(tau, w, comp)
    single = EnvelopeAccumulator(axis, irf, n_components=1)
    single.add(tau, w)
    out = multi.binned()
    for k in range(4):
        alone = EnvelopeAccumulator(axis, irf, n_components=1)
        alone.add(tau[comp == k], w[comp == k])
        np.testing.assert_allclose(out[k], alone.binned()[0], rtol=0, atol=1e-13 * out[k].max())
        assert multi.total_weight()[k] == pytest.approx(w[comp == k].sum(), rel=1e-13)
    np.testing.assert_allclose(out.sum(0), single.binned()[0], rtol=0, atol=1e-13 * out.sum(0).max())
    np.testing.assert_allclose(multi.outside().sum(), single.outside()[0], rtol=1e-12)
    assert np.all(_conservation_error(multi) <= 1e-12)


@pytest.mark.parametrize("irf, n_bins, n_tau, tau_stop, seed, e_stop", [
    # SPAD jitter: 40 ps FWHM core + 50 ps diffusion tail (docs/physics.md §5), 4 ps TDC bins
    (Irf(fwhm="40ps", kind="exgaussian", tail="50ps"), 1000, 400, 4.2 * NS, 4, 3 * NS),
    # the real SPAD's two tails (docs/detector.md "Two-tail IRF")
    (Irf(kind="two_tail", fwhm="60ps", tail="40ps", tail_weight=0.3, tail2="300ps", tail2_weight=0.2,
         tail_delay="50ps"), 1500, 300, 5 * NS, 70, 15 * NS),
], ids=["exgaussian", "two_tail"])
def test_a_tailed_irf_bins_as_the_exact_reference_and_conserves(irf, n_bins, n_tau, tau_stop, seed, e_stop):
    axis = TimeAxis(t_start=0.0, bin_width=4 * PS, n_bins=n_bins)
    e = np.linspace(-0.5 * NS, e_stop, 4001)
    assert irf.interval_mass(e[:-1], e[1:]).sum() == pytest.approx(1.0, rel=1e-13)
    rng = np.random.default_rng(seed)
    tau = rng.uniform(-0.5 * NS, tau_stop, n_tau)
    w = rng.uniform(0, 1, tau.size)
    acc = EnvelopeAccumulator(axis, irf, n_components=1)
    acc.add(tau, w)
    ref = bin_impulses(tau, w, axis, irf)
    ratio = acc.fine_step / irf.sigma                    # linear splatting: error ~ (fine step / sigma)² / 8
    np.testing.assert_allclose(acc.binned()[0], ref, rtol=0, atol=0.125 * ratio**2 * ref.max())
    assert _conservation_error(acc)[0] <= 1e-12


def test_fine_grid_cap_names_axis():
    axis = TimeAxis(t_start=0.0, bin_width=4 * PS, n_bins=2_000_000)
    with pytest.raises(ValueError, match=r"fine grid too large.*n_bins=2000000.*sigma"):
        # sigma = 0.5 ps: support 4.25 ps > one 4 ps bin, so the fine grid (oversample 32) is needed; a narrower
        # IRF would use the exact direct mode (one node per bin) and fit easily.
        EnvelopeAccumulator(axis, Irf(sigma=0.5 * PS), n_components=1)
    assert MAX_FINE_NODES >= 1 << 24


# ------------------------------------------------------------------------------------------ memory


def test_corridor_memory_bounded_by_bins_not_paths():
    # 1 km corridor: 2 km round trip ~ 6.7 us; 4 ps bins -> ~1.67 million bins; FWHM 600 ps IRF.
    # 10^7 impulses in chunks of 10^6 over 4 components. Memory: the histogram is 4 x n_fine float64
    # (~54 MB); one add() of 4*10^6 impulses must not allocate more than 32 MB beyond its inputs
    # (internal chunking), and the whole run conserves energy to 1e-12 and stays within seconds.
    t_range = 2 * 1000.0 / SPEED_OF_LIGHT
    axis = TimeAxis(t_start=0.0, bin_width=4 * PS, n_bins=int(math.ceil(t_range / (4 * PS))))
    assert 1_600_000 < axis.n_bins < 1_700_000
    irf = Irf(fwhm="600ps")
    acc = EnvelopeAccumulator(axis, irf, n_components=4)
    assert acc.oversample == 1
    rng = np.random.default_rng(2024)
    start = time.perf_counter()
    for _ in range(10):
        tau = rng.uniform(-1 * NS, axis.t_stop + 1 * NS, 1_000_000)
        w = rng.exponential(1e-6, tau.size)
        acc.add(tau, w, rng.integers(0, 4, tau.size, dtype=np.int32))
    tau = rng.uniform(0, axis.t_stop, 4_000_000)
    w = rng.exponential(1e-6, tau.size)
    tracemalloc.start()
    acc.add(tau, w, 3)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 32e6, peak
    out = acc.binned()
    assert out.shape == (4, axis.n_bins) and out.dtype == np.float64 and np.all(out >= 0)
    assert np.all(_conservation_error(acc) <= 1e-12)
    assert time.perf_counter() - start < 10.0


def test_pickled_accumulator_keeps_numpys_cached_dtypes_and_its_sums():
    """A partial accumulator sent through pickle (a replica in a worker process) comes back with numpy's cached
    dtype objects: an unpickled array otherwise carries a fresh dtype instance and np.add.at leaves its fast path
    (numpy/numpy#32298; 80× slower per call). Its sums are unchanged: the same impulses added before and after the
    round trip give bit-identical envelopes."""
    import pickle

    axis, irf = TimeAxis(t_start=0.0, bin_width=100 * PS, n_bins=64), Irf(fwhm="150ps")
    rng = np.random.default_rng(3)
    t, w = rng.uniform(0, 6.4 * NS, 5000), rng.uniform(0, 1, 5000)
    ref = EnvelopeAccumulator(axis, irf, n_components=2)
    ref.add(t, w, component=1)
    ref.add(t[::-1], w, component=0)
    acc = pickle.loads(pickle.dumps(EnvelopeAccumulator(axis, irf, n_components=2)))
    arrays = [v for v in vars(acc).values() if isinstance(v, np.ndarray)]
    assert arrays and all(a.dtype is np.dtype(a.dtype.str) for a in arrays)
    acc.add(t, w, component=1)
    back = pickle.loads(pickle.dumps(acc))
    back.add(t[::-1], w, component=0)
    assert np.array_equal(back.binned(), ref.binned())


@pytest.mark.parametrize("irf", [Irf(fwhm=70e-12), Irf(fwhm=0.0)], ids=["gaussian", "delta"])
def test_compiled_splat_equals_numpy_cloud_in_cell(irf):
    """EnvelopeAccumulator.add's compiled splat (timing/splat_kernel.py) against the cloud-in-cell written with
    numpy (node x = (t − t_start)/δ + n_left − ½, weights (1 − frac, frac) on ⌊x⌋, ⌊x⌋ + 1, or the containing cell
    for the delta IRF; np.add.at): the same histogram bit for bit, totals and beyond to 1e-15, for impulses inside,
    at both ends and far outside the grid, zero weights, one component id and an array of them."""
    axis = TimeAxis(t_start=1e-9, bin_width=16e-12, n_bins=64)
    rng = np.random.default_rng(3)
    n = 5000
    t = axis.t_start + rng.uniform(-0.3, 1.3, n) * axis.n_bins * axis.bin_width
    t[:4] = [axis.t_start - 1.0, axis.t_start + 1.0, axis.t_start, axis.t_start + axis.n_bins * axis.bin_width]
    w = rng.random(n) * (rng.random(n) < 0.9)
    comp = rng.integers(0, 3, n)
    for c in (comp, 2):
        acc = EnvelopeAccumulator(axis, irf, 3)
        acc.add(t, w, c)
        cc = np.broadcast_to(c, n)
        hist, beyond = np.zeros((3, acc.n_fine)), np.zeros(3)
        if irf.is_delta:
            g = np.floor((t - axis.t_start) / acc.fine_step) + acc.n_left
            inside = (g >= 0) & (g < acc.n_fine)
            np.add.at(hist, (cc[inside], g[inside].astype(int)), w[inside])
        else:
            x = (t - axis.t_start) / acc.fine_step + (acc.n_left - 0.5)
            inside = (x >= 0) & (x <= acc.n_fine - 1)
            i = np.minimum(np.floor(x[inside]), acc.n_fine - 2).astype(int)
            right = w[inside] * (x[inside] - i)
            np.add.at(hist, (cc[inside], i), w[inside] - right)
            np.add.at(hist, (cc[inside], i + 1), right)
        np.add.at(beyond, cc[~inside], w[~inside])
        assert 0 < (~inside & (w > 0)).sum() < n // 2
        np.testing.assert_array_equal(acc.fine_histogram(), hist)
        np.testing.assert_allclose(acc.total_weight(), np.bincount(cc, weights=w, minlength=3), rtol=1e-15, atol=0)
        np.testing.assert_allclose(acc.total_weight() - hist.sum(axis=1), beyond, rtol=1e-12, atol=0)


def test_gated_window_round_off_is_not_an_error():
    """A window that starts after most of the light (a 15 ns gate: the returns before it sit in the fine grid's
    guard nodes) keeps the FFT round-off of those returns, ~1e-16 of them, in its bins. That is not a negative
    envelope: binned() clamps it and keeps the in-window return (issue 28: the lookin smoke config died here)."""
    axis = TimeAxis(t_start="15ns", bin_width="200ps", n_bins=256)
    irf = Irf(fwhm="600ps")
    acc = EnvelopeAccumulator(axis, irf, n_components=1)
    rng = np.random.default_rng(5)
    before = 15 * NS - rng.uniform(1.9, 2.15, 400) * NS         # in the fine grid, the IRF tail ~1e-14 at 15 ns
    acc.add(before, rng.uniform(0.5, 1.0, before.size))
    acc.add(np.array([40 * NS]), np.array([1e-9]))              # the only return inside the window
    out = acc.binned()[0]
    assert out.min() >= 0.0
    peak = int(np.argmax(out[50:])) + 50
    assert axis.edges[peak] <= 40 * NS < axis.edges[peak + 1] + 0.3 * NS
    np.testing.assert_allclose(out[60:].sum(), 1e-9, rtol=1e-3)   # its mass; round-off of the gated light ~1e-14
    assert np.all(_conservation_error(acc) <= 1e-12)
