"""Compiled transition of the free-running SPAD chain (datagen/spad/free_running.py, Rapp et al. 2019).

One transition applies, per pixel, a scatter of detection mass onto the cells where the detector is live again
and a decayed prefix sum over two laser periods. Both are sequential O(cells) loops: numba runs a transition
about 15 times faster than the equivalent numpy (sort, reduceat and blocked exponentials) for one pixel of
800 cells (11 against 180 µs). A detector fit evaluates the chain some 10⁴ times (docs/capture_io.md), each
evaluation a few transitions of one pixel, so the power iteration to the stationary distribution and the
window mass also run here, free of numpy's per-call overhead on small arrays.

The transition of a row distribution π (cells,) is

    y = S(π ⊙ s) + Σ_k P_k ⊙ W_k(π ⊙ g_k)

with S the scatter onto the live cells ``a`` (S(v)_c = Σ_{j: a_j = c} v_j) and W_k the wrapped survival of mass
entering the cells ``b`` (:func:`_survive`, decay D_k across each cell, 1 − e^{−Λ_k} per period): one survival
term without afterpulsing, two with (the pending afterpulse's own decay). :func:`chain_factors` builds the
factors from the cells' avalanches (the chain's model: :class:`datagen.spad.free_running._Chain`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["chain_factors", "transition_rows", "power_rows", "window_mass_rows"]


@njit(cache=True)
def _survive(surv: np.ndarray, decay: np.ndarray, oms: float) -> None:
    """In place: the mass ``surv`` (cells,) entering each cell becomes the survival mass at the start of each cell
    over all later periods. The mass decays by ``decay[c]`` = e^{−q_c} across each cell c;
    U[t] = U[t − 1]·decay[t − 1] + entered[t] runs over two periods, and the second period's mass continues in every
    later one with the survival e^{−Λ} per period, so it is summed geometrically (÷ ``oms`` = 1 − e^{−Λ}; nothing
    where Λ = 0, no detection possible)."""
    n_cells = surv.shape[0]
    u = 0.0
    for t in range(n_cells):
        u = u * decay[t - 1] + surv[t] if t > 0 else surv[0]
        surv[t] = u
    if oms <= 0.0:
        return
    for t in range(n_cells):
        u = u * decay[t - 1] if t > 0 else u * decay[n_cells - 1]
        surv[t] += u / oms


@njit(cache=True)
def chain_factors(q: np.ndarray, edges: np.ndarray, dead_time: float, p_ap: float, tau_ap: float) -> tuple:
    """The factors of the chain's transition (module doc; :class:`datagen.spad.free_running._Chain` gives their
    meaning and sources) for avalanches ``q`` (pixels, cells) per cycle in the cells ``edges`` (cells + 1,) s of one
    period, dead time τ (s), afterpulse probability P_ap and time constant τ_ap (s).

    A detection in cell j is taken at its centre; the detector is live again at centre_j + τ (modulo the period),
    in cell a_j with the live fraction φ_j of it; b_j = a_j + 1. Per pixel, with Λ = Σ q:
    s = 1 − e^{−φ q_a} (a detection inside the partial cell) and one survival term g = e^{−φ q_a},
    P = 1 − e^{−q}, D = e^{−q}, 1 − e^{−Λ}. With afterpulsing the survival splits into the branch without a
    pending afterpulse (g·(1 − P_ap)) and, when τ_ap > 0, the pending one (g = P_ap e^{−φ q_a − φ k_a},
    P = 1 − e^{−(q + k)}, D = e^{−(q + k)}, 1 − e^{−(Λ + T/τ_ap)}; k = cell width / τ_ap), and s = (1 − P_ap) s +
    P_ap (1 − e^{−φ q_a − φ k_a}) (τ_ap = 0: P_ap + (1 − P_ap) s). The afterpulses alone (their share of the
    detections): s = P_ap (1 − e^{−φ q_a − φ k_a}) k_a/(q_a + k_a) and the pending term with P scaled by
    k/(q + k) (τ_ap = 0: s = P_ap, no survival term).

    Returns:
        (a, b) int64 (cells,); lam float64 (pixels,) Λ; then the transition's and the afterpulses' arguments of
        :func:`transition_rows` after ``a, b``: (stay, go, factor, decay, oms, terms) each.
    """
    n_pix, n_cells = q.shape
    period = edges[-1]
    a = np.empty(n_cells, dtype=np.int64)
    phi = np.empty(n_cells)
    idx = 0
    for j in range(n_cells):
        live = (0.5 * (edges[j] + edges[j + 1]) + dead_time) % period
        idx = _cell_at(edges, live, idx)
        a[j] = idx
        phi[j] = min(max((edges[idx + 1] - live) / (edges[idx + 1] - edges[idx]), 0.0), 1.0)
    b = (a + 1) % n_cells
    pending = p_ap > 0.0 and tau_ap > 0.0
    terms = 2 if pending else 1
    lam = np.zeros(n_pix)
    stay = np.empty((n_pix, n_cells))
    go = np.empty((terms, n_pix, n_cells))
    factor = np.empty((terms, n_pix, n_cells))
    decay = np.empty((terms, n_pix, n_cells))
    oms = np.empty((terms, n_pix))
    ap_stay = np.full((n_pix, n_cells), p_ap)
    ap_go = np.zeros((1, n_pix, n_cells))
    ap_factor = np.zeros((1, n_pix, n_cells))
    for i in range(n_pix):
        for j in range(n_cells):
            lam[i] += q[i, j]
            factor[0, i, j] = -math.expm1(-q[i, j])
            decay[0, i, j] = math.exp(-q[i, j])
        oms[0, i] = -math.expm1(-lam[i])
        for j in range(n_cells):
            x = phi[j] * q[i, a[j]]
            stay[i, j] = -math.expm1(-x)
            go[0, i, j] = math.exp(-x) * (1.0 - p_ap)
            if p_ap > 0.0 and not pending:
                stay[i, j] = p_ap + (1.0 - p_ap) * stay[i, j]
        if pending:
            oms[1, i] = -math.expm1(-(lam[i] + period / tau_ap))
            for j in range(n_cells):
                k = (edges[j + 1] - edges[j]) / tau_ap
                qk = q[i, j] + k
                factor[1, i, j] = -math.expm1(-qk)
                decay[1, i, j] = math.exp(-qk)
                ap_factor[0, i, j] = factor[1, i, j] * (k / qk if qk > 0.0 else 0.0)
            for j in range(n_cells):
                aj = a[j]
                ka = (edges[aj + 1] - edges[aj]) / tau_ap
                x = phi[j] * q[i, aj] + phi[j] * ka
                go[1, i, j] = math.exp(-x) * p_ap
                ap_go[0, i, j] = go[1, i, j]
                stay_ap = -math.expm1(-x)
                stay[i, j] = (1.0 - p_ap) * stay[i, j] + p_ap * stay_ap
                qka = q[i, aj] + ka
                ap_stay[i, j] = p_ap * stay_ap * (ka / qka if qka > 0.0 else 0.0)
    ap_terms = 1 if pending else 0
    ap_decay = decay[1:] if pending else ap_factor
    ap_oms = oms[1:] if pending else np.zeros((1, n_pix))
    return (a, b, lam, (stay, go, factor, decay, oms, terms),
            (ap_stay, ap_go, ap_factor, np.ascontiguousarray(ap_decay), np.ascontiguousarray(ap_oms), ap_terms))


@njit(cache=True)
def _transition_row(pi, i, a, b, stay, go, factor, decay, oms, terms, surv, out) -> None:
    """out = the transition (module doc) of row distribution ``pi`` (cells,) with pixel i's factors; ``surv``
    (cells,) scratch."""
    n_cells = pi.shape[0]
    for j in range(n_cells):
        out[j] = 0.0
    for j in range(n_cells):
        out[a[j]] += pi[j] * stay[i, j]
    for k in range(terms):
        for j in range(n_cells):
            surv[j] = 0.0
        for j in range(n_cells):
            surv[b[j]] += pi[j] * go[k, i, j]
        _survive(surv, decay[k, i], oms[k, i])
        for j in range(n_cells):
            out[j] += factor[k, i, j] * surv[j]


@njit(cache=True)
def transition_rows(pi, a, b, stay, go, factor, decay, oms, terms) -> np.ndarray:
    """One transition (module doc) of each row of ``pi``.

    Args:
        pi: float64 (pixels, cells) row distributions.
        a, b: int64 (cells,) the live cell after a detection in each cell, and the cell after it.
        stay: float64 (pixels, cells) s, the scattered weight.
        go, factor, decay: float64 (≥ terms, pixels, cells) g_k, P_k and D_k of each survival term.
        oms: float64 (≥ terms, pixels) 1 − e^{−Λ_k}.
        terms: int, the survival terms used (0, 1 or 2).
    Returns:
        float64 (pixels, cells).
    """
    n_pix, n_cells = pi.shape
    out = np.empty((n_pix, n_cells))
    surv = np.empty(n_cells)
    for i in range(n_pix):
        _transition_row(pi[i], i, a, b, stay, go, factor, decay, oms, terms, surv, out[i])
    return out


@njit(cache=True)
def power_rows(pi, a, b, stay, go, factor, decay, oms, terms, tol, max_iter) -> np.ndarray:
    """Power iteration of each row of ``pi`` (arguments as :func:`transition_rows`), in place: the row
    renormalised after every transition, until its L1 change is below ``tol`` or ``max_iter`` transitions.
    Returns bool (pixels,): the rows that converged."""
    n_pix, n_cells = pi.shape
    done = np.zeros(n_pix, dtype=np.bool_)
    nxt = np.empty(n_cells)
    surv = np.empty(n_cells)
    for i in range(n_pix):
        row = pi[i]
        for _ in range(max_iter):
            _transition_row(row, i, a, b, stay, go, factor, decay, oms, terms, surv, nxt)
            s = 0.0
            for j in range(n_cells):
                s += nxt[j]
            if s > 0.0:
                for j in range(n_cells):
                    nxt[j] /= s
            diff = 0.0
            for j in range(n_cells):
                diff += abs(nxt[j] - row[j])
                row[j] = nxt[j]
            if diff < tol:
                done[i] = True
                break
    return done


@njit(cache=True)
def _cell_at(edges: np.ndarray, u: float, idx: int) -> int:
    """The cell of ``edges`` holding u (edges[i] ≤ u < edges[i + 1], clipped to the cells), searched forward from
    cell ``idx`` when u lies at or beyond it (a walk over increasing u), else from the start."""
    n_cells = edges.shape[0] - 1
    if not edges[min(idx, n_cells)] <= u:
        idx = 0
    while idx < n_cells - 1 and edges[idx + 1] <= u:
        idx += 1
    return idx


@njit(cache=True)
def window_mass_rows(pi: np.ndarray, edges: np.ndarray, dead_time: float) -> np.ndarray:
    """(Wπ)_j: per row, the mass of ``pi`` (pixels, cells) in the periodic window (centre_j − τ, centre_j], π
    uniform within each cell of ``edges`` (cells + 1,) s (the period is edges[-1]); float64 (pixels, cells)."""
    n_pix, n_cells = pi.shape
    period = edges[-1]
    wrap = np.empty((2, n_cells))                 # whole periods back, cell and fraction of each window end
    cell = np.empty((2, n_cells), dtype=np.int64)
    frac = np.empty((2, n_cells))
    for end in range(2):
        idx = 0
        for j in range(n_cells):
            t = 0.5 * (edges[j] + edges[j + 1]) - (dead_time if end == 1 else 0.0)
            k = np.floor(t / period)
            u = t - k * period
            idx = _cell_at(edges, u, idx)
            wrap[end, j], cell[end, j] = k, idx
            frac[end, j] = (u - edges[idx]) / (edges[idx + 1] - edges[idx])
    out = np.empty((n_pix, n_cells))
    cum = np.empty(n_cells + 1)
    for i in range(n_pix):
        cum[0] = 0.0
        for j in range(n_cells):
            cum[j + 1] = cum[j] + pi[i, j]
        for j in range(n_cells):
            c, d = cell[0, j], cell[1, j]
            out[i, j] = ((wrap[0, j] * cum[n_cells] + cum[c] + frac[0, j] * pi[i, c])
                         - (wrap[1, j] * cum[n_cells] + cum[d] + frac[1, j] * pi[i, d]))
    return out
