"""The weight of each leg of a light path, written once (docs/physics.md §2).

Every estimator of the transient path integral — the lookin sampler (:mod:`.lookin`, :mod:`.secondary`), the
area sampler (:mod:`.area` and its compiled passes :mod:`.area.kernels`), the quadrature (:mod:`.quadrature`,
:mod:`.quadrature.kernel`) — and the effect planner's coarse quadrature and the figures weigh a path with the functions
here; they differ only in how they *sample* its vertices. Each formula is a numba device function
(``inline="always"``) that compiled kernels call and numpy code calls on arrays through
:func:`datagen.scene.brdf_kernel.on_arrays` (the same float operations in the same order); the BRDFs are those of
:mod:`datagen.scene.brdf_kernel`. For a path emitter → laser spot x_l → hidden point x → relay-wall point y (in the
sensor's FoV) → sensor x_s:

- laser spot, toward ω: f_l(ω_e, ω)·cosθ_l (:func:`emission_term`, :meth:`LegPhysics.spot_emission`); paper A1:
  Γ₁ B₁ (α₁ → 1/(N p)).
- laser → hidden point: E = Φ f_l cosθ_l cosθ_x,in / r² · V (:func:`irradiance_term`, :func:`laser_irradiance`,
  :meth:`LegPhysics.irradiance`); A1 in area measure. Its geometric factor cosθ_l cosθ_x,in / r², and that of a
  hidden → hidden leg: :func:`geometry_term`.
- scattering at any vertex: f(ω_in, ω_out) (:meth:`LegPhysics.brdf`); the paper's Γ and B per surface.
- hidden point → FoV point: cosθ_y,in dA_y / r² · collection(y) (:func:`fov_term`, :func:`fov_connection_weight`);
  A2 with α → the pixel's Ω or dA_y.
- FoV point → sensor: q f_y cosθ_y,out A_ap cosθ_ap / d² · V (:func:`collection_term`,
  :meth:`LegPhysics.sensor_collection`); A3 and the aperture term π f²/f_no², q.
- whole path: e^{−μ·(physical path)} (:func:`attenuation_term`, :meth:`LegPhysics.attenuation`); C_atm.
- time of flight: (switched legs + hidden legs) / c (:meth:`LegPhysics.laser_leg`, :meth:`LegPhysics.sensor_leg`).
- direct spot → sensor (first bounce): Φ q f_l cosθ_l A_ap cosθ_ap / d² · V (:func:`direct_term`,
  :meth:`LegPhysics.first_bounce`).

A point reached by a ray of solid angle dω from a vertex has area element dA = r² dω / cosθ, so the 1/r² of a
leg cancels when that leg is sampled by direction (lookins, camera pixels) and is genuine when it is sampled
by area (next-event connections, the area sampler, the quadrature): docs/physics.md §2 derives both.

The lookin estimator's weight for a camera FoV point, for instance, is
``flux · brdf · cos · (Ω · sensor_collection) · attenuation`` and the area sampler's primary is
``(1/ρ) · E · brdf · cos · fov_connection_weight(...) · attenuation``: the same factors, other densities.
The brute-force oracle of the tests (:mod:`datagen.analysis.oracle`) deliberately does *not* use this module.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import ConfigError
from ..scene import RayCaster, Scene
from ..scene.capture import Capture, FOV_PLANE_TOL
from ..scene.brdf_kernel import SIN_THETA
from ..scene.brdf_kernel import lambertian_value, on_arrays
from ..sampling.directions import stratified_grid
from ..units import SPEED_OF_LIGHT
from ..vectors import dot, matmul, norm, unit
from .base import Connections, Sink

PHYSICS_SWITCHES = ("attenuation", "pde", "count_laser_leg", "count_sensor_leg", "shadow_spot", "shadow_sensor",
                    "first_bounce", "brdf_angles")
"""The physics switches every estimator shares (fields of :class:`PhysicsSettings`), in one place."""


@dataclass(frozen=True)
class PhysicsSettings:
    """The physics every estimator's settings hold (each estimator's settings class derives from this one).

    Attributes:
        attenuation: μ in 1/m (0 = none): the factor e^{−μ·path} of each path (the paper's C_atm).
        pde: q, detection efficiency applied to every detected photon.
        count_laser_leg / count_sensor_leg: include emitter → spot / FoV → sensor in the time of flight
            (docs/physics.md §1: time zero is the pulse at the laser spot by default).
        shadow_spot: shadow rays on the laser spot → hidden point leg.
        shadow_sensor: shadow rays on the FoV point → sensor leg.
        first_bounce: add the direct laser spot → sensor return when the spot lies in a sensor pixel.
        brdf_angles: evaluate every BRDF in full (False: Lambertian materials take f = ρ/π with no angle work;
            the values are identical for the directions estimators pass).
        spot_blockers: every face that can cross a laser point → hidden point segment (the effect planner's
            pair test), or None (unknown: every laser shadow ray is cast). Segments that miss the bounding
            spheres of these faces (grouped by object) are unoccluded without a ray.
        sensor_blockers: the same for FoV point → sensor segments (the planner's sensor-pyramid test).
    """

    attenuation: float = 0.0
    pde: float = 1.0
    count_laser_leg: bool = False
    count_sensor_leg: bool = True
    shadow_spot: bool = True
    shadow_sensor: bool = True
    first_bounce: bool = False
    brdf_angles: bool = False
    spot_blockers: tuple[int, ...] | None = None
    sensor_blockers: tuple[int, ...] | None = None

    def switches(self) -> dict:
        """The :data:`PHYSICS_SWITCHES` of these settings as keyword arguments (to build another estimator's
        settings with the same physics: ``AreaSettings(**lookin_settings.switches(), samples=...)``)."""
        return {name: getattr(self, name) for name in PHYSICS_SWITCHES}

    def check_physics(self, where: str) -> None:
        """Raise :class:`~datagen.errors.ConfigError` ``"{where}: attenuation must be …"`` for μ not finite or < 0
        and q outside [0, 1]."""
        if not np.isfinite(self.attenuation) or self.attenuation < 0:
            raise ConfigError(f"{where}: attenuation must be finite and >= 0, got {self.attenuation!r}")
        if not np.isfinite(self.pde) or not 0 <= self.pde <= 1:
            raise ConfigError(f"{where}: pde must be in [0, 1], got {self.pde!r}")


# -- the leg formulas: scalar numba device functions, called by every compiled kernel (transport's area and
# quadrature kernels, the planner's coarse kernel) and, through on_arrays, by the numpy code below -------------

@njit(cache=True, inline="always")
def emission_term(f, cos):
    """Radiant intensity of the laser spot per photon of the pulse toward ω: f_l(ω_e, ω)·cosθ_l (1/sr), paper A1
    without its 1/R²; ``cos`` = max(n_l·ω, 0)."""
    return f * cos


@njit(cache=True, inline="always")
def irradiance_term(photons, emission, cos_in, r):
    """Laser irradiance at a hidden point, photons per m²: E = Φ · f_l cosθ_l · cosθ_x,in / r² (visibility is
    the caller's); ``emission`` = :func:`emission_term` toward the point, r the spot → point distance."""
    return photons * emission * cos_in / r ** 2


@njit(cache=True, inline="always")
def geometry_term(cos_a, cos_b, r):
    """The geometric factor of a leg sampled by area: cosθ_a cosθ_b / r² (1/m²; e.g. laser point → hidden point,
    whose cosine-direction density from the spot is geo/π, or hidden point → hidden point)."""
    return cos_a * cos_b / r ** 2


@njit(cache=True, inline="always")
def fov_term(cos_y, r, collection):
    """Next-event connection to the FoV: ``cos_y / r² · collection`` with ``cos_y`` cosθ_y,in (times dA_y, or
    times cosθ_x,out for the quadrature's symmetric form) and ``collection`` what a photon landing at y becomes
    at the sensor (:func:`collection_term`, times dA_y where the numerator lacks it); per unit radiant intensity
    of the hidden point toward y (paper A2)."""
    return cos_y / r ** 2 * collection


@njit(cache=True, inline="always")
def collection_term(pde, f, cos_out, aperture_area, cos_ap, d):
    """Sensor collection of a photon landing at a FoV point y (aperture convention): q f_y(ω_in, ω_s) cosθ_y,out
    A_ap cosθ_ap / d² (paper A3 and the aperture term; visibility is the caller's), d = |x_s − y|."""
    return pde * f * cos_out * aperture_area * cos_ap / d ** 2


@njit(cache=True, inline="always")
def direct_term(photons, pde, emission, aperture_area, cos_ap, d):
    """The direct laser point → sensor return (first bounce), photons per pulse: Φ q f_l cosθ_l A_ap cosθ_ap / d²
    (visibility and attenuation are the caller's); ``emission`` = :func:`emission_term` toward the sensor."""
    return photons * pde * emission * aperture_area * cos_ap / d ** 2


@njit(cache=True, inline="always")
def launched_flux(photons, emission, pdf):
    """Flux (photons) of a light path leaving the laser spot in a direction drawn with density ``pdf`` (1/sr):
    Φ · f_l cosθ_l / pdf, ``emission`` = :func:`emission_term` toward it (paper A1 sampled by direction, where the
    1/R² cancels: docs/physics.md §2); Φ f_l π for cosine-weighted directions."""
    return photons * emission / pdf


@njit(cache=True, inline="always")
def attenuation_term(mu, path):
    """e^{−μ·path} for a physical path length in metres, μ in 1/m (the paper's C_atm)."""
    return np.exp(-mu * path)


def laser_irradiance(photons: float, emission: np.ndarray, cos_in: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`irradiance_term` on numpy arrays: E = Φ · f_l cosθ_l · cosθ_x,in / r², photons per m². ``emission``
    is :meth:`LegPhysics.spot_emission` toward the points; (n,) arrays."""
    return on_arrays(irradiance_term)(photons, emission, cos_in, r)


def geometry_weight(cos_a: np.ndarray, cos_b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`geometry_term` on numpy arrays: G = cosθ_a cosθ_b / r², 1/m², (n,) arrays."""
    return on_arrays(geometry_term)(cos_a, cos_b, r)


def fov_connection_weight(numerator: np.ndarray, r: np.ndarray, collection: np.ndarray) -> np.ndarray:
    """:func:`fov_term` on numpy arrays: ``numerator / r² · collection``, (n,) arrays; per unit radiant intensity
    of the hidden point toward y."""
    return on_arrays(fov_term)(numerator, r, collection)


class LegPhysics:
    """Per-leg weights of one capture (laser points, sensor) in one scene, under one :class:`PhysicsSettings`.

    Args:
        scene: the scene (materials, object names).
        capture: :func:`datagen.scene.resolve_capture` of the scene.
        caster: the scene's ray caster (shadow rays).
        settings: the physics switches (any estimator's settings).
        stats: an object with an int ``shadow_rays`` counter that the shadow rays cast here are added to
            (estimators swap it per batch); default a fresh counter.

    Attributes:
        materials: the scene's :class:`~datagen.scene.materials.MaterialTable`.
        tol: metres within which a point lies on the FoV plane (``FOV_PLANE_TOL`` ray offsets).
    """

    def __init__(self, scene: Scene, capture: Capture, caster: RayCaster, settings: PhysicsSettings,
                 stats=None):
        self.scene, self.capture, self.caster = scene, capture, caster
        self.materials = scene.materials
        self.stats = stats if stats is not None else ShadowRayCount()
        self.tol = FOV_PLANE_TOL * caster.offset
        # f = ρ/π per object for Lambertian materials, NaN for the others (evaluated in full by brdf)
        self.lambert_f = np.where(self.materials.lambertian, on_arrays(lambertian_value)(self.materials.albedo),
                                  np.nan)
        self.angular_g = self.materials.kind == SIN_THETA        # g(ω) ≠ 1 in the separable split
        self.wall_object = self._find_wall_object()
        self.fov_objects = self._find_fov_objects()
        self.configure(settings)

    def configure(self, settings: PhysicsSettings) -> None:
        """Use ``settings`` from now on (recomputes the blockers' bounding spheres)."""
        self.settings = settings
        self.spot_spheres = self.blocker_spheres(settings.spot_blockers)
        self.sensor_spheres = self.blocker_spheres(settings.sensor_blockers)

    # -- laser side --------------------------------------------------------------------------------------

    def spot_emission(self, directions: np.ndarray, laser: int | np.ndarray = 0) -> np.ndarray:
        """f_l(ω_e, ω)·cosθ_l at laser point ``laser`` for outgoing unit directions ω (..., 3) → (...,); ``laser``
        an int, or an int array of the directions' leading shape (one laser point per direction).

        The beam arrives from the emitter, ω_e = unit(emitter − spot); radiant intensity per photon of the
        pulse is f_l·cosθ_l (docs/physics.md §2; the paper's A1 without its 1/R²).
        """
        c = self.capture
        spot, normal = c.spots[laser], c.spot_normals[laser]
        w_e = unit(c.emitter - spot)
        n = np.broadcast_to(normal, directions.shape)
        cos = np.maximum(dot(n, directions), 0.0)
        obj = c.spot_objects[laser]
        if np.all(self.materials.lambertian[obj]) and not self.settings.brdf_angles:
            return on_arrays(emission_term)(on_arrays(lambertian_value)(self.materials.albedo[obj]), cos)
        f = self.materials.evaluate(np.broadcast_to(obj, directions.shape[:-1]), n,
                                    np.broadcast_to(w_e, directions.shape), directions)
        return on_arrays(emission_term)(f, cos)

    def irradiance(self, points: np.ndarray, face_normals: np.ndarray, laser: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Laser irradiance at surface points (n, 3) with face normals (n, 3) (docs/physics.md §2), lit on
        whichever side faces the spot, with a shadow ray when ``shadow_spot``.

        Returns:
            E = Φ f_l cosθ_l cosθ_in / r² V, photons/m² (n,); r, distance to the laser point (n,); the unit
            direction toward it (n, 3); and the geometric factor cosθ_l cosθ_in / r² V (n,), 1/m² (the density
            of cosine-weighted directions from the spot is geo/π in area measure).
        """
        c = self.capture
        spot, spot_n = c.spots[laser], c.spot_normals[laser]
        to_spot = spot - points
        r = np.linalg.norm(to_spot, axis=-1)
        w = to_spot / np.maximum(r, 1e-300)[:, None]
        nfw = dot(face_normals, w)
        cos_in = np.abs(nfw)
        cos_l = -dot(w, spot_n)
        idx = np.flatnonzero((cos_l > 0) & (cos_in > 0) & (r > self.tol))
        if self.settings.shadow_spot and len(idx):
            n_lit = np.where(nfw[idx, None] < 0, -face_normals[idx], face_normals[idx])
            self.stats.shadow_rays += len(idx)
            idx = idx[self.caster.visible(points[idx], n_lit, spot, spot_n)]
        geo = np.zeros(len(points))
        e = np.zeros(len(points))
        geo[idx] = geometry_weight(cos_l[idx], cos_in[idx], r[idx])
        e[idx] = laser_irradiance(c.photons, self.spot_emission(-w[idx], laser), cos_in[idx], r[idx])
        return e, r, w, geo

    def laser_leg(self, laser: int | np.ndarray) -> float | np.ndarray:
        """Metres of the emitter → laser point leg of laser point(s) ``laser`` (int or (n,) int array) that count in
        the time of flight: 0 unless ``count_laser_leg``."""
        return self.capture.emitter_legs[laser] if self.settings.count_laser_leg else 0.0

    # -- surfaces ----------------------------------------------------------------------------------------

    def brdf(self, obj: np.ndarray, normals: np.ndarray, w_in: np.ndarray, w_out: np.ndarray,
             sign_in: float = 1.0, sign_out: float = 1.0) -> np.ndarray:
        """f(sign_in·ω_in, sign_out·ω_out) for directions known to lie above the surface; broadcasts obj (...),
        normals, w_in, w_out (..., 3) → (...,) 1/sr.

        Unless ``brdf_angles`` is set, Lambertian materials take f = ρ/π without any angle work and only the
        other materials are evaluated in full (the values are identical: callers only pass directions above
        the surface). The signs flip a direction without materialising the negated array.
        """
        if self.settings.brdf_angles:
            return self.materials.evaluate(obj, normals, sign_in * w_in, sign_out * w_out)
        shape = np.broadcast_shapes(np.shape(obj), normals.shape[:-1], w_in.shape[:-1], w_out.shape[:-1])
        obj_b = np.broadcast_to(obj, shape)
        f = self.lambert_f[obj_b]
        sel = np.isnan(f)
        if sel.any():
            full = lambda a: np.broadcast_to(a, shape + (3,))[sel]
            f[sel] = self.materials.evaluate(obj_b[sel], full(normals), sign_in * full(w_in), sign_out * full(w_out))
        return f

    def constant_brdf(self, obj: np.ndarray) -> np.ndarray:
        """f = ρ/π for objects whose BRDF needs no angles (Lambertian, unless ``brdf_angles``), NaN for the others
        (evaluate those with :meth:`brdf`); (n,) float64 from obj (n,) int."""
        if self.settings.brdf_angles:
            return np.full(np.shape(obj), np.nan)
        return self.lambert_f[obj]

    def separable_factor(self, obj: np.ndarray, n: np.ndarray, rows: np.ndarray, w: np.ndarray) -> np.ndarray:
        """g(ω) of the separable BRDF split f = c·g(ω_in)·g(ω_out) + lobe at the vertices ``rows`` (indices into
        obj (B,) and n (B, 3)) for directions w (n, 3) above them; 1 for Lambertian and Phong surfaces, so only
        the others (sin θ) are evaluated. (n,) float64."""
        g = np.ones(len(rows))
        sel = np.flatnonzero(self.angular_g[obj][rows])
        if len(sel):
            r = rows[sel]
            g[sel] = self.materials.separable_factor_above(obj[r], n[r], w[sel])
        return g

    def attenuation(self, path: np.ndarray) -> np.ndarray | float:
        """e^{−μ·path} for physical path lengths (metres), or 1.0 when μ = 0 (the paper's C_atm)."""
        mu = self.settings.attenuation
        return on_arrays(attenuation_term)(mu, path) if mu > 0 else 1.0

    # -- sensor side -------------------------------------------------------------------------------------

    def sensor_collection(self, points: np.ndarray, normals: np.ndarray, object_id: np.ndarray,
                          w_in: np.ndarray, sign_in: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """What a photon landing at FoV points (n, 3) becomes at the sensor, and the FoV → sensor distance (n,).

        Aperture convention: the detected fraction q·f_y(ω_in, ω_s)·cosθ_y,out·A_ap·cosθ_ap/d²·V(y, x_s)
        (paper A3 and the aperture term, docs/physics.md §2); the aperture normal is
        :meth:`~datagen.scene.capture.Capture.aperture_normals` (a confocal scan's follows the laser). Point radiance:
        f_y(ω_in, ω_s), the radiance toward the sensor per unit irradiance. ω_in is ``sign_in · w_in`` (see
        :meth:`brdf`).
        """
        c = self.capture
        to_sensor = c.sensor - points
        d = np.linalg.norm(to_sensor, axis=-1)
        w_s = to_sensor / d[..., None]
        f = self.brdf(object_id, normals, w_in, w_s, sign_in)
        if c.convention == "point_radiance":
            return f, d
        cos_out = np.maximum(dot(normals, w_s), 0.0)
        cos_ap = np.maximum(-dot(w_s, c.aperture_normals(points)), 0.0)
        out = on_arrays(collection_term)(self.settings.pde, f, cos_out, c.aperture_area, cos_ap, d)
        if self.settings.shadow_sensor:
            self.sensor_shadows(out, points, normals, w_s, d)
        return out, d

    def sensor_shadows(self, out: np.ndarray, points: np.ndarray, normals: np.ndarray, w_s: np.ndarray,
                       d: np.ndarray) -> None:
        """Set ``out`` (n,) to 0 where the FoV point → sensor segment is blocked: shadow rays from points (n, 3)
        with normals (n, 3) for the entries > 0 whose segment (unit directions to the sensor w_s (n, 3), lengths
        d (n,)) may meet a sensor blocker (:meth:`may_be_blocked`)."""
        c = self.capture
        idx = np.flatnonzero(out > 0)
        idx = idx[self.may_be_blocked(c.sensor, -w_s[idx], d[idx], self.sensor_spheres)]
        if len(idx):
            self.stats.shadow_rays += len(idx)
            out[idx[~self.caster.visible(points[idx], normals[idx], c.sensor, None)]] = 0.0

    def sensor_leg(self, d: np.ndarray) -> np.ndarray | float:
        """Metres of the FoV → sensor leg that count in the time of flight: d, or 0 unless ``count_sensor_leg``."""
        return d if self.settings.count_sensor_leg else 0.0

    def connect(self, x: np.ndarray, n_x: np.ndarray, laser: int, rng, connect_samples: tuple[int, int],
                jitter: np.ndarray | None = None) -> Connections:
        """Next-event connections from hidden points x (B, 3) with normals n_x (B, 3) to sensor points (point
        radiance) or to stratified area samples of each sensor pixel region (aperture), with shadow rays.

        Aperture: one stratified ``connect_samples`` grid per pixel region shared by the batch, or, with
        ``jitter`` (B, 2) in [0, 1)², row b connects to the single point at ``jitter[b]`` inside each pixel
        region (density 1/A_pixel; unbiased for uniform jitter, and uncorrelated across rows). Each connection
        weighs :func:`fov_connection_weight` (cosθ_y dA_y / r² · collection) per unit radiant intensity.
        """
        c = self.capture
        nx, ny = c.fov_pixels
        if c.convention == "point_radiance":
            targets = c.sensor_points().reshape(1, -1, 3)                     # (1, S, 3)
            pix = np.arange(c.n_pixels)[None]
            area = 1.0
        elif jitter is not None:
            iy, ix = np.divmod(np.arange(c.n_pixels), nx)
            targets = c.region_points(ix[None], iy[None], jitter[:, :1], jitter[:, 1:])      # (B, S, 3)
            pix = np.arange(c.n_pixels)[None]
            area = c.pixel_area()
        else:
            mu, mv = connect_samples
            uv = stratified_grid(mu, mv, rng, count=c.n_pixels)               # (S, M, 2)
            iy, ix = np.divmod(np.arange(c.n_pixels), nx)
            targets = c.region_points(ix[:, None], iy[:, None], uv[..., 0], uv[..., 1]).reshape(1, -1, 3)
            pix = np.repeat(np.arange(c.n_pixels), mu * mv)[None]
            area = c.pixel_area(mu * mv)
        ch = c.channel(laser, pix)
        keep = ch[0] >= 0
        targets, pix, ch = targets[:, keep], pix[:, keep], ch[:, keep]
        to_y = targets - x[:, None, :]                                      # (B, S, 3)
        r = np.linalg.norm(to_y, axis=-1)
        w = to_y / np.maximum(r, 1e-300)[..., None]
        cos_x = dot(n_x[:, None, :], w)
        n_y = np.broadcast_to(c.fov_normal, to_y.shape)
        cos_y = -dot(n_y, w)
        ok = (cos_x > 0) & (cos_y > 0)
        bi, si = np.nonzero(ok)
        row = bi if len(targets) > 1 else np.zeros_like(bi)
        vis = self.caster.visible(x[bi], n_x[bi], targets[row, si], c.fov_normal)
        self.stats.shadow_rays += len(bi)
        bi, si, row = bi[vis], si[vis], row[vis]
        y = targets[row, si]
        wk = w[bi, si]
        obj_y = np.full(len(bi), self.wall_object)
        collect, d_ys = self.sensor_collection(y, n_y[bi, si], obj_y, -wk)
        rr = r[bi, si]
        # photons landing on dA_y per unit radiant intensity toward ω_k: cosθ_y dA_y / r²
        weight = fov_connection_weight(cos_y[bi, si] * area, rr, collect)
        time = (rr + self.sensor_leg(d_ys)) / SPEED_OF_LIGHT
        return Connections(bi, wk, weight, time, rr + d_ys, ch[0, si])

    def first_bounce_weight(self, laser: int | np.ndarray) -> tuple:
        """Direct laser point → sensor return of laser point(s) ``laser`` (aperture convention), ignoring whether
        the point is imaged: (detected photons per pulse, physical path emitter → spot → sensor in metres,
        arrival time in seconds with the leg switches), floats for an int ``laser``, (n,) float64 arrays for an
        (n,) int array. Weight Φ q f_l cosθ_l A_ap cosθ_ap / d² · V · C_atm (docs/physics.md §2)."""
        c = self.capture
        lasers = np.atleast_1d(np.asarray(laser, dtype=np.int64))
        spot = c.spots[lasers]
        to_sensor = c.sensor - spot
        d = np.sqrt(np.einsum("ij,ij->i", to_sensor, to_sensor))
        w_s = to_sensor / d[:, None]
        emit = self.spot_emission(w_s, lasers)
        cos_ap = np.maximum(-dot(w_s, c.aperture_normals(spot)), 0.0)
        vis = self.caster.visible(spot, c.spot_normals[lasers], c.sensor, None)
        path = c.emitter_legs[lasers] + d
        weight = on_arrays(direct_term)(c.photons, self.settings.pde, emit, c.aperture_area, cos_ap, d) * vis
        weight = weight * self.attenuation(path)
        t = np.broadcast_to((self.laser_leg(lasers) + self.sensor_leg(d)) / SPEED_OF_LIGHT, d.shape)
        if np.ndim(laser) == 0:
            return float(weight[0]), float(path[0]), float(t[0])
        return weight, path, t.astype(np.float64)

    def first_bounce(self, sink: Sink, component: int) -> None:
        """Send the direct return of each laser point lying strictly inside a sensor pixel region (aperture
        convention) to ``sink`` as component ``component`` (its channels follow)."""
        c = self.capture
        if c.convention != "aperture":
            return
        lasers = np.flatnonzero(c.spots_inside_fov())   # on the FoV's edge (or outside): not imaged
        ch = c.points_channel(lasers, c.spots[lasers], self.tol)
        lasers, ch = lasers[ch >= 0], ch[ch >= 0]
        if len(lasers) == 0:
            return
        weight, _, t = self.first_bounce_weight(lasers)
        sink.add(t, weight, component * c.n_channels + ch)

    # -- shadow-ray culling ------------------------------------------------------------------------------

    def blocker_spheres(self, blockers: tuple[int, ...] | None) -> np.ndarray | None:
        """(G, 4) bounding spheres (centre, radius; metres) of the faces ``blockers`` grouped by object, padded
        by 10 surface offsets; None when the blockers are unknown."""
        if blockers is None:
            return None
        faces = np.asarray(blockers, dtype=np.int64)
        spheres = []
        for obj in np.unique(self.caster.face_object[faces]):
            mine = faces[self.caster.face_object[faces] == obj]
            pts = self.caster.vertices[self.caster.faces[mine]].reshape(-1, 3)
            centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            radius = float(np.max(np.linalg.norm(pts - centre, axis=1))) + 10 * self.caster.offset
            spheres.append([*centre, radius])
        return np.array(spheres).reshape(-1, 4)

    @staticmethod
    def may_be_blocked(origin: np.ndarray, w: np.ndarray, r: np.ndarray, spheres: np.ndarray | None) -> np.ndarray:
        """(n,) bool: the segment from ``origin`` (3,) along unit directions w (n, 3) over lengths r (n,) may meet
        one of the blockers' bounding ``spheres`` (inside its cone from the origin and not wholly before it);
        the others need no shadow ray. All True when ``spheres`` is None (blockers unknown)."""
        if spheres is None:
            return np.ones(len(w), dtype=bool)
        out = np.zeros(len(w), dtype=bool)
        for cx, cy, cz, radius in spheres:
            to_c = np.array([cx, cy, cz]) - origin
            dist = float(norm(to_c))
            if dist <= radius:                                      # the origin is inside the sphere
                return np.ones(len(w), dtype=bool)
            cos_cone = np.sqrt(1.0 - (radius / dist) ** 2)
            out |= (matmul(w, to_c / dist) >= cos_cone - 1e-12) & (r >= dist - radius)
        return out

    # -- the relay wall ----------------------------------------------------------------------------------

    def _find_fov_objects(self) -> np.ndarray:
        c, rc = self.capture, self.caster
        tri = rc.vertices[rc.faces]
        in_plane = np.abs(matmul(tri - c.fov_center, c.fov_normal)).max(axis=1) <= self.tol
        return np.unique(rc.face_object[in_plane])

    def _find_wall_object(self) -> int:
        c = self.capture
        h = self.caster.intersect((c.fov_center + 2 * FOV_PLANE_TOL * self.caster.offset * c.fov_normal)[None],
                                  (-c.fov_normal)[None])
        return int(h.object_id[0]) if h.hit[0] else int(c.spot_objects[0])


@dataclass
class ShadowRayCount:
    """A bare shadow-ray counter for :class:`LegPhysics` users without stats of their own."""

    shadow_rays: int = 0
