"""Room sampling: one :class:`SampledRoom` (a scene and its parameters) drawn from a room distribution.

:func:`sample_room` draws from a :class:`~datagen.dataset.rooms.RoomDistribution` with three independent
generators (docs/physics.md §7):

- ``geometry``: room dimensions, object counts, sizes, yaws, positions (rejection sampled);
- ``materials``: every material, a fixed 4 uniforms per surface, so a changed material distribution never
  moves the geometry of a sample (nor the material of another class);
- ``sensor``: emitter, sensor, laser spot and FoV placement.

Constraints on hidden objects, all checked exactly on oriented boxes (OBBs, rotated about z; a mesh's tight box)
inflated by ``objects.min_gap``: inside their placement region (the L-room proper, or the corridor end in front of
the relay wall), under the ceiling, no two overlapping (separating-axis test), none touching the laser beam
(segment emitter→spot; for a scan the pyramid emitter → laser rectangle) nor the sensor's view of the FoV (the
pyramid with apex at the sensor and the FoV or sensor-grid rectangle as base); the separating-axis tests are
:mod:`datagen.dataset.obb`'s.

World frame right-handed, z up, metres; yaw in degrees about +z (counter-clockwise seen from above).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..errors import ConfigError
from ..scene import FieldOfView, Laser, Scene, SceneObject, Sensor, box, l_room, pillar, quad
from ..scene import Material
from ..scene.builders import person
from ..scene.model import Moving
from ..scene.motion import WalkMotion
from ..scene.parts import ROOM_LABELS, CaptureSpec
from .assets import asset_box, asset_files, asset_name, load_asset, place_asset
from .obb import box_hits_pyramid, box_hits_segment, boxes_overlap
from .rooms import (OBJECT_CLASSES, UNIFORMS_PER_MATERIAL, MeshObjectDist, ObjectDist, PointDist, Range,
                    RoomDistribution)
from .scan import draw_scan, rectangle_corners, scan_capture

MOTION_STREAM = 6
"""Stream id of a dataset sample's walkers (docs/motion.md; the detector draw's is 5), drawn only when the
distribution has walkers, so that every other draw stays where it was."""

STREAMS = ("geometry", "materials", "sensor")
"""Keys of the generator mapping :func:`sample_room` takes; a distribution with walkers also takes "motion"."""

OBJECT_KEYS = ("class", "name", "region", "center", "size", "yaw_deg", "material")
"""Keys of every hidden object's record (``center``, ``size``, ``yaw_deg``: its oriented bounding box)."""

MESH_KEYS = ("asset", "asset_index", "scale", "tilt_deg", "tilt_axis_deg", "transform")
"""Extra keys of a mesh object: the asset file (its location-free name, e.g. ``meshes/A.ply``:
:func:`datagen.dataset.assets.asset_name`), its index in the distribution's sorted asset list, the size (longest
side of its bounding box, m), the tilt and its axis azimuth (degrees) and the (4, 4) file → world transform (row-major; :func:`datagen.dataset.assets.place_asset`)."""


@dataclass
class SampledRoom:
    """One sampled room.

    Attributes:
        scene: ready for :func:`datagen.simulate`.
        params: JSON-able record of every sampled parameter: ``room`` (relay_x, corridor_start,
            corridor_length, corridor_width, room_depth, room_length, ceiling, bend_side, closed_end; ``family``
            when not "l_room"), ``materials`` (per room label), ``laser`` (emitter, spot, pulse), ``sensor``
            (position, aperture_radius, fov center/size/pixels or None, and ``scan``: type, convention,
            laser_grid, sensor_grid, for scanned captures), ``objects`` (as :attr:`objects`), ``label_region``
            (origin, size) and ``layout_tries``.
        objects: one dict per hidden object: class ("box"|"pillar"|"mesh"), name, region ("room"|"corridor_end"),
            center [x, y, z] m, size [dx, dy, dz] m (its oriented bounding box; a pillar's dz is the ceiling
            height), yaw_deg, material (:class:`~datagen.scene.materials.Material` fields), and for meshes the
            :data:`MESH_KEYS`.
    """

    scene: Scene
    params: dict
    objects: list[dict]


