"""Hidden-surface quadrature: the primary transient by a deterministic area rule with exact time binning.

The primary (three-bounce) envelope of docs/physics.md §2, for laser point x_l and sensor target y (a sensor point for
point-radiance captures, an FoV cell of a pixel region for aperture captures), is an integral over hidden
surface points x:

    L_p(t) = ∫_S dA_x  E_l(x) · f_x(ω→x_l, ω→y) · cosθ_x,out cosθ_y,in / |y−x|² · V(x, y) · collection(y) · dA_y
                       · e^{−μ·path} · δ(t − τ(x)),     τ(x) = (|x−x_l| + |y−x| [+ |x_s−y|] [+ emitter leg]) / c,

with E_l(x) = Φ f_l cosθ_l cosθ_x,in / |x−x_l|² V(x_l, x) the laser irradiance
(:meth:`datagen.transport.physics.LegPhysics.irradiance`) and collection(y) the sensor leg
(:meth:`~datagen.transport.physics.LegPhysics.sensor_collection`). Every factor comes from those per-leg
functions; only the way x is visited differs from the samplers.

**The rule.** Every hidden face (:meth:`AreaSampler._hidden_faces`: the faces that can carry a primary path) is
split into k² congruent sub-triangles of edge ≤ h (``edge``, the split of :func:`datagen.sampling.subdivide_triangles`;
k even or not, with the error estimate that goes with each: :mod:`.split`). A face of a closed outward
surface whose front is turned away from every laser point is left out when the laser leg is shadow-tested: only its
inner side faces them, which is never lit (:func:`~datagen.transport.quadrature.primary.dark_faces`; a quarter to a
third of a hidden mesh's faces; the split is chosen before, so nothing else changes).
For each (sub-triangle T, laser point, target) the weight is evaluated at the centroid and multiplied by the area
of T (the midpoint rule), and the path length at the three *vertices* of T and at its centroid. On T the path
length is replaced by its linear interpolant, under which the area measure of T pushes forward to a tent density
between the sorted vertex times (peak at the middle one); :meth:`datagen.timing.EnvelopeAccumulator.add_tents`
deposits its exact integrals over the accumulator's cells. The path length (a sum of distances) is convex, so the
interpolant lies above it and the tent arrives late by O(h²/r); each tent is therefore shifted so that its mean
is the triangle rule (1/12)·Σ τ(vertex) + (3/4)·τ(centroid), exact for quadratics (the shift is
(3/4)·(τ(centroid) − mean vertex time)). On the hidden-square tal capture this took the error at h = 2 cm from
0.64 % to 0.13 % relative L2. There is no noise, and no binning error beyond that of the accumulator itself.

**Error order.** O(h²) in the hidden edge, from the midpoint rule's weight: its error is O(h²) per unit area (the
O(h) term integrates to a dipole per triangle whose time-binned effect is again O(h²)); the time model errs by
O(h⁴/r³) in each tent's mean and O(h³/r) in its spread after the shift. Away from kernel singularities (a hidden
surface touching the FoV, where 1/|y−x|² is not smooth on the scale of h) the relative L2 error of the binned
envelope therefore falls as h² (measured in tests/test_quadrature.py). Shadow edges cut sub-triangles, which
the midpoint rule counts as wholly lit or shadowed: O(h) per cell along the edge, but of alternating sign, so the
measured convergence with an occluder is still ≈ h². Aperture captures integrate each sensor pixel region with a
k×k grid of FoV cells at their midpoints (``fov_cells``; default ``ceil(pixel side / h)``, so FoV cells are no
larger than the hidden triangles): the weight error is O(h_F²), and the time spread of a cell (≈ h_F·|∇_y τ|),
which the rule leaves out, is symmetric to first order, so it too enters at O(h_F²), relative to the time scale
of the envelope (bin width or IRF width, whichever is larger). Point-radiance captures connect to the exact
sensor points.

**Visibility.** Shadow rays are cast per (sub-triangle centroid, laser point) and per (centroid, target) only when
an occluder can cross that leg. For each leg an exact conservative test is run first: no triangle may meet the
convex hull of a hidden triangle and the leg's other end (the laser points' hull or the FoV rectangle), by
separating planes (the planner's test, :func:`datagen.scene.separation.may_meet`). A hidden square in front of a flat
relay wall needs no shadow ray; the demo room does. Forcing ``shadow_spot`` / ``shadow_fov`` on or off overrides
the test. The effect planner's ``shadow_spot`` (a decision about the laser leg of secondary paths) is not one the
quadrature follows (its registry entry's ``follows_plan``); a value the user forces in ``effects`` is. Confocal
captures whose targets are the laser points themselves (point radiance, or one FoV cell per pixel) cast no ray on
the hidden → FoV leg unless ``shadow_fov`` is forced: it is the laser leg's segment, whose visibility the
irradiance already holds. The FoV → sensor leg follows ``shadow_sensor`` (the planner's decision, as for every
estimator).

**Scans.** Confocal and exhaustive captures reuse one subdivision for every laser point: the laser leg is
evaluated per (cell, laser point), the target leg per (cell, target), and path lengths at vertices per (vertex,
laser point) and (vertex, target); when the targets are the laser points themselves (point-radiance confocal
scans) the vertex distances are shared. Pairs are processed in blocks of at most ``batch`` (cell, connection)
rows, so memory stays bounded. The common case (Lambertian or Phong hidden surfaces, a fine-grid accumulator) runs
compiled, one pass per (sub-triangle, connection) pair with exact segment tests instead of most shadow rays (for
a big mesh too: per-face occluder candidates from a compiled hull test), channels in parallel on numba's threads for
long runs, bit-identical for any thread count (:mod:`.primary`, :mod:`.kernel`); the numpy blocks are its
reference.

**Secondary and first bounce.** When the plan asks for the secondary (paths with two hidden vertices), the
quadrature does not drop it: the area sampler (:mod:`datagen.transport.area`, ``secondary_only``) adds its unbiased
secondary with ``secondary_samples`` hidden samples per laser point (random: the only non-deterministic part,
drawn from the ``rng`` given to :meth:`Quadrature.run`). The direct first bounce is
:meth:`~datagen.transport.physics.LegPhysics.first_bounce`.

Sink component ids follow :class:`datagen.transport.LookinSampler`: ``component * n_channels + channel``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Literal

import numpy as np

from ...errors import ConfigError
from ...sampling.surfaces import subdivide_with_vertices
from ...scene import RayCaster, Scene
from ...scene.capture import Capture
from ...scene.materials import LAMBERTIAN, PHONG, RETROREFLECTIVE
from ...vectors import dot
from ..area.estimator import AREA_FOLLOWS_PLAN, AreaSampler, AreaSettings
from ..base import Sink, register
from ..physics import PhysicsSettings, fov_connection_weight
from .grading import GRADING_MIN_EDGE, graded_triangles, quadrature_memory
from .options import fov_cells_per_side
from .options import QUADRATURE_EDGE, QuadratureOptions
from .numpy_kernel import run_numpy
from .primary import dark_faces, front_only, leg_occluders, run_compiled
from .split import apply_split, choose_split, refined

__all__ = ["QUADRATURE_EDGE", "Quadrature", "QuadratureOptions", "QuadratureSettings", "QuadratureStats",
           "subdivide_with_vertices"]

MAX_PAIR_ROWS = 1 << 21
"""Default cap on (sub-triangle, connection) rows handled together (each row holds ~20 float64 temporaries)."""

@dataclass(frozen=True)
class QuadratureSettings(PhysicsSettings):
    """Settings of the hidden-surface quadrature (:class:`Quadrature`); the physics switches are those of
    :class:`~datagen.transport.physics.PhysicsSettings`, which this class extends, except that ``shadow_spot``
    may also be None (decided by the occluder test).

    Attributes:
        edge: h, the largest sub-triangle edge, metres (> 0).
        fov_cells: k, FoV cells per pixel side for aperture captures (None: ceil(pixel side / edge), at most
            ``MAX_FOV_CELLS``).
        grading: None, or r: hidden triangles are first cut into 4 while longer than r × their distance to the
            laser points and FoV (down to 0.4 h), so sub-triangles near the scan are finer
            (:func:`datagen.transport.quadrature.grading.graded_triangles`).
        secondary: "none" or "full" (the area sampler's unbiased secondary); secondary_samples: its hidden
            samples per laser point.
        shadow_spot, shadow_fov: shadow rays on the laser → hidden and hidden → FoV legs: None decides by the
            exact occluder test (module doc), True / False forces them.
        batch: (sub-triangle, connection) rows per block.
        split: "even", "plain" or "auto" (:mod:`.split`: the sub-triangles and the error estimate's rule).

    Raises:
        ConfigError: a field out of range (the message names the field and the value).
    """

    edge: float = QUADRATURE_EDGE
    fov_cells: int | str | None = None
    grading: float | None = None
    secondary: Literal["none", "full"] = "none"
    secondary_samples: int = 1 << 16
    shadow_spot: bool | None = None
    shadow_fov: bool | None = None
    batch: int = MAX_PAIR_ROWS
    split: Literal["auto", "even", "plain"] = "auto"

    def __post_init__(self):
        def bad(name, value, why):
            raise ConfigError(f"quadrature: {name} {why}, got {value!r}")

        def integer(name, value, low):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                bad(name, value, f"must be an integer >= {low}")

        if isinstance(self.edge, bool) or not isinstance(self.edge, (int, float, np.floating)) \
                or not np.isfinite(self.edge) or self.edge <= 0:
            bad("edge", self.edge, "must be a finite length > 0 (metres)")
        if self.fov_cells is not None and self.fov_cells != "edge":
            integer("fov_cells", self.fov_cells, 1)
        if self.grading is not None and (isinstance(self.grading, bool) or not isinstance(self.grading, (int, float))
                                         or not 0 < self.grading < np.inf):
            bad("grading", self.grading, "must be None or a finite ratio > 0")
        integer("secondary_samples", self.secondary_samples, 1)
        integer("batch", self.batch, 1)
        if self.split not in ("auto", "even", "plain"):
            bad("split", self.split, "must be 'auto', 'even' or 'plain'")
        if self.secondary not in ("none", "full"):
            bad("secondary", self.secondary, "must be 'none' or 'full'")
        self.check_physics("quadrature")
        for name in ("shadow_spot", "shadow_fov"):
            if getattr(self, name) not in (None, True, False):
                bad(name, getattr(self, name), "must be true, false or None (decide by the occluder test)")

    @classmethod
    def from_transport(cls, settings: PhysicsSettings, **kwargs) -> QuadratureSettings:
        """Quadrature settings with the physics switches of ``settings`` (any estimator's, or plain
        :class:`~datagen.transport.physics.PhysicsSettings`) except ``shadow_spot`` (a quadrature setting of its
        own: None lets its occluder test decide, unless ``kwargs`` force it), the secondary "full" when
        ``settings`` has a secondary mode other than "none", else "none"; ``kwargs`` set the rest."""
        base = {**settings.switches(), "secondary": "none" if getattr(settings, "secondary", "none") == "none"
                else "full"}
        del base["shadow_spot"]
        return cls(**{**base, **kwargs})

    def area_settings(self) -> AreaSettings:
        """The area sampler's settings for the secondary (and the per-leg weights)."""
        return AreaSettings(**{**self.switches(), "shadow_spot": self.shadow_spot is not False},
                            samples=self.secondary_samples, secondary=self.secondary,
                            sensor_blockers=self.sensor_blockers)


COARSE_CHANNELS = 4096
"""The coarse rule of the error estimate (:attr:`Quadrature.coarse`) is deposited for at most about this many
channels, every k-th (a 32 × 32 or 64 × 64 scan: all; 128 × 128: every 4th), when the compiled primary runs. A
sample of 64 channels of a confocal room scan put the estimate at 4.5 % where all channels give 2.6 %; with the
compiled primary the coarse tents cost ~10 % of the run."""

COARSE_CHANNELS_NUMPY = 64
"""The same for the numpy primary, where every coarse tent is a further pass (tal's hidden-square captures, delta
IRF: all 1 024 channels cost 25 % more time than 64, for an estimate of 0.86 % instead of 0.80 %)."""

MAX_FOV_CELLS = 64
"""Cap on the automatic FoV cells per pixel side (aperture captures)."""


@dataclass
class QuadratureStats:
    """Counters from a quadrature run (recorded in the result attributes); ``runs`` counts the primary's passes."""

    runs: int = 0
    cells: int = 0
    targets: int = 0
    connections: int = 0
    pair_rows: int = 0
    tents: int = 0
    shadow_rays: int = 0


NOMINAL_SECONDS = {"runs": 1.0e-2, "cells": 1.6e-6, "pair_rows": 1.4e-8, "tents": 4.0e-8}
"""Seconds of one core per counted unit of :class:`QuadratureStats` (:meth:`Quadrature.nominal_seconds`): a
non-negative least-squares fit (relative errors) of the CPU time of 30 tolerance-loop levels, set-up and run
(``python benchmarks/fit_nominal.py quadrature``: three rooms each of ``confocal_smoke.yaml``, ``wall_smoke.yaml``,
``confocal.yaml`` and the single-pixel-v2 suite at two or three edges; 0.013–3.9 s a level, the compiled kernel's
two threads counted) on the shared 2-core machine: relative residual 25 % RMS, worst 55 % (a 0.09 s level), the
``confocal.yaml`` levels within 14 %. Shadow rays took rate 0 and are left out."""


def _leg_may_be_blocked(caster: RayCaster, faces: np.ndarray, apexes: np.ndarray, tol: float,
                        first_only: bool = True) -> tuple[bool | None, tuple | None]:
    """(whether some triangle may meet a segment from a point of a triangle in ``faces`` to a point of the convex
    hull of ``apexes`` (A, 3), None: too many pairs to test; the :func:`leg_occluders` result, complete unless
    ``first_only``)."""
    if len(faces) == 0:
        return False, None
    found = leg_occluders(caster, faces, apexes, tol, first_only=first_only)
    return (None, None) if found is None else (bool(found[1].any()), found)


@register("quadrature", QuadratureSettings, "deterministic hidden-surface quadrature with exact time binning",
          options=QuadratureOptions, replica=QuadratureOptions.replica, refine=QuadratureOptions.refine,
          describe=QuadratureOptions.describe, memory=quadrature_memory, wide_pixels=True)
class Quadrature:
    """Deterministic hidden-surface quadrature of the primary with exact time binning (module doc).

    The estimator interface (:class:`datagen.transport.Estimator`); the sink needs
    :meth:`datagen.timing.EnvelopeAccumulator.add_tents` (a sink with only ``add`` receives one impulse per tent at
    its mean time: the midpoint rule in time as well).

    Attributes:
        settings: the settings with ``shadow_spot`` / ``shadow_fov`` resolved to booleans.
        visibility: why each leg does or does not cast shadow rays.
        component_names: names of the sink components (primary components, "secondary"[, "first_bounce"]).
        n_cells: M, sub-triangles; targets: (T, 3) FoV targets; total_rows: (cell, connection) rows of a run.
        stats: :class:`QuadratureStats`.
        front: (F_h,) bool per hidden face: only its front can be lit (a closed outward surface,
        :func:`~datagen.transport.quadrature.primary.front_only`).
        coarse: after a run on a point-sensor capture (or FoV cells that stay the same at 2h), the rule the error
        estimate compares with (summed over components, channel rows; only the channels ``coarse_channels``), as
        :mod:`.split` says: with the even split (``refine_lasers`` None, ``coarse_ratio`` 2) the primary at twice
        the edge from the same evaluations (4 fine sub-triangles make a coarse one whose centroid is the middle
        one's, :func:`datagen.sampling.coarse_cells`; every ``coarse_stride``-th channel: at most about
        ``COARSE_CHANNELS`` compiled, ``COARSE_CHANNELS_NUMPY`` in numpy), ‖P(h) − P(2h)‖/3 over those channels
        being the estimate; with the plain split (``coarse_ratio`` 1/2) the primary at half the edge on the
        laser points ``refine_lasers`` (a sub-scan), (4/3)·‖P(h) − P(h/2)‖ being the estimate.

    Raises:
        ConfigError: invalid settings. SceneError: the capture errors of :func:`datagen.scene.resolve_capture`;
            no face can take part in a path.
    """

    sensor_sampling = "quadrature: sensor points / FoV cells"   # how the FoV is reached (Estimator protocol)
    follows_plan = AREA_FOLLOWS_PLAN          # not the planner's shadow_spot: its own occluder test (from_config)

    def __init__(self, scene: Scene, settings: QuadratureSettings | None = None, caster: RayCaster | None = None,
                 capture: Capture | None = None):
        s = settings or QuadratureSettings()
        self.scene = scene
        self.caster = caster or RayCaster(scene)
        self.area = AreaSampler(scene, s.area_settings(), self.caster,       # per-leg physics, hidden faces and
                                secondary_only=s.secondary == "full", capture=capture)   # the secondary
        self.physics = self.area.physics
        self.capture = c = self.area.capture
        self.component_names = list(self.area.component_names)
        self.object_component = scene.object_component()
        self.n_primary = len(scene.component_names())
        self.materials = scene.materials
        self.stats = QuadratureStats()
        self.use_compiled = True                 # False: the numpy primary (the reference of the compiled one)
        self.segment_tests = True                # False: the compiled primary casts a ray for every lit pair
        tol = self.area.tol
        faces = self.area.hidden_faces
        # -- visibility: shadow rays only on legs an occluder can cross ---------------------------------------
        lx, ly = c.laser_shape
        grid = c.spots.reshape(ly, lx, 3)
        self.laser_hull = laser_hull = grid[[0, 0, -1, -1], [0, -1, -1, 0]]
        hw, hh = 0.5 * c.fov_extent[0], 0.5 * c.fov_extent[1]
        fov_hull = np.array([c.fov_center + a * hw * c.fov_u + b * hh * c.fov_v for a in (-1, 1) for b in (-1, 1)])
        self.visibility = {}
        self.spot_occluders = None              # the laser legs' complete occluder test, for the compiled primary
        decided = {}
        for name, apexes, what in (("shadow_spot", laser_hull, "laser point → hidden surface"),
                                   ("shadow_fov", fov_hull, "hidden surface → FoV")):
            forced = getattr(s, name)
            if forced is not None:
                decided[name] = forced
                self.visibility[name] = f"forced {'on' if forced else 'off'}"
                continue
            blocked, found = _leg_may_be_blocked(self.caster, faces, apexes, tol, first_only=name != "shadow_spot")
            if name == "shadow_spot":
                self.spot_occluders = found
            decided[name] = blocked is not False
            self.visibility[name] = ("too many triangle pairs to test: shadow rays kept" if blocked is None else
                                     f"a triangle may cross a {what} segment: shadow rays" if blocked else
                                     f"no triangle can cross a {what} segment (separating planes): no shadow rays")
        self.settings = replace(s, **decided)
        if self.area.settings.shadow_spot != decided["shadow_spot"]:
            self.area.configure(replace(self.area.settings, shadow_spot=decided["shadow_spot"]))
        # -- hidden sub-triangles ------------------------------------------------------------------------------
        tri = self.caster.vertices[self.caster.faces[faces]]
        piece_of = np.arange(len(tri))
        if s.grading is not None:                                       # finer near the scan (.grading)
            tri, piece_of = graded_triangles(tri, np.concatenate([c.spots, fov_hull]), s.grading,
                                             GRADING_MIN_EDGE * s.edge)
        self.refine_lasers = choose_split(tri, s.edge, c, s.split)        # None: the even split (.split)
        self.front = front_only(self.caster, faces, c.spots)            # per hidden face: only its front is lit
        dark = (dark_faces(self.caster, faces, self.front, c.spots, c.spot_normals, tol) if self.settings.shadow_spot
                else np.zeros(len(faces), dtype=bool))
        # never-lit faces left out (all of them dark: kept, so that the run has cells; they add nothing)
        keep = ~dark[piece_of] if not dark.all() else np.ones(len(tri), dtype=bool)
        tri, piece_of = tri[keep], piece_of[keep]
        self.split_faces = (tri, piece_of)                              # what the estimate's rule at h/2 splits
        apply_split(self, tri, s.edge, even=self.refine_lasers is None, piece_of=piece_of)
        self.coarse_ratio = 2.0 if self.refine_lasers is None else 0.5
        self.coarse: Sink | None = None
        # -- targets: sensor points (point radiance) or FoV cells of each pixel region (aperture) --------------
        nx, ny = c.fov_pixels
        if c.convention == "point_radiance":
            self.targets = c.sensor_points().reshape(-1, 3)
            self.target_pixel = np.arange(c.n_pixels)
            self.target_area = 1.0
            self.fov_cells = None
            self.fov_cells_fixed = True
        else:
            pw, ph = c.region_size
            k = self.aperture_cells(c, s.edge, s.fov_cells)
            self.fov_cells_fixed = self.aperture_cells(c, 2.0 * s.edge, s.fov_cells) == k      # the same at 2h
            g = (np.arange(k) + 0.5) / k
            gu, gv = np.meshgrid(g, g, indexing="xy")                          # (k, k): v rows, u columns
            iy, ix = np.divmod(np.arange(c.n_pixels), nx)
            self.targets = c.region_points(ix[:, None], iy[:, None], gu.reshape(1, -1),
                                           gv.reshape(1, -1)).reshape(-1, 3)
            self.target_pixel = np.repeat(np.arange(c.n_pixels), k * k)
            self.target_area = pw * ph / (k * k)
            self.fov_cells = k
        self._connections()
        if (s.shadow_fov is None and self.settings.shadow_fov and self.settings.shadow_spot and c.kind == "confocal"
                and np.array_equal(self.targets[self.conn_target], c.spots[self.conn_laser])):
            # each target is its laser point: V(x, y) = V(x_l, x), already in the laser leg's irradiance
            self.settings = replace(self.settings, shadow_fov=False)
            self.visibility["shadow_fov"] = "each target is its laser point: the laser leg's shadow rays"
        self.total_rows = self.n_cells * len(self.conn_laser)
        self.stats.cells, self.stats.targets, self.stats.connections = self.n_cells, len(self.targets), \
            len(self.conn_laser)

    @classmethod
    def from_config(cls, scene: Scene, config, physics: PhysicsSettings, caster: RayCaster,
                    capture: Capture | None, secondary: str) -> "Quadrature":
        """The registry's constructor (:attr:`datagen.transport.EstimatorEntry.from_config`): the edge, FoV cells,
        grading and secondary samples of ``config.estimator``
        (:class:`~datagen.transport.quadrature.options.QuadratureOptions`), the planned ``physics`` with its sensor
        blockers (FoV → sensor shadow rays only where the planner's pyramid test finds a triangle), and the area
        sampler's secondary unless ``secondary`` is "none". Its entry does not follow the planner's ``shadow_spot``
        (``follows_plan``): shadow rays on the laser and FoV legs follow the quadrature's own exact occluder test
        (module doc), unless the user forces ``shadow_spot`` in ``config.effects``."""
        forced_spot, opts = config.effects.get("shadow_spot"), config.estimator
        return cls(scene, QuadratureSettings.from_transport(
            physics, edge=opts.edge, fov_cells=opts.fov_cells, grading=opts.grading,
            secondary="none" if secondary == "none" else "full", secondary_samples=opts.secondary_samples,
            shadow_spot=forced_spot if isinstance(forced_spot, bool) else None,
            sensor_blockers=physics.sensor_blockers), caster, capture)

    def nominal_seconds(self) -> float:
        """A deterministic measure of the work done so far, in seconds of one core of the reference machine: the
        set-up's sub-triangles and the runs' (sub-triangle, connection) rows, tents and shadow rays (those of the
        error estimate's rule at h/2 included) at the rates ``NOMINAL_SECONDS``, plus the area sampler's secondary
        (:meth:`AreaSampler.nominal_seconds`). The tolerance loop caps its levels with it (``cost_cap``)."""
        counted = [self.stats] + ([self.refine_stats] if getattr(self, "refine_stats", None) is not None else [])
        work = sum(rate * getattr(st, key) for st in counted for key, rate in NOMINAL_SECONDS.items())
        return float(work + (self.area.nominal_seconds() if self.monte_carlo else 0.0))

    def progress_total(self) -> tuple[int, str]:
        """(sub-triangle, connection) pairs of a run."""
        return self.total_rows, "pair"

    # -- set-up --------------------------------------------------------------------------------------------

    def _connections(self) -> None:
        """(laser, target, channel) triples the capture records, target-major (each target's leg once)."""
        c = self.capture
        n_t = len(self.targets)
        if c.kind == "exhaustive":
            laser = np.tile(np.arange(c.n_lasers), n_t)
            target = np.repeat(np.arange(n_t), c.n_lasers)
        elif c.kind == "confocal":
            target = np.arange(n_t)
            laser = self.target_pixel.copy()               # pixel p is imaged while the laser is at point p
        else:
            target = np.arange(n_t)
            laser = np.zeros(n_t, dtype=np.int64)
        pixel = self.target_pixel[target]
        channel = laser * c.n_pixels + pixel if c.kind == "exhaustive" else pixel      # Capture.channel
        self.conn_laser, self.conn_target, self.conn_channel = laser, target, channel.astype(np.int64)
        # point-radiance confocal scans: each target is its laser point; share the vertex distances
        self.target_is_laser = bool(c.kind == "confocal" and c.convention == "point_radiance"
                                    and np.array_equal(self.targets, c.spots))

    def attrs(self) -> dict:
        """JSON-able settings and counts for the result attributes."""
        return {"settings": asdict(self.settings), "fov_cells_per_pixel_side": self.fov_cells,
                "sub_triangles": int(self.n_cells), "targets": int(len(self.targets)),
                "connections": int(len(self.conn_laser)), "visibility": dict(self.visibility)}

    # -- legs ----------------------------------------------------------------------------------------------

    def laser_leg(self, lasers: np.ndarray) -> dict:
        """Per (cell, laser): irradiance E (M, n) photons/m², distance r (M, n), side of the cell lit (M, n)
        (+1 / −1 along the face normal; 0 unlit), unit direction to the spot (M, n, 3) when BRDF angles matter,
        and vertex distances (V, n)."""
        M = self.n_cells
        e = np.zeros((M, len(lasers)))
        r = np.zeros((M, len(lasers)))
        side = np.zeros((M, len(lasers)), dtype=np.int8)
        w_all = np.zeros((M, len(lasers), 3)) if self.hidden_angles else None
        rays = self.physics.stats.shadow_rays
        for i, laser in enumerate(lasers):
            e[:, i], r[:, i], w, _ = self.physics.irradiance(self.centroids, self.cell_normal, int(laser))
            side[:, i] = np.where(e[:, i] > 0, np.sign(dot(self.cell_normal, w)), 0).astype(np.int8)
            if w_all is not None:
                w_all[:, i] = w
        self.stats.shadow_rays += self.physics.stats.shadow_rays - rays
        spots = self.capture.spots[lasers]
        rv = np.linalg.norm(self.vertices[:, None, :] - spots[None], axis=-1)
        return {"e": e, "r": r, "side": side, "w": w_all, "rv": rv}

    def target_leg(self, targets: np.ndarray, vertex_distances: bool = True) -> dict:
        """Per (cell, target ``targets`` (n,) int, indices of :attr:`targets`): G = cosθ_x,out cosθ_y,in / r² · V(x, y)
        · collection(y) · dA_y (M, n) (V: a shadow ray from the centroid where ``shadow_fov``), distance r (M, n), the
        side of the cell facing y (M, n) int8, unit direction x → y (M, n, 3) when BRDF angles matter, vertex
        distances (V, n; None unless ``vertex_distances``) and the FoV → sensor distance (n,); metres, float64."""
        c, s, legs = self.capture, self.settings, self.physics
        y = self.targets[targets]
        n_t = len(targets)
        n_y = np.broadcast_to(c.fov_normal, y.shape)
        obj_y = np.full(n_t, legs.wall_object)
        w_ref = np.broadcast_to(c.fov_normal, y.shape)                 # any direction above the wall
        rays = legs.stats.shadow_rays
        collect, d_ys = legs.sensor_collection(y, n_y, obj_y, w_ref)
        d = y[None] - self.centroids[:, None]                            # (M, n, 3)
        r = np.linalg.norm(d, axis=-1)
        w = d / np.maximum(r, 1e-300)[..., None]
        nw = dot(self.cell_normal[:, None], w)
        cos_y = -dot(w, c.fov_normal)
        g = np.where((np.abs(nw) > 0) & (cos_y > 0) & (r > self.area.tol),
                     fov_connection_weight(np.abs(nw) * cos_y, np.maximum(r, 1e-300),
                                           (collect * self.target_area)[None]), 0.0)
        side = np.where(g > 0, np.sign(nw), 0).astype(np.int8)
        if s.shadow_fov:
            mi, ti = np.nonzero(g > 0)
            n_side = side[mi, ti, None] * self.cell_normal[mi]
            vis = self.caster.visible(self.centroids[mi], n_side, y[ti], c.fov_normal)
            legs.stats.shadow_rays += len(mi)
            g[mi[~vis], ti[~vis]] = 0.0
        if self._wall_angles:                                            # f_y(ω_in) / f_y(ω_ref) per pair
            w_s = c.sensor - y
            w_s = w_s / np.linalg.norm(w_s, axis=-1, keepdims=True)
            f_ref = legs.brdf(obj_y, n_y, w_ref, w_s)
            mi, ti = np.nonzero(g > 0)
            f = legs.brdf(obj_y[ti], n_y[ti], -w[mi, ti], w_s[ti])
            g[mi, ti] *= np.divide(f, f_ref[ti], out=np.zeros_like(f), where=f_ref[ti] > 0)
        self.stats.shadow_rays += legs.stats.shadow_rays - rays
        rv = np.linalg.norm(self.vertices[:, None, :] - y[None], axis=-1) if vertex_distances else None
        return {"g": g, "r": r, "side": side, "w": w if self.hidden_angles else None, "rv": rv, "d": d_ys}

    @property
    def hidden_angles(self) -> bool:
        """BRDF angle work at hidden points (a non-Lambertian hidden material or ``brdf_angles``)."""
        return bool(self.settings.brdf_angles or not self.materials.lambertian[self.cell_object].all())

    @property
    def _wall_angles(self) -> bool:
        return bool(self.settings.brdf_angles or not self.materials.lambertian[self.physics.wall_object])

    # -- estimator -----------------------------------------------------------------------------------------

    @property
    def monte_carlo(self) -> bool:
        """Whether a run has noise: only the area sampler's secondary does."""
        return self.settings.secondary == "full"

    def run(self, sink: Sink, rng: np.random.Generator | None = None,
            progress: Callable[[int], None] | None = None) -> None:
        """Send every primary tent (and the secondary's and first bounce's impulses) to ``sink``.

        ``progress`` is called with the number of (cell, connection) rows done after each block. ``rng`` is used
        only by the secondary (default: ``np.random.default_rng(0)``).
        """
        self.coarse = self._coarse_sink(sink)
        self._primary(sink, progress)
        if self.settings.secondary == "full":
            self.area.run(sink, rng if rng is not None else np.random.default_rng(0))

    def run_replicas(self, sinks: list[Sink], rngs: list[np.random.Generator],
                     progress: Callable[[int], None] | None = None) -> None:
        """Replicas (:func:`datagen.transport.run_replicas`): the deterministic primary once, added to every sink
        (which must offer ``spawn`` and ``merge``, as :class:`~datagen.timing.EnvelopeAccumulator` does), and
        the Monte Carlo secondary once per (sink, generator)."""
        if len(sinks) == 1 or not hasattr(sinks[0], "spawn"):
            for sink, rng in zip(sinks, rngs):
                self.run(sink, rng, progress)
            return
        primary = sinks[0].spawn()
        self.coarse = self._coarse_sink(sinks[0])
        self._primary(primary, progress)
        for sink, rng in zip(sinks, rngs):
            sink.merge(primary)
            if self.settings.secondary == "full":
                self.area.run(sink, rng)

    def _coarse_sink(self, sink: Sink) -> Sink | None:
        """An empty accumulator like ``sink`` for :attr:`coarse` (the primary at 2h, summed over components
        into the channel rows 0 … n_channels−1), or None if ``sink`` cannot spawn one or the capture integrates
        FoV cells (aperture) that the run at 2h would make coarser: their discretisation error is part of the
        estimate, so it comes from a run at 2h with coarser FoV cells instead (:class:`datagen.simulation.Replicas`).
        With the same FoV cells at 2h (``fov_cells`` given, or one cell per pixel at both edges, as in the scan
        configs) the coarse rule from the same evaluations serves, as for point-radiance captures (its coarse
        cells join 2 × 2 of this run's sub-triangles: where an even split at 2h would differ, it is the finer of
        the two, measured 0.5 % apart on a confocal room)."""
        if not (hasattr(sink, "spawn") and hasattr(sink, "add_tents")) or not self.fov_cells_fixed:
            return None
        return type(sink)(sink.axis, sink.irf, self.capture.n_channels,
                          None if sink.direct else sink.oversample)

    def _primary(self, sink: Sink, progress: Callable[[int], None] | None) -> None:
        """The primary tents (and the first bounce) into ``sink``: compiled (:mod:`.primary`) when
        :attr:`use_compiled` and the case is one it covers (:meth:`compiled_case`), else in numpy."""
        self.stats.runs += 1
        grid = getattr(sink, "tent_grid", None)
        compiled = self.use_compiled and self.compiled_case() and grid is not None and grid() is not None
        n_channels = self.capture.n_channels
        self.coarse_stride = max(1, -(-n_channels // (COARSE_CHANNELS if compiled else COARSE_CHANNELS_NUMPY)))
        self.coarse_channels = np.arange(0, n_channels, self.coarse_stride)
        coarse = self.coarse if self.refine_lasers is None else None
        if compiled:
            run_compiled(self, sink.tent_grid(), None if coarse is None else coarse.tent_grid(), progress)
        else:
            run_numpy(self, sink, coarse, progress)
        if self.refine_lasers is not None and self.coarse is not None:     # the plain split's estimate: h/2
            sub = refined(self, QuadratureStats())                            # on a sub-scan (.split)
            self.coarse_channels = np.unique(sub.conn_channel)
            if compiled:
                run_compiled(sub, self.coarse.tent_grid(), None, None)
            else:
                run_numpy(sub, self.coarse, None, None)
            self.refine_stats = sub.stats
        if self.settings.first_bounce:
            self.physics.first_bounce(sink, self.n_primary + 1)

    @staticmethod
    def aperture_cells(capture: Capture, edge: float, forced: int | str | None = None) -> int | None:
        """FoV cells per pixel side of ``capture`` with hidden sub-triangles of edge ``edge`` (m): ``forced`` (the
        settings' ``fov_cells``) if an int; unset on a scanned capture (more than one laser point) one at every
        edge, so that the tolerance loop never changes the capture (:func:`~.options.fov_cells_per_side`,
        docs/scans.md); else ("edge", or unset on a single spot) ceil(pixel side / edge) clamped to 1 …
        ``MAX_FOV_CELLS`` (module doc, Error order); None for a point-radiance capture, which connects to its sensor
        points."""
        if capture.convention == "point_radiance":
            return None
        side = max(capture.region_size)
        k = fov_cells_per_side(forced, capture.n_lasers > 1, side, edge)
        return k if isinstance(forced, int) else min(MAX_FOV_CELLS, k)

    def compiled_case(self) -> bool:
        """Whether the compiled primary covers these settings: Lambertian, Phong or retroreflective hidden surfaces,
        Lambertian laser points and relay wall, no ``brdf_angles``."""
        m = self.materials
        return bool(m.lambertian[self.capture.spot_objects].all() and not self._wall_angles
                    and np.isin(m.kind[self.cell_object], (LAMBERTIAN, PHONG, RETROREFLECTIVE)).all()
                    and not self.settings.brdf_angles)
