"""An independent all-order estimator for the tests: a backward path tracer from the sensor point.

Written apart from datagen/transport (it weighs every leg itself, as datagen/analysis/oracle.py does), so that a
mistake in the fast light tracer of datagen/transport/multibounce cannot hide in a shared formula. It only borrows
the ray caster (intersections, shadow rays) and the scene's albedos.

Point-radiance captures with Lambertian materials (docs/physics.md §2): the quantity is the radiance leaving the
sensor point y toward the sensor per unit power at the laser spot, f_y · E(y). From y a cosine-weighted direction
is followed into the scene (throughput f_y π = ρ_y); at the j-th vertex x of the walk the laser spot is connected
(next-event: the spot's intensity f_l cosθ_l, times cosθ_x / r², times a shadow ray, times f_x = ρ_x/π): that is a
path of order j. The walk goes on by cosine-weighted directions (throughput × ρ_x) with Russian roulette (survival
ρ_x, so the throughput stays put), and stops once its length can no longer reach the window.
"""
from __future__ import annotations

import numpy as np

from datagen.scene import RayCaster, Scene, resolve_capture
from datagen.units import SPEED_OF_LIGHT

ORDERS = 16


def _cosine_directions(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Cosine-weighted unit directions about unit normals (n, 3), built here (not datagen.sampling)."""
    n = len(normals)
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u1))], axis=1)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(helper, normals)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    return local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * normals


def backward_orders(scene: Scene, paths: int, window: tuple[float, float], seed: int,
                    count_sensor_leg: bool = True) -> np.ndarray:
    """Each order's in-window radiance toward the sensor (orders 1..ORDERS; the last holds every higher one), per
    unit power at the laser spot, for a ``point_radiance`` capture with one sensor point: (ORDERS,) float64."""
    caster = RayCaster(scene)
    cap = resolve_capture(scene, caster)
    if cap.convention != "point_radiance" or cap.n_pixels != 1:
        raise ValueError("backward_orders takes point-radiance captures with one sensor point")
    albedo = np.array([o.material.albedo for o in scene.objects])
    if any(o.material.kind != "lambertian" for o in scene.objects):
        raise ValueError("backward_orders handles Lambertian materials only")
    rng = np.random.default_rng(seed)
    y = cap.sensor_points().reshape(3)
    n_wall = cap.fov_normal
    spot, n_spot = cap.spots[0], cap.spot_normals[0]
    rho_y = albedo[cap.spot_objects[0]]                 # the sensor point lies on the relay wall, as the spot does
    rho_l = rho_y
    t0 = np.linalg.norm(cap.sensor - y) if count_sensor_leg else 0.0
    limit = SPEED_OF_LIGHT * window[1]
    out = np.zeros(ORDERS)
    pos = np.repeat(y[None], paths, axis=0)
    nrm = np.repeat(n_wall[None], paths, axis=0)
    length = np.full(paths, t0)
    through = np.full(paths, rho_y / paths)             # f_y π over the paths
    order = 0
    while len(pos):
        d = _cosine_directions(nrm, rng)
        hits = caster.intersect(pos + caster.offset * nrm, d)
        ok = hits.hit
        pos, nrm, obj = hits.points[ok], hits.normals[ok], hits.object_id[ok]
        length = length[ok] + hits.distance[ok]
        through = through[ok]
        keep = length < limit
        pos, nrm, obj, length, through = pos[keep], nrm[keep], obj[keep], length[keep], through[keep]
        order += 1
        # next event to the laser spot: f_x · f_l cosθ_l cosθ_x / r² · V
        to_spot = spot - pos
        r = np.linalg.norm(to_spot, axis=1)
        w = to_spot / r[:, None]
        cos_x = np.einsum("ij,ij->i", nrm, w)
        cos_l = -(w @ n_spot)
        lit = (cos_x > 0) & (cos_l > 0)
        idx = np.flatnonzero(lit)
        vis = caster.visible(pos[idx], nrm[idx], np.broadcast_to(spot, (len(idx), 3)),
                             np.broadcast_to(n_spot, (len(idx), 3)))
        idx = idx[vis]
        contrib = through[idx] * (albedo[obj[idx]] / np.pi) * (rho_l / np.pi) * cos_l[idx] * cos_x[idx] / r[idx] ** 2
        t = (length[idx] + r[idx]) / SPEED_OF_LIGHT
        inside = (t >= window[0]) & (t < window[1])
        out[min(order, ORDERS) - 1] += contrib[inside].sum()
        # continue with Russian roulette at survival ρ_x (throughput × ρ_x / ρ_x)
        live = rng.random(len(pos)) < albedo[obj]
        pos, nrm, length, through = pos[live], nrm[live], length[live], through[live]
    return out