class _Layout:
    """Room rectangle regions and capture shapes that a hidden object must respect."""

    def __init__(self, room: dict, capture: dict, gap: float):
        self.room, self.gap = room, gap
        x1, w, s = room["relay_x"], room["corridor_width"], room["bend_side"]
        x_room = x1 - room["room_depth"]
        y_a, y_b = s * w / 2, s * (w / 2 + room["room_length"])
        self.rect = {"room": (x_room, x1, min(y_a, y_b), max(y_a, y_b))}
        self.x1, self.w = x1, w
        self.emitter = np.array(capture["emitter"])
        self.sensor = np.array(capture["sensor"])
        scan = capture.get("scan")
        if scan is None:
            self.spot, self.beam_base = np.array(capture["spot"]), None
            self.fov_corners = np.array(capture["fov_corners"])
        else:   # the beams sweep the pyramid emitter → laser rectangle; the sensor views its grid's rectangle
            self.spot, self.beam_base = None, np.array(rectangle_corners(scan["laser_grid"]))
            self.fov_corners = np.array(rectangle_corners(scan["sensor_grid"] or scan["laser_grid"]))

    def region(self, name: str, depth: float, min_depth: float = 0.0) -> tuple[float, float, float, float]:
        if name == "room":
            return self.rect["room"]
        return (self.x1 - min(depth, self.room["corridor_length"]), self.x1 - min_depth, -self.w / 2, self.w / 2)

    def reject_reason(self, obj: dict, placed: list[dict]) -> str | None:
        g = self.gap
        if any(boxes_overlap(obj, o, g) for o in placed):
            return "overlap"
        if self.beam_base is None and box_hits_segment(obj, self.emitter, self.spot, g):
            return "laser_beam"
        if self.beam_base is not None and box_hits_pyramid(obj, self.emitter, self.beam_base, g):
            return "laser_beam"
        if box_hits_pyramid(obj, self.sensor, self.fov_corners, g):
            return "fov_view"
        return None


def _uniform(rng: np.random.Generator, r: Range) -> float:
    return r.draw(float(rng.random()))


def _sample_point(rng: np.random.Generator, p: PointDist, length: float, w: float, m: float,
                  x1: float) -> list[float]:
    return [x1 - _uniform(rng, p.standoff) * length, _uniform(rng, p.lateral) * (w / 2 - m),
            _uniform(rng, p.height)]


def _check_aperture(dist: RoomDistribution, sensor, center, corners, field: str) -> None:
    """ConfigError when a corner of the imaged rectangle lies behind the sensor's aperture plane (a staring
    aperture faces the rectangle's centre, docs/physics.md §2: cos θ_ap ≤ 0 there, so part of it would be black).
    Exhaustive scans only: a confocal scan's aperture follows the laser (docs/scans.md)."""
    s, c = np.asarray(sensor, float), np.asarray(center, float)
    behind = [q for q in corners if float(np.dot(np.asarray(q) - s, c - s)) <= 0]
    if behind:
        raise ConfigError(f"{dist.source or 'room distribution'}: {field}: the sensor at "
                         f"{np.round(s, 3).tolist()} sees the rectangle corner {np.round(behind[0], 3).tolist()} "
                         "behind its aperture plane (the aperture faces the rectangle's centre); move "
                         "capture.sensor (or the emitter it follows) farther from the wall or nearer the "
                         "rectangle's centre line")


