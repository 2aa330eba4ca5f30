"""What the effect planner knows of a scene's geometry: triangles, their planes, the capture frame, and which
side of each face the laser light can reach (closed meshes are lit from one side only).
"""
from __future__ import annotations

import numpy as np

from ..scene import RayCaster, Scene
from ..scene.capture import Capture
from ..transport import LegPhysics, PhysicsSettings
from ..vectors import matmul, norm

class PlanGeometry:
    """Triangles, their planes and the capture frame, in float64 metres.

    ``lasers`` are the laser points the estimates use: the only one of a single capture, else the corners
    of the laser grid and its most central point (the estimates vary smoothly over a grid on a wall).
    ``corners`` are the laser grid's corners: every laser point lies in their convex hull. ``side`` tells,
    per face, which side light from the laser can ever reach (:func:`reachable_side`).
    """

    def __init__(self, scene: Scene, caster: RayCaster, capture: Capture, tol: float, physics: PhysicsSettings):
        self.scene, self.caster, self.capture, self.tol = scene, caster, capture, tol
        # the per-leg weights (spot emission, sensor collection, first bounce) under ``physics``
        self.physics = LegPhysics(scene, capture, caster, physics)
        self.tri = caster.vertices[caster.faces]                       # (F, 3, 3)
        self.normal = caster.face_normals                               # (F, 3), zero when degenerate
        self.offset = np.einsum("ij,ij->i", self.normal, self.tri[:, 0])
        self.valid = caster.face_area > 0
        self.object = caster.face_object
        c = capture
        lx, ly = c.laser_shape
        grid = np.arange(c.n_lasers).reshape(ly, lx)
        self.corners = np.unique(grid[[0, 0, -1, -1], [0, -1, -1, 0]])
        centre = grid[(ly - 1) // 2, (lx - 1) // 2]
        self.lasers = np.unique(np.append(self.corners, centre))
        hw, hh = 0.5 * c.fov_size[0], 0.5 * c.fov_size[1]
        self.fov_corners = np.array([c.fov_center + a * hw * c.fov_u + b * hh * c.fov_v
                                     for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        # signed distances of every vertex to each laser corner's wall plane (+ = hidden side) and the FoV's
        self.d_spot = np.einsum("fvk,lk->lfv", self.tri, c.spot_normals[self.corners]) \
            - np.einsum("lk,lk->l", c.spots[self.corners], c.spot_normals[self.corners])[:, None, None]
        self.d_fov = matmul(self.tri - c.fov_center, c.fov_normal)          # (F, 3), + = sensor side
        self.front = np.any(self.d_spot > tol, axis=2).any(axis=0)      # (F,) reaches the hidden side
        in_wall = np.all(np.abs(self.d_spot) <= tol, axis=2).all(axis=0)
        in_fov_plane = np.all(np.abs(self.d_fov) <= tol, axis=1)
        albedo = scene.materials.albedo[self.object]
        # hidden triangles: real surfaces off the relay-wall/FoV plane that reflect light
        self.hidden = self.valid & ~in_wall & ~in_fov_plane & (albedo > 0)
        self.side = reachable_side(scene, c.spots[self.corners])       # (F,) +1/−1/0
        bounds = np.stack([caster.vertices.min(axis=0), caster.vertices.max(axis=0)])
        self.diagonal = float(norm(bounds[1] - bounds[0]))
        self.max_sensor_leg = float(np.max(np.linalg.norm(self.fov_corners - c.sensor, axis=1)))

    def names(self, faces: np.ndarray) -> list[str]:
        """Object names of ``faces`` (sorted, unique)."""
        return sorted({self.scene.objects[i].name for i in np.unique(self.object[faces])})


WINDING_INSIDE = 0.75
"""|winding number| above this: the point is inside a closed mesh; below 0.25: outside; between (on the
surface): undecided, both sides are kept."""


def closed_components(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of a mesh that are closed with consistent winding.

    After merging identical vertices a component is closed and consistently wound when each of its directed
    edges occurs exactly once and so does the reverse. Returns (F,) component label per face (−1: the face
    belongs to an open or inconsistent component) and the (F, 3, 3) triangles.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    f = inverse.reshape(-1)[faces]
    n = len(unique)
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    _, vertex_label = connected_components(graph, directed=False)
    label = vertex_label[f[:, 0]]
    fwd = a * n + b
    keys, counts = np.unique(fwd, return_counts=True)
    edge_ok = (a != b) & (counts[np.searchsorted(keys, fwd)] == 1) & np.isin(b * n + a, fwd)
    bad = np.unique(label[~edge_ok.reshape(-1, 3).all(axis=1)])
    return np.where(np.isin(label, bad), -1, label), unique[f]


def winding_number(tri: np.ndarray, point: np.ndarray) -> float:
    """Generalised winding number of ``point`` w.r.t. triangles (F, 3, 3): Σ solid angles / 4π (Van Oosterom &
    Strackee, IEEE TBME 30(2), 1983); ±1 inside a closed surface, 0 outside, ±½ on it."""
    a, b, c = (tri[:, i] - point for i in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb \
        + np.einsum("ij,ij->i", b, c) * la
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * np.pi))


def reachable_side(scene: Scene, spots: np.ndarray) -> np.ndarray:
    """Which side of each face light from the laser can reach: (F,) int8, +1 / −1 the side the face normal
    (vertex winding as given) points to / away from, 0 either side.

    Only closed, consistently wound components restrict it: every ray from the laser spot (lookins, then the
    lookins' cameras) stays in the spot's region, inside or outside the closed surface, so it sees only
    that side of its faces. Inside/outside from the winding number of the spot (:func:`winding_number`),
    orientation from the component's signed volume. All ``spots`` must agree, else 0.
    """
    out = []
    for obj in scene.objects:
        side = np.zeros(len(obj.faces), dtype=np.int8)
        label, tri = closed_components(obj.vertices, obj.faces)
        for comp in np.unique(label[label >= 0]):
            t = tri[label == comp]
            orientation = np.sign(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum())
            sides = set()
            for p in spots:
                w = abs(winding_number(t, p))
                sides.add(0 if 1 - WINDING_INSIDE < w < WINDING_INSIDE
                          else int(-orientation if w >= WINDING_INSIDE else orientation))
            if len(sides) == 1 and orientation != 0:
                side[label == comp] = sides.pop()
        out.append(side)
    return np.concatenate(out)
