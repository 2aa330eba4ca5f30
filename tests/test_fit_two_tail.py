"""fit-detector with the two-tail IRF (datagen.spad.fit, datagen.spad.fit_two_tail; docs/detector.md "Two-tail
IRF"): parameters recovered from a histogram drawn from known ones, a histogram too short refused in one line, and
the direct returns of the Stanford LCT release's captures (skipped, saying why, when the files are absent)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from datagen.cli.main import main
from datagen.errors import ConfigError
from datagen.spad import DetectorConfig
from datagen.spad.fit import fit_detector
from datagen.spad.fit_two_tail import TWO_TAIL_MIN_BINS, response_fwhm, two_tail_envelope
from datagen.timing.irf import Irf
from test_orientation import NEEDS_REAL, REAL

PS = 1e-12
TRUE = {"signal": 0.02, "position": 120 * PS, "jitter_sigma": 24 * PS, "tail_weight": 0.25, "tail": 40 * PS,
        "tail2_weight": 0.3, "tail2": 280 * PS, "tail_delay": 30 * PS}


def _synthetic(seed: int = 7, n_bins: int = 500, cycles: int = 2_000_000):
    """A Poisson histogram of the two-tail return of TRUE in 4 ps bins, 5e4 Hz background (pulse sigma 2 ps)."""
    env = two_tail_envelope(n_bins, 4 * PS, TRUE, 2 * PS)
    mu = cycles * (env + 5e4 * 4 * PS)
    return np.random.default_rng(seed).poisson(mu)


def test_synthetic_two_tail_parameters_recovered_within_their_intervals():
    # every fitted parameter's simultaneous 95 % interval holds the value the histogram was drawn from
    h = _synthetic()
    fit = fit_detector(h, bin_width=4 * PS, repetition_rate=10e6, n_cycles=2_000_000, model="poisson",
                       irf="two_tail", pulse_sigma=2 * PS)
    for name, value in {**TRUE, "background_rate": 5e4}.items():
        lo, hi = fit.joint_intervals[name]
        assert lo <= value <= hi, (name, value, lo, hi)
    assert fit.pearson_chi2 / fit.dof < 1.3                       # 490 dof: chi2/dof > 1.3 has p < 1e-5
    assert isinstance(fit.irf_model, Irf) and fit.irf_model.kind == "two_tail"
    assert fit.irf_model.fwhm == pytest.approx(2.3548 * np.hypot(24, 2) * PS, rel=0.05)


def test_two_tail_fit_writes_a_detector_and_irf_yaml(tmp_path):
    h = _synthetic(seed=3)
    path = tmp_path / "h.npy"
    np.save(path, h)
    out = CliRunner().invoke(main, ["fit-detector", str(path), "--bin-width", "4ps", "--repetition-rate", "10MHz",
                                    "--n-cycles", "2000000", "--model", "poisson", "--irf", "two_tail",
                                    "--pulse-sigma", "2ps", "--out", str(tmp_path / "det.yaml")])
    assert out.exit_code == 0, out.output
    assert "core FWHM" in out.output and "chi2/dof" in out.output
    data = yaml.safe_load((tmp_path / "det.yaml").read_text())
    assert set(data) == {"detector", "irf"}
    irf = Irf(**data["irf"])
    assert irf.kind == "two_tail" and irf.tail2 == pytest.approx(TRUE["tail2"], rel=0.15)
    assert DetectorConfig.from_yaml(tmp_path / "det.yaml").model == "poisson"


def test_histogram_too_short_for_two_tails_is_one_line():
    h = _synthetic(n_bins=60)                               # peak near bin 30: 30 bins left for the tails
    with pytest.raises(ConfigError, match=f"at least {TWO_TAIL_MIN_BINS} after the peak") as err:
        fit_detector(h, bin_width=4 * PS, repetition_rate=10e6, n_cycles=2_000_000, model="poisson", irf="two_tail")
    assert "\n" not in str(err.value)


def test_response_fwhm_of_a_gaussian_and_of_a_tailed_response():
    assert response_fwhm(Irf(fwhm="60ps")) == pytest.approx(60 * PS, rel=1e-12)
    ex = Irf(kind="exgaussian", fwhm="60ps", tail="1fs")                  # a negligible tail: the core's FWHM
    assert response_fwhm(ex) == pytest.approx(60 * PS, rel=1e-3)
    two = Irf(kind="two_tail", fwhm="60ps", tail="40ps", tail_weight=0.5, tail2="300ps", tail2_weight=0.2)
    assert response_fwhm(two) > 60 * PS


# ---- the release's direct returns ----------------------------------------------------------------------------

# (capture, block of scan points summed): the charts' shoulder 40-80 ps after the direct peak needs the
# two-tail IRF's delay; an 8 x 8 block of the charts holds so many counts (1e5 per bin at the peak) that the
# shoulder's shape beyond the model shows (chi2/dof 1.8-2.1), a 4 x 4 block fits.
REAL_FITS = [("data_dot_chart_40cm", "30:34,30:34"), ("data_dot_chart_65cm", "30:34,30:34"),
             ("data_s_u", "28:36,28:36")]


def _fit_real(name: str, block: str):
    from datagen.io.lab_formats import read_lab_capture

    data = read_lab_capture(REAL / f"{name}.mat", bin_resolution=4 * PS).data()
    (a0, a1), (b0, b1) = (tuple(int(v) for v in part.split(":")) for part in block.split(","))
    h = np.asarray(data[a0:a1, b0:b1, :300], dtype=np.int64).reshape(-1, 300).sum(0)
    return fit_detector(h, bin_width=4 * PS, repetition_rate=10e6, n_cycles=1_000_000, model="poisson",
                        irf="two_tail", allow_cropped_edge=True)


@NEEDS_REAL
@pytest.mark.parametrize("name, block", REAL_FITS)
def test_two_tail_fits_the_release_direct_returns(name, block):
    """The direct return (bins 0-299, 1.2 ns: the hidden return starts after 2.4 ns) of a block of scan points:
    chi2/dof <= 1.5 (one exponential: 3.5-6.4)."""
    fit = _fit_real(name, block)
    assert fit.pearson_chi2 / fit.dof <= 1.5
    if name == "data_s_u":                                       # the paper's 60 ps system resolution
        assert fit.irf_model.fwhm == pytest.approx(60 * PS, rel=0.10)
