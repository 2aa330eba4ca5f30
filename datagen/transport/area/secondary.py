"""The area sampler's secondary: a partner vertex x' before each hidden point x, three strategies under MIS.

:class:`AreaSecondary` is a collaborator of :class:`datagen.transport.area.AreaSampler` (docs/physics.md §2, the
module docstring of :mod:`datagen.transport.area`), built from the state it reads: at each hidden point x with FoV connections, partners x' come from
the laser spot (cosine directions: density ∝ the laser irradiance pattern), from x (cosine directions: bounds
the corner singularity G ~ 1/r²) and by area (small objects); each has its own laser connection E(x') and the
irradiance estimate Σ E(x') f_x'(ω→x_l, ω→x) G(x', x) V(x', x) / Σ_t P_t p_t(x') feeds every FoV connection of
x that leaves the side the light arrived on. Weights come from :mod:`datagen.transport.physics`.
"""
from __future__ import annotations

import numpy as np

from ...sampling import sample_surfaces, square_to_hemisphere
from ...sampling.directions import to_world
from ...sampling.surfaces import SurfaceSamples
from ...vectors import dot
from .kernels import (material_arrays, partner_geometry, partner_irradiance, partner_rays, secondary_pairs,
                           spot_irradiance)
from ..base import Sink

MIN_PARTNER_DISTANCE_OFFSETS = 10.0
"""A partner x' closer to x than this many ray offsets is dropped: the shadow ray between them is shorter than
the surface offsets and cannot be trusted (the pair lies on a set of measure zero in the integral)."""


def spot_hits(capture, caster, uv: np.ndarray, laser: int) -> tuple[SurfaceSamples, np.ndarray]:
    """First hits of cosine-weighted rays from laser point ``laser`` through the points ``uv`` (n, ≥2) of the unit
    square (Malley's method; columns 2–3, when present, are kept as the samples' padding). Returns the hits (area
    field 0) and which rays hit (n,) bool."""
    local, _ = square_to_hemisphere(uv[:, 0], uv[:, 1], "cosine")
    normal = np.broadcast_to(capture.spot_normals[laser], local.shape)
    hits = caster.intersect(np.broadcast_to(capture.spots[laser] + caster.offset * capture.spot_normals[laser],
                                            local.shape), to_world(local, normal))
    face = np.where(hits.hit, hits.face, 0)
    found = SurfaceSamples(hits.hit_points(), caster.face_normals[face], face, caster.face_object[face],
                           np.zeros(len(face)), uv[:, 2:4] if uv.shape[1] >= 4 else np.zeros((len(face), 2)))
    return found, hits.hit


