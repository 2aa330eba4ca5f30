"""Scene sampling as in Scholes & Leach 2024 §3.1: lookins from the laser spot, hemispherical cameras.

- **Lookins**: N = n×n rays from the laser spot over the hemisphere about the relay-wall normal, one per cell
  of a stratified n×n grid on the unit square mapped to the hemisphere by the concentric (Shirley–Chiu 1997)
  disk map, then lifted to the hemisphere either *cosine-weighted* (Malley's method, pdf p(ω) = cos θ/π) or
  *uniform* (equal-area lift z = 1 − r², pdf p(ω) = 1/(2π)). With ``jitter`` each ray takes a uniform
  random position inside its cell (stratified Monte Carlo, unbiased); without, the cell centre (the paper's
  regular grid). The first hit of each ray is a lookin.
- **Hemispherical camera**: at each lookin a 180° camera of l×p pixels aligned with the surface normal.
  Pixels are the cells of an l×p grid under the *uniform* (equal-area) map, so every pixel covers the same
  solid angle 2π/(l·p) exactly and they sum to 2π. Each pixel's ray (its centre, or a jittered point
  inside it) gives an *observed point* with position, normal, object, material (via the object) and depth.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.materials import tangent_frame
from ..scene import RayCaster
from .directions import HemispherePdf, square_to_hemisphere, stratified_grid, to_world
from ..vectors import matmul


@dataclass(frozen=True)
class Lookins:
    """N lookin rays from the laser spot and what they hit.

    Attributes:
        n_rays: N, rays cast (the Monte Carlo denominator; missed rays count).
        directions: (N, 3) float64 unit directions from the spot.
        pdf: (N,) float64 sampling density of each direction, 1/sr.
        hit: (N,) bool.
        points, normals: (N, 3) float64 lookin positions (m) and unit normals facing the spot.
        object_id: (N,) int64.
        distance: (N,) float64 R_j, spot→lookin (m).
    """

    n_rays: int
    directions: np.ndarray
    pdf: np.ndarray
    hit: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    object_id: np.ndarray
    distance: np.ndarray


def sample_lookins(caster: RayCaster, spot: np.ndarray, spot_normal: np.ndarray, n_side: tuple[int, int],
                   pdf: HemispherePdf, rng: np.random.Generator | None) -> Lookins:
    """Cast the paper's √N×√N grid of lookin rays from the laser spot (Scholes & Leach 2024 §3.1, Eq. 2).

    Args:
        spot: (3,) laser spot (m); spot_normal: (3,) relay-wall normal there, facing the hidden scene.
        n_side: grid size (n_u, n_v); N = n_u·n_v.
        pdf: hemisphere mapping (see :func:`square_to_hemisphere`).
        rng: jitter generator, or None for cell centres.
    """
    uv = stratified_grid(n_side[0], n_side[1], rng)[0]
    local, density = square_to_hemisphere(uv[:, 0], uv[:, 1], pdf)
    normal = np.broadcast_to(spot_normal, local.shape)
    directions = to_world(local, normal)
    origin = spot + caster.offset * spot_normal
    hits = caster.intersect(np.broadcast_to(origin, directions.shape), directions)
    distance = np.where(hits.hit, np.linalg.norm(hits.points - spot, axis=-1), np.inf)
    return Lookins(len(directions), directions, density, hits.hit, hits.points, hits.normals, hits.object_id,
                   distance)


@dataclass(frozen=True)
class ObservedPoints:
    """Observed points of a batch of B lookins, l×p = P pixels each (Scholes & Leach 2024 §3.1).

    Attributes:
        directions: (B, P, 3) float64 world ray directions from each lookin.
        local_z: (B, P) float64 cos θ of each ray against the lookin normal.
        solid_angle: float, sr per pixel, 2π/P (identical for all pixels).
        hit: (B, P) bool.
        points, normals: (B, P, 3) float64 positions and unit normals facing the lookin.
        object_id: (B, P) int64.
        distance: (B, P) float64 lookin→observed point (m), inf where no hit.
    """

    directions: np.ndarray
    local_z: np.ndarray
    solid_angle: float
    hit: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    object_id: np.ndarray
    distance: np.ndarray


def camera_solid_angle(pixels: tuple[int, int]) -> float:
    """Solid angle of one pixel of the l×p equal-area hemispherical camera: 2π/(l·p) sr."""
    return 2.0 * np.pi / (pixels[0] * pixels[1])


def observe(caster: RayCaster, points: np.ndarray, normals: np.ndarray, pixels: tuple[int, int],
            rng: np.random.Generator | None) -> ObservedPoints:
    """Render the hemispherical camera of each lookin: cast l×p rays per lookin.

    Args:
        points, normals: (B, 3) lookin positions and normals.
        pixels: (l, p) camera resolution.
        rng: per-lookin pixel jitter generator, or None for pixel centres.
    """
    b = len(points)
    uv = stratified_grid(pixels[0], pixels[1], rng, count=b if rng is not None else 1)
    local, _ = square_to_hemisphere(uv[..., 0], uv[..., 1], "uniform", np.float32)
    local = np.broadcast_to(local, (b,) + local.shape[1:])
    t, bt = tangent_frame(normals)
    directions = matmul(local, np.stack([t, bt, normals], axis=1))          # (B, P, 3): rows of the local frame
    hits = caster.intersect((points + caster.offset * normals)[:, None, :], directions)   # origins broadcast
    # the ray starts ``offset`` off the lookin along its normal: distance from the lookin itself
    distance = hits.distance + caster.offset * local[..., 2]
    return ObservedPoints(directions, np.array(local[..., 2]), camera_solid_angle(pixels), hits.hit,
                          hits.points, hits.normals, hits.object_id, distance)
