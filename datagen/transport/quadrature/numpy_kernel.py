"""The quadrature's primary in numpy: the path of the cases the compiled kernel does not cover (a non-Lambertian
laser point or relay wall, ``brdf_angles``, another BRDF model:
:meth:`datagen.transport.quadrature.Quadrature.compiled_case`) and of sinks without a fine grid, and the
independent reference the tests compare the compiled path with
(``tests/test_quadrature_kernel.py``: 1e-9 with a ray per lit pair). The formulas are those of
:mod:`datagen.transport.physics` through the quadrature's :class:`~datagen.transport.physics.LegPhysics`; the tent
shift is the module doc of :mod:`datagen.transport.quadrature`.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...units import SPEED_OF_LIGHT
from ..base import Sink

__all__ = ["run_numpy"]


def run_numpy(q, sink: Sink, coarse: Sink | None, progress: Callable[[int], None] | None) -> None:
    """The primary tents into ``sink`` (and the rule at 2h into ``coarse``), in numpy blocks of (cell,
    connection) rows."""
    s, c = q.settings, q.capture
    M = q.n_cells
    per_block = max(1, s.batch // max(M, 1))
    add_tents = getattr(sink, "add_tents", None)
    laser_cache: dict = {}
    all_lasers = np.unique(q.conn_laser)
    if M * len(all_lasers) <= 4 * s.batch:                        # the laser legs of every laser point, once
        laser_cache = {"lasers": all_lasers, **q.laser_leg(all_lasers)}
    f_lamb = q.physics.lambert_f[q.cell_object]                   # ρ/π (NaN: not Lambertian, then f comes from brdf)
    comp_base = q.object_component[q.cell_object] * c.n_channels  # (M,)
    tri_v = q.cells                                               # (M, 3)
    n_conn = len(q.conn_laser)
    for start in range(0, n_conn, per_block):
        sl = slice(start, start + per_block)
        lasers, targets, channels = q.conn_laser[sl], q.conn_target[sl], q.conn_channel[sl]
        u_l, inv_l = np.unique(lasers, return_inverse=True)
        u_t, inv_t = np.unique(targets, return_inverse=True)
        if laser_cache:
            col = np.searchsorted(laser_cache["lasers"], u_l)
            lg = {k: (v[:, col] if v is not None and k != "lasers" else v) for k, v in laser_cache.items()}
        else:
            lg = q.laser_leg(u_l)
        shared = q.target_is_laser and np.array_equal(u_t, u_l)
        tg = q.target_leg(u_t, vertex_distances=not shared)
        if shared:                                                # the target is the laser point: same vertex distances
            tg["rv"] = lg["rv"]
        e = lg["e"][:, inv_l]                                     # (M, B)
        g = tg["g"][:, inv_t]
        ok = (e > 0) & (g > 0) & (lg["side"][:, inv_l] == tg["side"][:, inv_t])
        mi, bi = np.nonzero(ok)
        q.stats.pair_rows += M * len(lasers)
        if len(mi):
            f = f_lamb[mi]
            if q.hidden_angles:
                side = lg["side"][mi, inv_l[bi]].astype(np.float64)
                f = q.physics.brdf(q.cell_object[mi], side[:, None] * q.cell_normal[mi],
                                    lg["w"][mi, inv_l[bi]], tg["w"][mi, inv_t[bi]])
            weight = q.cell_area[mi] * e[mi, bi] * f * g[mi, bi]
            if s.attenuation > 0:
                weight = weight * q.physics.attenuation(c.emitter_legs[lasers[bi]] + lg["r"][mi, inv_l[bi]]
                                                           + tg["r"][mi, inv_t[bi]] + tg["d"][inv_t[bi]])
            offset = (np.zeros(len(mi)) + q.physics.laser_leg(lasers[bi])
                      + q.physics.sensor_leg(tg["d"][inv_t[bi]]))
            vert = tri_v[mi]                                      # (n, 3) vertex ids
            path = lg["rv"][vert, inv_l[bi][:, None]] + tg["rv"][vert, inv_t[bi][:, None]]
            # the path length is convex on T, so its linear interpolant (the tent) runs late: shift each tent
            # so its mean is the rule (1/12)Σ τ(v_i) + (3/4) τ(centroid), exact for quadratics (module doc)
            centre = lg["r"][mi, inv_l[bi]] + tg["r"][mi, inv_t[bi]]
            path = path + (0.75 * (centre - path.mean(axis=1)) + offset)[:, None]
            comp = comp_base[mi] + channels[bi]
            times = path / SPEED_OF_LIGHT
            if add_tents is not None:
                add_tents(times, weight, comp)
            else:
                sink.add(times.mean(axis=1), weight, comp)
            q.stats.tents += len(mi)
            if coarse is not None:  # the rule at 2h from the same evaluations (error estimate)
                sel = np.flatnonzero((q.coarse_of[mi] >= 0) & (channels[bi] % q.coarse_stride == 0))
                cv = q.coarse_cells[q.coarse_of[mi[sel]]]
                lb, tb = inv_l[bi[sel]][:, None], inv_t[bi[sel]][:, None]
                cpath = lg["rv"][cv, lb] + tg["rv"][cv, tb]
                cpath = cpath + (0.75 * (centre[sel] - cpath.mean(axis=1)) + offset[sel])[:, None]
                coarse.add_tents(cpath / SPEED_OF_LIGHT, 4.0 * weight[sel], channels[bi[sel]])
        if progress is not None:
            progress(M * len(lasers))
