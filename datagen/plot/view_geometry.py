"""What the 3D pictures draw, as plain arrays: coloured meshes, lines, points and legend entries.

:func:`build_drawables` turns a :class:`~datagen.scene.Scene` into a :class:`Drawables`: every object
coloured by its class (:data:`CLASS_COLORS`), the emitter and the laser beam to its spot(s), the sensor with
its lines of sight to the FoV rectangle (or the sensor / laser scan grid), optionally the lookins of a run
(:func:`lookin_points`), and the legend entries for them. No open3d here except the ray queries of the
cut-away (``open3d.t.geometry.RaycastingScene``, module passed in).

Cut-away. Room surfaces labelled ``wall`` or ``ceiling`` that stand between the camera and anything else of
the scene (the floor, the relay wall, the hidden objects, the emitter and sensor) are not drawn; their
outline is drawn in light grey instead. The test casts rays from sample points of the scene toward the
camera (:func:`cut_away_groups`); a surface is cut as a whole plane of its object.

Colours are flat class colours with a fixed headlight shading baked into each face (``shading="shaded"``)
or none (``shading="flat"``: every pixel of an object is exactly its class colour).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..scene import RayCaster, Scene, resolve_capture
from ..scene.builders import box_mesh
from ..scene.parts import ROOM_LABELS
from ..simulation import SimulationConfig
from ..simulation.config import STREAM_SAMPLING, stream_rng
from ..simulation.replicas import replica_rng, replica_root
from ..transport import LookinSampler, estimator
from .view_camera import ViewCamera, auto_camera, frame, safe_unit, scene_size

CLASS_COLORS: dict[str, tuple[float, float, float]] = {
    "relay_wall": (0.55, 0.74, 0.93),   # light blue: the visible wall the laser and the sensor point at
    "wall": (0.80, 0.80, 0.77),         # light warm grey
    "floor": (0.76, 0.66, 0.50),        # sand
    "ceiling": (0.90, 0.90, 0.90),      # near white (usually cut away)
    "box": (0.93, 0.53, 0.13),          # orange
    "pillar": (0.55, 0.36, 0.74),       # purple
    "mesh": (0.18, 0.62, 0.58),         # teal
}
"""RGB in [0, 1] of each object class (the scene's ``label``); other labels take :data:`EXTRA_COLORS`."""

EXTRA_COLORS = ((0.84, 0.30, 0.55), (0.40, 0.60, 0.20), (0.30, 0.45, 0.80), (0.60, 0.45, 0.30))
"""Colours of labels outside :data:`CLASS_COLORS`, in order of first appearance (cycled)."""

LASER_COLOR = (0.90, 0.05, 0.05)
SENSOR_COLOR = (0.10, 0.22, 0.75)
FOV_COLOR = (0.10, 0.72, 0.22)
LOOKIN_COLOR = (0.05, 0.05, 0.05)
LOOKIN_CORE_COLOR = (1.0, 0.88, 0.0)
LOOKIN_CUT_COLOR = (0.80, 0.80, 0.80)
"""Lookins on a cut-away wall or ceiling float where that surface was: drawn grey, not yellow."""
EDGE_COLOR = (0.25, 0.25, 0.25)
CUT_EDGE_COLOR = (0.62, 0.62, 0.62)

ON_SURFACE_REL = 1e-4
"""A point lies on a surface when within this fraction of the scene size of it (float32 distance queries)."""

FOV_FILL_MIX = 0.45
"""The FoV rectangle is filled with this mix of FoV green into the relay-wall colour (the wall stays legible)."""

CUT_LABELS = ("wall", "ceiling")
"""Room surfaces that are cut away where they hide the rest of the scene from the camera."""

AMBIENT = 0.7
"""Shaded mode: a face gets AMBIENT + (1 − AMBIENT)·|n·l| of its colour (l: the headlight), so faces at
different angles stay distinguishable while the darkest keeps its hue."""

MARKER_REL = 0.012
"""Radius of the emitter / spot / sensor markers as a fraction of the scene size (bounding-box diagonal)."""

DEPTH_BIAS_REL = 4e-3
"""Lines and points drawn on surfaces are moved toward the camera by this fraction of the scene size (an
orthographic camera: the picture does not change) so that they win the depth test against their surface."""

CUT_SAMPLES = 4000
"""Sample points on the scene's surfaces (area-weighted) whose rays toward the camera decide the cut-away."""

MAX_GRID_LINES = 48
"""FoV pixel grids with more cells than this per side are drawn as an outline and sensor points only."""

LINE_WIDTH_PX = 1.6
"""Width of outline edges in output pixels (beams and view lines are drawn wider)."""


@dataclass
class Drawables:
    """Everything drawn, as plain arrays (world metres); built by :func:`build_drawables`.

    Attributes:
        meshes: list of (name, vertices (3F, 3) float64 triangle soup, colours (3F, 3) float64 in [0, 1]).
        lines: list of (name, segments (E, 2, 3) float64, colour (3,), width in output pixels).
        points: list of (name, points (N, 3) float64, colour (3,), size in output pixels).
        legend: list of (text, kind "patch" | "line" | "point" | "ringed" (lookins: points ringed in
            LOOKIN_COLOR), colour (3,)).
        cut: names of the objects with cut-away faces.
        camera: the framed :class:`~datagen.plot.view_camera.ViewCamera`.
    """

    meshes: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    points: list = field(default_factory=list)
    legend: list = field(default_factory=list)
    cut: list = field(default_factory=list)
    camera: ViewCamera | None = None


# -- mesh helpers (numpy only) ----------------------------------------------------------------------------


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals (right-hand winding) of triangles ``faces`` (F, 3) int of ``vertices`` (V, 3) m."""
    tri = vertices[faces]
    return safe_unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))


def feature_edges(vertices: np.ndarray, faces: np.ndarray, crease_cos: float = 0.999) -> np.ndarray:
    """(E, 2, 3) float64 edges that outline a mesh: boundary edges and creases between faces whose normals
    differ by more than ``crease_cos`` (the diagonals of flat quads are dropped)."""
    if len(faces) == 0:
        return np.zeros((0, 2, 3))
    n = face_normals(vertices, faces)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face = np.tile(np.arange(len(faces)), 3)
    key = np.sort(edges, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    _, last_rev = np.unique(key[::-1], axis=0, return_index=True)
    last = len(key) - 1 - last_rev
    flat = (counts == 2) & (np.abs(np.einsum("ij,ij->i", n[face[first]], n[face[last]])) > crease_cos)
    return vertices[edges[first[~flat]]]


def plane_groups(vertices: np.ndarray, faces: np.ndarray, tol: float) -> np.ndarray:
    """(F,) int64 group id of each face: faces on one plane (normal up to sign, offset within ``tol`` m) share
    an id (the cut-away removes a wall plane as a whole)."""
    n = face_normals(vertices, faces)
    lead = np.argmax(np.abs(n), axis=1)
    n = n * np.sign(n[np.arange(len(n)), lead])[:, None]
    d = np.einsum("ij,ij->i", n, vertices[faces[:, 0]])
    key = np.concatenate([np.round(n, 3), np.round(d / max(tol, 1e-12))[:, None]], axis=1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    return inverse.reshape(-1).astype(np.int64)


def area_samples(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count + F, 3) points: ``count`` drawn uniformly by area over the triangles, then every centroid."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if area.sum() <= 0:
        return tri.mean(axis=1)
    pick = rng.choice(len(faces), size=count, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    t = tri[pick]
    pts = (1 - r1)[:, None] * t[:, 0] + (r1 * (1 - r2))[:, None] * t[:, 1] + (r1 * r2)[:, None] * t[:, 2]
    return np.concatenate([pts, tri.mean(axis=1)])


def soup(vertices: np.ndarray, faces: np.ndarray, color, shade: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray]:
    """Triangle soup of both windings (double-sided) and per-vertex colours, (6F, 3) and (6F, 3) float64;
    ``shade`` (F,) scales each face's colour (None: flat)."""
    tri = vertices[faces]                                               # (F, 3, 3)
    both = np.concatenate([tri, tri[:, ::-1]]).reshape(-1, 3)
    c = np.broadcast_to(np.asarray(color, dtype=np.float64), (len(faces), 3))
    if shade is not None:
        c = c * shade[:, None]
    return both, np.repeat(np.concatenate([c, c]), 3, axis=0)


def sphere_marker(center: np.ndarray, radius: float, rings: int = 8, sectors: int = 14
                  ) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere around ``center`` (m): (V, 3) float64 vertices and (F, 3) int faces."""
    th = np.linspace(0, np.pi, rings + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, sectors, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) * radius + center
    last = len(verts) - 1
    j = np.arange(sectors)
    jn = (j + 1) % sectors
    faces = [np.stack([np.zeros(sectors, int), 1 + j, 1 + jn], axis=1)]
    for r in range(rings - 2):
        a, b = 1 + r * sectors, 1 + (r + 1) * sectors
        faces += [np.stack([a + j, b + j, b + jn], axis=1), np.stack([a + j, b + jn, a + jn], axis=1)]
    base = 1 + (rings - 2) * sectors
    faces.append(np.stack([np.full(sectors, last), base + jn, base + j], axis=1))
    return verts, np.concatenate(faces)


def grid_segments(center, u, v, size, cells) -> np.ndarray:
    """(E, 2, 3) lines of an nx×ny cell grid of size (w, h) m around ``center`` in the (u, v) frame."""
    nx, ny = cells
    w, h = size
    a = (np.arange(nx + 1) / nx - 0.5) * w
    b = (np.arange(ny + 1) / ny - 0.5) * h
    vert = np.stack([center + a[:, None] * u - 0.5 * h * v, center + a[:, None] * u + 0.5 * h * v], axis=1)
    horiz = np.stack([center - 0.5 * w * u + b[:, None] * v, center + 0.5 * w * u + b[:, None] * v], axis=1)
    return np.concatenate([vert, horiz])


# -- colours, cut-away, lookins ---------------------------------------------------------------------------


def class_colors(labels: Iterable[str]) -> dict[str, tuple[float, float, float]]:
    """Colour of every label: :data:`CLASS_COLORS`, then :data:`EXTRA_COLORS` in order of appearance."""
    out, extra = {}, 0
    for label in labels:
        if label in out:
            continue
        if label in CLASS_COLORS:
            out[label] = CLASS_COLORS[label]
        else:
            out[label] = EXTRA_COLORS[extra % len(EXTRA_COLORS)]
            extra += 1
    return out


def cut_away_groups(o3d, scene: Scene, forward: np.ndarray, rng: np.random.Generator) -> dict[int, np.ndarray]:
    """Which faces of the :data:`CUT_LABELS` surfaces hide the rest of the scene from a camera looking along
    ``forward`` (orthographic).

    Rays go from :data:`CUT_SAMPLES` area-weighted points on every other surface, plus the emitter, spot and
    sensor, toward the camera (along −forward); every plane group (:func:`plane_groups`) of a cut-label object
    that any of them crosses is cut.

    Args:
        o3d: the open3d module (:func:`datagen.plot.view_worker.require_open3d`).
    Returns:
        object index → (F_obj,) bool, True for the faces cut away (objects with no cut face are absent).
    """
    size = scene_size(scene)
    candidates = [i for i, o in enumerate(scene.objects) if o.label in CUT_LABELS]
    others = [o for o in scene.objects if o.label not in CUT_LABELS]
    if not candidates or not others:
        return {}
    verts = np.concatenate([o.vertices for o in others])
    offsets = np.cumsum([0] + [len(o.vertices) for o in others[:-1]])
    faces = np.concatenate([o.faces + off for o, off in zip(others, offsets)])
    targets = np.concatenate([area_samples(verts, faces, CUT_SAMPLES, rng),
                              [scene.laser.emitter, scene.laser.spot, scene.sensor.position]])
    rs = o3d.t.geometry.RaycastingScene()
    groups, ids = {}, {}
    for i in candidates:
        o = scene.objects[i]
        groups[i] = plane_groups(o.vertices, o.faces, ON_SURFACE_REL * size)
        ids[int(rs.add_triangles(o.vertices.astype(np.float32), o.faces.astype(np.uint32)))] = i
    back = -np.asarray(forward, dtype=np.float64)
    origins = targets + ON_SURFACE_REL * size * back
    rays = np.concatenate([origins, np.broadcast_to(back, origins.shape)], axis=1).astype(np.float32)
    res = rs.list_intersections(rays)
    geo, prim = res["geometry_ids"].numpy().astype(np.int64), res["primitive_ids"].numpy().astype(np.int64)
    out = {}
    for gid, i in ids.items():
        sel = geo == gid
        if sel.any():
            out[i] = np.isin(groups[i], np.unique(groups[i][prim[sel]]))
    return out


def on_faces(o3d, points: np.ndarray, meshes: list, tol: float) -> np.ndarray:
    """(N,) bool: ``points`` (N, 3) m within ``tol`` m of any triangle of ``meshes`` [(vertices, faces)]."""
    meshes = [(v, f) for v, f in meshes if len(f)]
    if not meshes or not len(points):
        return np.zeros(len(points), dtype=bool)
    rs = o3d.t.geometry.RaycastingScene()
    for v, f in meshes:
        rs.add_triangles(v.astype(np.float32), f.astype(np.uint32))
    return rs.compute_distance(points.astype(np.float32)).numpy() <= tol


def lookin_points(scene: Scene, config: SimulationConfig, rng: np.random.Generator | None = None) -> np.ndarray:
    """Hit points of the lookins a simulation of ``scene`` with ``config`` casts (the lookin estimator).

    Follows :class:`datagen.simulation.run.Replicas` and :meth:`datagen.transport.LookinSampler.run_replicas`: the
    config's first round of ``replicas`` runs on the replica grid, each with one root ``SeedSequence``, then per
    laser point one child stream for its lookins (jittered grids) and one per batch of hit lookins
    (tests/test_view.py checks the points equal those of a run).

    Args:
        config: :class:`~datagen.simulation.SimulationConfig` (lookins, lookin_pdf, jitter, batch, seed).
        rng: the run's sampling stream (default ``stream_rng(config.seed, STREAM_SAMPLING)``, as ``simulate``;
            a dataset sample passes its ``sampling`` stream).
    Returns:
        (N, 3) float64 metres, the lookins that hit a surface, over every laser point.
    """
    rng = rng if rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    root_seed = replica_root(rng)                                     # as simulation.run.Replicas
    entry = estimator("lookin")
    one = config.with_estimator(**entry.replica(config.estimator, config.error.replicas)) if entry.replica else config
    transport = LookinSampler(scene, one.transport_settings())
    s = transport.settings
    out = []
    for replica in range(config.error.replicas):                            # as LookinSampler.run_replicas
        root = np.random.SeedSequence(int(replica_rng(root_seed, replica).integers(0, 2 ** 63)))
        for laser in range(transport.capture.n_lasers):
            look = transport.lookins(np.random.default_rng(root.spawn(1)[0]) if s.jitter else None, laser)
            if s.jitter:
                root.spawn(-(-int(look.hit.sum()) // s.batch))       # the run's per-batch streams
            out.append(look.points[look.hit])
    return np.concatenate(out) if out else np.zeros((0, 3))


# -- the whole picture ------------------------------------------------------------------------------------


def _objects(d: Drawables, o3d, scene: Scene, cam: ViewCamera, shading: str, edges: bool, cut_away: bool,
             bias: np.ndarray) -> tuple[list, dict]:
    """Add the scene's objects (cut-away applied) and their legend to ``d``; returns (points to frame,
    the cut-away masks of :func:`cut_away_groups`)."""
    light = safe_unit(-cam.forward + 0.3 * cam.up - 0.6 * cam.right)
    cut = cut_away_groups(o3d, scene, cam.forward, np.random.default_rng(0)) if cut_away else {}
    colors = class_colors(scene.labels)
    counts: dict[str, int] = {}
    for o in scene.objects:
        counts[o.label] = counts.get(o.label, 0) + 1
    frame_pts, cut_labels = [], set()
    for i, o in enumerate(scene.objects):
        mask = cut.get(i, np.zeros(len(o.faces), dtype=bool))
        keep = o.faces[~mask]
        if len(keep):
            shade = AMBIENT + (1 - AMBIENT) * np.abs(face_normals(o.vertices, keep) @ light) \
                if shading == "shaded" else None
            d.meshes.append((o.name, *soup(o.vertices, keep, colors[o.label], shade)))
            frame_pts.append(o.vertices[np.unique(keep)])
            if edges:
                d.lines.append((f"{o.name} edges", feature_edges(o.vertices, keep) + bias, EDGE_COLOR,
                                LINE_WIDTH_PX))
        if mask.any():
            cut_labels.add(o.label)
            d.cut.append(o.name)
            outline = feature_edges(o.vertices, o.faces[mask])
            # half the bias: where an outline meets a kept edge (the relay wall's top), the kept edge wins
            d.lines.append((f"{o.name} cut away", outline + 0.5 * bias, CUT_EDGE_COLOR, LINE_WIDTH_PX))
            frame_pts.append(outline.reshape(-1, 3))
    for label, color in colors.items():
        n = counts[label]
        text = label.replace("_", " ") + (f" ×{n}" if n > 1 and label not in ROOM_LABELS else "")
        d.legend.append((text + (" (cut away where in front)" if label in cut_labels else ""), "patch", color))
    if cut_labels:
        d.legend.append(("outline of a cut-away surface", "line", CUT_EDGE_COLOR))
    return frame_pts, cut


def _laser_and_sensor(d: Drawables, scene: Scene, cap, bias: np.ndarray) -> list:
    """Add the emitter, beams and spots, the sensor, its lines of sight and the FoV / scan grid (with their
    legend) to ``d``; returns the points to frame."""
    r = MARKER_REL * scene_size(scene)
    emitter = np.asarray(scene.laser.emitter, dtype=np.float64)
    spots = np.asarray(cap.spots, dtype=np.float64)
    lx, ly = cap.laser_shape
    corners = sorted({0, lx - 1, (ly - 1) * lx, lx * ly - 1}) if len(spots) > 1 else [0]
    beams = np.stack([np.broadcast_to(emitter, (len(corners), 3)), spots[corners]], axis=1)
    d.meshes.append(("emitter", *soup(*sphere_marker(emitter, 1.3 * r), LASER_COLOR)))
    d.lines.append(("laser beam", beams + bias, LASER_COLOR, 2.5))
    if len(spots) == 1:
        d.meshes.append(("laser spot", *soup(*sphere_marker(spots[0], 0.8 * r), LASER_COLOR)))
    else:
        d.points.append(("laser grid", spots + bias, LASER_COLOR, 5.0))
    d.legend.append(("laser: emitter (sphere), beam" + (" and spot" if len(spots) == 1 else
                     f"s to the corners of its {lx}×{ly} scan grid (dots)"), "line", LASER_COLOR))
    sensor = np.asarray(cap.sensor, dtype=np.float64)
    d.meshes.append(("sensor", *soup(*box_mesh(tuple(sensor), (2.2 * r,) * 3), SENSOR_COLOR)))
    c, u, v, fs = cap.fov_center, cap.fov_u, cap.fov_v, cap.fov_size
    hu, hv = 0.5 * fs[0] * u, 0.5 * fs[1] * v
    rect = c + np.array([-hu - hv, hu - hv, hu + hv, -hu + hv])
    d.lines.append(("sensor view", np.stack([np.broadcast_to(sensor, (4, 3)), rect], axis=1) + bias,
                    SENSOR_COLOR, 1.2))
    nx, ny = cap.fov_pixels
    wall_color = np.asarray(class_colors(scene.labels).get("relay_wall", CLASS_COLORS["relay_wall"]))
    fill = (1 - FOV_FILL_MIX) * wall_color + FOV_FILL_MIX * np.asarray(FOV_COLOR)
    aperture = cap.convention == "aperture"
    if min(fs) > 0 and aperture:
        d.meshes.append(("fov", *soup(rect + 0.5 * bias, np.array([[0, 1, 2], [0, 2, 3]]), fill)))
    outline = np.stack([rect, np.roll(rect, -1, axis=0)], axis=1)
    cells = aperture and 1 < max(nx, ny) <= MAX_GRID_LINES and min(fs) > 0
    grid = grid_segments(c, u, v, fs, (nx, ny)) if cells else outline     # point radiance: points, no cells
    d.lines.append(("fov", grid + bias, FOV_COLOR, 2.0))
    what = {"single": "FoV", "confocal": "confocal scan grid (laser = sensor points)",
            "exhaustive": "sensor grid"}[cap.kind]
    if nx * ny > 1:
        d.points.append(("sensor points", cap.sensor_points().reshape(-1, 3) + bias, FOV_COLOR, 4.0))
        what += f" {nx}×{ny} points"
    d.legend.append((f"{what}, {fs[0]:.3g}×{fs[1]:.3g} m", "patch" if aperture else "point",
                     tuple(fill) if aperture else FOV_COLOR))
    d.legend.append(("sensor (cube) and its view of the FoV", "line", SENSOR_COLOR))
    return [emitter[None], spots, sensor[None], rect]


def build_drawables(o3d, scene: Scene, *, lookins: np.ndarray | None = None, shading: str = "shaded",
                    edges: bool = True, camera: ViewCamera | None = None, aspect: float = 1.5,
                    cut_away: bool = True, extra: Drawables | None = None) -> Drawables:
    """Assemble the coloured geometry, lines, points and legend of ``scene`` for a camera.

    Args:
        o3d: the open3d module (:func:`datagen.plot.view_worker.require_open3d`), for the cut-away's rays.
        lookins: (N, 3) m lookin hit points to overlay (:func:`lookin_points`), or None.
        shading: "shaded" (headlight baked into faces) or "flat" (exact class colours).
        edges: draw the objects' outlines.
        camera: a camera (default :func:`~datagen.plot.view_camera.auto_camera`); framed here to everything
            drawn at ``aspect`` = width / height.
        cut_away: cut away the walls and ceiling that hide the scene (:func:`cut_away_groups`).
        extra: more lines and legend entries to draw on surfaces (a multi-zone scene's lit patch and zones,
            :func:`datagen.plot.view_flood.flood_drawables`), or None.
    Raises:
        SceneError: the capture cannot be resolved (a laser spot off every surface, a FoV the sensor cannot see).
        ValueError: unknown shading.
    """
    if shading not in ("shaded", "flat"):
        raise ValueError(f"shading must be 'shaded' or 'flat', got {shading!r}")
    cap = resolve_capture(scene, RayCaster(scene))
    cam = camera or auto_camera(scene, cap)
    size = scene_size(scene)
    bias = -cam.forward * DEPTH_BIAS_REL * size          # toward the camera
    d = Drawables()
    frame_pts, cut = _objects(d, o3d, scene, cam, shading, edges, cut_away, bias)
    frame_pts += _laser_and_sensor(d, scene, cap, bias)
    if extra is not None:
        d.lines += [(name, seg + 1.5 * bias, color, width) for name, seg, color, width in extra.lines]
        d.legend += extra.legend
    if lookins is not None and len(lookins):
        pts = np.asarray(lookins, dtype=np.float64).reshape(-1, 3)
        on_cut = on_faces(o3d, pts, [(scene.objects[i].vertices, scene.objects[i].faces[m]) for i, m in cut.items()],
                          ON_SURFACE_REL * size)
        d.points.append(("lookins", pts + bias, LOOKIN_COLOR, 7.0))
        for sel, color, what in ((~on_cut, LOOKIN_CORE_COLOR, "lookins"),
                                 (on_cut, LOOKIN_CUT_COLOR, "lookins on cut-away surfaces")):
            if sel.any():                                    # a coloured dot in a black ring
                d.points.append((what, pts[sel] + 1.5 * bias, color, 3.5))
                d.legend.append((f"{what} ({int(sel.sum())} of {len(pts)} hit points)", "ringed", color))
    d.camera = frame(cam, np.concatenate(frame_pts), aspect)
    return d
