"""The second round trip of a retroreflector (docs/real.md, "The second round trip"): laser spot → object → wall →
object → FoV point, order 3, simulated by the light tracer beside the estimator's order 1; and its measurement
(datagen.analysis.second_round_trip), applied alike to a real capture and to its simulation.

Closed form. A retroreflective square patch (side 2h) faces a Lambertian relay wall of albedo ρ_w at distance r from
the one scanned point x_l of a confocal capture, its lobe narrow enough (α = 0.002: ~1 mm on the wall) that every
returned cone lands inside the pixel region. The wall sends the share ρ_w F of the laser's power to the patch (F the
form factor from x_l to the patch: 4 F(h/r, h/r) of Howell's catalogue, B-3), the patch returns the share ρ of it to
x_l's neighbourhood (its lobe's albedo, 1 − O(α²)): the main return. That light is on the wall again, next to x_l,
whose form factor to the patch is the same: the second round trip is ρ_w F ρ times the main return, at the sum of two
of its round trips, so its mean arrival is twice the main return's.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import NEEDS_REAL, REAL

import datagen
from datagen.analysis.second_round_trip import second_round_trip
from datagen.scene import scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
WALL_X, SPOT = 2.0, np.array([2.0, 0.0, 1.0])
SENSOR = np.array([1.5, -3.0, 1.0])
HALF = 0.05                      # the pixel region's half side, m
PATCH, R = 0.10, 0.25            # the patch's side and distance, m
RHO_WALL, RHO = 0.8, 0.9


def patch_scene(paths: int):
    data = {"name": "echo", "objects": [
        {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [WALL_X, -1.05, -0.05],
         "edge_u": [0.0, 0.0, 2.1], "edge_v": [0.0, 2.1, 0.0], "material": {"kind": "lambertian", "albedo": RHO_WALL}},
        {"builder": "quad", "name": "patch", "corner": [WALL_X - R, -PATCH / 2, 1.0 - PATCH / 2],
         "edge_u": [0.0, PATCH, 0.0], "edge_v": [0.0, 0.0, PATCH],
         "material": {"kind": "retroreflective", "albedo": RHO, "specular": 1.0, "lobe_width": 0.002}}],
        "laser": {"emitter": SENSOR.tolist(), "spot": SPOT.tolist(), "photons_per_pulse": 1.0e6},
        "sensor": {"position": SENSOR.tolist(), "aperture_radius": 0.02},
        "capture": {"type": "confocal", "laser_grid": {"center": SPOT.tolist(), "size": [2 * HALF, 2 * HALF],
                                                       "points": [1, 1]}},
        "simulation": {"estimator": {"kind": "area", "samples": 8192}, "orders": 3,
                       "multibounce": {"paths": paths, "smoothing": False},
                       "effects": {"first_bounce": False, "secondary": False}, "count_laser_leg": False,
                       "count_sensor_leg": False, "time": {"t_start": "0ns", "bin_width": "8ps", "n_bins": 1024},
                       "irf": {"fwhm": "30ps"},
                       "detector": {"model": "poisson", "pde": 0.3, "repetition_rate": 1.0e7, "exposure": "1ms"}}}
    return scene_from_dict(data, source="echo.yaml")


def form_factor(x: float, y: float) -> float:
    """Point → parallel rectangle x·r × y·r with one corner above the point (Howell's catalogue, B-3)."""
    a, b = math.sqrt(1 + x * x), math.sqrt(1 + y * y)
    return (x / a * math.atan(y / a) + y / b * math.atan(x / b)) / (2 * math.pi)


def test_the_second_round_trip_is_the_wall_albedo_times_what_the_patch_returns():
    scene = patch_scene(paths=16_000_000)
    config = datagen.resolve_config(scene, {})
    result = datagen.simulate(scene, config, sampling_rng=np.random.default_rng(4), noise_rng=np.random.default_rng(5))
    main = np.asarray(result.components["patch"]).ravel()
    echo = np.asarray(result.components["multibounce"]).ravel()
    t = np.asarray(result.time_centers)
    f = 4 * form_factor(PATCH / 2 / R, PATCH / 2 / R)
    # the run traces 4 M light paths (its tracer's two replicas) in ~2 s; five seeds gave 0.987-1.007 of the closed form
    assert echo.sum() / main.sum() == pytest.approx(RHO_WALL * f * RHO, rel=0.05)
    mean = lambda x: float((x * t).sum() / x.sum())                                # noqa: E731
    assert mean(echo) == pytest.approx(2 * mean(main), abs=3e-12)                 # within 3 ps (seen: 0.2-0.8 ps)


# -- the measurement -------------------------------------------------------------------------------------------

DT, K = 4e-12, 2048
EDGES = np.arange(K + 1) * DT
T = (np.arange(K) + 0.5) * DT


def irf() -> np.ndarray:
    """(K,) per bin, summing to 1: a 30 ps Gaussian core and a 400 ps slow tail holding 12 % (the SPAD's diffusion
    tail, which puts the main return under the echo: the Stanford 40 cm chart's reads 0.38 ns on the echo's sides)."""
    x = T - T[K // 2]
    core = np.exp(-0.5 * (x / 30e-12) ** 2)
    slow = np.where(x < 0, 0.0, np.exp(-np.clip(x, 0, None) / 400e-12))
    return 0.88 * core / core.sum() + 0.12 * slow / slow.sum()


def synthetic(size: float, main_counts: float = 3e6, floor: float = 1500.0, t0: float = 2.7e-9):
    """(expected counts (K,), the echo alone (K,)): a scan-summed main return whose round trips spread from ``t0``
    with a 250 ps decay (G), its second round trip ``size`` × its counts spread as G ⊛ G (the sum of two round trips),
    both through :func:`irf`, and a floor."""
    g = np.where(T >= t0, np.exp(-np.clip(T - t0, 0, None) / 250e-12), 0.0)
    g /= g.sum()
    gg = np.convolve(g, g)[:K]
    gg = np.r_[gg[1:], 0.0]                     # bin centres: (i + ½) + (j + ½) = (i + j + 1) + ½
    h = irf()
    blur = lambda x: np.convolve(x, h)[K // 2:K // 2 + K]                        # noqa: E731
    main, echo = main_counts * blur(g), size * main_counts * blur(gg / max(gg.sum(), 1e-300))
    return main + echo + floor, echo


def median_time(echo: np.ndarray) -> float:
    run = np.cumsum(echo)
    k = int(np.argmax(run >= 0.5 * run[-1]))
    return float(EDGES[k] + (0.5 * run[-1] - run[k - 1]) / echo[k] * DT)


def test_the_measurement_takes_the_slow_tail_out_and_finds_the_echo():
    mu, echo = synthetic(0.004)
    m = second_round_trip(mu, EDGES)
    assert m.window[0] == pytest.approx(2 * 2.7e-9, abs=0.15e-9)
    # the echo's last ~2 % lies past the window, where the baseline's second side takes it in: the size reads 6 %
    # low and the time 23 ps early here (on the simulated chart 2-4 % and 3-11 ps against its order-3 component)
    assert m.size == pytest.approx(0.004, rel=0.08)
    assert m.time == pytest.approx(median_time(echo), abs=30e-12)
    none = second_round_trip(synthetic(0.0)[0], EDGES)
    assert abs(none.size) < 0.03 * 0.004                                           # the tail alone: no echo
    noisy = second_round_trip(np.random.default_rng(1).poisson(mu).astype(float), EDGES)
    assert 0.8 < noisy.baseline_chi2 < 1.3                                         # one exponential fits that tail


def test_counting_noise_is_stated_and_does_not_bias_the_size():
    mu, echo = synthetic(0.004)
    rng = np.random.default_rng(3)
    sizes = [second_round_trip(rng.poisson(mu).astype(float), EDGES).size for _ in range(12)]
    m = second_round_trip(rng.poisson(mu).astype(float), EDGES, draws=12, rng=np.random.default_rng(4))
    clean = second_round_trip(mu, EDGES).size
    assert 0.5 < m.size_sd / np.std(sizes, ddof=1) < 2.0
    assert abs(np.mean(sizes) - clean) < 3 * m.size_sd / math.sqrt(len(sizes))
    assert 0 < m.time_sd < 60e-12


def test_an_echo_past_the_record_is_refused():
    late = synthetic(0.0, t0=4.2e-9)[0]                                            # 65 cm: an echo from ~8.4 ns
    with pytest.raises(ValueError, match="leaves less than"):
        second_round_trip(late, EDGES)
    with pytest.raises(ValueError, match="draws need an rng"):
        second_round_trip(synthetic(0.004)[0], EDGES, draws=2)


# -- the scene files and the real capture ----------------------------------------------------------------------

def test_the_40cm_chart_simulates_its_second_round_trip_and_the_65cm_chart_not():
    from datagen.scene.load import load_scene

    near = load_scene(ROOT / "scene_library" / "stanford_dot_chart_40cm.yaml")
    far = load_scene(ROOT / "scene_library" / "stanford_dot_chart_65cm.yaml")
    c = datagen.resolve_config(near, {})
    assert c.orders_setting() == 3 and c.multibounce.smoothing is False and c.effects["secondary"] is False
    assert datagen.resolve_config(far, {}).orders_setting() == 1       # its echo (~8.7 ns) is past the record


def test_the_40cm_charts_second_round_trip_is_the_closed_form_when_every_cone_lands_in_the_pixel():
    """The chart of the scene file, its lobe narrowed to α = 0.0005 and all in it (k_s = 1), without its entrance
    falloff, scanned at 2 x 2 points whose pixel regions (their cells) are 70 mm wide: ρ_w ρ ⟨F⟩, F summed over the
    chart's 2.5 mm cells from each scan point and averaged with the main return's weights. (The shipped lobe spills
    out of 6.35 mm pixels, the echo's more than the main return's: docs/real.md, "The second round trip".)"""
    import yaml

    data = yaml.safe_load((ROOT / "scene_library" / "stanford_dot_chart_40cm.yaml").read_text())
    chart = data["objects"][1]
    chart["material"].update(lobe_width=0.0005, specular=1.0, entrance_falloff=0)
    data["capture"] = {"type": "confocal", "laser_grid": {"center": [0.0, 0.0, 0.0], "size": [0.14, 0.14],
                                                          "points": [2, 2]}}
    data["simulation"].update(estimator={"kind": "area", "samples": 4096},
                              multibounce={"paths": 8_000_000, "smoothing": False})
    scene = scene_from_dict(data, source="chart.yaml")
    result = datagen.simulate(scene, datagen.resolve_config(scene, {}), sampling_rng=np.random.default_rng(1),
                              noise_rng=np.random.default_rng(2))
    main = np.asarray(result.components["dot_chart"]).reshape(4, -1).sum(axis=1)
    echo = np.asarray(result.components["multibounce"]).reshape(4, -1).sum(axis=1)
    rows = np.array([[c == "#" for c in row] for row in chart["rows"][::-1]])
    pitch, centre = chart["pitch"], np.array(chart["center"])
    eu, ev = np.array(chart["u"]), np.array(chart["v"])             # the chart's plane (tilted a little)
    normal = np.cross(eu, ev)
    v, u = (np.nonzero(rows)[i] - (rows.shape[i] - 1) / 2 for i in (0, 1))
    cells = centre + (u * pitch)[:, None] * eu + (v * pitch)[:, None] * ev
    d = cells[None] - np.asarray(result.laser_points).reshape(-1, 3)[:, None]
    r2 = np.sum(d * d, axis=-1)
    cos_chart = np.abs(d @ normal) / np.sqrt(r2)
    f = np.sum((d[..., 1] / np.sqrt(r2)) * cos_chart / (np.pi * r2), axis=1) * pitch ** 2   # cosθ_wall cosθ_chart / (π r²) dA
    closed = data["objects"][0]["material"]["albedo"] * chart["material"]["albedo"] * np.sum(f * main) / main.sum()
    # seeds 0-3: 0.985-1.038 of it (the area sampler's main and the tracer's echo each a few per cent)
    assert echo.sum() / main.sum() == pytest.approx(closed, rel=0.06)


@NEEDS_REAL
def test_the_real_40cm_charts_second_round_trip_is_the_one_docs_real_md_reports():
    from datagen.io.lab_formats import read_lab_capture

    cap = read_lab_capture(REAL / "data_dot_chart_40cm.mat", bin_resolution=4e-12)
    m = second_round_trip(cap.data(), cap.time_edges())
    assert m.size == pytest.approx(0.00423, abs=0.00002) and m.time == pytest.approx(5.906e-9, abs=2e-12)
