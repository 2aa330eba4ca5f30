"""Ray casting: exact hits, oriented normals, visibility, scale-aware offsets (6 m room and 600 m tunnel)."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.scene import RayCaster
from datagen.sampling import observe
from datagen.scene import FieldOfView, Laser, Scene, Sensor, box, l_room


def room(scale: float) -> Scene:
    objs = l_room(relay_x=6 * scale, corridor_start=-2 * scale, corridor_width=2.1 * scale,
                  room_depth=3 * scale, room_length=4 * scale, height=3 * scale)
    objs.append(box("box", (5.0 * scale, 0.3 * scale, 0.5 * scale), (0.5 * scale,) * 3))
    return Scene(objs, Laser(emitter=(0, 0, scale), spot=(6 * scale, 0, 2.5 * scale)),
                 Sensor(position=(0, 0, scale), fov=FieldOfView(center=(6 * scale, 0, 1.5 * scale),
                                                                size=(2 * scale, 2 * scale))))


def test_hit_distance_point_and_normal_are_exact():
    caster = RayCaster(room(1.0))
    o = np.array([[0.0, 0.3, 0.5], [0.0, 0.0, 1.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    h = caster.intersect(o, d)
    assert h.hit.all()
    np.testing.assert_allclose(h.distance, [4.75, 1.0], rtol=1e-12)  # box face at x = 4.75; floor
    np.testing.assert_allclose(h.normals, [[-1, 0, 0], [0, 0, 1]], atol=1e-12)  # facing the ray origin
    assert [caster.face_object[f] for f in h.face] == [4, 2]


def test_hit_points_are_the_points_with_zero_where_a_ray_misses():
    """Hits.hit_points: a hit's point as it is (box face at x = 4.75), a miss (a ray out of the room through the
    open corridor end) 0 instead of nan."""
    caster = RayCaster(room(1.0))
    h = caster.intersect(np.array([[0.0, 0.3, 0.5], [5.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]))
    assert h.hit.tolist() == [True, False] and np.isnan(h.points[1]).all()
    np.testing.assert_array_equal(h.hit_points(), [[4.75, 0.3, 0.5], [0.0, 0.0, 0.0]])


def test_visibility_blocked_by_box():
    caster = RayCaster(room(1.0))
    p = np.array([[4.0, 0.3, 0.5], [4.0, -0.8, 0.5]])
    q = np.array([[5.9, 0.3, 0.5], [5.9, -0.8, 0.5]])
    assert caster.visible(p, None, q, None).tolist() == [False, True]


@pytest.mark.parametrize("scale", [1.0, 100.0])
def test_no_self_intersection_and_float64_hits_at_any_scale(scale):
    """Cameras on the ceiling/floor/walls: no ray hits its own surface, hit points lie on their planes."""
    scene = room(scale)
    caster = RayCaster(scene)
    pts = np.array([[3.0, 0.0, 2.999], [1.0, 0.5, 0.0], [2.0, -1.05, 1.5]]) * scale
    pts[0, 2] = 3.0 * scale
    normals = np.array([[0, 0, -1.0], [0, 0, 1.0], [0, 1.0, 0]])
    obs = observe(caster, pts, normals, (40, 40), np.random.default_rng(0))
    assert obs.hit.mean() > 0.9          # the corridor's far end is open
    # nothing is hit closer than a small fraction of the room size (a self-hit would be ~0)
    assert np.nanmin(np.where(obs.hit, obs.distance, np.nan)) > 1e-3 * scale
    # floor hits lie on z = 0 to float64 precision relative to the scene size
    floor = obs.object_id == 2
    assert floor.any()
    assert np.abs(obs.points[floor][:, 2]).max() < 1e-9 * scale


def test_a_scene_far_from_the_world_origin_gives_the_same_primary():
    """The patch scene moved 100 km along x: ray origins are centred in float64 before Embree's float32, so
    the primary equals the unshifted one to 1e-9 (before, origins were rounded to float32 first — a 4 mm
    error against a 40 µm surface offset — and every camera ray hit its own lookin: the primary was 0)."""
    from conftest import patch_scene

    from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
    from datagen.scene import FieldOfView, Laser, Scene, SceneObject, Sensor
    from datagen.transport import LookinSampler, LookinSettings

    def shifted(dx):
        base, d = patch_scene(), np.array([dx, 0.0, 0.0])
        move = lambda p: tuple(np.array(p) + d)
        objects = [SceneObject(o.name, o.label, o.material, o.vertices + d, o.faces) for o in base.objects]
        return Scene(objects, Laser(emitter=move(base.laser.emitter), spot=move(base.laser.spot)),
                     Sensor(position=move(base.sensor.position), aperture_radius=0.02,
                            fov=FieldOfView(center=move(base.sensor.fov.center), size=(0.8, 0.8))))

    totals = []
    for dx in (0.0, 1e5):
        tr = LookinSampler(shifted(dx), LookinSettings(lookins=(32, 32), pixels=(24, 24), secondary="none"))
        acc = EnvelopeAccumulator(TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=1000), Irf(fwhm=100e-12), 3)
        tr.run(acc, np.random.default_rng(0))
        totals.append(acc.total_weight().sum())
    assert totals[0] > 0 and totals[1] == pytest.approx(totals[0], rel=1e-9)


def test_compiled_hits_and_segments_follow_the_documented_formulas_and_broadcast():
    """intersect: t = (n·p₀ − n·o)/(n·d) of the hit face (float64), points o + t·d, normals facing the origin,
    ids of the hit face; misses give inf / nan / 0 / −1. Broadcast batches equal their flattened rays, for
    intersect and visible (the compiled passes of datagen/scene/raycast.py index rows, not numpy broadcasting)."""
    import datagen

    scene = datagen.load_scene("scene_library/demo_room.yaml")
    rc = RayCaster(scene)
    rng = np.random.default_rng(2)
    lo, hi = scene.bounds()
    o = rng.uniform(lo + 0.1, hi - 0.1, (20, 3))
    d = rng.normal(size=(30, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    h = rc.intersect(o[:, None], d[None])                                   # (20, 30)
    flat = rc.intersect(np.repeat(o, 30, axis=0), np.tile(d, (20, 1)))
    for name in ("hit", "distance", "points", "normals", "face", "object_id"):
        np.testing.assert_array_equal(getattr(h, name).reshape(getattr(flat, name).shape), getattr(flat, name))
    hit = flat.hit
    assert 0.5 < hit.mean() <= 1.0
    oo, dd = np.repeat(o, 30, axis=0)[hit], np.tile(d, (20, 1))[hit]
    n = rc.face_normals[flat.face[hit]]
    p0 = rc.vertices[rc.faces[flat.face[hit], 0]]
    t = np.einsum("ij,ij->i", n, p0 - oo) / np.einsum("ij,ij->i", n, dd)
    np.testing.assert_allclose(flat.distance[hit], t, rtol=1e-9)
    np.testing.assert_allclose(flat.points[hit], oo + t[:, None] * dd, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.einsum("ij,ij->i", flat.normals[hit], dd) < 0, True)
    np.testing.assert_array_equal(flat.object_id[hit], rc.face_object[flat.face[hit]])
    miss = rc.intersect(np.array([[0.0, 0.0, 1e3]]), np.array([[0.0, 0.0, 1.0]]))
    assert not miss.hit[0] and miss.distance[0] == np.inf and np.isnan(miss.points).all()
    assert (miss.normals == 0).all() and miss.face[0] == -1 and miss.object_id[0] == -1
    q = rng.uniform(lo + 0.1, hi - 0.1, (30, 3))
    v = rc.visible(o[:, None], None, q[None], None)
    np.testing.assert_array_equal(v.ravel(), rc.visible(np.repeat(o, 30, axis=0), None, np.tile(q, (20, 1)), None))
    np.testing.assert_array_equal(v, rc.visible(q[None], None, o[:, None], None))   # the segment either way
    assert 0.05 < v.mean() < 0.95
