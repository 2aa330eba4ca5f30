"""The earliest time any light of the hidden scene can reach each output channel: a bound from the geometry.

Every path with at least one hidden vertex runs laser point s → v₁ → … → v_k → FoV point y → sensor. By the triangle
inequality its counted length is at least laser_leg + |s − v₁| + |v₁ − y| + the shortest FoV → sensor leg, and v₁
lies on a surface in front of the relay wall at s (the spot sees it). So no path of any order arrives before

    t_onset = (laser_leg + min over surface points x in front of s of (|s − x| + d(x, R)) + min_tail) / c,

d(x, R) the distance to the channel's pixel region R (y lies in it). Near a room's concave edges paths of every order come arbitrarily close
to the order-1 minimum (v₁, v₂, … at the corner), so this one bound is also the tightest one for orders ≥ 2 that
the geometry alone gives. :func:`earliest_arrival` computes it by branch and bound on the scene's triangles: f(x) =
|s − x| + d(x, R) is 2-Lipschitz, so a triangle with centroid c and circumradius r holds no point below f(c) − 2r,
nor below d(s, T) + d(y, T) − the pixel's half-diagonal (y its centre), and only triangles that can hold a point below the best value found so far are split (into four). The bound it
returns is a true lower bound (visibility beyond the spot's half-space is ignored, which can only lower it) and lies
within :data:`ONSET_GAP` of the unoccluded minimum.

The tracer's time smoothing keeps its kernels after this time (:mod:`.smoothing`, docs/physics.md §2, "Light of every
order": causality).
"""
from __future__ import annotations

import hashlib

import numpy as np
from numba import njit

from ...scene import RayCaster
from ...scene.capture import Capture
from ...units import SPEED_OF_LIGHT
from ..physics import LegPhysics

ONSET_GAP = 0.02
"""How far (metres of path) the bound may lie below the unoccluded minimum path length: triangles are split until
none could lower it by more (0.067 ns)."""

MAX_LEVELS = 40
"""Safety bound on the splitting levels (a 100 m triangle reaches the gap in ~13)."""

CACHE_SIZE = 8
"""Bounds kept (a tolerance loop builds the tracer more than once on the same capture)."""

_CACHE: dict[str, np.ndarray] = {}


def channel_pairs(capture: Capture) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (laser point, pixel) pairs a capture records and their channels: (laser (P,) int64, pixel (P,) int64,
    channel (P,) int64). Confocal: pixel l from laser point l; exhaustive: every pixel from every laser point; single:
    every pixel from every laser point into the pixel's channel."""
    n_pix = capture.n_pixels
    if capture.kind == "confocal":
        pix = np.arange(min(capture.n_lasers, n_pix), dtype=np.int64)
        return pix, pix, pix
    laser, pix = (a.ravel().astype(np.int64) for a in np.meshgrid(np.arange(capture.n_lasers), np.arange(n_pix),
                                                                   indexing="ij"))
    return laser, pix, capture.channel(laser, pix).astype(np.int64)


def earliest_arrival(capture: Capture, caster: RayCaster, physics: LegPhysics, gap: float = ONSET_GAP) -> np.ndarray:
    """A lower bound on the arrival time of every path with a hidden vertex, per output channel (module docstring).

    Args:
        capture: the resolved capture; caster: the scene's ray caster (its triangles); physics: the leg switches
            (:meth:`~datagen.transport.physics.LegPhysics.laser_leg`, :meth:`~datagen.transport.physics.LegPhysics.sensor_leg`);
        gap: metres of path the bound may lie below the unoccluded minimum (:data:`ONSET_GAP`).
    Returns:
        (n_channels,) float64 seconds; +inf for a channel no surface in front of its laser points can reach.
    """
    key = _key(capture, caster, physics, gap)
    cached = _CACHE.get(key)
    if cached is not None:
        return cached.copy()
    laser, pix, chan = channel_pairs(capture)
    iy, ix = np.divmod(pix, capture.fov_pixels[0])
    centres = np.ascontiguousarray(capture.fov_points(ix + 0.5, iy + 0.5), dtype=np.float64)
    frame = (np.asarray(capture.fov_u, dtype=np.float64), np.asarray(capture.fov_v, dtype=np.float64),
             0.5 * capture.region_size[0], 0.5 * capture.region_size[1])
    tris = np.ascontiguousarray(np.asarray(caster.vertices, dtype=np.float64)[np.asarray(caster.faces)])
    length = _min_lengths(np.ascontiguousarray(capture.spots[laser], dtype=np.float64),
                          np.ascontiguousarray(capture.spot_normals[laser], dtype=np.float64), centres, frame, tris,
                          float(gap), float(caster.offset))
    lead = np.asarray(physics.laser_leg(laser), dtype=np.float64) + float(
        physics.sensor_leg(capture.fov_sensor_distance()))
    out = np.full(capture.n_channels, np.inf)
    np.minimum.at(out, chan, (length + lead) / SPEED_OF_LIGHT)
    if len(_CACHE) >= CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = out.copy()
    return out