class AreaSecondary:
    """Partners and secondary impulses of one :class:`~datagen.transport.area.AreaSampler`.

    Args:
        capture: the resolved :class:`~datagen.scene.Capture`; settings: the sampler's
            :class:`~datagen.transport.area.AreaSettings` (replaced by :meth:`configure`); caster: the scene's ray
            caster; physics: the :class:`~datagen.transport.physics.LegPhysics` weighing every leg (its
            ``stats.shadow_rays`` counts the partners' shadow rays); hidden_faces: (F_h,) int64 faces that can be
            hidden vertices, hidden_area their area, m²; is_hidden: (F,) bool over every face; n_primary: the
            number of primary components (the secondary's component id is ``n_primary * n_channels + channel``).
    """

    def __init__(self, capture, settings, caster, physics, hidden_faces: np.ndarray, hidden_area: float,
                 is_hidden: np.ndarray, n_primary: int):
        self.capture, self.settings, self.caster, self.physics = capture, settings, caster, physics
        self.hidden_faces, self.hidden_area, self.is_hidden = hidden_faces, float(hidden_area), is_hidden
        self.n_primary = int(n_primary)

    def configure(self, settings) -> None:
        """Use the sampler's new ``settings`` from now on."""
        self.settings = settings

    def partners(self, x: np.ndarray, nf: np.ndarray, pos: np.ndarray, neg: np.ndarray, laser: int,
                  rng: np.random.Generator, slots: tuple[np.ndarray, int] | None = None
                  ) -> tuple[SurfaceSamples, np.ndarray]:
        """Secondary partners of the n points x (n, 3): P_l from the spot, P_d from x, P_a by area. ``slots``
        (rows (n,), N): draw for N points and take the rows (the aligned draws of ``AreaSettings.aligned``).

        The direction strategy samples the hemisphere of each side of x that has FoV connections (pos: the
        +normal side, neg: the −normal side; both: each with probability ½). Returns the partners flattened
        to n·P rows (owner-major; spot, then direction, then area partners) and whether each was found.
        """
        s, cst = self.settings, self.caster
        n, pl, pd, pa = len(x), s.spot_partners, s.direction_partners, s.area_partners
        rows, total = slots if slots is not None else (slice(None), n)

        def draw(k: int, *tail: int) -> np.ndarray:      # (n, k, *tail) uniforms, in slots of their own if aligned
            return rng.random((total, k, *tail))[rows]
        blocks, found = [], []
        if pl:
            sp, hit = spot_hits(self.capture, cst, draw(pl, 2).reshape(n * pl, 2), laser)
            blocks.append(sp)
            found.append(hit)
        if pd:
            coin = draw(pd) < 0.5
            flip = np.where((pos & neg)[:, None], coin, ~pos[:, None])        # sample the −normal side
            n_side = np.where(flip[..., None], -nf[:, None], nf[:, None])
            local, _ = square_to_hemisphere(draw(pd), draw(pd), "cosine")
            hits = cst.intersect(x[:, None] + cst.offset * n_side, to_world(local, n_side))
            face = np.where(hits.hit, hits.face, 0).ravel()
            blocks.append(SurfaceSamples(hits.hit_points().reshape(-1, 3), cst.face_normals[face], face,
                                         cst.face_object[face], np.zeros(len(face)), np.zeros((len(face), 2))))
            found.append(hits.hit.ravel())
        if pa:
            ap, _ = sample_surfaces(cst, self.hidden_faces, total * pa, "random", rng)
            if slots is not None:
                ap = ap.take((np.asarray(rows)[:, None] * pa + np.arange(pa)).ravel())
            blocks.append(ap)
            found.append(np.ones(n * pa, dtype=bool))
        # blocks are strategy-major (n·P_t rows each, owner-major inside); gather owner-major rows
        sizes = [k for k in (pl, pd, pa) if k]
        offsets = np.cumsum([0] + [n * k for k in sizes])[:-1]
        idx = np.concatenate([off + np.arange(n)[:, None] * k + np.arange(k)[None]
                              for off, k in zip(offsets, sizes)], axis=1).ravel()
        allp = SurfaceSamples.concat(blocks)
        return allp.take(idx), np.concatenate(found)[idx]

    def paths(self, xs: SurfaceSamples, laser: int, conn: dict, sink: Sink, rng: np.random.Generator, stats) -> None:
        """Partners x' of the hidden samples that have FoV connections, combined by MIS (module doc); counts go to
        ``stats`` (:class:`~datagen.transport.area.AreaStats`)."""
        c, s, cst = self.capture, self.settings, self.caster
        used = np.zeros(len(xs.points), dtype=bool)                 # hidden samples with FoV connections
        used[conn["b"]] = True
        rows = np.flatnonzero(used)                                 # np.unique(b, return_inverse=True) in O(n)
        inv = (np.cumsum(used) - 1)[conn["b"]]
        n = len(rows)
        x, nf = xs.points[rows], xs.normals[rows]
        side = dot(nf[inv], conn["normal"]) > 0                    # the connection leaves x's +normal side
        pos = np.zeros(n, dtype=bool)
        neg = np.zeros(n, dtype=bool)
        pos[inv[side]] = True
        neg[inv[~side]] = True
        n_sides = pos.astype(int) + neg.astype(int)
        pl, pd, pa = s.spot_partners, s.direction_partners, s.area_partners
        p_tot = pl + pd + pa
        xp, found = self.partners(x, nf, pos, neg, laser, rng, (rows, len(xs.points)) if s.aligned else None)
        rp, wpx, cos_p, cos_x, on_pos, keep, n_px, n_xp = partner_geometry(
            x, nf, pos, neg, p_tot, xp.points, xp.normals, found, MIN_PARTNER_DISTANCE_OFFSETS * cst.offset)
        e_p, r_lp, w_sp, geo_p = spot_irradiance(self.physics, xp.points, xp.normals, laser, np.flatnonzero(keep))
        check = partner_rays(keep, e_p, n_px, w_sp, p_tot, (pl, pl + pd))   # spot and area partners: not first hits
        if len(check):
            keep[check] = cst.visible(xp.points[check], n_px[check], x[check // p_tot], n_xp[check])
            self.physics.stats.shadow_rays += len(check)
        stats.partners += int(keep.sum())
        if not keep.any():
            return
        mat = material_arrays(self.physics)
        # the irradiance at x from each partner (MIS terms), then every FoV connection of x with every partner
        irr = partner_irradiance(keep, e_p, geo_p, cos_p, cos_x, rp, n_sides, p_tot,
                                 self.is_hidden[xp.face] / self.hidden_area, (pl, pd, pa), xp.object_id, n_px, w_sp,
                                 wpx, mat)
        legs = (float(s.attenuation), float(c.emitter_legs[laser]), float(self.physics.laser_leg(laser)))
        conns = (conn["normal"], conn["direction"], conn["weight"], conn["phys"], conn["time"], conn["channel"])
        t, weight, comp = secondary_pairs(inv, side, p_tot, (irr, on_pos, wpx, r_lp, rp), conns,
                                          xs.object_id[conn["b"]], mat, legs, self.n_primary * c.n_channels)
        if len(t) == 0:
            return
        stats.secondary_pairs += len(t)
        sink.add(t, weight, comp)
