"""Procedural rooms: reproducibility, stream independence, exact constraints over many samples, config errors."""
from __future__ import annotations

import json
from itertools import product
from pathlib import Path

import numpy as np
import pytest
import yaml

import datagen
from datagen.errors import ConfigError
from datagen.scene import RayCaster
from datagen.dataset import load_room_distribution, sample_room
from datagen.dataset.obb import box_hits_pyramid, box_hits_segment, boxes_overlap
from datagen.dataset.rooms import RoomDistribution
from datagen.dataset.sampler import STREAMS

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "rooms"
SMOKE, DEFAULT = CONFIGS / "smoke.yaml", CONFIGS / "default.yaml"


def rngs_for(seed: int, i: int, split: int = 0) -> dict[str, np.random.Generator]:
    """Streams as a dataset build derives them: SeedSequence(seed, spawn_key=(split, i, stream))."""
    return {name: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(split, i, k)))
            for k, name in enumerate(STREAMS)}


def geometry_of(room) -> dict:
    """Everything but the materials, as JSON text and the mesh arrays."""
    p = room.params
    objs = [{k: o[k] for k in ("class", "center", "size", "yaw_deg", "region")} for o in room.objects]
    return {"json": json.dumps([p["room"], p["laser"], p["sensor"], objs]),
            "vertices": room.scene.vertices, "faces": room.scene.faces}


@pytest.fixture(scope="module")
def default_dist() -> RoomDistribution:
    return load_room_distribution(DEFAULT)


@pytest.fixture(scope="module")
def smoke_dist() -> RoomDistribution:
    return load_room_distribution(SMOKE)


@pytest.fixture(scope="module")
def default_rooms(default_dist):
    return [sample_room(default_dist, rngs_for(7, i)) for i in range(200)]


# --- reproducibility and stream independence ---------------------------------------------------------------


def test_same_generators_give_identical_room(default_dist):
    a, b = (sample_room(default_dist, rngs_for(3, 11)) for _ in range(2))
    assert json.dumps(a.params) == json.dumps(b.params)
    assert np.array_equal(a.scene.vertices, b.scene.vertices) and np.array_equal(a.scene.faces, b.scene.faces)
    assert [o.material for o in a.scene.objects] == [o.material for o in b.scene.objects]
    c = sample_room(default_dist, rngs_for(3, 12))
    assert json.dumps(c.params) != json.dumps(a.params)


def test_materials_stream_does_not_move_geometry(default_dist):
    base = rngs_for(3, 5)
    other = dict(rngs_for(3, 5), materials=np.random.default_rng(999))
    a, b = sample_room(default_dist, base), sample_room(default_dist, other)
    ga, gb = geometry_of(a), geometry_of(b)
    assert ga["json"] == gb["json"]
    assert np.array_equal(ga["vertices"], gb["vertices"])
    assert a.params["materials"] != b.params["materials"]


def test_changed_material_distribution_keeps_geometry_and_other_classes(default_dist):
    phong_boxes = default_dist.with_overrides({"materials": {"box": {"kinds": {"phong": 1.0}}}})
    n_boxes = 0
    for i in range(20):
        a, b = sample_room(default_dist, rngs_for(1, i)), sample_room(phong_boxes, rngs_for(1, i))
        assert geometry_of(a)["json"] == geometry_of(b)["json"]
        assert a.params["materials"] == b.params["materials"]        # room surfaces: same draws
        for oa, ob in zip(a.objects, b.objects):
            if oa["class"] == "box":
                n_boxes += 1
                assert ob["material"]["kind"] == "phong"
                assert ob["material"]["albedo"] == oa["material"]["albedo"]   # same uniform, same range
            else:
                assert ob["material"] == oa["material"]
    assert n_boxes >= 5