def _key(capture: Capture, caster: RayCaster, physics: LegPhysics, gap: float) -> str:
    """A digest of everything :func:`earliest_arrival` reads."""
    h = hashlib.sha1()
    for a in (caster.vertices, caster.faces, capture.spots, capture.spot_normals, capture.emitter_legs,
              capture.fov_center, capture.fov_u, capture.fov_v, capture.sensor):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((capture.kind, capture.fov_size, capture.fov_pixels, capture.pixel_size, float(caster.offset),
                   float(gap), bool(physics.settings.count_laser_leg), bool(physics.settings.count_sensor_leg))).encode())
    return h.hexdigest()


@njit(cache=True)
def _length(x, s, centre, frame):
    """|s − x| + d(x, R) for the pixel rectangle R of centre ``centre`` and ``frame`` (u, v, half-width,
    half-height), m."""
    u, v, hw, hh = frame
    a = (x[0] - centre[0]) * u[0] + (x[1] - centre[1]) * u[1] + (x[2] - centre[2]) * u[2]
    b = (x[0] - centre[0]) * v[0] + (x[1] - centre[1]) * v[1] + (x[2] - centre[2]) * v[2]
    a = min(max(a, -hw), hw)
    b = min(max(b, -hh), hh)
    d_r = 0.0
    d_s = 0.0
    for k in range(3):
        e = x[k] - centre[k] - a * u[k] - b * v[k]
        d_r += e * e
        d_s += (x[k] - s[k]) ** 2
    return np.sqrt(d_s) + np.sqrt(d_r)


@njit(cache=True)
def triangle_distance(p, t):
    """The distance of point p (3,) to triangle t (3, 3) (its closest point: Ericson, Real-Time Collision Detection
    §5.1.5), m. Scalar arithmetic (no temporary arrays: it runs for every triangle visited)."""
    ax, ay, az = t[0, 0], t[0, 1], t[0, 2]
    abx, aby, abz = t[1, 0] - ax, t[1, 1] - ay, t[1, 2] - az
    acx, acy, acz = t[2, 0] - ax, t[2, 1] - ay, t[2, 2] - az
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    if d1 <= 0.0 and d2 <= 0.0:
        v, w = 0.0, 0.0                                   # (v, w): the closest point a + v·ab + w·ac
    elif d3 >= 0.0 and d4 <= d3:
        v, w = 1.0, 0.0
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v, w = d1 / (d1 - d3), 0.0
    elif d6 >= 0.0 and d5 <= d6:
        v, w = 0.0, 1.0
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        v, w = 0.0, d2 / (d2 - d6)
    elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        v = 1.0 - w
    else:
        denom = va + vb + vc
        v, w = (vb / denom, vc / denom) if denom > 0.0 else (0.0, 0.0)
    ex, ey, ez = apx - v * abx - w * acx, apy - v * aby - w * acy, apz - v * abz - w * acz
    return np.sqrt(ex * ex + ey * ey + ez * ez)


@njit(cache=True)
def _lower(t, c, r, f, s, centre, half_diag):
    """A lower bound of |s − x| + d(x, R) over triangle t (3, 3) with centroid c, circumradius r and f = the sum at c:
    the larger of f − 2r (the sum is 2-Lipschitz) and d(s, t) + d(centre, t) − the pixel's half-diagonal."""
    return max(f - 2.0 * r, triangle_distance(s, t) + triangle_distance(centre, t) - half_diag)


