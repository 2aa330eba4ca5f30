"""What the figures of the lookin estimator show, computed (Scholes & Leach 2024, Figures 3 and 5).

- :func:`laser_energy` (Figure 3): the laser energy reaching every observed point of every lookin: the spreading
  loss 1/R², the laser-spot emission f_l cosθ_l toward each point and the laser irradiance
  Φ f_l cosθ_l cosθ_x V / R² (:func:`datagen.transport.physics.laser_irradiance`), zero in the laser's shadow.
- :func:`lookin_energy` (Figure 5): one lookin's camera: its BRDF lobe f·cosθ over its observed points, the same
  over r², and each FoV point's primary weight f cosθ Ω × the detected fraction
  (:meth:`datagen.transport.LegPhysics.sensor_collection`).

Every weight comes from the lookin estimator's per-leg physics (:mod:`datagen.transport.physics`), so the figures
show what the estimator computes; :mod:`datagen.plot.figures` draws them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sampling import observe
from ..sampling.lookins import Lookins
from ..scene import Scene
from ..scene.capture import FOV_PLANE_TOL
from ..simulation import SimulationConfig
from ..simulation.config import STREAM_SAMPLING, stream_rng
from ..transport import LookinSampler
from ..transport.physics import laser_irradiance
from ..vectors import dot, unit

LOOKIN_PIXELS = (120, 120)
"""Camera resolution of the two Figure 5 lookins (finer than the simulation's so the lobes read well)."""

@dataclass(frozen=True)
class LaserEnergy:
    """Laser energy at the observed points of all lookins (Figure 3). M observed points.

    Attributes:
        points, normals: (M, 3) float64 positions (m) and unit normals facing the lookin that saw them.
        object_id: (M,) int64; label: (M,) str, the object's semantic label.
        distance: (M,) float64 R, laser spot → point (m).
        inv_square: (M,) float64 1/R² (m⁻²).
        spot_emission: (M,) float64 f_l(ω_e, ω)·cosθ_l toward the point (sr⁻¹).
        cos_in: (M,) float64 cosine at the point of the direction to the spot (0 if it faces away).
        lit: (M,) bool, the point sees the spot (shadow ray) and faces it.
        irradiance: (M,) float64 Φ·f_l cosθ_l cosθ_x·V/R², laser photons per m² per pulse.
        photons: Φ, photons per pulse.
        lookins: the sampled lookins whose cameras gave the points.
    """

    points: np.ndarray
    normals: np.ndarray
    object_id: np.ndarray
    label: np.ndarray
    distance: np.ndarray
    inv_square: np.ndarray
    spot_emission: np.ndarray
    cos_in: np.ndarray
    lit: np.ndarray
    irradiance: np.ndarray
    photons: float
    lookins: Lookins


@dataclass(frozen=True)
class LookinEnergy:
    """One lookin's camera and the energy it sends to its P observed points (Figure 5).

    Attributes:
        position, normal: (3,) the lookin (m) and its unit normal; object_id: its object; label: its label.
        points, normals: (P, 3) observed points (nan / 0 where the pixel ray escaped); hit: (P,) bool.
        object_id_obs: (P,) int64 objects of the observed points.
        distance: (P,) float64 r, lookin → observed point (m).
        brdf_cos: (P,) float64 f_j(ω_in = toward the spot, ω_k)·cosθ_k (sr⁻¹).
        brdf_cos_r2: (P,) float64 brdf_cos / r² (sr⁻¹ m⁻², the paper's illustration).
        in_fov: (P,) bool, the point is in the SPAD's FoV on the relay wall and faces the sensor.
        contribution: (P,) float64 f_j cosθ_k Ω · q f_y cosθ_y A_ap cosθ_ap V / d²: expected detections per
            photon scattered at the lookin (zero outside the FoV).
        solid_angle: Ω, sr per pixel; n_pixels: the camera's (l, p).
    """

    position: np.ndarray
    normal: np.ndarray
    object_id: int
    label: str
    points: np.ndarray
    normals: np.ndarray
    hit: np.ndarray
    object_id_obs: np.ndarray
    distance: np.ndarray
    brdf_cos: np.ndarray
    brdf_cos_r2: np.ndarray
    in_fov: np.ndarray
    contribution: np.ndarray
    solid_angle: float
    n_pixels: tuple[int, int]


def laser_energy(scene: Scene, config: SimulationConfig, transport: LookinSampler | None = None,
                 rng: np.random.Generator | None = None) -> LaserEnergy:
    """Sample lookins and observed points as the simulation does and weigh each point by the laser (Fig. 3).

    Args:
        scene, config: the scene and its sampling (lookins, pixels, lookin_pdf, jitter, seed).
        transport: reuse a transport built on ``scene`` (default: a new one).
        rng: sampling generator (default ``stream_rng(config.seed, STREAM_SAMPLING)``).
    """
    t = transport or LookinSampler(scene, config.transport_settings())
    rng = rng if rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    s, c = t.settings, t.capture
    jitter_rng = rng if s.jitter else None
    look = t.lookins(jitter_rng)
    idx = np.flatnonzero(look.hit)
    pts, nrm, obj = [], [], []
    for start in range(0, len(idx), s.batch):
        sel = idx[start:start + s.batch]
        obs = observe(t.caster, look.points[sel], look.normals[sel], s.pixels, jitter_rng)
        pts.append(obs.points[obs.hit])
        nrm.append(obs.normals[obs.hit])
        obj.append(obs.object_id[obs.hit])
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
    object_id = np.concatenate(obj) if obj else np.zeros(0, dtype=np.int64)
    to_point = points - c.spot
    distance = np.linalg.norm(to_point, axis=-1)
    w = to_point / np.maximum(distance, 1e-300)[:, None]
    emission = t.physics.spot_emission(w)
    cos_in = np.maximum(-dot(normals, w), 0.0)
    cand = (emission > 0) & (cos_in > 0)
    lit = np.zeros(len(points), dtype=bool)
    lit[cand] = t.caster.visible(points[cand], normals[cand], c.spot, c.spot_normal)
    inv_square = 1.0 / np.maximum(distance, 1e-300) ** 2
    irradiance = laser_irradiance(c.photons, emission, cos_in, np.maximum(distance, 1e-300)) * lit
    labels = np.array(scene.labels, dtype=object)[object_id] if len(object_id) else np.zeros(0, dtype=object)
    return LaserEnergy(points, normals, object_id, labels, distance, inv_square, emission, cos_in, lit,
                       irradiance, c.photons, look)


def lookin_energy(transport: LookinSampler, position: np.ndarray, normal: np.ndarray, object_id: int,
                  pixels: tuple[int, int] = LOOKIN_PIXELS) -> LookinEnergy:
    """Render one lookin's hemispherical camera at pixel centres and weigh its observed points (Fig. 5).

    Args:
        transport: supplies the caster, capture geometry, materials and per-leg physics.
        position, normal: (3,) the lookin and its unit normal (facing the laser spot).
        object_id: the lookin's object.
        pixels: camera resolution (l, p).
    """
    t, c = transport, transport.capture
    position, normal = np.asarray(position, float), np.asarray(normal, float)
    obs = observe(t.caster, position[None], normal[None], pixels, None)
    hit = obs.hit[0]
    points, normals, dirs = obs.points[0], obs.normals[0], obs.directions[0]
    obj = obs.object_id[0]
    r = obs.distance[0]
    w_to_spot = unit(c.spot - position)
    f = t.materials.evaluate(np.full(len(dirs), object_id), np.broadcast_to(normal, dirs.shape),
                             np.broadcast_to(w_to_spot, dirs.shape), dirs)
    brdf_cos = np.where(hit, f * obs.local_z[0], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        brdf_cos_r2 = np.where(hit, brdf_cos / r ** 2, 0.0)
    y = np.nan_to_num(points)
    tol = FOV_PLANE_TOL * t.caster.offset
    in_fov = hit & (c.fov_pixel(y, tol) >= 0) & (dot(normals, c.sensor - y) > 0)
    contribution = np.zeros(len(points))
    if in_fov.any():
        collect, _ = t.physics.sensor_collection(y[in_fov], normals[in_fov], obj[in_fov], -dirs[in_fov])
        contribution[in_fov] = brdf_cos[in_fov] * obs.solid_angle * collect
    return LookinEnergy(position, normal, int(object_id), t.scene.objects[object_id].label, points, normals,
                        hit, obj, r, brdf_cos, brdf_cos_r2, in_fov, contribution, obs.solid_angle,
                        tuple(pixels))


def pick_lookin(transport: LookinSampler, look: Lookins, labels: tuple[str, ...]
                ) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The lookin nearest the laser spot on an object with one of ``labels``.

    Taken from the sampled lookins ``look`` when one landed there, else found by casting rays from the spot
    toward the centres of the object's triangles (so a coarse lookin grid still gives the paper's view).
    Returns (position, normal, object id), or None when no such object is visible from the spot.
    """
    scene, c = transport.scene, transport.capture
    ids = [i for i, o in enumerate(scene.objects) if o.label in labels]
    if not ids:
        return None
    on = look.hit & np.isin(look.object_id, ids)
    if on.any():
        j = np.flatnonzero(on)[np.argmin(look.distance[on])]
        return look.points[j], look.normals[j], int(look.object_id[j])
    best = None
    for i in ids:
        o = scene.objects[i]
        tri = o.vertices[o.faces]
        targets = np.concatenate([tri.mean(axis=1), 0.5 * (tri.mean(axis=1) + tri[:, 0])])
        d = unit(targets - c.spot)
        ok = dot(d, c.spot_normal) > 0
        if not ok.any():
            continue
        hits = transport.caster.intersect(np.broadcast_to(c.spot + transport.caster.offset * c.spot_normal,
                                                          d[ok].shape), d[ok])
        good = hits.hit & (hits.object_id == i)
        if good.any():
            k = np.flatnonzero(good)[np.argmin(hits.distance[good])]
            if best is None or hits.distance[k] < best[0]:
                best = (hits.distance[k], hits.points[k], hits.normals[k], i)
    return None if best is None else best[1:]


# -- drawing -----------------------------------------------------------------------------------------------