def _sample_capture(dist: RoomDistribution, room: dict, rng: np.random.Generator) -> dict:
    cap, m = dist.capture, dist.capture.edge_margin
    x1, w, h, length = room["relay_x"], room["corridor_width"], room["ceiling"], room["corridor_length"]
    emitter = _sample_point(rng, cap.emitter, length, w, m, x1)
    sensor = list(emitter) if cap.sensor is None else _sample_point(rng, cap.sensor, length, w, m, x1)
    if cap.scan is not None:
        scan = draw_scan(cap.scan, rng, x1, w, h, m)
        if scan["sensor_grid"] is not None:   # a confocal aperture follows the laser: nothing lies behind it
            grid = scan["sensor_grid"]
            _check_aperture(dist, sensor, grid["center"], rectangle_corners(grid), "capture.scan")
        return {"emitter": emitter, "sensor": sensor, "spot": scan["laser_grid"]["center"], "scan": scan}
    spot = [x1, _uniform(rng, cap.spot.lateral) * (w / 2 - m), _uniform(rng, cap.spot.height)]
    fw, fh = _uniform(rng, cap.fov.width), _uniform(rng, cap.fov.height)
    cy = float((rng.random() - 0.5) * (w - 2 * m - fw))          # |cy| <= (w - 2m - fw)/2
    cz = float(m + fh / 2 + rng.random() * (h - 2 * m - fh))
    center = [x1, cy, cz]
    corners = [[x1, cy + a * fw / 2, cz + b * fh / 2] for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return {"emitter": emitter, "sensor": sensor, "spot": spot, "fov_center": center, "fov_size": [fw, fh],
            "fov_corners": corners}


def _mesh_shape(rng: np.random.Generator, cls: MeshObjectDist) -> tuple[dict, tuple[float, float, float]]:
    """Asset (uniform over the files), size, tilt and tilt axis of one mesh object; its box size (3,)."""
    files = asset_files(tuple(cls.assets))
    index = int(rng.integers(len(files)))
    size, tilt, axis = _uniform(rng, cls.size), _uniform(rng, cls.tilt_deg), float(rng.random() * 360.0)
    box_size, _ = asset_box(load_asset(files[index]), size, tilt, axis)
    shape = {"asset": asset_name(tuple(cls.assets), files[index]), "asset_index": index, "scale": size,
             "tilt_deg": tilt, "tilt_axis_deg": axis}
    return shape, tuple(float(v) for v in box_size)


def _sample_object(rng: np.random.Generator, cls_name: str, cls: ObjectDist | MeshObjectDist, layout: _Layout,
                   ceiling: float, gap: float) -> tuple[dict | None, str]:
    regions = cls.placement.regions()
    weights = np.array([r.weight for _, r in regions])
    k = min(int(np.searchsorted(np.cumsum(weights) / weights.sum(), rng.random(), side="right")),
            len(regions) - 1)
    reg_name, reg = regions[k]
    extra: dict = {}
    if cls_name == "mesh":
        extra, (sx, sy, sz) = _mesh_shape(rng, cls)
    else:
        sx = _uniform(rng, cls.size.x)
        sy = sx if cls.cube else _uniform(rng, cls.size.y)
    if cls_name == "pillar":
        sz = ceiling
    elif cls_name == "box":
        sz = sx if cls.cube else _uniform(rng, cls.size.z)
    yaw = _uniform(rng, cls.yaw_deg)
    elevation = 0.0 if cls_name == "pillar" else _uniform(rng, reg.elevation)
    u_x, u_y = rng.random(), rng.random()
    x0, x1, y0, y1 = layout.region(reg_name, getattr(reg, "depth", 0.0), getattr(reg, "min_depth", 0.0))
    a = math.radians(yaw)
    ex = abs(math.cos(a)) * sx / 2 + abs(math.sin(a)) * sy / 2 + gap
    ey = abs(math.sin(a)) * sx / 2 + abs(math.cos(a)) * sy / 2 + gap
    if x1 - x0 < 2 * ex or y1 - y0 < 2 * ey:
        return None, "region_too_small"
    if cls_name != "pillar" and elevation + sz > ceiling - gap:
        return None, "ceiling"
    center = [x0 + ex + u_x * (x1 - x0 - 2 * ex), y0 + ey + u_y * (y1 - y0 - 2 * ey), elevation + sz / 2]
    return {"class": cls_name, "region": reg_name, "center": [float(v) for v in center],
            "size": [float(sx), float(sy), float(sz)], "yaw_deg": float(yaw), **extra}, ""


def _sample_layout(dist: RoomDistribution, layout: _Layout, room: dict,
                   rng: np.random.Generator) -> tuple[list[dict], int]:
    obj = dist.objects
    n_pillars = int(rng.integers(obj.pillar.count.min, obj.pillar.count.max + 1))
    n_boxes = int(rng.integers(obj.box.count.min, obj.box.count.max + 1))
    # drawn only when meshes can occur, so distributions without them keep their geometry stream
    n_meshes = int(rng.integers(obj.mesh.count.min, obj.mesh.count.max + 1)) if obj.mesh.count.max > 0 else 0
    wanted = [("pillar", obj.pillar)] * n_pillars + [("box", obj.box)] * n_boxes + [("mesh", obj.mesh)] * n_meshes
    reasons: dict[str, int] = {}
    tries = 0
    for _ in range(obj.max_layouts):
        placed: list[dict] = []
        for cls_name, cls in wanted:
            for _ in range(obj.max_tries):
                tries += 1
                cand, why = _sample_object(rng, cls_name, cls, layout, room["ceiling"], obj.min_gap)
                if cand is not None:
                    why = layout.reject_reason(cand, placed)
                    if why is None:
                        placed.append(cand)
                        break
                reasons[why] = reasons.get(why, 0) + 1
            else:
                break   # this object failed: restart the layout
        else:
            return placed, tries
    detail = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
    meshes = f", {n_meshes} meshes" if n_meshes else ""
    raise ConfigError(f"{dist.source or 'room distribution'}: objects: could not place {n_pillars} pillars{meshes} and "
                     f"{n_boxes} boxes in a {room['room_depth']:.3g} × {room['room_length']:.3g} m room after "
                     f"{obj.max_layouts} layouts × {obj.max_tries} tries per object; rejections by constraint: "
                     f"{detail}. Lower objects.*.count.max or sizes, or raise objects.max_tries")


def sample_room(dist: RoomDistribution, rngs: Mapping[str, np.random.Generator]) -> SampledRoom:
    """Draw one room from ``dist``.

    Args:
        dist: the distribution.
        rngs: independent generators under keys "geometry", "materials" and "sensor" (see module doc); no
            other randomness is used, so the same generator states give a bit-identical room.
    Returns:
        :class:`SampledRoom`.
    Raises:
        ConfigError: a missing stream, or no valid object layout within the bounded rejection sampling (the
            message counts rejections per constraint: region_too_small, ceiling, overlap, laser_beam,
            fov_view).
    """
    missing = [k for k in STREAMS if k not in rngs]
    if missing:
        raise ConfigError(f"sample_room: rngs lacks streams {missing} (needs {list(STREAMS)})")
    g, ms, ss = rngs["geometry"], rngs["materials"], rngs["sensor"]
    length = _uniform(g, dist.corridor.length)
    width = _uniform(g, dist.corridor.width)
    side = int(dist.room.bend_side[int(g.integers(len(dist.room.bend_side)))])
    room = {"relay_x": float(dist.relay_x), "corridor_start": float(dist.relay_x - length),
            "corridor_length": length, "corridor_width": width, "room_depth": _uniform(g, dist.room.depth),
            "room_length": _uniform(g, dist.room.length), "ceiling": _uniform(g, dist.ceiling),
            "bend_side": side, "closed_end": dist.corridor.closed_end}
    if dist.family != "l_room":
        room["family"] = dist.family
    capture = _sample_capture(dist, room, ss)
    layout = _Layout(room, capture, dist.objects.min_gap)
    objects, tries = _sample_layout(dist, layout, room, g)

    mats = dist.materials
    room_mats = {label: getattr(mats, label).draw(ms.random(UNIFORMS_PER_MATERIAL)) for label in ROOM_LABELS}
    counters = {c: 0 for c in OBJECT_CLASSES}
    if dist.family == "wall":   # the relay wall alone: the corridor end's w × ceiling rectangle
        scene_objects = [quad("relay_wall", (room["relay_x"], -width / 2, 0.0), (0.0, width, 0.0),
                              (0.0, 0.0, room["ceiling"]), room_mats["relay_wall"], "relay_wall")]
    else:
        scene_objects = l_room(room["relay_x"], room["corridor_start"], width, room["room_depth"],
                               room["room_length"], room["ceiling"], side, room["closed_end"], room_mats)
    for o in objects:
        material = getattr(mats, o["class"]).draw(ms.random(UNIFORMS_PER_MATERIAL))
        o["name"] = f"{o['class']}_{counters[o['class']]}"
        counters[o["class"]] += 1
        o["material"] = material.model_dump(mode="json")
        if o["class"] == "pillar":
            scene_objects.append(pillar(o["name"], tuple(o["center"][:2]), tuple(o["size"][:2]), o["size"][2],
                                        o["yaw_deg"], material))
        elif o["class"] == "mesh":
            asset = load_asset(asset_files(tuple(dist.objects.mesh.assets))[o["asset_index"]])
            vertices, transform = place_asset(asset, o["scale"], o["tilt_deg"], o["tilt_axis_deg"], o["center"],
                                              o["yaw_deg"])
            o["transform"] = transform.tolist()
            scene_objects.append(SceneObject(o["name"], "mesh", material, vertices, asset.faces))
        else:
            scene_objects.append(box(o["name"], tuple(o["center"]), tuple(o["size"]), o["yaw_deg"], material))
    objects = [{k: o[k] for k in OBJECT_KEYS + (MESH_KEYS if o["class"] == "mesh" else ())} for o in objects]

    cap = dist.capture
    laser = Laser(emitter=tuple(capture["emitter"]), spot=tuple(capture["spot"]), **cap.laser_settings())
    scan = capture.get("scan")
    if scan is None:
        fov = FieldOfView(center=tuple(capture["fov_center"]), size=tuple(capture["fov_size"]),
                          pixels=cap.fov.pixels)
        fov_params = {"center": capture["fov_center"], "size": capture["fov_size"], "pixels": list(cap.fov.pixels)}
    else:
        fov = fov_params = None
    sensor = Sensor(position=tuple(capture["sensor"]), aperture_radius=cap.aperture_radius, fov=fov)
    scene = Scene(scene_objects, laser, sensor, name=dist.name, source=None, defaults=dict(dist.simulation),
                  capture=None if scan is None else scan_capture(scan))
    origin, size = dist.label_box()
    params = {
        "room": room,
        "materials": {label: m.model_dump(mode="json") for label, m in room_mats.items()},
        "laser": {"emitter": capture["emitter"], "spot": capture["spot"], **cap.laser_settings()},
        "sensor": {"position": capture["sensor"], "aperture_radius": cap.aperture_radius, "fov": fov_params,
                   **({"scan": scan} if scan is not None else {})},
        "objects": objects,
        "label_region": {"origin": origin.tolist(), "size": size.tolist()},
        "layout_tries": tries,
    }
    if dist.motion.walkers.max > 0:
        if "motion" not in rngs:
            raise ConfigError("sample_room: a distribution with walkers needs a 'motion' stream in rngs")
        scene, params["motion"] = _add_walkers(dist, room, scene, objects, rngs["motion"])
    return SampledRoom(scene, params, objects)


PERSON_DEPTH, PERSON_WIDTH = 0.17, 0.43
"""A :func:`~datagen.scene.builders.person`'s bounding box, depth and width over its height."""

def room_floor(room: dict) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi) m: the L-bend room's floor rectangle from a sample's room params (``params["room"]``:
    relay_x, room_depth, room_length, corridor_width, bend_side)."""
    side, half_w = room["bend_side"], room["corridor_width"] / 2
    y_near, y_far = side * half_w, side * (half_w + room["room_length"])
    return room["relay_x"] - room["room_depth"], room["relay_x"], min(y_near, y_far), max(y_near, y_far)


WALK_TRIES = 64
"""Draws of a walker's way (8 uniforms each) before giving up on a room whose objects block every way across."""


