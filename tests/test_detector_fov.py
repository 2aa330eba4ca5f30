"""A confocal scan's detector field of view on the relay wall (``capture.detector_fov``, docs/real.md): the SPAD sees a
patch of wall around each scan point that may be larger than the scan's pitch, and a retroreflector returns its light
in a lobe around the laser point, so how much of that light is collected depends on the patch's size.

Closed form. A retroreflective square patch (side 2h) faces a Lambertian relay wall of albedo ρ_w at distance r from
the scanned point x_l. The wall sends the share ρ_w F(r) of the laser's power to the patch (F the form factor from x_l
to the patch: 4 F(h/r, h/r) of Howell's catalogue, B-3) and the patch returns its lobe's share of it to x_l's
neighbourhood. Where the detector's patch of wall holds the whole returned lobe, what it collects is ρ_w F(r) ρ times
one constant of the sensor, so returns at two distances stand as F(r1) / F(r2) (about (r2 / r1)², the
retroreflector's 1/r²); a patch of wall smaller than the lobe's footprint on it (2 α r across) catches a share that
falls with r as well, and the ratio is steeper (towards the diffuse 1/r⁴).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import datagen
from datagen.errors import SceneError
from datagen.scene import scene_from_dict

WALL_X, SPOT = 2.0, np.array([2.0, 0.0, 1.0])
SENSOR = np.array([1.5, -3.0, 1.0])
PATCH = 0.04                      # the patch's side, m
RHO_WALL, RHO = 0.8, 0.9


def scene_dict(r: float, cell: float, detector_fov=None, points: int = 1, alpha: float = 0.005, orders: int = 1,
               estimator: dict | None = None) -> dict:
    capture = {"type": "confocal", "laser_grid": {"center": SPOT.tolist(), "size": [points * cell, points * cell],
                                                  "points": [points, points]}}
    if detector_fov is not None:
        capture["detector_fov"] = detector_fov
    data = {"name": "fov", "objects": [
        {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [WALL_X, -1.05, -0.05],
         "edge_u": [0.0, 0.0, 2.1], "edge_v": [0.0, 2.1, 0.0], "material": {"kind": "lambertian", "albedo": RHO_WALL}},
        {"builder": "quad", "name": "patch", "corner": [WALL_X - r, -PATCH / 2, 1.0 - PATCH / 2],
         "edge_u": [0.0, PATCH, 0.0], "edge_v": [0.0, 0.0, PATCH],
         "material": {"kind": "retroreflective", "albedo": RHO, "specular": 1.0, "lobe_width": alpha}}],
        "laser": {"emitter": SENSOR.tolist(), "spot": SPOT.tolist(), "photons_per_pulse": 1.0e6},
        "sensor": {"position": SENSOR.tolist(), "aperture_radius": 0.02},
        "capture": capture,
        "simulation": {"estimator": estimator or {"kind": "quadrature", "edge": 0.004, "fov_cells": 64},
                       "orders": orders, "effects": {"first_bounce": False, "secondary": False}, "count_laser_leg": False, "count_sensor_leg": False,
                       "time": {"t_start": "0ns", "bin_width": "8ps", "n_bins": 1024}, "irf": {"fwhm": "30ps"},
                       "detector": {"model": "poisson", "pde": 0.3, "repetition_rate": 1.0e7, "exposure": "1ms"}}}
    return data


def scene(*args, **kwargs):
    return scene_from_dict(scene_dict(*args, **kwargs), source="fov.yaml")


def returned(s) -> float:
    result = datagen.simulate(s, datagen.resolve_config(s, {}))
    return float(np.asarray(result.components["patch"]).sum())


def form_factor(x: float, y: float) -> float:
    """Point → parallel rectangle x·r × y·r with one corner above the point (Howell's catalogue, B-3)."""
    a, b = math.sqrt(1 + x * x), math.sqrt(1 + y * y)
    return (x / a * math.atan(y / a) + y / b * math.atan(x / b)) / (2 * math.pi)


def test_a_detector_fov_that_holds_the_lobe_gives_the_retroreflectors_inverse_square():
    r1, r2 = 0.30, 0.60
    closed = form_factor(PATCH / 2 / r1, PATCH / 2 / r1) / form_factor(PATCH / 2 / r2, PATCH / 2 / r2)   # 3.98
    # the lobe (alpha 0.005: its footprint 2 alpha r = 3-6 mm across) inside a 150 mm patch of wall, but for its GGX
    # tails (beyond 75 mm at 0.6 m: alpha^2 / (alpha^2 + tan^2) = 0.4 % of the energy); 2.3 mm FoV cells.
    # Seen: 0.9994 of the closed form (a 60 mm patch: 1.024, its tails cut more at 0.6 m)
    wide = returned(scene(r1, 0.002, "150mm")) / returned(scene(r2, 0.002, "150mm"))
    assert wide == pytest.approx(closed, rel=0.01)
    narrow = returned(scene(r1, 0.002)) / returned(scene(r2, 0.002))        # the 2 mm cell: steeper (seen 14.4)
    assert narrow > 2.0 * closed


def test_a_detector_fov_of_the_scans_cell_is_the_capture_without_one():
    cell = 0.01
    plain = datagen.simulate(s := scene(0.4, cell, points=3), datagen.resolve_config(s, {}))
    same = datagen.simulate(s := scene(0.4, cell, f"{cell * 1000}mm", points=3), datagen.resolve_config(s, {}))
    a, b = np.asarray(plain.envelope), np.asarray(same.envelope)
    assert a.shape == b.shape == (3, 3, 1024)
    assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()


def test_the_tracer_collects_the_second_round_trip_over_the_detector_fov():
    # the second round trip (tests/test_second_round_trip.py's closed form, rho_w F rho of the main return) with a
    # lobe wider than the 2 mm cell, both returns collected over a 150 mm patch of wall (seen: 1.028 of the closed
    # form at 16 M light paths; over the 2 mm cell alone 0.36: the echo's two lobes spill further than the main's)
    r = 0.25
    s = scene(r, 0.002, "150mm", orders=3)
    config = datagen.resolve_config(s, {"multibounce": {"paths": 8_000_000, "smoothing": False}})
    result = datagen.simulate(s, config, sampling_rng=np.random.default_rng(4), noise_rng=np.random.default_rng(5))
    main = np.asarray(result.components["patch"]).sum()
    echo = np.asarray(result.components["multibounce"]).sum()
    f = 4 * form_factor(PATCH / 2 / r, PATCH / 2 / r)
    assert echo / main == pytest.approx(RHO_WALL * f * RHO, rel=0.05)


@pytest.mark.parametrize("capture, words", [
    ({"type": "single"}, "detector_fov is the field of view at each scan point of a confocal capture"),
    ({"detector_fov": 0}, "both sides must be > 0"),
    ({"detector_fov": "-3mm"}, "both sides must be > 0"),
    ({"detector_fov": [1, 2, 3]}, "give one side or [w, h]"),
])
def test_a_bad_detector_fov_is_refused_in_one_line_naming_the_field(capture, words):
    data = scene_dict(0.3, 0.01, "20mm")
    data["capture"].update(capture)
    if data["capture"]["type"] == "single":
        data["capture"].pop("laser_grid")
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="fov.yaml")
    message = str(err.value)
    assert "\n" not in message and "fov.yaml" in message and "detector_fov" in message and words in message


def test_an_estimator_that_cannot_integrate_the_detector_fov_says_so_before_the_work():
    s = scene(0.3, 0.002, "20mm", estimator={"kind": "area", "samples": 1024})
    with pytest.raises(SceneError) as err:
        datagen.simulate(s, datagen.resolve_config(s, {}))
    message = str(err.value)
    assert "\n" not in message and message.startswith("fov.yaml: capture.detector_fov [0.02, 0.02] m")
    assert "integrated by the quadrature estimator only" in message and "'area'" in message