@njit(cache=True)
def _min_lengths(spots, normals, centres, frame, tris, gap, tol):
    """For each pair p: min over surface points x of triangles ``tris`` (K, 3, 3) in front of spot s_p (n_p·(x − s_p)
    > tol) of |s_p − x| + d(x, R_p), less at most ``gap``: (P,) float64 m (module docstring). Depth-first branch and
    bound: a triangle is split into four while it may hold a point more than ``gap`` below the best value attained."""
    n_pairs, n_tris = spots.shape[0], tris.shape[0]
    half_diag = np.sqrt(frame[2] ** 2 + frame[3] ** 2)
    out = np.empty(n_pairs)
    stack = np.empty((n_tris + 3 * MAX_LEVELS + 3, 3, 3))
    depth = np.empty(n_tris + 3 * MAX_LEVELS + 3, np.int64)
    c = np.empty(3)
    x_best = np.full(3, np.nan)             # the point of the best value of the previous pair (scan neighbours)
    roots = np.empty(n_tris)
    for p in range(n_pairs):
        s, n_s = spots[p], normals[p]
        plane = n_s[0] * s[0] + n_s[1] * s[1] + n_s[2] * s[2]
        best = np.inf
        if not np.isnan(x_best[0]) and n_s[0] * x_best[0] + n_s[1] * x_best[1] + n_s[2] * x_best[2] - plane > tol:
            best = _length(x_best, s, centres[p], frame)
        for k in range(n_tris):                 # attained values: the centroids ahead of the spot
            r = 0.0
            for d in range(3):
                c[d] = (tris[k, 0, d] + tris[k, 1, d] + tris[k, 2, d]) / 3.0
            for v in range(3):
                r = max(r, np.sqrt((tris[k, v, 0] - c[0]) ** 2 + (tris[k, v, 1] - c[1]) ** 2
                                   + (tris[k, v, 2] - c[2]) ** 2))
            f = _length(c, s, centres[p], frame)
            roots[k] = _lower(tris[k], c, r, f, s, centres[p], half_diag)
            if n_s[0] * c[0] + n_s[1] * c[1] + n_s[2] * c[2] - plane > tol and f < best:
                best = f
                x_best[:] = c
        floor = np.inf
        top = 0
        for k in np.argsort(-roots):            # the most promising triangle on top of the stack
            stack[top] = tris[k]
            depth[top] = 0
            top += 1
        while top > 0:
            top -= 1
            t = stack[top].copy()
            level = depth[top]
            ahead = -np.inf
            for v in range(3):
                ahead = max(ahead, n_s[0] * t[v, 0] + n_s[1] * t[v, 1] + n_s[2] * t[v, 2] - plane)
            if ahead <= tol:                    # wholly in the spot's plane or behind it: no first vertex there
                continue
            for d in range(3):
                c[d] = (t[0, d] + t[1, d] + t[2, d]) / 3.0
            r = 0.0
            for v in range(3):
                r = max(r, np.sqrt((t[v, 0] - c[0]) ** 2 + (t[v, 1] - c[1]) ** 2 + (t[v, 2] - c[2]) ** 2))
            f = _length(c, s, centres[p], frame)
            if n_s[0] * c[0] + n_s[1] * c[1] + n_s[2] * c[2] - plane > tol and f < best:
                best = f
                x_best[:] = c
            lower = _lower(t, c, r, f, s, centres[p], half_diag)
            if lower >= best - gap or 2.0 * r <= gap or level >= MAX_LEVELS:
                floor = min(floor, lower)
                continue
            a, b, e = t[0], t[1], t[2]
            ab, bc, ca = 0.5 * (a + b), 0.5 * (b + e), 0.5 * (e + a)
            for child in range(4):
                if child == 0:
                    stack[top, 0], stack[top, 1], stack[top, 2] = a, ab, ca
                elif child == 1:
                    stack[top, 0], stack[top, 1], stack[top, 2] = ab, b, bc
                elif child == 2:
                    stack[top, 0], stack[top, 1], stack[top, 2] = ca, bc, e
                else:
                    stack[top, 0], stack[top, 1], stack[top, 2] = ab, bc, ca
                depth[top] = level + 1
                top += 1
        out[p] = floor
    return out
