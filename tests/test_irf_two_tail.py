"""The two-tail IRF (datagen.timing.irf, docs/detector.md "Two-tail IRF"): a Gaussian core plus two exponential
tails, delayed alike, as a mixture of a Gaussian and two ex-Gaussians. Checked against closed forms and quadrature:
unit area, its CDF, mean and variance, the tents' closed form, and binning by the accumulator."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid, quad

from datagen.timing import Irf
from datagen.timing.tents import tent_irf_cdf

PS = 1e-12
NS = 1e-9

IRF = Irf(kind="two_tail", fwhm="60ps", tail="40ps", tail_weight=0.3, tail2="300ps", tail2_weight=0.2,
          tail_delay="50ps")


def test_unit_area_and_cdf_closed_form_against_quadrature_of_the_density():
    # the density integrates to 1 (quadrature to 1e-10) and its closed-form CDF is the running integral of it
    area, _ = quad(IRF.pdf, -1 * NS, 30 * NS, points=[0.0, 50 * PS, 0.3 * NS], limit=400)
    assert area == pytest.approx(1.0, abs=1e-10)
    x = np.linspace(-0.3 * NS, 15 * NS, 600_001)
    running = cumulative_trapezoid(IRF.pdf(x), x, initial=0.0) + float(IRF.cdf(x[0]))
    # trapezoid error dx²/12 · ∫|h''| ≈ (0.026 ps)²/12 · 2/sigma² ≈ 8e-8
    np.testing.assert_allclose(IRF.cdf(x), running, rtol=0, atol=2e-7)
    np.testing.assert_allclose(IRF.cdf(x) + IRF.sf(x), 1.0, rtol=0, atol=1e-15)
    e = np.linspace(-1 * NS, 20 * NS, 5001)
    assert IRF.interval_mass(e[:-1], e[1:]).sum() == pytest.approx(1.0, abs=1e-13)


def test_mean_and_variance_closed_forms():
    # mean (a1 + a2) d + a1 tau1 + a2 tau2; variance from the components' second moments (Irf.variance)
    a1, a2, t1, t2, d, s = 0.3, 0.2, 40 * PS, 300 * PS, 50 * PS, IRF.sigma
    mean = (a1 + a2) * d + a1 * t1 + a2 * t2
    second = s * s + a1 * ((d + t1) ** 2 + t1 ** 2) + a2 * ((d + t2) ** 2 + t2 ** 2)
    assert IRF.mean == pytest.approx(mean, rel=1e-14)
    assert IRF.variance == pytest.approx(second - mean * mean, rel=1e-14)
    m1, _ = quad(lambda x: x * IRF.pdf(x), -1 * NS, 30 * NS, points=[0.0, 50 * PS, 0.3 * NS], limit=400)
    m2, _ = quad(lambda x: (x - mean) ** 2 * IRF.pdf(x), -1 * NS, 30 * NS, points=[0.0, 50 * PS, 0.3 * NS],
                 limit=400)
    assert m1 == pytest.approx(mean, rel=1e-8)
    assert m2 == pytest.approx(IRF.variance, rel=1e-8)


def test_one_undelayed_tail_of_weight_one_is_the_ex_gaussian():
    two = Irf(kind="two_tail", sigma="20ps", tail="50ps", tail_weight=1.0, tail2="1ns", tail2_weight=0.0)
    ex = Irf(kind="exgaussian", sigma="20ps", tail="50ps")
    x = np.linspace(-0.2 * NS, 2 * NS, 1001)
    np.testing.assert_allclose(two.cdf(x), ex.cdf(x), rtol=1e-15, atol=1e-300)
    np.testing.assert_allclose(two.sf(x), ex.sf(x), rtol=1e-15, atol=1e-300)
    assert two.mean == pytest.approx(ex.mean, rel=1e-15)
    assert two.variance == pytest.approx(20e-12 ** 2 + 50e-12 ** 2, rel=1e-12)


def test_other_kinds_dump_as_before():
    # the frozen suites' configs: a Gaussian or an ex-Gaussian IRF dumps the same keys as before the two-tail kind
    assert Irf(fwhm="600ps").model_dump().keys() == {"sigma", "kind", "tail"}
    assert Irf(sigma="20ps", kind="exgaussian", tail="5ps").model_dump().keys() == {"sigma", "kind", "tail"}
    assert Irf.model_validate(IRF.model_dump()) == IRF


@pytest.mark.parametrize("kwargs, needle", [
    ({"kind": "two_tail", "sigma": 1e-11, "tail": 1e-11, "tail_weight": 0.7, "tail2": 1e-10, "tail2_weight": 0.4},
     "tail_weight + tail2_weight <= 1"),
    ({"kind": "two_tail", "sigma": 1e-11, "tail": 1e-11, "tail_weight": 0.3, "tail2_weight": 0.2}, "tail2 > 0"),
    ({"kind": "two_tail", "sigma": 1e-11, "tail": 1e-11, "tail_weight": 0.3, "tail2": 1e-10}, "tail2_weight"),
    ({"kind": "two_tail", "sigma": 0.0, "tail": 1e-11, "tail_weight": 0.3, "tail2": 1e-10, "tail2_weight": 0.1},
     "sigma > 0"),
    ({"sigma": 1e-11, "tail2": 1e-10}, "tail2 is only used by kind='two_tail'"),
    ({"kind": "exgaussian", "sigma": 1e-11, "tail": 1e-11, "tail_delay": 1e-11}, "tail_delay is only used"),
    ({"kind": "two_tail", "sigma": 1e-11, "tail": 1e-11, "tail_weight": -0.1, "tail2": 1e-10, "tail2_weight": 0.1},
     "tail_weight"),
])
def test_invalid_two_tail_is_one_line_naming_the_field(kwargs, needle):
    with pytest.raises(ValueError, match=needle.replace("+", r"\+")):
        Irf(**kwargs)


def test_tent_closed_form_matches_quadrature():
    # P(T + X < e) for a tent T: the closed form (partial moments of the mixture) against ∫ tent(t) F_X(e - t) dt
    t0, t1, t2 = 0.1 * NS, 0.16 * NS, 0.4 * NS
    e = np.linspace(0.0, 3 * NS, 61)
    closed = tent_irf_cdf(IRF, e, np.full_like(e, t0), np.full_like(e, t1), np.full_like(e, t2))

    def tent(t):
        return np.where(t < t1, (t - t0) / (t1 - t0), (t2 - t) / (t2 - t1)) * 2 / (t2 - t0)

    ref = [quad(lambda t: tent(t) * IRF.cdf(v - t), t0, t2, points=[t1], limit=200)[0] for v in e]
    np.testing.assert_allclose(closed, ref, rtol=0, atol=1e-10)
