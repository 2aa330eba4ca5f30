"""The demonstration room shows what the paper reports where it is geometry (docs/physics.md §3, §4)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

import datagen

SMOOTH_NS = 1.0
"""Gaussian smoothing (σ, ns) before locating a broad peak: at 10×10 lookins a plateau has several local
maxima within a few per cent of each other, and the raw argmax jumps between them."""


@pytest.fixture(scope="module")
def scene():
    return datagen.load_scene("scene_library/demo_room.yaml")


@pytest.fixture(scope="module")
def full(scene):
    return datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "10x10", "pixels": "60x60",
                                                                  "secondary": "full"}))


@pytest.fixture(scope="module")
def optimized(scene):
    return datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "10x10", "pixels": "60x60",
                                                                  "secondary": "optimized"}))


def smooth_peak(result, y):
    dt_ns = (result.time_edges[1] - result.time_edges[0]) * 1e9
    return float(result.time_centers[np.argmax(gaussian_filter1d(y, SMOOTH_NS / dt_ns))] * 1e9)


def test_returns_peak_where_the_paper_reports(full):
    # paper: box 24.9 ns, room 25.6 ns, pillar 35.3 ns (FoV→sensor leg included); 10×10 sampling is coarse
    assert full.peak_time("box") * 1e9 == pytest.approx(24.9, abs=1.0)
    assert full.peak_time("room") * 1e9 == pytest.approx(25.6, abs=1.0)
    assert full.peak_time("pillar") * 1e9 == pytest.approx(35.3, abs=1.0)


def test_box_earlier_and_stronger_than_pillar(scene, full):
    assert full.peak_time("box") < full.peak_time("pillar") - 5e-9
    # At 10×10 lookins the pillar is hit by one or two lookins (its area varies 0–3× between seeds), so the
    # strength ratio is checked on a denser primary-only run: measured 14–19× in area, 19–22× in peak
    # over seeds 0–2 at 30×30×30×30.
    dense = datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "30x30", "pixels": "30x30",
                                                                   "secondary": "none"}))
    assert dense.area("box") > 10 * dense.area("pillar")
    assert dense.components["box"].max() > 10 * dense.components["pillar"].max()


def test_extended_surfaces_dominate(full):
    primary = sum(full.area(n) for n in ("room", "box", "pillar"))
    assert full.area("room") > 0.8 * primary
    # around the main peak the total follows the room component
    i = np.argmax(full.envelope)
    assert full.components["room"][i] > 0.5 * full.envelope[i]


def test_secondary_arrives_later(full):
    t = full.time_centers
    primary = sum(full.components[n] for n in ("room", "box", "pillar"))
    sec = full.components["secondary"]
    assert smooth_peak(full, sec) > smooth_peak(full, primary) + 2.0
    assert (t * sec).sum() / sec.sum() > (t * primary).sum() / primary.sum() + 5e-9   # mean arrival time
    first = lambda y: t[np.argmax(y > 1e-3 * y.max())]
    assert first(sec) > first(primary)


def test_optimized_secondary_keeps_peak_time_with_lower_amplitude(scene, full, optimized):
    sec_full, sec_opt = full.components["secondary"], optimized.components["secondary"]
    # The secondary is a broad plateau with bumps near 30 and 34 ns. The optimized scheme keeps one path per
    # (lookin, FoV point), chosen by a weight dominated by far or grazing lookins, so its peak is noisy: at
    # 30×30×30×30 over seeds 0–3 it peaked at 28.6, 29.2, 29.3 and 35.1 ns against 29.3–29.6 ns for the full
    # secondary. The paper's claim (same peak time) holds for the typical seed: the median over three.
    dense = {"lookins": "30x30", "pixels": "30x30"}
    d_full = datagen.simulate(scene, datagen.resolve_config(scene, {**dense, "secondary": "exact"}))
    peak_full = smooth_peak(d_full, d_full.components["secondary"])
    peaks = []
    for seed in range(3):
        d_opt = datagen.simulate(scene, datagen.resolve_config(scene, {**dense, "secondary": "optimized",
                                                                       "seed": seed}))
        peaks.append(smooth_peak(d_opt, d_opt.components["secondary"]))
    assert abs(np.median(peaks) - peak_full) < 0.8
    assert peak_full == pytest.approx(smooth_peak(full, sec_full), abs=1.0)
    assert sec_opt.max() < 0.2 * sec_full.max()
    assert sec_opt.sum() < 0.2 * sec_full.sum()
    for name in ("room", "box", "pillar"):        # the primary is untouched
        np.testing.assert_array_equal(optimized.components[name], full.components[name])


def test_components_sum_to_total_and_seed_reproduces(scene, full):
    total = sum(full.components.values())
    np.testing.assert_allclose(total, full.envelope, rtol=1e-12, atol=1e-300)
    again = datagen.simulate(scene, datagen.resolve_config(scene, {"secondary": "none", "seed": 7}))
    same = datagen.simulate(scene, datagen.resolve_config(scene, {"secondary": "none", "seed": 7}))
    other = datagen.simulate(scene, datagen.resolve_config(scene, {"secondary": "none", "seed": 8}))
    assert again.counts.dtype == np.int64
    np.testing.assert_array_equal(again.counts, same.counts)
    np.testing.assert_array_equal(again.envelope, same.envelope)
    assert not np.array_equal(again.counts, other.counts)
    assert full.counts.sum() > 0