def test_retroreflective_objects_are_opt_in_and_leave_every_other_draw_in_place(default_dist):
    """The retroreflective kind (road signs, safety apparel, bicycle reflectors) weighs 0 unless a config names it:
    naming it with weight 0 changes nothing, and with a weight it replaces the same boxes' kinds from the same
    uniforms (albedo and k_s where Phong's would be, α log-uniform in lobe_width), every other draw unmoved."""
    zero = default_dist.with_overrides({"materials": {"box": {"kinds": {**default_dist.materials.box.kinds,
                                                                        "retroreflective": 0.0}}}})
    retro = default_dist.with_overrides({"materials": {"box": {"kinds": {"retroreflective": 1.0},
                                                               "lobe_width": {"min": 0.005, "max": 0.02}}}})
    n_boxes = 0
    for i in range(12):
        a, z, b = (sample_room(d, rngs_for(2, i)) for d in (default_dist, zero, retro))
        assert json.dumps(a.params, sort_keys=True) == json.dumps(z.params, sort_keys=True)
        assert geometry_of(a)["json"] == geometry_of(b)["json"] and a.params["materials"] == b.params["materials"]
        for oa, ob in zip(a.objects, b.objects):
            if oa["class"] != "box":
                assert ob["material"] == oa["material"]
                continue
            n_boxes += 1
            m = ob["material"]
            assert m["kind"] == "retroreflective" and m["albedo"] == oa["material"]["albedo"]
            assert 0.005 <= m["lobe_width"] <= 0.02 and "lobe_width" not in oa["material"]
    assert n_boxes >= 3


def test_sampled_room_simulates(smoke_dist):
    room = sample_room(smoke_dist, rngs_for(0, 0))
    config = datagen.resolve_config(room.scene, {"lookins": "3x3", "pixels": "8x8"})
    result = datagen.simulate(room.scene, config, sampling_rng=np.random.default_rng(0),
                              noise_rng=np.random.default_rng(1))
    assert result.envelope.sum() > 0
    assert {"room", *(o["name"] for o in room.objects)} <= set(result.components)


# --- exact constraints over 200 rooms -----------------------------------------------------------------------