def _add_walkers(dist: RoomDistribution, room: dict, scene: Scene, placed: list[dict], rng: np.random.Generator):
    """``scene`` with the walkers of ``dist.motion`` (:class:`~datagen.dataset.rooms.MotionDist`) and its frames;
    their record (name, size, path, speed) for the sample's params. A walker's way is drawn (8 uniforms a try) until
    its straight path, widened by the walker and ``objects.min_gap``, passes every object below its height.

    Raises:
        ConfigError: no way found in :data:`WALK_TRIES` draws."""
    walk = dist.motion
    x_lo, x_hi, y_lo, y_hi = room_floor(room)
    objects, moving, record = list(scene.objects), {}, []
    for i in range(int(rng.integers(walk.walkers.min, walk.walkers.max + 1))):
        for _ in range(WALK_TRIES):
            u = rng.random(8)
            size = [walk.size.x.min + u[0] * (walk.size.x.max - walk.size.x.min),
                    walk.size.y.min + u[1] * (walk.size.y.max - walk.size.y.min),
                    walk.size.z.min + u[2] * (walk.size.z.max - walk.size.z.min)]
            if walk.shape == "person":                             # its proportions (datagen.scene.builders.person)
                size[:2] = [PERSON_DEPTH * size[2], PERSON_WIDTH * size[2]]
            inset = math.hypot(size[0], size[1]) / 2 + 1e-3          # any heading stays inside the room
            ends = [(x_lo + inset + a * (x_hi - x_lo - 2 * inset), y_lo + inset + b * (y_hi - y_lo - 2 * inset))
                    for a, b in (u[3:5], u[5:7])]
            gap = 2 * inset + dist.objects.min_gap
            if not any(box_hits_segment(o, np.array([*ends[0], o["center"][2]]), np.array([*ends[1], o["center"][2]]),
                                        gap) for o in placed + record
                       if o["center"][2] - o["size"][2] / 2 < size[2]):
                break
        else:
            raise ConfigError(f"motion.walkers: no straight walk across the room avoids its objects in {WALK_TRIES} "
                              "draws: fewer or smaller objects, or fewer walkers")
        speed = walk.speed.min + u[7] * (walk.speed.max - walk.speed.min)
        heading = math.degrees(math.atan2(ends[1][1] - ends[0][1], ends[1][0] - ends[0][0]))
        name = f"walker_{i}"
        objects.append(person(name, ends[0], size[2], heading, Material(), "walker") if walk.shape == "person" else
                       box(name, (ends[0][0], ends[0][1], size[2] / 2), tuple(size), heading, Material(), "walker"))
        moving[name] = Moving(WalkMotion(kind="walk", path=ends, speed=speed, at_end="back_and_forth"),
                              objects[-1].vertices,
                              f"motion.walkers ({name})")
        record.append({"name": name, "size": [float(v) for v in size], "path": [[float(v) for v in e] for e in ends],
                       "speed": float(speed), "center": [float(ends[0][0]), float(ends[0][1]), float(size[2] / 2)],
                       "yaw_deg": heading})
    spec = (scene.capture.model_copy(update={"frames": walk.frames}) if scene.capture is not None
            else CaptureSpec(frames=walk.frames))
    out = Scene(objects, scene.laser, scene.sensor, scene.name, scene.source, scene.defaults, spec)
    return out.with_motion(moving), {"walkers": record, "frames": walk.frames.model_dump(mode="json")}
