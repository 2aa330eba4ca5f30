"""The hidden-count ratio of one object at two distances with the direct light's slow tail taken out
(datagen.analysis.hidden_ratio; docs/real.md, "The set-up fitted on the dot charts").

Synthetic captures of known parts: a direct return (a 60 ps core and a 600 ps exponential tail, the same shape in
both), a hidden return at each distance (a rise at its round trip and a 400 ps decay) and a flat floor, different in
each. The true ratio is that of the two hidden returns over the release's window; the release's measure, which
counts the direct tail too, misses it.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import NEEDS_REAL, REAL

from datagen.analysis.hidden_ratio import WINDOW, hidden_count_ratio

BIN = 4e-12
T = (np.arange(2048) + 0.5) * BIN
C = 299_792_458.0


def direct(total: float) -> np.ndarray:
    shape = np.exp(-T / 30e-12) + 2e-3 * np.exp(-T / 600e-12)
    return total * shape / shape.sum()


def hidden(depth: float, total: float) -> np.ndarray:
    t0 = 2 * depth / C
    shape = np.where(T > t0, (1 - np.exp(-(T - t0) / 40e-12)) * np.exp(-(T - t0) / 400e-12), 0.0)
    return total * shape / shape.sum()


def captures(rng=None):
    h40, h65 = hidden(0.40, 3.3e6), hidden(0.65, 1.75e6)
    near = direct(2.3e8) + h40 + 1500.0
    far = direct(2.4e8) + h65 + 950.0
    if rng is not None:
        near, far = rng.poisson(near).astype(float), rng.poisson(far).astype(float)
    truth = h40[WINDOW[0]:WINDOW[1]].sum() / h65[WINDOW[0]:WINDOW[1]].sum()
    return near, far, truth


def test_the_ratio_of_the_hidden_light_alone_is_recovered_where_the_release_measure_counts_the_direct_tail():
    near, far, truth = captures()
    onset = int(2 * 0.60 / C / BIN)
    r = hidden_count_ratio(near, far, onset)
    assert r.hidden == pytest.approx(truth, rel=2e-3)
    assert r.hidden_range[0] <= r.hidden <= r.hidden_range[1] + 1e-12
    assert r.hidden_range[1] / r.hidden_range[0] - 1 < 0.01
    assert r.tau == pytest.approx(600e-12, rel=0.02)
    assert r.shape_check == pytest.approx(1.0, abs=3e-3)  # the far floor holds the last 3e-4 of its hidden tail
    assert abs(r.release / truth - 1) > 0.03          # the release's measure is off by the tail: 4–9 % of the windows
    assert 0.03 < r.tail_share[0] < r.tail_share[1] < 0.12
    # with counting noise (seeded): within 0.5 %
    noisy = hidden_count_ratio(*captures(np.random.default_rng(7))[:2], onset)
    assert noisy.hidden == pytest.approx(truth, rel=5e-3)


def test_bad_input_gives_one_line():
    near, far, _ = captures()
    with pytest.raises(ValueError, match="far_onset 700 outside"):
        hidden_count_ratio(near, far, 700)
    with pytest.raises(ValueError, match="2048 bins"):
        hidden_count_ratio(near[:1000], far[:1000], 1000)


@NEEDS_REAL
def test_the_release_charts_hidden_light_is_1_87_apart_once_the_direct_tail_is_out():
    from datagen.io.lab_formats import read_lab_capture

    summed = [read_lab_capture(REAL / f"data_dot_chart_{d}cm.mat", bin_resolution=4e-12).data().sum(axis=(0, 1))
              for d in (40, 65)]
    r = hidden_count_ratio(*summed, far_onset=1000)
    assert r.release == pytest.approx(1.787, abs=0.001)
    assert r.hidden == pytest.approx(1.867, abs=0.002)
    assert r.hidden_range[1] - r.hidden_range[0] < 0.003
    assert r.shape_check == pytest.approx(1.0, abs=0.005)
