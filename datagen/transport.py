"""Light transport: primary and secondary path weights and times, summed into the envelope L(t).

The estimated quantity is the transient path integral of DESIGN.md §2. For one laser spot x_l with Φ photons
per pulse, primary (three-bounce) light detected by a sensor imaging the FoV region F of the relay wall is

    L_p(t) = q·∫_S dA_x ∫_F dA_y  Φ f_l cosθ_l cosθ_x,in /|x−x_l|² V(x_l,x)
                               · f_x cosθ_x,out cosθ_y,in /|y−x|² V(x,y)
                               · f_y cosθ_y,out · A_ap cosθ_ap /|x_s−y|² V(y,x_s) · e^{−μ·path} h(t − τ).

How the paper's factors (Scholes & Leach 2024, Eqs. 1, 6, 8) map to this, per leg:

- **A1** (laser spot → lookin, Γ_1 α_1 B_1 / R_j²): lookins are sampled by *direction* ω_j at the spot with
  pdf p(ω_j), and a point reached through solid angle dω has dA = R² dω / cosθ, so the paper's 1/R_j² cancels:
  the flux a lookin carries is W_j = Φ·f_l(ω_e, ω_j)·cosθ_l / (N·p(ω_j)) photons (f_l = Γ_1/π for a
  Lambertian relay wall, B_1 = cos φ is our cosθ_l; α_1 is replaced by the exact 1/(N·p)).
- **A2** (lookin → observed point, Γ_j α_j B_j / (R_k^o)²): the camera pixel of solid angle Ω = 2π/(l·p)
  carries W_j·f_j(ω_in, ω_k)·cosθ_k·Ω photons to the observed point; again the 1/R² cancels against the
  pixel's area on the surface, and α_j is replaced by Ω.
- **A3/A4** (FoV point → sensor, Γ β B / (R^s)² and the aperture term π f²/f_no²): a point on the relay
  wall that receives F photons sends F·f_y(ω_in, ω_s)·cosθ_y,out·A_ap·cosθ_ap/|x_s−y|² of them into the
  aperture of area A_ap = π r_ap² (the paper's (f/f_no)² aperture term with r_ap = f/(2 f_no)); β is unity.
- **Secondary** (Eq. 8, A^1 A^2 A^3): paths x_l → y' → x_j → y → sensor, with y' the observed points of
  lookin j lit by the laser (a real shadow ray to the spot). The laser irradiance at y' is
  E' = Φ f_l cosθ_l cosθ_y',in / r² · V (an area quantity: here the 1/r² is genuine), y' reflects radiance
  L' = f_y' E' toward x_j, which receives L' cosθ_j Ω through the pixel. x_j now acts as an *area* sample:
  its area measure is dA_j = R_j² / (N·p(ω_j)·cosθ_j,l). The lookin then scatters with f_j(ω_k', ω_k)
  exactly like the primary. Each factor is therefore the same as for the primary; only the sampling differs.
- C_atm = e^{−μ R} per leg: one factor e^{−μ·(total physical path)}; q is the PDE (quantum efficiency).

Estimators: ``full`` secondary sums every (k', k) pair: O(Ñ²) per lookin. ``optimized`` keeps, for each
lookin and FoV point k, only the ``top_k`` strongest k' (the paper's optimized scheme, §4: top_k = 1). It is
*biased low by design*: it keeps the secondary's timing and drops most of its energy. Primary and full
secondary are consistent: they converge to the path integral as N and l×p grow (tests compare against an
independent area quadrature).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal, Protocol

import numpy as np

from .brdf import MaterialTable
from .raycast import RayCaster
from .sampling import Lookins, ObservedPoints, observe, sample_lookins
from .scene import Scene, SceneError
from .units import SPEED_OF_LIGHT

SecondaryMode = Literal["none", "optimized", "full"]

FOV_PLANE_TOL = 10.0
"""A hit lies on the FoV plane when within this many ray offsets of it (hit points are float64 rebuilt
from float32 barycentrics, accurate to a few offsets)."""

@dataclass(frozen=True)
class Capture:
    """Resolved capture geometry (all float64, metres).

    Attributes:
        spot, spot_normal: laser spot and relay-wall normal there (facing the hidden scene / sensor side).
        spot_object: object id the spot lies on.
        emitter, sensor: positions; emitter_leg: |spot − emitter|.
        aperture_area: m²; aperture_normal: unit vector from the sensor toward the FoV centre.
        fov_center, fov_u, fov_v, fov_normal: FoV rectangle frame; fov_size: (width, height);
        fov_pixels: (nx, ny).
        photons: Φ, photons per pulse.
    """

    spot: np.ndarray
    spot_normal: np.ndarray
    spot_object: int
    emitter: np.ndarray
    emitter_leg: float
    sensor: np.ndarray
    aperture_area: float
    aperture_normal: np.ndarray
    fov_center: np.ndarray
    fov_u: np.ndarray
    fov_v: np.ndarray
    fov_normal: np.ndarray
    fov_size: tuple[float, float]
    fov_pixels: tuple[int, int]
    photons: float

    @property
    def n_pixels(self) -> int:
        return self.fov_pixels[0] * self.fov_pixels[1]

    def fov_pixel(self, points: np.ndarray, tol: float) -> np.ndarray:
        """Sensor pixel index (row-major over (v, u)) of each point, −1 outside the FoV. (..., 3) → (...,)."""
        rel = points - self.fov_center
        a = (rel @ self.fov_u) / self.fov_size[0] + 0.5
        b = (rel @ self.fov_v) / self.fov_size[1] + 0.5
        inside = (np.abs(rel @ self.fov_normal) <= tol) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        nx, ny = self.fov_pixels
        ix = np.clip((np.nan_to_num(a) * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip((np.nan_to_num(b) * ny).astype(np.int64), 0, ny - 1)
        return np.where(inside, iy * nx + ix, -1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _on_surface(caster: RayCaster, point: np.ndarray, direction: np.ndarray, tol: float) -> bool:
    """True when a surface passes within ``tol`` of ``point`` along ``direction`` (a short probe ray)."""
    probe = caster.intersect((point - 2 * tol * direction)[None], direction[None])
    return bool(probe.hit[0] and probe.distance[0] <= 4 * tol)


def resolve_capture(scene: Scene, caster: RayCaster) -> Capture:
    """Find the laser spot's surface and normal, and check the FoV sees a surface.

    Raises:
        SceneError: the laser spot is off every surface or hidden from the emitter; the FoV rectangle
            sees no surface from the sensor; the sensor is behind the relay wall.
    """
    where = f"{scene.source}: " if scene.source else ""
    emitter = np.asarray(scene.laser.emitter, dtype=np.float64)
    spot = np.asarray(scene.laser.spot, dtype=np.float64)
    leg = float(np.linalg.norm(spot - emitter))
    if leg == 0:
        raise SceneError(f"{where}laser.spot equals laser.emitter {spot.tolist()}")
    hits = caster.intersect(emitter[None], _unit(spot - emitter)[None])
    tol = FOV_PLANE_TOL * caster.offset
    if not hits.hit[0] or hits.distance[0] < leg - tol:
        if hits.hit[0] and _on_surface(caster, spot, _unit(spot - emitter), tol):
            blocker = scene.objects[hits.object_id[0]].name
            raise SceneError(f"{where}laser.spot {spot.tolist()} is hidden from the emitter: the beam hits "
                             f"object {blocker!r} at {np.round(hits.points[0], 4).tolist()} first")
        raise SceneError(f"{where}laser.spot {spot.tolist()} is off every surface (no surface there along "
                         f"the beam from the emitter {emitter.tolist()})")
    if hits.distance[0] > leg + tol:
        raise SceneError(f"{where}laser.spot {spot.tolist()} is off every surface (the beam from the emitter "
                         f"first hits {np.round(hits.points[0], 4).tolist()})")
    spot_normal = hits.normals[0]
    spot_object = int(hits.object_id[0])

    sensor = np.asarray(scene.sensor.position, dtype=np.float64)
    fov = scene.sensor.fov
    center = np.asarray(fov.center, dtype=np.float64)
    hit_c = caster.intersect(sensor[None], _unit(center - sensor)[None])
    normal = hit_c.normals[0] if hit_c.hit[0] else _unit(sensor - center)
    up = np.array([0.0, 0.0, 1.0])
    u = np.cross(normal, up)
    u = _unit(np.cross(normal, np.array([0.0, 1.0, 0.0]))) if np.linalg.norm(u) < 1e-9 else _unit(u)
    v = np.cross(u, normal)
    capture = Capture(spot, spot_normal, spot_object, emitter, leg, sensor, scene.sensor.aperture_area,
                      _unit(center - sensor), center, u, v, normal, fov.size, fov.pixels, scene.laser.photons)
    # Probe the FoV from the sensor on a grid: some of it must be a surface the sensor sees.
    g = (np.arange(9) + 0.5) / 9 - 0.5
    gu, gv = np.meshgrid(g * fov.size[0], g * fov.size[1])
    targets = center + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * v
    probe = caster.intersect(np.broadcast_to(sensor, targets.shape), _unit(targets - sensor))
    seen = probe.hit & (capture.fov_pixel(np.nan_to_num(probe.points), tol) >= 0)
    if not seen.any():
        raise SceneError(f"{where}sensor.fov (center {center.tolist()}, size {list(fov.size)}) sees no surface "
                         f"from the sensor at {sensor.tolist()}")
    return capture


@dataclass(frozen=True)
class TransportSettings:
    """Sampling and transport options (see :class:`datagen.simulate.SimulationConfig` for the user side).

    Attributes:
        lookins: (n_u, n_v) lookin grid; pixels: (l, p) camera resolution.
        lookin_pdf: "cosine" or "uniform" hemisphere sampling at the spot.
        jitter: stratified jitter (True) or cell centres (False).
        secondary: "none" | "optimized" | "full"; top_k: kept k' per (lookin, FoV point) when optimized.
        attenuation: μ in 1/m (0 = none).
        pde: q, detection efficiency applied to every detected photon.
        count_laser_leg / count_sensor_leg: include emitter→spot / FoV→sensor in the time of flight.
        batch: lookins processed together (bounds memory).
    """

    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    secondary: SecondaryMode = "full"
    top_k: int = 1
    attenuation: float = 0.0
    pde: float = 1.0
    count_laser_leg: bool = False
    count_sensor_leg: bool = True
    batch: int = 32


@dataclass
class TransportStats:
    """Counters from a transport run (recorded in the result attributes)."""

    lookins_cast: int = 0
    lookins_hit: int = 0
    observed_points: int = 0
    fov_points: int = 0
    lit_points: int = 0
    secondary_pairs: int = 0


class Sink(Protocol):
    """Where transport sends path impulses (e.g. :class:`datagen.irf.EnvelopeAccumulator`)."""

    def add(self, times: np.ndarray, weights: np.ndarray, component: np.ndarray) -> None: ...


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


class Transport:
    """Runs the lookin estimator over a scene and sends impulses to a sink.

    Component ids sent to the sink: ``component * n_pixels + pixel`` where component indexes
    ``scene.component_names()`` for primary paths (by the object the lookin hit) and
    ``len(scene.component_names())`` for secondary paths.
    """

    def __init__(self, scene: Scene, settings: TransportSettings, caster: RayCaster | None = None):
        self.scene = scene
        self.settings = settings
        self.caster = caster or RayCaster(scene)
        self.capture = resolve_capture(scene, self.caster)
        self.materials: MaterialTable = scene.materials
        self.object_component = scene.object_component()
        self.n_primary = len(scene.component_names())
        self.stats = TransportStats()

    # -- per-leg physics (written once, used by every estimator) -----------------------------------------

    def _spot_emission(self, directions: np.ndarray) -> np.ndarray:
        """f_l(ω_e, ω)·cosθ_l at the laser spot for outgoing unit directions ω (..., 3) → (...,).

        The beam arrives from the emitter, ω_e = unit(emitter − spot); radiant intensity per photon of the
        pulse is f_l·cosθ_l (DESIGN.md §2).
        """
        c = self.capture
        w_e = _unit(c.emitter - c.spot)
        n = np.broadcast_to(c.spot_normal, directions.shape)
        f = self.materials.evaluate(np.full(directions.shape[:-1], c.spot_object), n,
                                    np.broadcast_to(w_e, directions.shape), directions)
        return f * np.maximum(_dot(n, directions), 0.0)

    def _sensor_collection(self, points: np.ndarray, normals: np.ndarray, object_id: np.ndarray,
                           w_in: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fraction of photons landing at FoV points that are detected, and the FoV→sensor distance.

        q·f_y(ω_in, ω_s)·cosθ_y,out·A_ap·cosθ_ap/d²·V(y, x_s) (paper A3 and aperture term), (n,) each.
        """
        c = self.capture
        to_sensor = c.sensor - points
        d = np.linalg.norm(to_sensor, axis=-1)
        w_s = to_sensor / d[..., None]
        cos_out = np.maximum(_dot(normals, w_s), 0.0)
        cos_ap = np.maximum(-_dot(w_s, c.aperture_normal), 0.0)
        f = self.materials.evaluate(object_id, normals, w_in, w_s)
        visible = self.caster.visible(points, normals, c.sensor, None)
        return self.settings.pde * f * cos_out * c.aperture_area * cos_ap / d ** 2 * visible, d

    def _attenuation(self, path: np.ndarray) -> np.ndarray | float:
        mu = self.settings.attenuation
        return np.exp(-mu * path) if mu > 0 else 1.0

    # -- estimator ---------------------------------------------------------------------------------------

    def lookins(self, rng: np.random.Generator | None) -> Lookins:
        s = self.settings
        return sample_lookins(self.caster, self.capture.spot, self.capture.spot_normal, s.lookins,
                              s.lookin_pdf, rng)

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Sample lookins and observed points and send every primary (and secondary) impulse to ``sink``."""
        s = self.settings
        look = self.lookins(rng if s.jitter else None)
        self.stats.lookins_cast += look.n_rays
        idx = np.flatnonzero(look.hit)
        self.stats.lookins_hit += len(idx)
        for start in range(0, len(idx), s.batch):
            sel = idx[start:start + s.batch]
            obs = observe(self.caster, look.points[sel], look.normals[sel], s.pixels, rng if s.jitter else None)
            self._batch(look, sel, obs, sink)
            if progress is not None:
                progress(len(sel))
        if progress is not None and len(idx) == 0:
            progress(0)

    def _batch(self, look: Lookins, sel: np.ndarray, obs: ObservedPoints, sink: Sink) -> None:
        c, s = self.capture, self.settings
        n = look.n_rays
        x = look.points[sel]                                   # (B, 3)
        n_x = look.normals[sel]
        obj_x = look.object_id[sel]
        r_lx = look.distance[sel]
        w_to_spot = (c.spot - x) / r_lx[:, None]
        cos_x_l = np.maximum(_dot(n_x, w_to_spot), 0.0)
        flux = c.photons * self._spot_emission(look.directions[sel]) / (n * look.pdf[sel])   # W_j, photons
        self.stats.observed_points += int(obs.hit.sum())

        tol = FOV_PLANE_TOL * self.caster.offset
        pix = np.where(obs.hit, c.fov_pixel(np.nan_to_num(obs.points), tol), -1)
        fov = (pix >= 0) & (_dot(obs.normals, c.sensor - np.nan_to_num(obs.points)) > 0)
        bi, ki = np.nonzero(fov)                               # FoV observed points (batch idx, pixel idx)
        self.stats.fov_points += len(bi)
        if len(bi) == 0:
            return
        y = obs.points[bi, ki]
        w_y_in = -obs.directions[bi, ki]
        collect, d_ys = self._sensor_collection(y, obs.normals[bi, ki], obs.object_id[bi, ki], w_y_in)
        # lookin → FoV point: f_j(ω_in = to spot, ω_k)·cosθ_k·Ω (paper A2)
        f_out = self.materials.evaluate(obj_x[bi], n_x[bi], w_to_spot[bi], obs.directions[bi, ki])
        out = f_out * obs.local_z[bi, ki] * obs.solid_angle * collect          # per photon at lookin
        out_path = obs.distance[bi, ki] + (d_ys if s.count_sensor_leg else 0.0)
        phys_out = obs.distance[bi, ki] + d_ys
        laser_leg = c.emitter_leg if s.count_laser_leg else 0.0
        comp = self.object_component[obj_x[bi]] * c.n_pixels + pix[bi, ki]
        weight = flux[bi] * out * self._attenuation(c.emitter_leg + r_lx[bi] + phys_out)
        sink.add((laser_leg + r_lx[bi] + out_path) / SPEED_OF_LIGHT, weight, comp)
        if s.secondary != "none":
            self._secondary(look, sel, obs, bi, ki, out_path, phys_out, pix, cos_x_l, collect, sink)

    def _secondary(self, look, sel, obs, bi, ki, out_path, phys_out, pix, cos_x_l, collect, sink) -> None:
        c, s = self.capture, self.settings
        x, n_x, obj_x = look.points[sel], look.normals[sel], look.object_id[sel]
        r_lx = look.distance[sel]
        # area measure of each lookin as a second hidden vertex: dA_j = R_j² / (N p_j cosθ_j,l)
        with np.errstate(divide="ignore", invalid="ignore"):
            area = np.where(cos_x_l > 0, r_lx ** 2 / (look.n_rays * look.pdf[sel] * cos_x_l), 0.0)
        # laser-lit observed points y' (real shadow rays to the spot)
        y1 = np.nan_to_num(obs.points)
        to_y1 = y1 - c.spot
        r_ly = np.linalg.norm(to_y1, axis=-1)
        w_ly = to_y1 / np.maximum(r_ly, 1e-300)[..., None]
        cos_l = _dot(c.spot_normal, w_ly)
        cos_y_in = -_dot(obs.normals, w_ly)
        cand = obs.hit & (cos_l > 0) & (cos_y_in > 0) & (area[:, None] > 0)
        lit = np.zeros_like(cand)
        lit[cand] = self.caster.visible(y1[cand], obs.normals[cand], c.spot, c.spot_normal)
        self.stats.lit_points += int(lit.sum())
        lb, lk = np.nonzero(lit)
        if len(lb) == 0:
            return
        yp, n_yp, obj_yp = y1[lb, lk], obs.normals[lb, lk], obs.object_id[lb, lk]
        irradiance = c.photons * self._spot_emission(w_ly[lb, lk]) * cos_y_in[lb, lk] / r_ly[lb, lk] ** 2
        w_yp_out = -obs.directions[lb, lk]                                   # toward the lookin
        radiance = irradiance * self.materials.evaluate(obj_yp, n_yp, -w_ly[lb, lk], w_yp_out)
        in_w = radiance * obs.local_z[lb, lk] * obs.solid_angle * area[lb]   # photons leaving lookin area
        in_path = r_ly[lb, lk] + obs.distance[lb, lk]
        # FoV side, per photon arriving at the lookin (without the lookin's BRDF)
        out_w = obs.local_z[bi, ki] * obs.solid_angle * collect
        laser_leg = c.emitter_leg if s.count_laser_leg else 0.0
        sec_comp = self.n_primary * c.n_pixels
        for j in range(len(sel)):
            a = np.flatnonzero(lb == j)
            b = np.flatnonzero(bi == j)
            if len(a) == 0 or len(b) == 0:
                continue
            if self.materials.lambertian[obj_x[j]]:
                f = np.full((1, 1), self.materials.albedo[obj_x[j]] / np.pi)
            else:
                f = self.materials.evaluate(np.full((len(a), len(b)), obj_x[j]), n_x[j],
                                            obs.directions[j, lk[a]][:, None, :], obs.directions[j, ki[b]][None])
            pair = in_w[a, None] * f * out_w[None, b]
            t_pair = in_path[a, None] + out_path[None, b]
            if s.secondary == "optimized" and s.top_k < len(a):
                keep = np.argpartition(-pair, s.top_k - 1, axis=0)[:s.top_k]   # (K, n_fov)
                pair = np.take_along_axis(pair, keep, axis=0)
                t_pair = np.take_along_axis(np.broadcast_to(t_pair, (len(a), len(b))), keep, axis=0)
                phys = np.take_along_axis(np.broadcast_to(in_path[a, None] + phys_out[None, b],
                                                          (len(a), len(b))), keep, axis=0)
            else:
                phys = in_path[a, None] + phys_out[None, b]
            weight = pair * self._attenuation(c.emitter_leg + phys)
            comp = np.broadcast_to(sec_comp + pix[j, ki[b]][None, :], weight.shape)
            self.stats.secondary_pairs += weight.size
            sink.add(((laser_leg + t_pair) / SPEED_OF_LIGHT).ravel(), weight.ravel(), comp.ravel())
