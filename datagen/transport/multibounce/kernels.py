"""The tracer's per-vertex arithmetic in one compiled pass (:class:`~datagen.transport.multibounce.tracer.MultibounceTracer`).

:func:`continue_paths` is the compiled form of three numpy steps of the tracer, with the same formulas:

- the cosine-weighted direction about the normal: :func:`datagen.sampling.square_to_hemisphere` (``"cosine"``:
  Shirley & Chiu's concentric disk lifted by Malley's method) rotated by :func:`datagen.sampling.directions.to_world`
  (the tangent frame of Duff et al. 2017, :func:`datagen.scene.materials.tangent_frame`), or, at a retroreflective
  vertex, a draw of its lobe (:func:`datagen.scene.brdf_kernel.retro_sample`) with probability k_s;
- the BRDF f(ω_in, ω_out) of :func:`datagen.scene.brdf_kernel.brdf_value` (each formula defined once there);
- the flux update Φ·f·π/(q·s) over the direction's density (s = 1 for a cosine direction,
  :func:`datagen.scene.brdf_kernel.sampling_ratio`) and Russian roulette with survival q
  (docs/physics.md §2, "Light of every order").

``tests/test_multibounce.py`` checks the directions against the numpy functions for the same uniforms, so the two
forms cannot drift apart.

The per-step bookkeeping of the tracer runs compiled too, each pass the numpy expressions it replaced in the same
order (so results keep their bits): :func:`arrive` (the window test of a step's hits, their compaction and the light's
area density of the vertices), :func:`survivors` (the paths the roulette keeps and their next rays),
:func:`nee_weights` and :func:`eye_weights` (the impulses of visible next-event and eye connections). Every leg
weight inside them is a formula function of :mod:`datagen.transport.physics` or :mod:`datagen.scene.brdf_kernel`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...scene.brdf_kernel import brdf_value, sample_direction, samples_lobe, sampling_ratio
from ...units import SPEED_OF_LIGHT
from ..leg_kernels import fov_target
from ..physics import fov_term, geometry_term
from .eye import eye_share


@njit(cache=True)
def continue_paths(n_x, obj, w_in, u, v, r, flux, survival, mat):
    """Continue m paths from their vertices: a direction from the material's sampler, the flux over its density and
    the survival probability, and Russian roulette.

    The sampler is :func:`~datagen.scene.brdf_kernel.sample_direction`: the cosine-weighted hemisphere about the
    normal for every kind but retroreflective with k_s > 0, which draws from its lobe when u < k_s and a cosine
    direction from (u − k_s)/(1 − k_s) otherwise.

    Args:
        n_x (m, 3) unit normals on the side the light arrives from; obj (m,) int object ids; w_in (m, 3) unit
        directions toward where the light came from; u, v (m,) uniforms of the direction, r (m,) of the roulette;
        flux (m,) photons; survival (n_objects,) q per object; mat the material arrays
        (:func:`datagen.transport.leg_kernels.material_arrays`).
    Returns:
        (w_out (m, 3) float64, flux_out (m,) float64 = flux·f·π/(q·s) (0 where q = 0), live (m,) bool: the roulette
        kept the path and its flux is > 0, s (m,) float64: the direction's density over the cosine density,
        :func:`~datagen.scene.brdf_kernel.sampling_ratio`, exactly 1 for a cosine direction).
    """
    m = n_x.shape[0]
    w_out = np.empty((m, 3))
    flux_out = np.zeros(m)
    live = np.zeros(m, dtype=np.bool_)
    ratio = np.ones(m)
    for i in range(m):
        n0, n1, n2 = n_x[i, 0], n_x[i, 1], n_x[i, 2]
        i0, i1, i2 = w_in[i, 0], w_in[i, 1], w_in[i, 2]
        o = obj[i]
        o0, o1, o2, z = sample_direction(mat, o, n0, n1, n2, i0, i1, i2, u[i], v[i])
        w_out[i, 0], w_out[i, 1], w_out[i, 2] = o0, o1, o2
        q = survival[o]
        if q > 0.0:
            f = brdf_value(mat, o, n0, n1, n2, i0, i1, i2, o0, o1, o2)
            cos_in = n0 * i0 + n1 * i1 + n2 * i2
            if samples_lobe(mat, o, cos_in):
                ratio[i] = sampling_ratio(mat, o, cos_in, z, i0 * o0 + i1 * o1 + i2 * o2)
                flux_out[i] = flux[i] * f * math.pi / (q * ratio[i]) if f > 0.0 else 0.0
            else:
                flux_out[i] = flux[i] * f * math.pi / q
        live[i] = r[i] < q and flux_out[i] > 0.0
    return w_out, flux_out, live, ratio


@njit(cache=True)
def fov_targets_ranged(x, n_x, first, count, ix, iy, jitter, fov):
    """One uniform FoV point in each pixel region that a vertex's laser point records, and the geometry of the pairs
    that face each other: :func:`datagen.transport.area.kernels.fov_targets` with one cell per pixel, over each
    vertex's own range of a pixel table (a confocal scan point records its own pixel only).

    Args:
        x, n_x: (B, 3) vertices and the normals of the side they connect from; first, count: (B,) int64 the range
            ``first … first + count − 1`` of the table rows that vertex b connects to; ix, iy: (T,) int64 pixel
            column and row of each table row; jitter: (B, J, 2) uniforms in [0, 1)², J ≥ max(count) (entry j of
            row b places the point in the range's j-th pixel); fov: as for ``fov_targets``.
    Returns:
        (bi (n,) int64, ti (n,) int64 table row, y (n, 3), w (n, 3) unit x → y, r (n,) |y − x|, cos_y (n,)) for
        the pairs with n_x·w > 0 and cosθ_y = −w·n_fov > 0, in (b, j) order.
    """
    nb = x.shape[0]
    cap = 0
    for b in range(nb):
        cap += count[b]
    bi = np.empty(cap, np.int64)
    ti = np.empty(cap, np.int64)
    y = np.empty((cap, 3))
    w = np.empty((cap, 3))
    r = np.empty(cap)
    cy = np.empty(cap)
    k = 0
    for b in range(nb):
        for j in range(count[b]):
            s = first[b] + j
            cu = ix[s] + (0.0 + jitter[b, j, 0] / 1.0)         # (as fov_targets with one cell per pixel)
            cv = iy[s] + (0.0 + jitter[b, j, 1] / 1.0)
            t0, t1, t2, rr, w0, w1, w2, cos_y, faces = fov_target(x, n_x, b, cu, cv, fov)
            if faces:
                bi[k], ti[k] = b, s
                y[k, 0], y[k, 1], y[k, 2] = t0, t1, t2
                w[k, 0], w[k, 1], w[k, 2] = w0, w1, w2
                r[k], cy[k] = rr, cos_y
                k += 1
    return bi[:k], ti[:k], y[:k], w[:k], r[:k], cy[:k]


@njit(cache=True)
def eye_pairs(x, n_x, e, z, n_z, ok):
    """The pairs (light vertex x_b, its path's eye vertex z_{e[b]}) that face each other (:mod:`.eye`).

    Args:
        x, n_x: (m, 3) light vertices and their normals on the lit side; e: (m,) int64 each one's row of the eye
        vertices z, n_z (E, 3) (normals facing the FoV); ok: (E,) bool the eye vertices that exist.
    Returns:
        (rows (k,) int64 into x, w (k, 3) unit x → z, d (k,) |z − x| m, cos_x (k,), cos_z (k,) = −n_z·w) for the
        pairs with d > 0, n_x·w > 0 and n_z·(x − z) > 0.
    """
    m = x.shape[0]
    rows = np.empty(m, np.int64)
    w = np.empty((m, 3))
    d = np.empty(m)
    cx = np.empty(m)
    cz = np.empty(m)
    k = 0
    for b in range(m):
        j = e[b]
        if not ok[j]:
            continue
        t0, t1, t2 = z[j, 0] - x[b, 0], z[j, 1] - x[b, 1], z[j, 2] - x[b, 2]
        dd = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if dd <= 0.0:
            continue
        t0, t1, t2 = t0 / dd, t1 / dd, t2 / dd
        c_x = n_x[b, 0] * t0 + n_x[b, 1] * t1 + n_x[b, 2] * t2
        c_z = -(n_z[j, 0] * t0 + n_z[j, 1] * t1 + n_z[j, 2] * t2)
        if c_x > 0.0 and c_z > 0.0:
            rows[k] = b
            w[k, 0], w[k, 1], w[k, 2] = t0, t1, t2
            d[k], cx[k], cz[k] = dd, c_x, c_z
            k += 1
    return rows[:k], w[:k], d[:k], cx[:k], cz[:k]


@njit(cache=True)
def eye_weights(rows, w, d, cos_x, cos_z, obj, n_x, w_in, flux, counted, physical, pid, eye, survival, mat, consts):
    """The impulses of visible eye connections (:mod:`.eye`; docs/physics.md §2): weights before attenuation, arrival
    times and physical path lengths. The weight is the radiant intensity of x toward z f_x cosθ_x, its irradiance at
    z (G = cosθ_x cosθ_z / d², :func:`~datagen.transport.physics.geometry_term`), z's intensity toward y f_z cosθ_zy,
    the FoV leg ``fov``; over the eye vertex's density b = (p_A / n_rec) g times its balance weight b / (a + b + c),
    a = p_light p_A, c = p_light q_z g s_z, p_light = q_x G s_x / π (the FoV leg carries A_pixel = 1 / p_A; s the
    continuation's density over the cosine density, :func:`~datagen.scene.brdf_kernel.sampling_ratio`).

    Args (k visible pairs): rows (k,) int64 the light vertex of each; w (k, 3) unit x → z; d, cos_x, cos_z (k,)
        from :func:`eye_pairs`; per light vertex: obj (int64), n_x, w_in (3,), flux, counted, physical, pid (int64:
        its path's eye row); eye: (obj, n_z, w_zy, g, n_rec, fov, r, d_ys) per eye row (:class:`~.eye.EyeVertices`);
        survival (n_objects,) q; mat the material arrays; consts = (p_A 1/m², count the sensor leg 0/1).
    Returns:
        (weight (k,) photons before attenuation, time (k,) s, physical path (k,) m).
    """
    obj_z, n_z, w_zy, g, n_rec, fov, r_zy, d_ys = eye
    p_a, sensor = consts
    k = rows.shape[0]
    out, time, path = np.empty(k), np.empty(k), np.empty(k)
    for m in range(k):
        i = rows[m]
        j = pid[i]
        f_x = brdf_value(mat, obj[i], n_x[i, 0], n_x[i, 1], n_x[i, 2], w_in[i, 0], w_in[i, 1], w_in[i, 2],
                         w[m, 0], w[m, 1], w[m, 2])
        f_z = brdf_value(mat, obj_z[j], n_z[j, 0], n_z[j, 1], n_z[j, 2], -w[m, 0], -w[m, 1], -w[m, 2],
                         w_zy[j, 0], w_zy[j, 1], w_zy[j, 2])
        cos_zy = n_z[j, 0] * w_zy[j, 0] + n_z[j, 1] * w_zy[j, 1] + n_z[j, 2] * w_zy[j, 2]
        geo = geometry_term(cos_x[m], cos_z[m], d[m])
        cos_in_x = n_x[i, 0] * w_in[i, 0] + n_x[i, 1] * w_in[i, 1] + n_x[i, 2] * w_in[i, 2]
        cos_io_x = w_in[i, 0] * w[m, 0] + w_in[i, 1] * w[m, 1] + w_in[i, 2] * w[m, 2]
        p_light = survival[obj[i]] * geo / math.pi * sampling_ratio(mat, obj[i], cos_in_x, cos_x[m], cos_io_x)
        b = p_a / n_rec[j] * g[j]
        cos_io_z = -(w[m, 0] * w_zy[j, 0] + w[m, 1] * w_zy[j, 1] + w[m, 2] * w_zy[j, 2])
        s_z = sampling_ratio(mat, obj_z[j], cos_z[m], cos_zy, cos_io_z)
        mis_over_pdf = p_a / (p_light * p_a + b + p_light * survival[obj_z[j]] * g[j] * s_z)
        out[m] = flux[i] * f_x * geo * f_z * cos_zy * fov[j] * mis_over_pdf
        path[m] = physical[i] + d[m] + r_zy[j] + d_ys[j]
        time[m] = (counted[i] + d[m] + r_zy[j] + (d_ys[j] if sensor else 0.0)) / SPEED_OF_LIGHT
    return out, time, path


# -- the per-step bookkeeping of MultibounceTracer._trace in compiled passes: the numpy expressions they replace, in
# the same order (numpy's row-wise dot of 3-vectors sums (x₀y₀ + x₂y₂) + x₁y₁: _dot3) -----------------------------

@njit(cache=True, inline="always")
def _dot3(a0, a1, a2, b0, b1, b2):
    """a·b as :func:`datagen.vectors.dot` rounds it for 3-vectors: (a₀b₀ + a₂b₂) + a₁b₁."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True)
def arrive(hit, dist, points, normals, obj, ray_dir, counted, physical, flux, laser, pid, q_prev, cos_src, limit,
           far_fov, fov):
    """The vertices m of one step of the tracer that some impulse of theirs can still reach the window with.

    A ray that hit adds its length to the path's counted and physical metres; its vertex is kept while the counted
    metres are below ``limit`` and, for those within ``far_fov`` of it, while the counted metres plus the vertex's
    distance to the FoV rectangle (:meth:`~datagen.scene.capture.Capture.fov_distance`) are (the tracer's
    "Termination").

    Args:
        hit (n,) bool, dist (n,) m, points, normals (n, 3), obj (n,) int64: the rays' hits; ray_dir (n, 3) their
        directions; counted, physical, flux (n,) float64, laser (n,) int64, pid (n,) or (0,) int64, q_prev, cos_src
        (n,) float64: the paths' state; limit, far_fov m; fov = (centre, u, v (3,), half width, half height).
    Returns:
        (keep (m,) int64 rows, x, n_x, w_in (m, 3), obj, laser, pid (m,) int64, flux, counted, physical, d, p_in (m,)
        float64, escaped, out of window): w_in = −ray direction, p_in = q_prev · cosθ_src cosθ_in / d² / π (the light's
        area density of the vertex), the counts of rays that left the scene and of vertices past the window.
    """
    centre, u, v, half_w, half_h = fov
    n = hit.shape[0]
    keep = np.empty(n, np.int64)
    k = 0
    escaped = 0
    late = 0
    for i in range(n):
        if not hit[i]:
            escaped += 1
            continue
        c = counted[i] + dist[i]
        inside = c < limit
        if inside and c + far_fov >= limit:
            r0, r1, r2 = points[i, 0] - centre[0], points[i, 1] - centre[1], points[i, 2] - centre[2]
            a = min(max(_dot3(r0, r1, r2, u[0], u[1], u[2]), -half_w), half_w)
            b = min(max(_dot3(r0, r1, r2, v[0], v[1], v[2]), -half_h), half_h)
            e0, e1, e2 = r0 - a * u[0] - b * v[0], r1 - a * u[1] - b * v[1], r2 - a * u[2] - b * v[2]
            inside = c + math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) < limit
        if not inside:
            late += 1
            continue
        keep[k] = i
        k += 1
    keep = keep[:k]
    x, n_x, w_in = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
    obj_k, laser_k = np.empty(k, np.int64), np.empty(k, np.int64)
    pid_k = np.empty(k if pid.shape[0] else 0, np.int64)
    flux_k, counted_k, physical_k, d_k, p_in = np.empty(k), np.empty(k), np.empty(k), np.empty(k), np.empty(k)
    for j in range(k):
        i = keep[j]
        for c in range(3):
            x[j, c], n_x[j, c], w_in[j, c] = points[i, c], normals[i, c], -ray_dir[i, c]
        obj_k[j], laser_k[j] = obj[i], laser[i]
        if pid.shape[0]:
            pid_k[j] = pid[i]
        flux_k[j], counted_k[j], physical_k[j], d_k[j] = flux[i], counted[i] + dist[i], physical[i] + dist[i], dist[i]
        cos_in = _dot3(n_x[j, 0], n_x[j, 1], n_x[j, 2], w_in[j, 0], w_in[j, 1], w_in[j, 2])
        p_in[j] = q_prev[i] * geometry_term(cos_src[i], cos_in, dist[i]) / math.pi
    return (keep, x, n_x, w_in, obj_k, laser_k, pid_k, flux_k, counted_k, physical_k, d_k, p_in, escaped, late)


@njit(cache=True)
def survivors(live, r, survival, obj, x, n_x, w_out, flux, counted, physical, laser, pid, p_in, offset, ratio):
    """The paths that go on after :func:`continue_paths` (``live``), compacted, and their next rays.

    Args: live (m,) bool; r (m,) the roulette's uniforms; survival (n_objects,) q; obj (m,) int64; x, n_x, w_out
        (m, 3) the vertices, their normals (lit side) and continuation directions; flux (m,) (after the
        continuation), counted, physical (m,), laser (m,) int64, pid (m,) or (0,) int64, p_in (m,); offset: the ray
        caster's offset, m; ratio (m,): each direction's density over the cosine density (:func:`continue_paths`).
    Returns:
        (flux, counted, physical (s,), laser, pid (s,) int64, p_in (s,), src_normal (s, 3), q_prev (s,) = q × ratio
        (the ray's density is q_prev·cosθ_src/π per sr), ray_origin = x + offset·n_x, ray_dir (s, 3), cos_src =
        n_x·ray_dir (s,), the roulette's count of r ≥ q).
    """
    m = live.shape[0]
    roulette = 0
    s = 0
    for i in range(m):
        if r[i] >= survival[obj[i]]:
            roulette += 1
        if live[i]:
            s += 1
    flux_s, counted_s, physical_s, p_in_s, q_s, cos_s = (np.empty(s), np.empty(s), np.empty(s), np.empty(s),
                                                         np.empty(s), np.empty(s))
    laser_s, pid_s = np.empty(s, np.int64), np.empty(s if pid.shape[0] else 0, np.int64)
    normal_s, origin_s, dir_s = np.empty((s, 3)), np.empty((s, 3)), np.empty((s, 3))
    j = 0
    for i in range(m):
        if not live[i]:
            continue
        flux_s[j], counted_s[j], physical_s[j], p_in_s[j] = flux[i], counted[i], physical[i], p_in[i]
        laser_s[j] = laser[i]
        if pid.shape[0]:
            pid_s[j] = pid[i]
        q_s[j] = survival[obj[i]] * ratio[i]
        for c in range(3):
            normal_s[j, c] = n_x[i, c]
            origin_s[j, c] = x[i, c] + offset * n_x[i, c]
            dir_s[j, c] = w_out[i, c]
        cos_s[j] = _dot3(n_x[i, 0], n_x[i, 1], n_x[i, 2], w_out[i, 0], w_out[i, 1], w_out[i, 2])
        j += 1
    return flux_s, counted_s, physical_s, laser_s, pid_s, p_in_s, normal_s, q_s, origin_s, dir_s, cos_s, roulette


@njit(cache=True)
def nee_weights(conn, obj, n_x, w_in, flux, counted, physical, count, p_in, survival, mat, consts):
    """Weights (before attenuation), arrival times and physical path lengths of visible next-event connections
    (MultibounceTracer._connect, aperture captures): the radiant intensity flux·f(ω_in, ω_y)·cosθ_x toward y times
    the FoV leg :func:`~datagen.transport.physics.fov_term` (cosθ_y A_pixel, r, collection), under the balance
    heuristic p_A / (p_A + q g s + [eye] :func:`~.eye.eye_share`), g = cosθ_x cosθ_y / (π r²), s the continuation's
    density over the cosine density toward y (:func:`~datagen.scene.brdf_kernel.sampling_ratio`).

    Args (k connections): conn = (b (k,) int64 the vertex of each, wk (k, 3) unit x → y, r, cos_y, collect, d_ys
        (k,)); per vertex: obj (int64), n_x, w_in (3,), flux, counted, physical, count (int64: pixel regions recorded),
        p_in; survival (n_objects,) q; mat the material arrays; consts = (A_pixel m², p_A 1/m², eye term 0/1,
        count the sensor leg 0/1).
    Returns:
        (weight (k,) photons before attenuation, time (k,) s, physical path (k,) m).
    """
    b, wk, r, cos_y, collect, d_ys = conn
    area, p_a, eye, sensor = consts
    k = b.shape[0]
    weight, time, path = np.empty(k), np.empty(k), np.empty(k)
    for j in range(k):
        i = b[j]
        cos_x = _dot3(n_x[i, 0], n_x[i, 1], n_x[i, 2], wk[j, 0], wk[j, 1], wk[j, 2])
        f = brdf_value(mat, obj[i], n_x[i, 0], n_x[i, 1], n_x[i, 2], w_in[i, 0], w_in[i, 1], w_in[i, 2],
                       wk[j, 0], wk[j, 1], wk[j, 2])
        w = flux[i] * f * cos_x * fov_term(cos_y[j] * area, r[j], collect[j])
        g = geometry_term(cos_x, cos_y[j], r[j]) / math.pi
        p_d = survival[obj[i]] * g * sampling_ratio(mat, obj[i], _dot3(n_x[i, 0], n_x[i, 1], n_x[i, 2], w_in[i, 0],
                                                                       w_in[i, 1], w_in[i, 2]), cos_x,
                                                    _dot3(w_in[i, 0], w_in[i, 1], w_in[i, 2], wk[j, 0], wk[j, 1],
                                                          wk[j, 2]))
        p_e = eye_share(p_a, g, count[i], p_in[i]) if eye else 0.0
        weight[j] = w * (p_a / (p_a + p_d + p_e))
        path[j] = physical[i] + r[j] + d_ys[j]
        time[j] = (counted[i] + r[j] + (d_ys[j] if sensor else 0.0)) / SPEED_OF_LIGHT
    return weight, time, path
