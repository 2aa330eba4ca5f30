"""Hidden-surface area sampler: the transient path integral with next-event connections (transient path tracing).

The integral is docs/physics.md §2's, the same one the lookin estimator of :mod:`datagen.transport.lookin`
converges to, written in *area* measure. Every factor comes from the per-leg functions of
:mod:`datagen.transport.physics` (laser irradiance ``irradiance``, sensor collection ``sensor_collection``, BRDFs
``brdf``, attenuation, the FoV connection weight); what differs is how the vertices are sampled:

- **Hidden points x** come from two strategies combined by multiple importance sampling (balance heuristic,
  Veach & Guibas 1995): M_a points by *area* over every triangle that can take part in a path (a face wholly
  behind every laser-spot plane and the FoV plane cannot: the relay wall itself), and M_s points by
  *cosine-weighted direction from the laser spot* (the first hits; density M_s·cosθ_l cosθ_x,in /(π r²) in
  area measure, for points the spot sees). Each x weighs 1/(ρ_a(x) + ρ_s(x)), the inverse of the summed
  sample densities. ``sampling`` sets how both sets are drawn: ``"stratified"`` (each triangle split into k²
  congruent sub-triangles of edge ≤ h with one uniform point in each, so ρ_a = k_f²/A_f on face f; a
  jittered √M_s×√M_s grid of directions), ``"sobol"`` (scrambled Sobol points, scipy.stats.qmc: randomised
  QMC) or ``"random"`` (independent points). All three are unbiased. Area samples alone put as many points on
  the far walls as on the ceiling 35 cm above the spot, whose irradiance is 100× higher; spot samples alone
  miss every point the spot does not see (the secondary's middle vertex can lie in a laser shadow).
- **Laser leg** (next-event connection to the laser spot x_l, a shadow ray): the irradiance
  E(x) = Φ f_l cosθ_l cosθ_x,in / |x−x_l|² V(x_l, x), photons per m² (docs/physics.md §2: in area measure the
  1/r² is genuine).
- **FoV leg** (:meth:`AreaSampler._connect`): stratified points y on each sensor pixel region (a k_u×k_v grid
  per hidden point, shifted by that point's two *padding* coordinates: Sobol dimensions 3–4 for "sobol", a
  permuted jittered grid for "stratified", fresh jitter for "random"; shadow ray x→y) and ``fov_directions``
  cosine-weighted rays from x that hit the FoV, combined by the balance heuristic; then the sensor leg
  q f_y cosθ_y,out A_ap cosθ_ap / |x_s−y|² V(y, x_s) (paper A3 and aperture term). Point-radiance captures
  connect to the sensor points instead.
- **Primary**: w_x · E(x) · f_x(ω→x_l, ω→y) · cosθ_x,out cosθ_y,in / |y−x|² · w_y · collection(y) at time
  (|x−x_l| + |y−x| [+ |x_s−y|]) / c.
- **Secondary** (a vertex x' before x): at each x the irradiance arriving from other surfaces is estimated
  with up to three partner strategies under the balance heuristic: ``spot_partners`` cosine directions from
  the laser spot (density ∝ the laser irradiance pattern), ``direction_partners`` cosine directions from x
  (density cosθ_x cosθ_x' /(π r²)) and ``area_partners`` points by area (1/A_hidden). Each partner x' has its
  own laser connection E(x') and the estimate is Σ E(x') f_x'(ω→x_l, ω→x) G(x',x) V(x',x) / Σ_t P_t p_t(x'),
  G = cosθ_x' cosθ_x / |x−x'|². Area or spot partners alone have *infinite variance* where two surfaces meet
  (G ~ 1/r² at a room corner: the second moment diverges like 1/ε); the direction strategy bounds the
  weight there by π E f / P_d, and the spot strategy keeps the brightly lit patch next to the spot cheap.

Unlike the lookin estimator's secondary, whose middle vertex is a lookin (a point the laser spot sees),
the middle vertex x here ranges over every surface, laser-shadowed ones included, as the integral asks: in the
demo room 6.9 % of the secondary (2.2 % of the total) passes through laser-shadowed middle vertices
(docs/accuracy.md).

Sink component ids follow :class:`datagen.transport.LookinSampler`: ``component * n_channels + channel`` with the
component of the object x lies on for primary paths, ``len(scene.component_names())`` for secondary and one
more for the direct first bounce when ``first_bounce`` is on (:attr:`AreaSampler.component_names`). Every
laser point of the capture is sampled (confocal and exhaustive scans included).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from ...errors import ConfigError, SceneError
from ...processes import ForkedCall
from ...sampling import sample_surfaces, square_to_hemisphere
from ...sampling.directions import stratified_grid, to_world
from ...sampling.surfaces import AreaSampling, SurfaceSamples, unit_square_points
from ...scene import RayCaster, Scene, resolve_capture
from ...scene.capture import Capture
from ...vectors import distinct_rows, dot, matmul
from ..base import PLANNED_SWITCHES, Connections, Counters, EstimatorOptions, Sink, register
from .kernels import (connection_weights, fov_targets, lobe_directions, material_arrays, primary_impulses,
                      sensor_collection, spot_irradiance)
from .memory import area_memory
from .secondary import AreaSecondary, spot_hits
from ..physics import LegPhysics, PhysicsSettings

MAX_CONNECTIONS = 1 << 17
"""Cap on hidden samples × FoV targets handled together (the (B, S, 3) float64 arrays of one batch)."""

NOMINAL_SECONDS = {"sample": 4.0e-6, "pair": 3.2e-7}
"""Seconds per hidden sample (FoV connections and shadow rays included) and per secondary pair of
:meth:`AreaSampler.nominal_seconds`: a non-negative least-squares fit of the CPU time of 36 runs (6 default-config
rooms, 4096–16384 samples; residual 10 %) on the shared 2-core machine."""

MIN_REPLICA_SAMPLES = 16


def _inverse(density: np.ndarray) -> np.ndarray:
    """1/density where it is positive, else 0 (points no strategy can draw carry no weight)."""
    return np.divide(1.0, density, out=np.zeros_like(density), where=density > 0)
"""Fewest hidden samples per laser point of one replica (the config's ``area_samples`` lower bound)."""


@dataclass(frozen=True)
class AreaSettings(PhysicsSettings):
    """Settings of the area sampler (:class:`AreaSampler`); the physics switches are those of
    :class:`~datagen.transport.physics.PhysicsSettings`, which this class extends.

    Attributes:
        samples: M, hidden samples per run and laser point: M_a = M − M_s by area, M_s = round(spot_fraction
            · M) by direction from the spot (stratified: the closest achievable counts, at least one point per
            triangle and a square grid of directions; sobol: each rounded up to a power of two).
        sampling: "stratified" | "sobol" | "random" (see the module docstring).
        spot_fraction: share of the hidden samples drawn by direction from the laser spot, in [0, 1).
        fov_fraction: share drawn as FoV paths (a uniform FoV point y, then x the first hit of a cosine
            direction from y; aperture captures only): spot_fraction + fov_fraction < 1.
        fov_samples: (k_u, k_v) stratified FoV points per sensor pixel region for every hidden sample.
        fov_directions: D, cosine-weighted rays per hidden sample (and side) that connect where they hit the
            FoV, combined with the stratified points by MIS (0: stratified points only).
        secondary: "none" or "full" (the unbiased secondary; there is no "optimized" variant here).
        spot_partners, direction_partners, area_partners: P_l, P_d, P_a secondary partners x' per hidden
            sample for each strategy (sum ≥ 1 when secondary is "full").
        batch: hidden samples processed together (lowered so that batch × FoV points ≤ ``MAX_CONNECTIONS``).
        workers: processes sharing the replicas of :meth:`AreaSampler.run_replicas` (results do not depend on it).
        aligned: the draws of the back connections and the secondary partners made for every hidden sample of a
            batch and picked for those that use them (``SimulationConfig.common_random_numbers``: scenes that differ
            in one object draw alike for every sample it does not touch; ``error.common_random_numbers``, docs/motion.md).

    Raises:
        ConfigError: a field out of range (the message names the field and the value).
    """

    samples: int = 1 << 16
    sampling: AreaSampling = "sobol"
    spot_fraction: float = 0.4
    fov_fraction: float = 0.4
    fov_samples: tuple[int, int] = (3, 3)
    fov_directions: int = 1
    secondary: Literal["none", "full"] = "full"
    spot_partners: int = 2
    direction_partners: int = 1
    area_partners: int = 1
    batch: int = 4096
    workers: int = 1
    aligned: bool = False

    def __post_init__(self):
        def bad(name, value, why):
            raise ConfigError(f"area sampler: {name} {why}, got {value!r}")

        def count(name, low):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                bad(name, v, f"must be an integer >= {low}")

        count("samples", 1)
        count("batch", 1)
        count("workers", 1)
        for name in ("fov_directions", "spot_partners", "direction_partners", "area_partners"):
            count(name, 0)
        if self.sampling not in ("stratified", "sobol", "random"):
            bad("sampling", self.sampling, "must be 'stratified', 'sobol' or 'random'")
        if not (isinstance(self.spot_fraction, (int, float)) and 0 <= self.spot_fraction < 1):
            bad("spot_fraction", self.spot_fraction, "must be in [0, 1) (area samples are needed for points "
                                                     "the laser spot does not see)")
        if not (isinstance(self.fov_fraction, (int, float)) and 0 <= self.fov_fraction
                and self.spot_fraction + self.fov_fraction < 1):
            bad("fov_fraction", self.fov_fraction, "must be >= 0 with spot_fraction + fov_fraction < 1")
        fs = tuple(self.fov_samples)
        if len(fs) != 2 or any(isinstance(v, bool) or int(v) != v or v < 1 for v in fs):
            bad("fov_samples", self.fov_samples, "must be two integers >= 1")
        if self.secondary not in ("none", "full"):
            bad("secondary", self.secondary, "must be 'none' or 'full'")
        n_partners = self.spot_partners + self.direction_partners + self.area_partners
        if self.secondary == "full" and n_partners < 1:
            bad("spot_partners + direction_partners + area_partners", n_partners,
                "must be >= 1 when secondary is 'full'")
        self.check_physics("area sampler")
        object.__setattr__(self, "fov_samples", (int(fs[0]), int(fs[1])))

    @property
    def spot_samples(self) -> int:
        """M_s, hidden samples drawn by direction from each laser spot (before rounding)."""
        return int(round(self.spot_fraction * self.samples))

    @property
    def fov_paths(self) -> int:
        """M_f, hidden points drawn by cosine direction from uniform FoV points (before rounding)."""
        return int(round(self.fov_fraction * self.samples))

    @property
    def area_samples(self) -> int:
        """M_a, hidden samples drawn by area (before rounding; at least 1)."""
        return max(1, self.samples - self.spot_samples - self.fov_paths)

    @classmethod
    def from_transport(cls, settings: PhysicsSettings, **kwargs) -> AreaSettings:
        """Area settings with the physics switches of ``settings`` (any estimator's, or plain
        :class:`~datagen.transport.physics.PhysicsSettings`; the secondary is "full" when ``settings`` has a
        secondary mode other than "none", else "none"); ``kwargs`` set the sampling fields and may set
        ``secondary``."""
        base = {**settings.switches(), "secondary": "none" if getattr(settings, "secondary", "none") == "none"
                else "full"}
        return cls(**{**base, **kwargs})


@dataclass
class AreaStats(Counters):
    """Counters from an area-sampler run (summed over laser points; ``add`` merges replicas)."""

    area_samples: int = 0
    spot_samples: int = 0
    fov_paths: int = 0
    lit_samples: int = 0
    fov_connections: int = 0
    partners: int = 0
    secondary_pairs: int = 0


def _forked_replicas(sampler: "AreaSampler", sinks: list[Sink], rngs: list[np.random.Generator]) -> list[tuple]:
    """Replicas one after another in a forked child (:class:`~datagen.processes.ForkedCall`): per replica the sink
    it filled, its counters and its shadow rays."""
    out = []
    for sink, rng in zip(sinks, rngs):
        sampler.stats, rays = AreaStats(), sampler.physics.stats.shadow_rays
        sampler.run(sink, rng)
        out.append((sink, sampler.stats, sampler.physics.stats.shadow_rays - rays))
    return out


class AreaOptions(EstimatorOptions):
    """The area sampler's settings (``estimator: {kind: area, samples: M}``): M hidden samples per laser point."""

    kind: Literal["area"] = "area"
    samples: int = Field(65536, ge=16)

    LEGACY: ClassVar[dict[str, str]] = {"area_samples": "samples"}

    def replica(self, replicas: int) -> dict:
        """One of ``replicas`` independent runs: ``samples`` / R per laser point (rounded up; at least
        ``MIN_REPLICA_SAMPLES``)."""
        return {"samples": max(MIN_REPLICA_SAMPLES, -(-int(self.samples) // int(replicas)))}

    def describe(self) -> str:
        return f"{self.samples} hidden samples per laser point"


AREA_FOLLOWS_PLAN = tuple(s for s in PLANNED_SWITCHES if s != "shadow_spot")
"""The planned switches the area sampler (and the quadrature, which samples the same way) follows: all but
``shadow_spot``, which the planner decides for the laser leg of secondary paths only."""

@register("area", AreaSettings,
          "hidden-surface area sampling with next-event connections to the laser spot and the FoV",
          options=AreaOptions, replica=AreaOptions.replica, describe=AreaOptions.describe, memory=area_memory)
class AreaSampler:
    """Area-sampling estimator with next-event connections to the laser spot and the FoV.

    Same interface as :class:`datagen.transport.LookinSampler`: ``AreaSampler(scene, settings, caster).run(sink,
    rng, progress)`` sends path impulses (times s, weights photons, component ids) to ``sink``.

    ``secondary_only=True`` deposits only the secondary (no primary and no first-bounce impulses; the samples,
    connections and random streams are unchanged), for estimators that compute the primary another way
    (:mod:`datagen.transport.quadrature`). It is an argument, not an :class:`AreaSettings` field, so that the
    settings' hashes (the reference cache keys of :mod:`datagen.analysis.reference`) stay as they were.

    Attributes:
        component_names: names of the sink components (primary components, "secondary"[, "first_bounce"]).
        hidden_faces: (F_h,) int64 faces that can be hidden vertices; hidden_area: their area, m²; is_hidden:
        (F,) bool over every face of the caster.
        stats: :class:`AreaStats`; physics: the :class:`~datagen.transport.physics.LegPhysics` weighing every
        leg (its ``stats.shadow_rays`` counts the shadow rays); secondary_paths: the
        :class:`~datagen.transport.area.secondary.AreaSecondary` computing the secondary.

    Raises:
        ConfigError: invalid settings (``secondary_only`` with secondary "none"). SceneError: the capture errors
            of :func:`datagen.scene.resolve_capture`; no triangle can take part in a path.
    """

    sensor_sampling = "area next-event connections"
    """How the FoV is reached (result attribute ``effects.sensor_sampling``)."""

    follows_plan = AREA_FOLLOWS_PLAN
    """The planned switches its registry entry follows (:attr:`datagen.transport.EstimatorEntry.follows_plan`)."""

    def __init__(self, scene: Scene, settings: AreaSettings | None = None, caster: RayCaster | None = None,
                 secondary_only: bool = False, capture: Capture | None = None):
        self.scene = scene
        self.settings = settings or AreaSettings()
        if secondary_only and self.settings.secondary != "full":
            raise ConfigError(f"area sampler: secondary_only needs secondary 'full' (there is nothing else to "
                             f"deposit), got secondary {self.settings.secondary!r}")
        self.secondary_only = bool(secondary_only)
        self.caster = caster or RayCaster(scene)
        self.capture = capture if capture is not None else resolve_capture(scene, self.caster)
        self.physics = LegPhysics(scene, self.capture, self.caster, self.settings)
        self.component_names = scene.component_names() + ["secondary"] + (
            ["first_bounce"] if self.settings.first_bounce else [])
        self.object_component = scene.object_component()
        self.n_primary = len(scene.component_names())
        self.tol = self.physics.tol
        self.hidden_faces = self._hidden_faces()
        if len(self.hidden_faces) == 0:
            raise SceneError(f"{scene.source + ': ' if scene.source else ''}no surface lies in front of the laser "
                             "spot or the FoV: nothing can be lit and seen")
        self.hidden_area = float(self.caster.face_area[self.hidden_faces].sum())
        self.is_hidden = np.zeros(len(self.caster.faces), dtype=bool)
        self.is_hidden[self.hidden_faces] = True
        self._fov_density = 0.0                   # M_f / A_FoV of the run under way (FoV paths), 1/m²
        self.stats = AreaStats()
        self.secondary_paths = AreaSecondary(self.capture, self.settings, self.caster, self.physics, self.hidden_faces,
                                             self.hidden_area, self.is_hidden, self.n_primary)

    @classmethod
    def from_config(cls, scene: Scene, config, physics: PhysicsSettings, caster: RayCaster,
                    capture: Capture | None, secondary: str) -> "AreaSampler":
        """The registry's constructor (:attr:`datagen.transport.EstimatorEntry.from_config`):
        ``config.estimator.samples`` hidden samples per laser point with the planned ``physics`` and its sensor
        blockers, the secondary "full" unless ``secondary`` is "none", and ``config.workers``. Its entry does not
        follow the planner's ``shadow_spot`` (``follows_plan``): area-sampled hidden points need the laser leg's
        shadow ray for the primary too, so ``physics.shadow_spot`` is the user's forced value or on."""
        return cls(scene, AreaSettings.from_transport(physics, samples=config.estimator.samples,
                                                      secondary="none" if secondary == "none" else "full",
                                                      sensor_blockers=physics.sensor_blockers,
                                                      workers=config.workers,
                                                      aligned=config.error.common_random_numbers), caster,
                   capture=capture)

    def configure(self, settings: AreaSettings) -> None:
        """Use ``settings`` from now on (same physics object; e.g. the quadrature's shadow-ray decision)."""
        self.settings = settings
        self.physics.configure(settings)
        self.secondary_paths.configure(settings)

    def nominal_seconds(self) -> float:
        """A deterministic measure of the work done so far (runs and replicas summed), in seconds of one core of
        the reference machine: a linear model of the counted hidden samples and secondary pairs (rates
        ``NOMINAL_SECONDS``). Dataset builds cap the adaptive sampling with it, so that the cap, unlike a wall
        clock, never depends on the machine's load."""
        st = self.stats
        n = NOMINAL_SECONDS
        return float(n["sample"] * (st.area_samples + st.spot_samples + st.fov_paths)
                     + n["pair"] * st.secondary_pairs)

    def progress_total(self) -> tuple[int, str]:
        """Hidden samples over all laser points."""
        return self.settings.samples * self.capture.n_lasers, "sample"

    def _hidden_faces(self) -> np.ndarray:
        """Faces that can be a hidden vertex: non-degenerate and not wholly behind every laser-spot plane and
        the FoV plane (such a face has cosθ_l ≤ 0 and cosθ_y,in ≤ 0 everywhere, so every path through it is
        0: the relay wall itself)."""
        c, cst = self.capture, self.caster
        tri = cst.vertices[cst.faces]                                          # (F, 3, 3)
        planes, _ = distinct_rows(np.round(np.concatenate([c.spot_normals, dot(c.spots, c.spot_normals)[:, None]],
                                                          1), 12))            # distinct laser-spot planes
        front_spot = np.zeros(len(tri), dtype=bool)
        for n_x, n_y, n_z, d in planes:
            front_spot |= (matmul(tri, np.array([n_x, n_y, n_z])) - d > self.tol).any(axis=1)
        front_fov = (matmul(tri - c.fov_center, c.fov_normal) > self.tol).any(axis=1)
        return np.flatnonzero((cst.face_area > 0) & (front_spot | front_fov))

    def _weight_constants(self) -> tuple[float, float, float, float]:
        """(ρ_a = 1/dA_y of the stratified FoV points, D, M_f/A_FoV, sensor leg counted) for
        :func:`~datagen.transport.area.kernels.connection_weights` (aperture captures)."""
        c, s = self.capture, self.settings
        rho_a = c.n_pixels * s.fov_samples[0] * s.fov_samples[1] / (c.fov_size[0] * c.fov_size[1])
        return (float(rho_a), float(s.fov_directions), float(self._fov_density), float(s.count_sensor_leg))

    def _targets_per_sample(self) -> int:
        c = self.capture
        if c.convention == "point_radiance":
            return c.n_pixels
        return c.n_pixels * self.settings.fov_samples[0] * self.settings.fov_samples[1]

    def from_spot(self, uv: np.ndarray, laser: int) -> tuple[SurfaceSamples, np.ndarray]:
        """First hits of cosine-weighted rays from laser point ``laser`` (:func:`~datagen.transport.area.secondary.spot_hits`)."""
        return spot_hits(self.capture, self.caster, uv, laser)

    def _connect(self, x: np.ndarray, n_x: np.ndarray, rho_x: np.ndarray, laser: int, rng: np.random.Generator,
                 pad: np.ndarray | None, obj: np.ndarray, w_spot: np.ndarray,
                 drawn: dict | None = None) -> Connections:
        """Next-event connections of hidden points x (B, 3), from the side of normals n_x (B, 3), to the sensor.

        Two strategies under the balance heuristic: the area strategy of transport's ``connect`` sensor
        sampling (:meth:`datagen.transport.physics.LegPhysics.connect`: stratified points y on each sensor pixel
        region, density ρ_a = 1/dA_y, a shadow ray x→y), but with its own grid shift *for every hidden point*
        (``pad`` (B, 2) in [0,1)², the padding coordinates of the sampling pattern; None: independent jitter
        per cell), since transport draws one grid per batch of lookins, which would correlate the FoV error of
        thousands of area samples; and ``fov_directions`` cosine-weighted rays from x whose first hit lies in the FoV
        (density p_d = cosθ_x cosθ_y /(π r²) in area measure; at a retroreflective point, objects ``obj`` (B,), lit
        from the unit directions ``w_spot`` (B, 3) toward the laser point, the rays follow its BRDF instead,
        :func:`~datagen.scene.brdf_kernel.sample_direction` from the same uniforms, density p_d s). Each connection weighs cosθ_y / r² ·
        collection(y) / (ρ_a + D·p_d), per unit radiant intensity of x toward y (:attr:`Connections.weight`).
        Without the direction strategy a point a few cm from the FoV (a side wall meeting the relay wall, the
        box 10 cm in front of it) has G(x, y) ~ 1/r² and a huge variance; with it the weight stays below
        π·collection/(D cosθ_x). Point-radiance captures connect to the sensor points (transport's code).
        ``drawn``: the uniforms to use instead of drawing them ("jitter" (B, P, 2), "u" and "v" (B, D); the aligned
        draws of :attr:`AreaSettings.aligned`).
        """
        c, s, cst = self.capture, self.settings, self.caster
        if c.convention == "point_radiance":
            out = self.physics.connect(x, n_x, laser, rng, s.fov_samples)
            out.weight = out.weight * _inverse(rho_x)[out.b]
            return out
        nx, ny = c.fov_pixels
        mu, mv = s.fov_samples
        n_dir = s.fov_directions
        pix = np.repeat(np.arange(c.n_pixels), mu * mv)
        ch = c.channel(laser, pix)
        keep = ch >= 0
        pix, ch = pix[keep], ch[keep]
        iy, ix = np.divmod(pix, nx)
        cell = stratified_grid(mu, mv, None)[0] - 0.5 / np.array([mu, mv])      # cell corners, (M, 2)
        corner = np.tile(cell, (c.n_pixels, 1))[keep]
        jitter = (pad[:, None, :] if pad is not None else drawn["jitter"] if drawn is not None
                  else rng.random((len(x), len(pix), 2)))
        fov = (c.fov_center, c.fov_u, c.fov_v, c.fov_normal, np.asarray(c.fov_size, dtype=np.float64),
               np.asarray(c.fov_pixels, dtype=np.float64))
        bi, si, y, wk, rr, cy = fov_targets(np.ascontiguousarray(x), np.ascontiguousarray(n_x), ix, iy,
                                            np.ascontiguousarray(corner), np.ascontiguousarray(jitter),
                                            (float(mu), float(mv)), fov)
        vis = cst.visible(x[bi], n_x[bi], y, c.fov_normal)
        self.physics.stats.shadow_rays += len(bi)
        bi, y, wk, rr, cy, chan = bi[vis], y[vis], wk[vis], rr[vis], cy[vis], ch[si[vis]]
        n_y = np.broadcast_to(c.fov_normal, y.shape)
        obj_y = np.full(len(bi), self.physics.wall_object)
        if n_dir:
            u, v = ((drawn["u"], drawn["v"]) if drawn is not None
                    else (rng.random((len(x), n_dir)), rng.random((len(x), n_dir))))
            local, _ = square_to_hemisphere(u, v, "cosine")
            n_b = np.broadcast_to(n_x[:, None], (len(x), n_dir, 3))
            dirs = to_world(local, n_b)
            lobe_directions(dirs, n_x, obj, w_spot, (u, v), material_arrays(self.physics))
            hits = cst.intersect(x[:, None] + cst.offset * n_b, dirs)
            hp = hits.hit_points()
            hch = np.where(hits.hit, c.channel(laser, c.fov_pixel(hp, self.tol)), -1)
            db, dk = np.nonzero(hch >= 0)
            y = np.concatenate([y, hp[db, dk]])
            wk = np.concatenate([wk, dirs[db, dk]])
            rr = np.concatenate([rr, np.linalg.norm(hp[db, dk] - x[db], axis=-1)])   # from x, not the offset origin
            cy = np.concatenate([cy, -dot(dirs[db, dk], c.fov_normal)])
            chan = np.concatenate([chan, hch[db, dk]])
            n_y = np.concatenate([n_y, hits.normals[db, dk]])
            obj_y = np.concatenate([obj_y, hits.object_id[db, dk]])
            bi = np.concatenate([bi, db])
        collect, d_ys = sensor_collection(self.physics, y, n_y, obj_y, -wk)
        weight, time, phys = connection_weights(bi, np.ascontiguousarray(n_x), rho_x, wk, rr, cy, collect, d_ys,
                                                self._weight_constants(), obj, np.ascontiguousarray(w_spot),
                                                material_arrays(self.physics))
        return Connections(bi, wk, weight, time, phys, chan)

    # -- estimator -------------------------------------------------------------------------------------------

    def run(self, sink: Sink, rng: np.random.Generator, progress: Callable[[int], None] | None = None) -> None:
        """Sample hidden points and send every primary (and secondary) impulse to ``sink``.

        ``progress`` is called with the number of hidden samples done after each batch (per laser point).
        """
        s, c = self.settings, self.capture
        n_fov = s.fov_paths if c.convention == "aperture" else 0      # point sensors: FoV paths go to area samples
        area_set, density_a = sample_surfaces(self.caster, self.hidden_faces, s.area_samples + s.fov_paths - n_fov,
                                              s.sampling, rng)
        batch = max(1, min(s.batch, MAX_CONNECTIONS // max(self._targets_per_sample(), 1)))
        fov_uv = unit_square_points(n_fov, s.sampling, rng) if n_fov else np.zeros((0, 4))
        self._fov_density = len(fov_uv) / (c.fov_size[0] * c.fov_size[1])         # M_f / A_FoV, 1/m²
        for laser in range(c.n_lasers):
            parts, n_spot = [area_set], 0
            if s.spot_samples > 0:
                uv = unit_square_points(s.spot_samples, s.sampling, rng)
                found, hit = self.from_spot(uv, laser)
                parts.append(found.take(hit))
                n_spot = len(uv)
            xs = SurfaceSamples.concat(parts)
            self.stats.area_samples += len(area_set)
            self.stats.spot_samples += n_spot
            self.stats.fov_paths += len(fov_uv)
            for start in range(0, len(xs), batch):
                part = xs.take(slice(start, start + batch))
                self._batch(part, laser, density_a, n_spot, sink, rng)
                if progress is not None:
                    progress(len(part))
            for start in range(0, len(fov_uv), batch):
                self._fov_batch(fov_uv[start:start + batch], laser, density_a, n_spot, sink, rng)
                if progress is not None:
                    progress(len(fov_uv[start:start + batch]))
        if s.first_bounce and not self.secondary_only:
            self.physics.first_bounce(sink, self.n_primary + 1)

    def run_replicas(self, sinks: list[Sink], rngs: list[np.random.Generator],
                     progress: Callable[[int], None] | None = None) -> None:
        """Independent runs into ``sinks``, one per generator (:func:`datagen.transport.run_replicas`); with
        ``workers`` > 1 and sinks that can ``spawn``/``merge`` (:class:`~datagen.timing.EnvelopeAccumulator`),
        replicas run in this process and ``workers`` − 1 forked ones (querying the BVH built before the fork), at
        most ``workers`` at a time, and are merged in order, so the sinks hold the same sums whatever the worker
        count."""
        workers = min(self.settings.workers, len(sinks))
        if workers <= 1 or not hasattr(sinks[0], "spawn"):
            for sink, rng in zip(sinks, rngs):
                self.run(sink, rng, progress)
            return
        # replica r runs in process r mod W: this one (0) and W − 1 forked children (ForkedCall: a child inherits this
        # sampler, its sinks and generators, and queries the BVH committed before the fork, RayCaster.commit), each
        # running its share one replica after another; results are merged in replica order
        share = {k: list(range(k, len(sinks), workers)) for k in range(workers)}
        self.caster.commit()
        calls: dict[int, ForkedCall] = {}
        try:
            for k in range(1, workers):
                calls[k] = ForkedCall(_forked_replicas, self, [sinks[r].spawn() for r in share[k]],
                                      [rngs[r] for r in share[k]])
            parts = {}
            for r in share[0]:
                parts[r] = sinks[r].spawn()
                self.run(parts[r], rngs[r])
            for k, call in calls.items():
                for r, (part, stats, rays) in zip(share[k], call.result()):
                    parts[r] = part
                    self.stats.add(stats)
                    self.physics.stats.shadow_rays += rays
            for r, sink in enumerate(sinks):
                sink.merge(parts[r])
                if progress is not None:
                    progress(self.settings.samples * self.capture.n_lasers)
        finally:
            for call in calls.values():
                call.cancel()

    def _batch(self, xs: SurfaceSamples, laser: int, density_a: np.ndarray, n_spot: int, sink: Sink,
               rng: np.random.Generator) -> None:
        """Hidden points by area or from the spot: next-event connections to the FoV from the side the spot
        lights (and, for the secondary, from the other side where the FoV lies behind it)."""
        c, s = self.capture, self.settings
        e_x, r_lx, w_spot, geo = spot_irradiance(self.physics, xs.points, xs.normals, laser)
        self.stats.lit_samples += int((e_x > 0).sum())
        rho_x = density_a[xs.face] + n_spot * geo / np.pi                    # ρ_a + ρ_s, 1/m²
        n_front = np.where(dot(xs.normals, w_spot)[:, None] < 0, -xs.normals, xs.normals)   # facing the spot
        pad = None if s.sampling == "random" else xs.pad
        out = self._connect(xs.points, n_front, rho_x, laser, rng, pad, xs.object_id, w_spot)
        self.stats.fov_connections += len(out.b)
        conn = {"normal": n_front[out.b], **{name: getattr(out, name) for name in Connections.FIELDS}}
        lit = np.ones(len(out.b), dtype=bool)
        if s.secondary == "full":
            # FoV behind the spot-facing side: only where the FoV rectangle reaches behind x's plane
            half = np.array([[a * c.fov_size[0] / 2, b * c.fov_size[1] / 2] for a in (-1, 1) for b in (-1, 1)])
            corners = c.fov_center + matmul(half, np.stack([c.fov_u, c.fov_v]))
            behind = np.flatnonzero((dot(corners[None] - xs.points[:, None], -n_front[:, None]) > 0).any(axis=1))
            drawn = None
            if s.aligned:                 # drawn for every sample, picked for those behind (common random numbers)
                n, n_pix, n_dir = len(xs.points), c.n_pixels * s.fov_samples[0] * s.fov_samples[1], s.fov_directions
                drawn = {"jitter": rng.random((n, n_pix, 2))[behind] if pad is None else None,
                         "u": rng.random((n, n_dir))[behind], "v": rng.random((n, n_dir))[behind]}
            back = self._connect(xs.points[behind], -n_front[behind], rho_x[behind], laser, rng,
                                 None if pad is None else pad[behind], xs.object_id[behind], w_spot[behind], drawn)
            back.b = behind[back.b]
            self.stats.fov_connections += len(back.b)
            conn = {name: np.concatenate([conn[name], getattr(back, name)]) for name in Connections.FIELDS}
            conn["normal"] = np.concatenate([n_front[out.b], -n_front[back.b]])
            lit = np.concatenate([lit, np.zeros(len(back.b), dtype=bool)])
        self._deposit(xs, e_x, r_lx, w_spot, conn, lit, laser, sink, rng)

    def _fov_batch(self, uv: np.ndarray, laser: int, density_a: np.ndarray, n_spot: int, sink: Sink,
                   rng: np.random.Generator) -> None:
        """FoV paths: y uniform on the FoV (``uv`` (n, 4) dims 0–1), x the first hit of a cosine direction from y
        (dims 2–3); the pair (x, y) weighs f / (ρ_x(x)·(ρ_a + D·p_d) + M_f·p_d/A_FoV) as in :meth:`_connect`
        (p_d = cosθ_x cosθ_y /(π r²), the density of this pair being M_f·p_d/A_FoV). No shadow ray x ↔ y: x is the
        first hit. They put hidden points where the FoV kernel 1/r² is large (floors and walls next to the relay
        wall), which area and spot samples reach rarely and then with large weights."""
        c, cst = self.capture, self.caster
        nx, ny = c.fov_pixels
        y = c.fov_points(uv[:, 0] * nx, uv[:, 1] * ny)
        local, _ = square_to_hemisphere(uv[:, 2], uv[:, 3], "cosine")
        normal = np.broadcast_to(c.fov_normal, y.shape)
        hits = cst.intersect(y + cst.offset * normal, to_world(local, normal))
        chan = c.channel(laser, c.fov_pixel(y, self.tol))
        keep = hits.hit & self.is_hidden[np.where(hits.hit, hits.face, 0)] & (chan >= 0)
        if not keep.any():
            return
        face, y, chan = hits.face[keep], y[keep], chan[keep]
        x, n_side = hits.points[keep], hits.normals[keep]                     # n_side faces y
        xs = SurfaceSamples(x, cst.face_normals[face], face, cst.face_object[face], np.zeros(len(face)),
                            np.zeros((len(face), 2)))
        e_x, r_lx, w_spot, geo = spot_irradiance(self.physics, x, xs.normals, laser)
        self.stats.lit_samples += int((e_x > 0).sum())
        rho_x = density_a[face] + n_spot * geo / np.pi
        w = y - x
        r = np.linalg.norm(w, axis=-1)
        w = w / r[:, None]
        cos_y = -dot(w, c.fov_normal)
        collect, d_ys = sensor_collection(self.physics, y, normal[keep], np.full(len(y), self.physics.wall_object), -w)
        b = np.arange(len(x))
        weight, time, phys = connection_weights(b, np.ascontiguousarray(n_side), rho_x, w, r, cos_y, collect, d_ys,
                                                self._weight_constants(), xs.object_id.astype(np.int64),
                                                np.ascontiguousarray(w_spot), material_arrays(self.physics))
        conn = {"b": b, "direction": w, "weight": weight, "time": time, "phys": phys, "channel": chan,
                "normal": n_side}
        self._deposit(xs, e_x, r_lx, w_spot, conn, dot(n_side, w_spot) > 0, laser, sink, rng)

    def _deposit(self, xs: SurfaceSamples, e_x: np.ndarray, r_lx: np.ndarray, w_spot: np.ndarray, conn: dict,
                 primary: np.ndarray, laser: int, sink: Sink, rng: np.random.Generator) -> None:
        """Primary impulses of the connections ``conn`` (rows b into ``xs``, weights with the densities of x and
        y; ``primary`` marks those leaving x on the side the spot lights) and the secondary's."""
        c, s = self.capture, self.settings
        b = conn["b"]
        if not self.secondary_only:
            legs = (float(s.attenuation), float(c.emitter_legs[laser]), float(self.physics.laser_leg(laser)))
            t, weight, comp = primary_impulses(b, primary, e_x, xs.object_id, w_spot, r_lx, conn["normal"],
                                               conn["direction"], conn["weight"], conn["phys"], conn["time"],
                                               conn["channel"], self.object_component, c.n_channels,
                                               material_arrays(self.physics), legs)
            if len(t):
                sink.add(t, weight, comp)
        if s.secondary == "full" and len(b):
            self.secondary_paths.paths(xs, laser, conn, sink, rng, self.stats)
