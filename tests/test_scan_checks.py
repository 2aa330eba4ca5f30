"""Scanned captures checked against independent answers: a converged reference of the same capture, single-spot
simulations of each laser point, and a backprojection that must find the hidden mesh where its label says."""
from __future__ import annotations

import numpy as np
import pytest

import datagen
from conftest import box_before_wall, wall_room
from datagen.analysis.backprojection import locate_confocal, wall_leg_weights
from datagen.dataset import LabelSpec, scene_labels
from datagen.scene import FieldOfView, RayCaster, Scene, Sensor, resolve_capture


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


SMALL_SCAN = {"points": [4, 4], "width": 0.5, "height": 0.5}     # 12.5 cm pixels


def test_confocal_scan_matches_a_converged_reference():
    """The wall config's quadrature (h = 6 cm, wall.yaml) against the same capture at h = 1.5 cm with 3 × 3 FoV
    cells per pixel: the quadrature's error falls as h² (docs/physics.md §2), so the reference is 16× closer to the
    integral than the sample; the sample must be within 2 % relative L2 over the whole scan."""
    room = wall_room(3, 0, {"capture": {"scan": SMALL_SCAN}})
    base = {"estimator": "quadrature", "secondary": "none", "count_sensor_leg": False, "quadrature_fov": 3,
            "time": {"t_start": 0.0, "bin_width": 64e-12, "n_bins": 256}, "irf": {"fwhm": 70e-12},
            "effects": {"first_bounce": False, "secondary": False}}
    sample = datagen.simulate(room.scene, datagen.resolve_config(room.scene, {**base, "quadrature_edge": 0.06}))
    ref = datagen.simulate(room.scene, datagen.resolve_config(room.scene, {**base, "quadrature_edge": 0.015}))
    assert sample.envelope.shape == (4, 4, 256) and ref.envelope.sum() > 0
    err = rel_l2(sample.envelope, ref.envelope)
    assert err <= 0.02, err
    # the reference itself: halving its edge changes it by a quarter of the sample's error at most (h² order)
    mid = datagen.simulate(room.scene, datagen.resolve_config(room.scene, {**base, "quadrature_edge": 0.03}))
    assert rel_l2(mid.envelope, ref.envelope) < 0.5 * err


def test_each_laser_point_equals_a_single_spot_simulation():
    """Laser point p of a confocal scan is the single-spot capture with the spot at p and the sensor imaging p's
    pixel region: same sub-triangles, same weights, and the same aperture direction (a confocal detector follows
    the laser, Capture.aperture_normals; a single capture faces its FoV's centre p), so the envelopes are equal.
    The grid is 1.2 m wide, so a staring aperture would differ by up to cos θ_ap ≈ 0.9 at the corners."""
    room = wall_room(3, 1, {"capture": {"scan": {"points": [6, 5], "width": 1.2, "height": 1.0}}})
    over = {"estimator": "quadrature", "quadrature_edge": 0.08, "quadrature_fov": 1, "secondary": "none",
            "count_sensor_leg": False, "time": {"t_start": 0.0, "bin_width": 64e-12, "n_bins": 256},
            "irf": {"fwhm": 70e-12},
            "effects": {"first_bounce": False, "secondary": False, "shadow_spot": True, "shadow_sensor": True}}
    scan = datagen.simulate(room.scene, datagen.resolve_config(room.scene, over))
    capture = resolve_capture(room.scene, RayCaster(room.scene))
    grid = capture.spots.reshape(5, 6, 3)
    scene = room.scene
    s = np.asarray(scene.sensor.position)
    assert np.allclose(capture.aperture_normals(grid[0, 0]), (grid[0, 0] - s) / np.linalg.norm(grid[0, 0] - s))
    corner_cos = float(capture.aperture_normal @ (grid[0, 0] - s) / np.linalg.norm(grid[0, 0] - s))
    assert corner_cos < 0.99, corner_cos                # the test tells a following aperture from a staring one
    for iy, ix in [(0, 0), (2, 3), (4, 5), (1, 4)]:
        p = grid[iy, ix]
        fov = FieldOfView(center=tuple(p), size=(1.2 / 6, 1.0 / 5), pixels=(1, 1))
        single = Scene(scene.objects, scene.laser.model_copy(update={"spot": tuple(p)}),
                       Sensor(position=scene.sensor.position, aperture_radius=scene.sensor.aperture_radius, fov=fov),
                       defaults=scene.defaults)
        spot = datagen.simulate(single, datagen.resolve_config(single, over))
        assert spot.envelope.shape == (256,) and spot.envelope.sum() > 0
        np.testing.assert_allclose(scan.envelope[iy, ix], spot.envelope, rtol=1e-9,
                                   atol=1e-12 * spot.envelope.max())


@pytest.mark.slow
def test_backprojection_puts_the_hidden_mesh_at_its_labelled_position():
    """Filtered backprojection (datagen.analysis.backprojection) of a 32 × 32 confocal scan of one hidden mesh in
    front of the wall — the shipped box primitive, upright and facing the wall, drawn by the wall distribution —
    finds it within 3 cm of the centroid of its labelled visible surface (wall point + n · wall_depth over its
    mask). Upright letters land within 1.2–3.9 cm (6 draws, docs/datasets.md): their brightest strokes pull the
    half-maximum centroid."""
    room = box_before_wall(32)
    over = {"estimator": "quadrature", "quadrature_edge": 0.06, "secondary": "none", "count_sensor_leg": False,
            "time": {"t_start": 0.0, "bin_width": 32e-12, "n_bins": 512}, "irf": {"fwhm": 70e-12},
            "effects": {"first_bounce": False, "secondary": False}}
    result = datagen.simulate(room.scene, datagen.resolve_config(room.scene, over))
    labels = scene_labels(room, LabelSpec(max_objects=1, voxels=4))
    depth, mask = labels["wall_depth"], labels["wall_mask"][0] > 0
    assert mask.sum() > 20
    points = result.laser_points.reshape(-1, 3)
    n = result.wall_normal                                        # (−1, 0, 0): toward the hidden side
    target = (result.laser_points + depth[..., None] * n)[mask].mean(0)
    w = wall_leg_weights(points, n, np.asarray(room.scene.sensor.position))
    x0 = room.params["room"]["relay_x"]
    found, _ = locate_confocal(result.envelope.reshape(len(points), -1), result.time_edges, points,
                               np.array([x0 - 1.6, -1.0, 0.05]), np.array([x0 - 0.45, 1.0, 2.05]), weights=w)
    assert np.linalg.norm(found - target) <= 0.03, (found, target)
    # the labelled surface is the box's face toward the wall: the object's centre minus half its depth along x
    obj = room.objects[0]
    assert target[0] == pytest.approx(obj["center"][0] + obj["size"][0] / 2, abs=1e-6)