def obb_axes_and_corners(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box mesh vertices (8, 3) in box_mesh order (index 4ix+2iy+iz) → unit axes (3, 3), corners."""
    axes = np.stack([vertices[4] - vertices[0], vertices[2] - vertices[0], vertices[1] - vertices[0]])
    return axes / np.linalg.norm(axes, axis=1, keepdims=True), vertices


def obb_gap(va: np.ndarray, vb: np.ndarray) -> float:
    """Largest separation of two OBBs (given by their 8 corners) over the 15 separating axes (3D SAT);
    > 0 means disjoint by that much along some axis, <= 0 means they overlap."""
    aa, _ = obb_axes_and_corners(va)
    ab, _ = obb_axes_and_corners(vb)
    axes = list(aa) + list(ab) + [np.cross(x, y) for x, y in product(aa, ab)]
    best = -np.inf
    for axis in axes:
        n = np.linalg.norm(axis)
        if n < 1e-9:
            continue
        pa, pb = va @ (axis / n), vb @ (axis / n)
        best = max(best, pb.min() - pa.max(), pa.min() - pb.max())
    return best


def test_200_rooms_objects_disjoint_and_inside(default_rooms, default_dist):
    gap = default_dist.objects.min_gap
    n_objects = 0
    for room in default_rooms:
        p = room.params["room"]
        hidden = [o for o in room.scene.objects if o.label in ("box", "pillar")]
        assert len(hidden) == len(room.objects)
        n_objects += len(hidden)
        for a in range(len(hidden)):
            for b in range(a + 1, len(hidden)):
                # boxes are kept min_gap apart; the SAT bound is a lower bound of the true distance
                assert obb_gap(hidden[a].vertices, hidden[b].vertices) >= gap - 1e-9
        x1, w, s = p["relay_x"], p["corridor_width"], p["bend_side"]
        for mesh, obj in zip(hidden, room.objects):
            v = mesh.vertices
            if obj["region"] == "room":
                y_lo, y_hi = sorted([s * w / 2, s * (w / 2 + p["room_length"])])
                x_lo = x1 - p["room_depth"]
            else:
                y_lo, y_hi, x_lo = -w / 2, w / 2, p["corridor_start"]
            assert np.all(v[:, 0] >= x_lo + gap - 1e-9) and np.all(v[:, 0] <= x1 - gap + 1e-9)
            assert np.all(v[:, 1] >= y_lo + gap - 1e-9) and np.all(v[:, 1] <= y_hi + 1e-9 - gap)
            assert np.all(v[:, 2] >= -1e-9) and np.all(v[:, 2] <= p["ceiling"] + 1e-9)
    assert n_objects >= 200 * 1.5   # the default draws 1–4 objects


def test_200_rooms_beam_and_fov_view_unobstructed(default_rooms):
    g = (np.arange(11) / 10 - 0.5)  # 11×11 grid including the FoV's edges
    for room in default_rooms:
        scene = room.scene
        caster = RayCaster(scene)
        relay = [o.label for o in scene.objects].index("relay_wall")
        emitter, spot = np.array(scene.laser.emitter), np.array(scene.laser.spot)
        fov = scene.sensor.fov
        gu, gv = np.meshgrid(g * fov.size[0], g * fov.size[1])
        targets = np.array(fov.center) + np.stack([0 * gu, gu, gv], axis=-1).reshape(-1, 3)  # u = +y, v = +z
        sensor = np.array(scene.sensor.position)
        origins = np.concatenate([emitter[None], np.broadcast_to(sensor, targets.shape)])
        ends = np.concatenate([spot[None], targets])
        d = ends - origins
        length = np.linalg.norm(d, axis=1)
        hits = caster.intersect(origins, d / length[:, None])
        assert np.all(hits.object_id == relay)
        np.testing.assert_allclose(hits.distance, length, atol=1e-4)


def test_200_rooms_parameters_inside_ranges(default_rooms, default_dist):
    d = default_dist
    cap, m = d.capture, d.capture.edge_margin
    counts = {"box": [], "pillar": []}
    kinds_seen = set()
    for room in default_rooms:
        p = room.params
        r = p["room"]
        assert d.corridor.length.contains(r["corridor_length"]) and d.corridor.width.contains(r["corridor_width"])
        assert d.room.depth.contains(r["room_depth"]) and d.room.length.contains(r["room_length"])
        assert d.ceiling.contains(r["ceiling"]) and r["bend_side"] in d.room.bend_side
        w, h, x1 = r["corridor_width"], r["ceiling"], r["relay_x"]
        e = p["laser"]["emitter"]
        assert cap.emitter.standoff.contains((x1 - e[0]) / r["corridor_length"])
        assert cap.emitter.lateral.contains(e[1] / (w / 2 - m)) and cap.emitter.height.contains(e[2])
        assert p["sensor"]["position"] == e   # co-located (sensor: null)
        s = p["laser"]["spot"]
        assert s[0] == x1 and cap.spot.lateral.contains(s[1] / (w / 2 - m)) and cap.spot.height.contains(s[2])
        fc, (fw, fh) = p["sensor"]["fov"]["center"], p["sensor"]["fov"]["size"]
        assert cap.fov.width.contains(fw) and cap.fov.height.contains(fh)
        assert fc[0] == x1 and abs(fc[1]) + fw / 2 <= w / 2 - m + 1e-9
        assert fc[2] - fh / 2 >= m - 1e-9 and fc[2] + fh / 2 <= h - m + 1e-9
        for label, mat in p["materials"].items():
            md = getattr(d.materials, label)
            assert md.albedo.contains(mat["albedo"]) and md.kinds.get(mat["kind"], 0) > 0
        for cls in counts:
            counts[cls].append(sum(o["class"] == cls for o in room.objects))
        for o in room.objects:
            od, md = getattr(d.objects, o["class"]), getattr(d.materials, o["class"])
            sx, sy, sz = o["size"]
            assert od.size.x.contains(sx) and od.size.y.contains(sy) and od.yaw_deg.contains(o["yaw_deg"])
            if o["class"] == "pillar":
                assert sz == r["ceiling"] and o["center"][2] == pytest.approx(h / 2)
            else:
                assert od.size.z.contains(sz)
                region = getattr(od.placement, o["region"])
                assert region.weight > 0 and region.elevation.contains(o["center"][2] - sz / 2)
            mat = o["material"]
            kinds_seen.add((o["class"], mat["kind"]))
            assert md.albedo.contains(mat["albedo"]) and md.kinds.get(mat["kind"], 0) > 0
            if mat["kind"] == "phong":
                assert md.specular.contains(mat["specular"]) and md.exponent.contains(mat["exponent"])
    for cls, c in counts.items():
        rng = getattr(d.objects, cls).count
        assert min(c) == rng.min and max(c) == rng.max   # 200 draws reach both ends
    assert {("box", k) for k in ("lambertian", "phong", "sin_theta")} <= kinds_seen


# --- exact geometry helpers ---------------------------------------------------------------------------------


def test_box_overlap_closed_forms():
    a = {"center": [0, 0, 0.5], "size": [1, 1, 1], "yaw_deg": 0.0}
    # a unit cube rotated 45° reaches √2/2 from its centre along x
    reach = 0.5 + np.sqrt(0.5)
    for dx, expected in ((reach - 0.01, True), (reach + 0.01, False)):
        b = {"center": [dx, 0, 0.5], "size": [1, 1, 1], "yaw_deg": 45.0}
        assert boxes_overlap(a, b) is expected
    b = {"center": [1.05, 0, 0.5], "size": [1, 1, 1], "yaw_deg": 0.0}
    assert not boxes_overlap(a, b) and boxes_overlap(a, b, gap=0.06)
    high = {"center": [0, 0, 1.6], "size": [1, 1, 1], "yaw_deg": 10.0}
    assert not boxes_overlap(a, high)


def test_segment_and_pyramid_closed_forms():
    cube = {"center": [0, 0, 0], "size": [1, 1, 1], "yaw_deg": 45.0}
    p = np.array([-5.0, 0.0, 0.0])
    assert box_hits_segment(cube, p, np.array([5.0, 0.0, 0.0]))
    # passes beside the rotated cube's corner (|y| reach √2/2 at x = 0)
    assert not box_hits_segment(cube, np.array([-5.0, 0.72, 0.0]), np.array([5.0, 0.72, 0.0]))
    assert box_hits_segment(cube, np.array([-5.0, 0.70, 0.0]), np.array([5.0, 0.70, 0.0]))
    assert not box_hits_segment(cube, p, np.array([-1.0, 0.0, 0.0]))       # stops short
    base = np.array([[3, -1, -1], [3, 1, -1], [3, 1, 1], [3, -1, 1]], dtype=float)
    assert box_hits_pyramid(cube, np.array([-3.0, 0.0, 0.0]), base)
    # the pyramid from (−3,0,0) to the square at x = 3 has half-width |x+3|/6 at x; at x = 0 it is 0.5
    off = {"center": [0, 1.3, 0], "size": [0.5, 0.5, 0.5], "yaw_deg": 0.0}      # nearest y = 1.05 > 0.5
    assert not box_hits_pyramid(off, np.array([-3.0, 0.0, 0.0]), base)
    near = {"center": [0, 0.7, 0], "size": [0.5, 0.5, 0.5], "yaw_deg": 0.0}     # nearest y = 0.45 < 0.5
    assert box_hits_pyramid(near, np.array([-3.0, 0.0, 0.0]), base)


# --- configuration errors -----------------------------------------------------------------------------------


BAD = [
    ({"corridor": {"width": {"min": 3.0, "max": 2.0}}}, "corridor.width", "min (3.0) must be <= max (2.0)"),
    ({"materials": {"box": {"albedo": {"min": -0.1, "max": 0.5}}}}, "materials.box.albedo", "-0.1"),
    ({"materials": {"wall": {"albedo": {"min": 0.5, "max": 1.2}}}}, "materials.wall.albedo", "1.2"),
    ({"materials": {"box": {"kinds": {"glossy": 1.0}}}}, "materials.box.kinds.glossy.[key]", "glossy"),
    ({"materials": {"box": {"kinds": {"phong": 0.0}}}}, "materials.box.kinds", "positive weight"),
    ({"materials": {"box": {"lobe_width": {"min": 0.0, "max": 0.05}}}}, "materials.box.lobe_width", "0.0"),
    ({"materials": {"box": {"lobe_width": {"min": 0.01, "max": 3.0}}}}, "materials.box.lobe_width", "3.0"),
    ({"objects": {"pillar": {"count": {"min": 0, "max": 12}}}}, "objects", "room too small"),
    ({"objects": {"pillar": {"size": {"x": {"min": 0.5, "max": 3.5}}}}}, "objects.pillar.size", "does not fit"),
    ({"objects": {"box": {"count": {"min": -1, "max": 1}}}}, "objects.box.count.min", "-1"),
    ({"objects": {"box": {"placement": {"corridor_end": {"elevation": {"min": 0, "max": 2.2}}}}}},
     "objects.box.placement.corridor_end.elevation.max", "ceiling"),
    ({"room": {"depth": {"min": 3.0, "max": 4.5}}}, "room.depth.max", "corridor.length.min"),
    ({"capture": {"fov": {"width": {"min": 1.0, "max": 1.6}}}}, "capture.fov.width.max", "1.6"),
    ({"capture": {"spot": {"height": {"min": 1.0, "max": 2.5}}}}, "capture.spot.height", "2.5"),
    ({"capture": {"emitter": {"standoff": {"min": 0.5, "max": 1.0}}}}, "capture.emitter.standoff", "< 1"),
    ({"room": {"bend_side": 2}}, "room.bend_side.0", "got 2"),
    ({"corridor": {"lenght": 5.0}}, "corridor.lenght", "Extra inputs"),
]


@pytest.mark.parametrize("override, field, detail", BAD, ids=[b[1] for b in BAD])
def test_bad_config_names_the_field(default_dist, override, field, detail):
    with pytest.raises(ConfigError) as err:
        default_dist.with_overrides(override)
    msg = str(err.value)
    assert f"{field}:" in msg and detail in msg, msg


def test_bad_file_names_the_file(tmp_path):
    data = yaml.safe_load(SMOKE.read_text())
    data["ceiling"] = {"min": 3.0, "max": 2.0}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"bad\.yaml: ceiling: .*min \(3\.0\) must be <= max \(2\.0\)"):
        load_room_distribution(path)
    with pytest.raises(ConfigError, match="not found"):
        load_room_distribution(tmp_path / "missing.yaml")


def test_rejection_is_bounded_and_names_the_constraint(smoke_dist):
    # a corridor-end box beside a FoV that fills the whole corridor end always hides part of it
    impossible = smoke_dist.with_overrides({
        "corridor": {"width": 2.0},
        "capture": {"fov": {"width": 1.9, "height": 1.5}},
        "objects": {"max_tries": 30, "max_layouts": 2, "pillar": {"count": 0},
                    "box": {"count": 1, "placement": {"room": {"weight": 0.0}, "corridor_end": {"weight": 1.0}}}},
    })
    with pytest.raises(ConfigError, match=r"objects: could not place 0 pillars and 1 boxes.*fov_view \d+"):
        sample_room(impossible, rngs_for(0, 0))


def test_overrides_and_loading(smoke_dist, tmp_path):
    more = smoke_dist.with_overrides({"objects": {"box": {"count": {"max": 2}}}, "ceiling": 2.85})
    assert more.objects.box.count.max == 2 and more.objects.box.count.min == 0
    assert more.ceiling.min == more.ceiling.max == 2.85
    assert smoke_dist.objects.box.count.max == 1                       # the original is untouched
    assert more.objects.pillar == smoke_dist.objects.pillar
    with pytest.raises(ConfigError, match=r"objects\.box\.colour: Extra inputs"):
        smoke_dist.with_overrides({"objects": {"box": {"colour": "red"}}})
    as_dict = load_room_distribution(yaml.safe_load(SMOKE.read_text()))
    assert as_dict.model_dump() == smoke_dist.model_dump()
    with pytest.raises(ConfigError, match="sample_room: rngs lacks streams"):
        sample_room(smoke_dist, {"geometry": np.random.default_rng(0)})
