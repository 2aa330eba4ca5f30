"""Ray casting: exact hits, oriented normals, visibility, scale-aware offsets (6 m room and 600 m tunnel)."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.raycast import RayCaster
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
