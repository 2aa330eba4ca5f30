"""The lookin estimator's secondary: paths laser spot → y' → lookin x_j → FoV point → sensor (docs/physics.md §3).

:class:`LookinSecondary` is a collaborator of :class:`datagen.transport.lookin.LookinSampler` (the paper's lookin
sampler), built from the capture, settings, leg physics, ray caster and materials it reads:

- ``full``: every (k', k) pair of observed points of a lookin, O(Ñ²) per lookin (the paper's full scheme,
  Eq. 8); ``optimized``: the ``top_k`` strongest k' per (lookin, FoV point) (the paper's optimized scheme,
  biased low by design).
- ``exact``: the same sum as ``full`` at O(Ñ) cost: with the BRDF at the lookin split as
  f = c·g(ω_in)·g(ω_out) + lobe, the pair sum is c × (incoming time profile ⊛ outgoing time profile), one FFT
  convolution per lookin and channel (:class:`ConvGrid` holds the profiles); lobes (Phong, retroreflective) are
  summed pairwise.
- dark-middle connections: paths whose middle vertex the laser does not light, which the lookin secondary
  cannot sample (docs/accuracy.md), by next-event connections from the lookins' laser-shadowed observed points.

Each path is weighed with the per-leg functions of :mod:`datagen.transport.physics`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...errors import ConfigError
from ...sampling.lookins import ObservedPoints
from ...units import SPEED_OF_LIGHT
from ...vectors import dot, matmul
from ..base import Connections, Sink
from ..physics import laser_irradiance

@dataclass
class LitPoints:
    """Hit observed points of a batch (flat: index into the batch's B·P pixels; hb: lookin) with their
    laser-spot geometry: y, n_y (facing the lookin), r and unit w (spot → y), cos_l (at the spot), cos_in (at
    y, on the lookin's side), and lit (the spot lights y on that side: both cosines > 0 and, with
    ``shadow_spot``, an unoccluded ray)."""

    flat: np.ndarray
    hb: np.ndarray
    y: np.ndarray
    n_y: np.ndarray
    r: np.ndarray
    w: np.ndarray
    cos_l: np.ndarray
    cos_in: np.ndarray
    lit: np.ndarray



CONV_REFINE_MAX = 1024
"""Largest automatic refinement of the exact secondary's profile grid (for IRFs much narrower than a bin)."""

CONV_DENSE_MAX = 1 << 22
"""Cap on rows × nodes of the exact secondary's dense profile buffers (32 MiB of float64)."""


class ConvGrid:
    """Time profiles of the exact secondary, summed on a grid of step ``step`` aligned to the sink's grid.

    Holds ``(n_channels, n_nodes)`` float64 node weights; node n sits at ``t0 + n·step``. Impulses beyond
    the grid are kept as a total per channel and sent as one impulse past the window by :meth:`flush`.
    """

    def __init__(self, t0: float, step: float, n_nodes: int, n_channels: int):
        self.t0, self.step, self.n_nodes = t0, step, n_nodes
        self.nodes = np.zeros((n_channels, n_nodes))
        self.beyond = np.zeros(n_channels)

    def empty_like(self) -> "ConvGrid":
        return ConvGrid(self.t0, self.step, self.n_nodes, len(self.nodes))

    def merge(self, other: "ConvGrid") -> None:
        self.nodes += other.nodes
        self.beyond += other.beyond

    def add_block(self, channel: int, start: int, values: np.ndarray) -> None:
        """Add node weights ``values`` to ``channel`` from node ``start`` on (clipped; clipped mass → beyond)."""
        lo, hi = max(start, 0), min(start + len(values), self.n_nodes)
        if hi > lo:
            self.nodes[channel, lo:hi] += values[lo - start:hi - start]
        self.beyond[channel] += values.sum() - (values[lo - start:hi - start].sum() if hi > lo else 0.0)

    def add_impulses(self, times: np.ndarray, weights: np.ndarray, channel: np.ndarray) -> None:
        """Linear (cloud-in-cell) splat of impulses onto the nodes."""
        x = (times - self.t0) / self.step
        inside = (x >= 0) & (x <= self.n_nodes - 1)
        if not inside.all():
            np.add.at(self.beyond, channel[~inside], weights[~inside])
        x, w, c = x[inside], weights[inside], channel[inside]
        i = np.minimum(np.floor(x).astype(np.int64), self.n_nodes - 2)
        wr = w * (x - i)
        flat = self.nodes.reshape(-1)
        idx = c * self.n_nodes + i
        flat += np.bincount(idx, w - wr, minlength=flat.size) + np.bincount(idx + 1, wr, minlength=flat.size)

    def flush(self, sink: Sink, component_offset: int, t_beyond: float) -> None:
        ch, n = np.nonzero(self.nodes)
        if len(ch):
            sink.add(self.t0 + n * self.step, self.nodes[ch, n], component_offset + ch)
        far = np.flatnonzero(self.beyond > 0)
        if len(far):
            sink.add(np.full(len(far), t_beyond), self.beyond[far], component_offset + far)


def cic_rows(x: np.ndarray, w: np.ndarray, row: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Cloud-in-cell splat of positions ``x`` (in nodes) into per-row local windows.

    Returns (start (n_rows,) int64 first node of each row's window, dense (n_rows, width) weights).
    """
    i = np.floor(x).astype(np.int64)
    start = np.zeros(n_rows, dtype=np.int64)
    width = 1
    if len(i):
        if np.all(row[1:] >= row[:-1]):                # already grouped (the usual case): no sort
            rs, io = row, i
        else:
            order = np.argsort(row, kind="stable")
            rs, io = row[order], i[order]
        first = np.flatnonzero(np.r_[True, rs[1:] != rs[:-1]])
        start[rs[first]] = np.minimum.reduceat(io, first)
        width = int((np.maximum.reduceat(io, first) + 2 - start[rs[first]]).max())
    dense = np.zeros(n_rows * width)
    local = row * width + (i - start[row])
    wr = w * (x - i)
    dense += np.bincount(local, w - wr, minlength=dense.size) + np.bincount(local + 1, wr, minlength=dense.size)
    return start, dense.reshape(n_rows, width)




class LookinSecondary:
    """Secondary paths of the lookin estimator (module doc), for one :class:`~datagen.transport.lookin.LookinSampler`.

    Args:
        capture: the resolved :class:`~datagen.scene.Capture`; settings: the sampler's
            :class:`~datagen.transport.lookin.LookinSettings` (replaced by :meth:`configure`); physics: the
            :class:`~datagen.transport.physics.LegPhysics` weighing every leg; caster: the scene's ray caster;
            materials: the scene's :class:`~datagen.scene.MaterialTable`; n_primary: the number of primary
            components (the secondary's component id is ``n_primary * n_channels + channel``).

    The counting methods add to the :class:`~datagen.transport.lookin.LookinStats` they are given (one per batch).
    """

    def __init__(self, capture, settings, physics, caster, materials, n_primary: int):
        self.capture, self.settings, self.physics = capture, settings, physics
        self.caster, self.materials, self.n_primary = caster, materials, int(n_primary)

    def configure(self, settings) -> None:
        """Use the sampler's new ``settings`` from now on."""
        self.settings = settings

    def conv_grid(self, sink: Sink) -> ConvGrid:
        """Exact-secondary profile grid aligned to the sink's fine grid, ``conv_refine`` times finer (and at most
        σ/4 for an IRF narrower than four fine steps, up to ``CONV_REFINE_MAX``).

        Raises:
            ConfigError: the sink has no fine grid (an :class:`~datagen.timing.EnvelopeAccumulator` is needed).
        """
        k = max(1, int(self.settings.conv_refine))
        irf = getattr(sink, "irf", None)
        if irf is not None and irf.sigma > 0 and hasattr(sink, "fine_step"):
            # a narrow IRF (σ below 4 grid steps) would show the profiles' binning: refine to ≤ σ/4
            k = max(k, min(CONV_REFINE_MAX, int(np.ceil(4.0 * sink.fine_step / irf.sigma))))
        if hasattr(sink, "fine_step"):
            step = sink.fine_step / k
            t0 = float(sink.fine_times[0])
            n = (sink.n_fine - 1) * k + 1
        else:
            raise ConfigError("secondary 'exact' needs an EnvelopeAccumulator sink")
        return ConvGrid(t0, step, n, self.capture.n_channels)

    def spot_light(self, obs: ObservedPoints, laser: int, stats) -> "LitPoints":
        """Which observed points the laser spot lights on the side facing their lookin (one shadow ray each
        where ``shadow_spot``), with the spot → point geometry; shared by both secondary estimators."""
        c, s = self.capture, self.settings
        spot, spot_n = c.spots[laser], c.spot_normals[laser]
        flat = np.flatnonzero(obs.hit)
        y = np.take(obs.points.reshape(-1, 3), flat, axis=0)
        n_y = np.take(obs.normals.reshape(-1, 3), flat, axis=0)          # facing the lookin
        w = y - spot
        r = np.sqrt(dot(w, w))
        w /= np.maximum(r, 1e-300)[:, None]
        cos_l = matmul(w, spot_n)
        cos_in = -dot(n_y, w)
        lit = (cos_l > 0) & (cos_in > 0)
        if s.shadow_spot and lit.any():
            idx = np.flatnonzero(lit)
            idx = idx[self.physics.may_be_blocked(spot, w[idx], r[idx], self.physics.spot_spheres)]
            stats.shadow_rays += len(idx)
            lit[idx] = self.caster.visible(y[idx], n_y[idx], spot, spot_n)
        return LitPoints(flat, flat // obs.hit.shape[1], y, n_y, r, w, cos_l, cos_in, lit)

    def lit_middle(self, laser, n_rays, pdf, x, n_x, obj_x, r_lx, cos_x_l, obs, light: "LitPoints",
                   out: Connections, sink, conv, stats) -> None:
        """Paths spot → y' (lit observed point) → lookin x_j → FoV point, for one slice of lookins (B of them).

        Each lookin acts as an *area* sample with dA_j = R_j² / (N p_j cosθ_j,l); y' receives the laser
        irradiance E' and reflects it toward x_j through its camera pixel (Ω); x_j scatters toward the FoV
        connections ``out`` like the primary. ``full`` sums every pair, ``optimized`` the ``top_k`` strongest per
        FoV point, ``exact`` hands the sums to :meth:`exact` (``conv``, a :class:`ConvGrid`).
        """
        c, s = self.capture, self.settings
        # area measure of each lookin as a second hidden vertex: dA_j = R_j² / (N p_j cosθ_j,l)
        with np.errstate(divide="ignore", invalid="ignore"):
            area = np.where(cos_x_l > 0, r_lx ** 2 / (n_rays * pdf * cos_x_l), 0.0)
        # laser-lit observed points y' of lookins with an area
        cand = np.flatnonzero(light.lit & (area[light.hb] > 0))
        stats.lit_points += len(cand)
        stats.secondary_lookins += len(x)
        if len(cand) == 0:
            return
        lb, flat = light.hb[cand], light.flat[cand]
        n_yp, obj_yp = light.n_y[cand], obs.object_id.ravel()[flat]
        w_l = light.w[cand]
        r_l = light.r[cand]
        irradiance = laser_irradiance(c.photons, self.physics.spot_emission(w_l, laser), light.cos_in[cand], r_l)
        in_dir = np.take(obs.directions.reshape(-1, 3), flat, axis=0)
        radiance = irradiance * self.physics.brdf(obj_yp, n_yp, w_l, in_dir, -1.0, -1.0)     # toward the lookin
        in_w = radiance * obs.local_z.ravel()[flat] * (obs.solid_angle * area[lb])   # photons arriving at the lookin
        in_path = r_l + obs.distance.ravel()[flat]
        laser_t = self.physics.laser_leg(laser) / SPEED_OF_LIGHT
        if s.attenuation > 0:
            in_w = in_w * self.physics.attenuation(c.emitter_legs[laser] + in_path)
        cos_out = np.maximum(dot(n_x[out.b], out.direction), 0.0)
        out_w = cos_out * out.weight * self.physics.attenuation(out.phys)
        out_t = laser_t + out.time
        if s.secondary == "exact":
            self.exact(x, n_x, obj_x, lb, in_w, in_path / SPEED_OF_LIGHT, in_dir, out, out_w, out_t, conv, stats)
            return
        sec_comp = self.n_primary * c.n_channels
        for j in range(len(x)):
            a = np.flatnonzero(lb == j)
            b = np.flatnonzero(out.b == j)
            if len(a) == 0 or len(b) == 0:
                continue
            f = self.physics.brdf(np.full((len(a), len(b)), obj_x[j]), n_x[j], in_dir[a][:, None, :],
                                  out.direction[b][None])
            pair = in_w[a, None] * f * out_w[None, b]
            t_pair = in_path[a, None] / SPEED_OF_LIGHT + out_t[None, b]
            chan = np.broadcast_to(out.channel[b][None, :], pair.shape)
            if s.secondary == "optimized" and s.top_k < len(a):
                keep = np.argpartition(-pair, s.top_k - 1, axis=0)[:s.top_k]   # (K, n_fov)
                pair = np.take_along_axis(pair, keep, axis=0)
                t_pair = np.take_along_axis(np.broadcast_to(t_pair, (len(a), len(b))), keep, axis=0)
                chan = chan[:s.top_k]
            stats.secondary_pairs += pair.size
            stats.pairs_summed += len(a) * len(b)
            if not self.materials.lambertian[obj_x[j]]:
                stats.glossy_pairs += len(a) * len(b)
            if s.secondary == "optimized" and s.top_k < len(a):
                stats.ranked_pairs += len(a) * len(b)
            sink.add(t_pair.ravel(), pair.ravel(), (sec_comp + chan).ravel())

    def dark_middle(self, laser, flux, x, n_x, obj_x, r_lx, w_to_spot, obs: ObservedPoints,
                    light: "LitPoints", sink, rng, stats) -> None:
        """Secondary paths whose middle vertex the laser does not light (docs/physics.md §2's path integral;
        docs/accuracy.md, "dark middle vertices").

        The lookin secondary (:meth:`lit_middle`) puts the middle vertex of spot → y' → x → FoV on a lookin
        x, i.e. on a point the laser spot lights; paths whose middle vertex lies in a laser shadow (behind
        the box, on the side of the pillar turned away from the spot) have no lookin and are missed (6.9 % of
        the demo room's secondary). They are sampled here the other way round: lookin x_j (lit, first
        hidden vertex) → observed point z of its camera that the spot does *not* light on the side facing
        x_j (shadowed or facing away) → a next-event connection from z to the FoV (one uniformly jittered
        point per sensor pixel region, or every sensor point, with a shadow ray). The two sets split the
        paths by whether the middle vertex is lit, so together they count every path once.

        Weight: Φ_z = W_j f_x cosθ_x Ω photons reach z through pixel k (W_j the lookin's photons, Ω the pixel
        solid angle); z radiates Φ_z f_z cosθ_z,out per sr toward y, times the connection weight
        cosθ_y dA_y / r² · collection(y) (:meth:`datagen.transport.physics.LegPhysics.connect`).
        Time: spot → x_j → z → y [→ sensor].
        """
        c, s = self.capture, self.settings
        # not lit on the side facing x_j, and in front of the spot's plane (the relay wall cannot reflect to it)
        dark = np.flatnonzero(~light.lit & (light.cos_l > 1e-12))
        if len(dark) == 0:
            return
        z, n_z = light.y[dark], light.n_y[dark]
        stats.dark_points += len(dark)
        jitter = rng.random((len(dark), 2)) if rng is not None else np.full((len(dark), 2), 0.5)
        out = self.physics.connect(z, n_z, laser, rng, s.connect_samples, jitter)
        if len(out.b) == 0:
            return
        j, flat = light.hb[dark[out.b]], light.flat[dark[out.b]]
        d_in = np.take(obs.directions.reshape(-1, 3), flat, axis=0)                 # x_j → z
        phi = (flux[j] * self.physics.brdf(obj_x[j], n_x[j], w_to_spot[j], d_in) * obs.local_z.ravel()[flat]
               * obs.solid_angle)
        f_z = self.physics.brdf(obs.object_id.ravel()[flat], n_z[out.b], d_in, out.direction, -1.0)
        cos_z = np.maximum(dot(n_z[out.b], out.direction), 0.0)
        path = r_lx[j] + obs.distance.ravel()[flat]
        weight = phi * f_z * cos_z * out.weight * self.physics.attenuation(c.emitter_legs[laser] + path + out.phys)
        laser_t = self.physics.laser_leg(laser) / SPEED_OF_LIGHT
        stats.secondary_pairs += len(out.b)
        stats.pairs_summed += len(out.b)
        sink.add(laser_t + path / SPEED_OF_LIGHT + out.time, weight, self.n_primary * c.n_channels + out.channel)

    def exact(self, x, n_x, obj_x, lb, in_w, in_t, in_dir, out: Connections, out_w, out_t,
              conv: ConvGrid, stats) -> None:
        """Exact secondary at O(N·l·p) cost (docs/physics.md §3): with the split f = c·g(ω_in)·g(ω_out) + lobe, the
        sum over pairs (k', k) at each lookin is c × (incoming profile weighted by g) ⊛ (outgoing profile
        weighted by g): one FFT convolution per lookin and channel. Lobes (Phong, retroreflective) are summed
        pairwise. Profiles are binned on ``conv``'s grid (cloud-in-cell), its only approximation."""
        B = len(x)
        if B > 1:
            t_all = np.concatenate([in_t, out_t])
            span = (t_all.max() - t_all.min()) / conv.step if len(t_all) else 0.0
            if B * span > CONV_DENSE_MAX:                 # bound the dense profile buffers: split the batch
                half = B // 2
                for sel in (np.arange(half), np.arange(half, B)):
                    mi, mo = np.isin(lb, sel), np.isin(out.b, sel)
                    remap = np.full(B, -1)
                    remap[sel] = np.arange(len(sel))
                    sub = out.take(mo)
                    sub.b = remap[sub.b]
                    self.exact(x[sel], n_x[sel], obj_x[sel], remap[lb[mi]], in_w[mi], in_t[mi], in_dir[mi], sub,
                               out_w[mo], out_t[mo], conv, stats)
                return
        scale = self.materials.separable_scale(obj_x)                                  # (B,)
        g_in = self.physics.separable_factor(obj_x, n_x, lb, in_dir)
        g_out = self.physics.separable_factor(obj_x, n_x, out.b, out.direction)
        step = conv.step
        # incoming profiles, one row per lookin, on nodes n·step (time from the spot)
        a_start, a_dense = cic_rows(in_t / step, in_w * g_in, lb, B)
        # outgoing profiles per (lookin, channel) on nodes t0 + n·step
        pairs, pair_row = np.unique(out.b * conv.nodes.shape[0] + out.channel, return_inverse=True)
        b_start, b_dense = cic_rows((out_t - conv.t0) / step, out_w * g_out, pair_row, len(pairs))
        p_lookin, p_channel = np.divmod(pairs, conv.nodes.shape[0])
        has_in = np.bincount(lb, minlength=B) > 0
        use = has_in[p_lookin]
        n = scipy.fft.next_fast_len(a_dense.shape[1] + b_dense.shape[1] - 1, real=True)
        fa = scipy.fft.rfft(a_dense, n, axis=1)
        fb = scipy.fft.rfft(b_dense[use], n, axis=1)
        prod = scipy.fft.irfft(fa[p_lookin[use]] * fb, n, axis=1)
        length = a_dense.shape[1] + b_dense.shape[1] - 1
        for row, (j, ch, bs) in enumerate(zip(p_lookin[use], p_channel[use], b_start[use])):
            vals = prod[row, :length] * scale[j]
            np.maximum(vals, 0.0, out=vals)                       # FFT round-off below zero
            conv.add_block(int(ch), int(a_start[j] + bs), vals)
        stats.secondary_pairs += int(np.bincount(lb, minlength=B) @ np.bincount(out.b, minlength=B))
        lobe = self.materials.has_lobe(obj_x)
        for j in np.flatnonzero(lobe):
            a = np.flatnonzero(lb == j)
            b = np.flatnonzero(out.b == j)
            if len(a) == 0 or len(b) == 0:
                continue
            f = self.materials.lobe(np.full((len(a), len(b)), obj_x[j]), n_x[j], in_dir[a][:, None, :],
                                    out.direction[b][None])
            pair = in_w[a, None] * f * out_w[None, b]
            stats.pairs_summed += pair.size
            stats.glossy_pairs += pair.size
            t_pair = in_t[a, None] + out_t[None, b]
            chan = np.broadcast_to(out.channel[b][None, :], pair.shape)
            conv.add_impulses(t_pair.ravel(), pair.ravel(), chan.ravel())


