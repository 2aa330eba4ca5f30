"""The eye vertex of the order ≥ 2 light tracer: one hidden vertex seen from the FoV, joined to every light vertex.

The light tracer (:mod:`.tracer`) ends a path of order k at the FoV in two ways: a next-event connection from its
k-th vertex x_k to a point y of a pixel region, or its continuation ray landing there. Both sample x_k by following
the light, so a vertex close to the relay wall, where the FoV leg's G(x_k, y) = cosθ_x cosθ_y / r² is large, is
reached no more often than any other: the next-event weight carries that 1/r², and a few such paths carry much of
the estimate (on a confocal scan's order 2, the top 1 % of the impulses carried 21 % of the light, weight CV² ≈ 8).

The third strategy samples x_k from the FoV's side instead: a point y uniform in one of the pixel regions the path's
laser point records (chosen uniformly among them), a cosine-weighted direction from y into the room, and its hit z
(density cosθ_y cosθ_z / (π r²) in area measure: the FoV leg's own G). Every light vertex x_{k−1} of the path is
then joined to z by a shadow ray: a path of order k whose last leg's 1/r² is sampled, not weighed. The three are
combined by the balance heuristic (Veach & Guibas 1995) over the densities of (x_k, y) given the path up to x_{k−1}:

- next event:  p_light(x_k | x_{k−1}) · p_A
- eye vertex:  p_A / n_rec · g(x_k, y)
- direction hit: p_light(x_k | x_{k−1}) · q_k · g(x_k, y)

with p_A = 1 / A_pixel, n_rec the pixel regions the laser point records, g = cosθ_y cosθ_x / (π r²) and
p_light(x_k | x_{k−1}) = q_{k−1} cosθ_{k−1} cosθ_{k,in} / (π d²) (Russian roulette at x_{k−1}, then a cosine
direction; at a retroreflective vertex both light densities carry the factor s of its lobe sampler,
:func:`~datagen.scene.brdf_kernel.sampling_ratio`). Each weight is bounded: near the relay wall the eye vertex takes over, near a corner between hidden
surfaces the light's own continuation does. docs/physics.md §2 ("Light of every order") gives the estimator.

Every leg weight is the one the other strategies use (:func:`~datagen.transport.physics.fov_connection_weight`,
:func:`~datagen.transport.leg_kernels.sensor_collection`, the BRDFs of :mod:`datagen.scene.brdf_kernel`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...sampling import square_to_hemisphere
from ...sampling.directions import to_world
from ...scene import RayCaster
from ...scene.capture import Capture
from ...vectors import dot
from ..leg_kernels import sensor_collection
from ..physics import LegPhysics, fov_connection_weight, geometry_weight

EYE_MIN_ORDER = 2
"""The lowest order the eye vertex serves: joined to the light's first hidden vertex it makes a path of order 2
(order 1, laser spot to the eye vertex, is the estimators' primary)."""


@dataclass(frozen=True)
class PixelTable:
    """The pixel regions each laser point records, as ranges of one table (the tracer's next-event targets).

    Attributes:
        first, count: (n_lasers,) int64, laser point l records table rows first[l] … first[l] + count[l] − 1;
        ix, iy, pix: (T,) int64 each row's pixel column, row and index; area: one pixel region's area, m².
    """

    first: np.ndarray
    count: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    pix: np.ndarray
    area: float

    @property
    def max_count(self) -> int:
        """The most pixel regions one laser point records."""
        return int(self.count.max()) if len(self.count) else 0


@dataclass
class EyeVertices:
    """One eye vertex per light path (:func:`eye_vertices`); rows follow the batch's paths.

    Attributes:
        ok: (n,) bool, the path has one (its laser point records a pixel region and the ray from y hit a surface).
        z, n_z: (n, 3) the vertex and its normal (facing y); obj: (n,) int64 its object.
        w_zy: (n, 3) unit direction z → y. r: (n,) |y − z|, m. g: (n,) cosθ_y cosθ_z / (π r²), 1/m².
        fov: (n,) the FoV leg per unit radiant intensity of z toward y,
            :func:`~datagen.transport.physics.fov_connection_weight` (cosθ_y A_pixel, r, collection).
        d_ys: (n,) the FoV point's distance to the sensor, m. row: (n,) int64 the pixel table's row of y's pixel.
        n_rec: (n,) float64 the pixel regions the path's laser point records (the choice's 1 / probability).
    """

    ok: np.ndarray
    z: np.ndarray
    n_z: np.ndarray
    obj: np.ndarray
    w_zy: np.ndarray
    r: np.ndarray
    g: np.ndarray
    fov: np.ndarray
    d_ys: np.ndarray
    row: np.ndarray
    n_rec: np.ndarray


def eye_vertices(capture: Capture, caster: RayCaster, physics: LegPhysics, pixels: PixelTable, laser: np.ndarray,
                 rng: np.random.Generator, uniforms: np.ndarray | None = None) -> EyeVertices:
    """Sample one eye vertex for each path of laser points ``laser`` (n,) int64 (module docstring): a uniform pixel
    region among the ``pixels`` its laser point records, a uniform point y in it, a cosine-weighted direction about
    the FoV normal, and the ray's hit (aperture captures: the FoV leg of ``physics``). ``uniforms`` (n, 5): the
    uniforms to use in that order (the tracer's aligned draws) instead of five draws from ``rng``."""
    c, cst, ph = capture, caster, physics
    n = len(laser)
    if uniforms is None:
        def take(_):
            return rng.random(n)
    else:
        def take(k):
            return uniforms[:, k]
    count = pixels.count[laser]
    pick = np.minimum((take(0) * count).astype(np.int64), np.maximum(count - 1, 0))
    row = np.minimum(pixels.first[laser] + pick, max(len(pixels.ix) - 1, 0))
    y = c.region_points(pixels.ix[row], pixels.iy[row], take(1), take(2)) if len(pixels.ix) \
        else np.zeros((n, 3))
    normal = np.broadcast_to(np.asarray(c.fov_normal, dtype=np.float64), (n, 3))
    local, _ = square_to_hemisphere(take(3), take(4), "cosine")
    w = to_world(local, normal)
    hits = cst.intersect(y + cst.offset * normal, w)
    cos_y = local[:, 2]
    cos_z = -dot(hits.normals, w)
    ok = (count > 0) & hits.hit & (cos_y > 0) & (cos_z > 0)
    r = np.where(ok, hits.distance, 1.0)
    g = np.where(ok, geometry_weight(cos_y, cos_z, r) / np.pi, 0.0)
    fov, d_ys = np.zeros(n), np.zeros(n)
    rows = np.flatnonzero(ok)
    if len(rows):
        collect, d_ys[rows] = sensor_collection(ph, y[rows], normal[rows], np.full(len(rows), ph.wall_object), w[rows])
        fov[rows] = fov_connection_weight(cos_y[rows] * pixels.area, r[rows], collect)
    ok &= fov > 0
    return EyeVertices(ok, hits.points, hits.normals, hits.object_id.astype(np.int64), -w, r, g, fov, d_ys, row,
                       count.astype(np.float64))


@njit(cache=True, inline="always")
def eye_share(p_a, g, n_rec, p_in):
    """The eye strategy's balance-heuristic term over the next-event strategy's density, p_A g / (n_rec p_in): added
    to the denominators of the next-event and direction-hit weights of a path of an order the eye vertex serves
    (``p_in``: p_light(x_k | x_{k−1}), the light's density of the vertex in area measure, 1/m²). A scalar device
    function for the compiled next-event weights (:func:`~.kernels.nee_weights`); on arrays through
    :func:`~datagen.scene.brdf_kernel.on_arrays`."""
    return p_a * g / (n_rec * np.maximum(p_in, 1e-300))
