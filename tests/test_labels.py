"""Ground-truth labels: closed-form depth of a plane, voxel counts of hand-placed boxes, padding, shapes."""
from __future__ import annotations

from itertools import product
from pathlib import Path

import numpy as np
import pytest

from datagen.errors import ConfigError
from datagen.scene import Material
from datagen.dataset import LabelSpec, scene_labels
from datagen.dataset.labels import camera_directions, label_shapes, occupancy_grid
from datagen.dataset import load_room_distribution, sample_room
from datagen.dataset.sampler import SampledRoom
from datagen.dataset.sampler import STREAMS
from datagen.scene import FieldOfView, Laser, Scene, Sensor, box, l_room, quad

DEFAULT = Path(__file__).resolve().parents[1] / "configs" / "rooms" / "default.yaml"


def rngs_for(seed: int, i: int) -> dict[str, np.random.Generator]:
    return {name: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, i, k)))
            for k, name in enumerate(STREAMS)}


def capture(fov_center=(6.0, 0.0, 1.5)) -> tuple[Laser, Sensor]:
    return (Laser(emitter=(0.0, 0.0, 1.0), spot=(6.0, 0.0, 2.5)),
            Sensor(position=(5.8, 0.0, 1.0), fov=FieldOfView(center=fov_center, size=(1.0, 1.0))))


def plane_room(distance: float, half: float) -> SampledRoom:
    """Relay wall x = 6 facing −x and a square plane of half-size ``half`` parallel to it at x = 6 − distance."""
    c = np.array([6.0, 0.0, 1.5])
    objects = [quad("relay_wall", (6.0, -200.0, -200.0), (0.0, 400.0, 0.0), (0.0, 0.0, 400.0), label="relay_wall"),
               quad("plane", (6.0 - distance, c[1] - half, c[2] - half), (0.0, 2 * half, 0.0), (0.0, 0.0, 2 * half),
                    label="wall")]
    laser, sensor = capture(tuple(c))
    params = {"label_region": {"origin": [0.0, 0.0, 0.0], "size": [1.0, 1.0, 1.0]}}
    return SampledRoom(Scene(objects, laser, sensor), params, [])


def test_depth_of_parallel_plane_matches_closed_form():
    d, half = 0.5, 2.0
    spec = LabelSpec(depth_map=(48, 40), voxels=4)
    labels = scene_labels(plane_room(d, half), spec)
    n = np.array([-1.0, 0.0, 0.0])                                  # relay-wall normal, toward the plane
    dirs = camera_directions(spec.depth_map, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), n)
    t = d / (dirs @ n)                                              # ray–plane distance d / cos θ
    p = np.array([6.0, 0.0, 1.5]) + t[..., None] * dirs
    inside = (np.abs(p[..., 1]) <= half) & (np.abs(p[..., 2] - 1.5) <= half)
    near_edge = np.abs(np.maximum(np.abs(p[..., 1]), np.abs(p[..., 2] - 1.5)) - half) < 1e-3
    ok = ~near_edge
    assert inside.sum() > 0.5 * inside.size and (~inside).sum() > 100     # both cases are exercised
    expected = np.where(inside, t, 0.0)
    np.testing.assert_allclose(labels["depth"][ok], expected[ok], rtol=1e-5, atol=1e-5)
    normals = labels["normal"]
    np.testing.assert_array_equal(normals[inside & ok], np.broadcast_to([1.0, 0.0, 0.0], normals[inside & ok].shape))
    assert np.all(normals[~inside & ok] == 0.0)


def test_camera_pixels_cover_the_hemisphere_equally():
    u, v, n = np.eye(3)[1], np.eye(3)[2], -np.eye(3)[0]
    dirs = camera_directions((64, 64), u, v, n)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    cos = dirs @ n
    assert cos.min() > 0
    # equal-area pixels: the share of pixels within θ of the normal is the cap's share 1 − cos θ of 2π
    for c in (0.25, 0.5, 0.75):
        assert np.mean(cos >= c) == pytest.approx(1 - c, abs=0.02)
    # column index grows along u, row index along v
    assert dirs[32, -1] @ u > 0.9 and dirs[-1, 32] @ v > 0.9


def box_room(objects: list[dict], region=((2.0, -3.0, 0.0), (4.0, 4.0, 4.0))) -> SampledRoom:
    scene_objects = l_room(6.0, -2.0, 2.0, 3.0, 4.0, 3.0, 1)
    for i, o in enumerate(objects):
        scene_objects.append(box(f"b{i}", tuple(o["center"]), tuple(o["size"]), o["yaw_deg"], Material()))
    laser, sensor = capture()
    params = {"label_region": {"origin": list(region[0]), "size": list(region[1])}}
    return SampledRoom(Scene(scene_objects, laser, sensor), params, objects)


def obj(center, size, yaw, cls="box", kind="lambertian", albedo=0.5) -> dict:
    return {"class": cls, "center": list(center), "size": list(size), "yaw_deg": yaw,
            "material": Material(kind=kind, albedo=albedo).model_dump(mode="json")}


def test_voxel_count_of_hand_placed_boxes():
    spec = LabelSpec(voxels=80)                     # 4 m region → pitch 0.05 m
    aligned = obj((4.5, -1.0, 1.0), (1.0, 0.6, 0.8), 0.0)                # faces on voxel boundaries
    labels = scene_labels(box_room([aligned]), spec)
    pitch = float(labels["occupancy_pitch"])
    assert pitch == pytest.approx(0.05)
    np.testing.assert_array_equal(labels["occupancy_origin"], np.float32([2.0, -3.0, 0.0]))
    assert labels["occupancy"].sum() == 20 * 12 * 16                    # exact: 1.0/0.05 × 0.6/0.05 × 0.8/0.05
    idx = np.argwhere(labels["occupancy"])
    np.testing.assert_array_equal(idx.min(0), [40, 34, 12])             # (4.0−2)/0.05, (−1.3+3)/0.05, 0.6/0.05
    # rotated boxes: count ≈ volume / pitch³ = 3840. Under a uniformly random translation the count is an
    # unbiased estimate of V/p³; one placement errs by boundary cells only (≤ 8 %: ~90 cells straddle the
    # 3.2 m perimeter at 45°, 16 layers), the mean over an 8×8 grid of sub-voxel shifts by ≤ 0.5 %.
    for yaw in (17.0, 30.0, 45.0):
        counts = []
        for sx, sy in product((np.arange(8) + 0.5) / 8 * pitch, repeat=2):
            rotated = obj((4.0 + sx, -1.1 + sy, 1.23), (1.0, 0.6, 0.8), yaw)
            counts.append(occupancy_grid([rotated], np.array([2.0, -3.0, 0.0]), pitch, 80).sum())
        assert np.all(np.abs(np.array(counts) / 3840 - 1) <= 0.08)
        assert np.mean(counts) == pytest.approx(3840, rel=0.005)
    rotated = obj((4.0, -1.1, 1.23), (1.0, 0.6, 0.8), 30.0)             # scene_labels uses the same grid
    np.testing.assert_array_equal(scene_labels(box_room([rotated]), spec)["occupancy"],
                                  occupancy_grid([rotated], np.array([2.0, -3.0, 0.0]), pitch, 80))


def test_occupancy_of_disjoint_boxes_adds_and_clips_to_region():
    a, b = obj((3.0, -2.0, 0.5), (0.5, 0.5, 0.5), 10.0), obj((5.0, 0.0, 2.0), (0.4, 0.8, 0.6), 60.0)
    origin, pitch = np.array([2.0, -3.0, 0.0]), 0.05
    ga, gb = (occupancy_grid([o], origin, pitch, 80) for o in (a, b))
    both = occupancy_grid([a, b], origin, pitch, 80)
    assert both.sum() == ga.sum() + gb.sum() and not np.any(ga & gb)
    # a box half outside the region keeps only its inside half
    edge = obj((2.0, -1.0, 1.0), (1.0, 1.0, 1.0), 0.0)                  # x from 1.5 to 2.5, region starts at 2
    assert occupancy_grid([edge], origin, pitch, 80).sum() == 10 * 20 * 20


def test_padded_object_arrays():
    objects = [obj((3.5, 2.0, 1.5), (0.5, 0.5, 3.0), 45.0, cls="pillar", kind="sin_theta", albedo=0.7),
               obj((5.5, 0.5, 1.75), (0.5, 0.5, 0.5), -20.0, kind="phong", albedo=0.3),
               obj((4.0, 3.0, 0.25), (0.6, 0.4, 0.5), 5.0, albedo=0.9)]
    spec = LabelSpec(max_objects=5, depth_map=(8, 8), voxels=8)
    labels = scene_labels(box_room(objects), spec)
    assert labels["object_count"] == 3
    np.testing.assert_array_equal(labels["object_class"], [1, 0, 0, -1, -1])
    np.testing.assert_array_equal(labels["object_brdf"], [1, 2, 0, -1, -1])
    np.testing.assert_allclose(labels["object_albedo"], [0.7, 0.3, 0.9, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(labels["object_yaw"], np.deg2rad([45.0, -20.0, 5.0, 0, 0]), rtol=1e-6)
    np.testing.assert_allclose(labels["object_center"][:3], [o["center"] for o in objects], rtol=1e-6)
    np.testing.assert_allclose(labels["object_size"][:3], [o["size"] for o in objects], rtol=1e-6)
    assert not labels["object_center"][3:].any() and not labels["object_size"][3:].any()
    with pytest.raises(ConfigError, match=r"labels\.max_objects: the room has 3 hidden objects, more than "
                                         r"max_objects = 2"):
        scene_labels(box_room(objects), LabelSpec(max_objects=2))


def test_sampled_rooms_have_fixed_shapes_and_deterministic_labels():
    dist = load_room_distribution(DEFAULT)
    spec = LabelSpec(depth_map=(32, 24), voxels=24)
    shapes = label_shapes(spec)
    origins, volume, occupied = set(), 0.0, 0.0
    for i in range(10):
        room = sample_room(dist, rngs_for(5, i))
        labels = scene_labels(room, spec)
        again = scene_labels(room, spec)
        assert set(labels) == set(shapes)
        for key, (shape, dtype) in shapes.items():
            assert labels[key].shape == shape and labels[key].dtype == dtype, key
            np.testing.assert_array_equal(labels[key], again[key])
        origins.add(tuple(labels["occupancy_origin"]) + (float(labels["occupancy_pitch"]),))
        assert labels["object_count"] == len(room.objects)
        assert (labels["object_class"] >= 0).sum() == len(room.objects)
        hit = labels["depth"] > 0
        assert hit.mean() > 0.5                                   # the room surrounds the camera
        np.testing.assert_allclose(np.linalg.norm(labels["normal"][hit], axis=-1), 1.0, atol=1e-6)
        volume += sum(np.prod(o["size"]) for o in room.objects)
        fine = scene_labels(room, LabelSpec(depth_map=(4, 4), voxels=96))
        occupied += fine["occupancy"].sum() * float(fine["occupancy_pitch"]) ** 3
    assert len(origins) == 1                                     # every grid is aligned
    # default objects (≥ 0.3 m) on a 0.156 m grid: the occupied volume matches the objects' within 10 %
    assert occupied == pytest.approx(volume, rel=0.10)
