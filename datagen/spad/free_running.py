"""Free-running SPAD whose dead time crosses laser cycles (time-tagging TCSPC; docs/physics.md §6).

Expected histogram: stationary distribution of the Markov chain on the detection phase (Rapp, Ma, Dawson &
Goyal, "Dead time compensation for high-flux ranging", IEEE Trans. Signal Process. 67(13), 2019), or the closed
form of a paralyzable dead time.  Samples: exact continuous-time event simulation (with afterpulsing); the batched
simulator of the same process without afterpulsing is in datagen/spad/free_running_batched.py.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .arrays import as_rates, check_event_count, row_search
from .config import DetectorConfig
from .markov_kernel import chain_factors, power_rows, transition_rows, window_mass_rows
from .rates import gate_fraction

__all__ = [
    "MARKOV_MAX_STATES",
    "MARKOV_CELL_HAZARD",
    "MARKOV_TOL",
    "MARKOV_MAX_ITER",
    "EVENT_FLUSH",
    "MARKOV_CHUNK_ELEMENTS",
    "free_running_expected",
    "free_running_rate",
    "event_simulation",
    "period_cells",
]


MARKOV_MAX_STATES = 60_000
"""Cap on the number of phase cells of the free-running Markov chain (per pixel)."""

MARKOV_CELL_HAZARD = 0.02
"""Automatic oversampling keeps the expected avalanches per Markov cell below this."""

MARKOV_TOL = 1e-13
"""L1 convergence tolerance of the stationary distribution of the free-running chain."""

MARKOV_MAX_ITER = 20_000
"""Power iterations before falling back to ARPACK for a slowly mixing free-running chain."""

EVENT_FLUSH = 4_000_000
"""Detections buffered by the event simulator before they are binned."""


def period_cells(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cover the whole laser period with cells (shared by the chain and both event simulators): the histogram bins
    plus background cells before/after the window (avalanche rate ``background_rate`` × gate).  Returns (edges
    (cells+1,) in s within the period, q (pixels, cells) expected avalanches per cycle, cell_bin (cells,) histogram
    bin or -1)."""
    bins = r2.shape[1]
    T = config.period
    win = config.bin_edges(bins)
    if win[-1] > T * (1 + 1e-9):
        raise ValueError(f"the histogram window [{win[0]!r}, {win[-1]!r}] s exceeds the laser period {T!r} s; "
                         "free-running time tags are taken modulo the period")
    parts = [win]
    n_pre = int(round(win[0] / config.bin_width))
    if win[0] > 0:
        parts.insert(0, np.linspace(0.0, win[0], max(n_pre, 1) + 1)[:-1])
    tail = T - win[-1]
    if tail > 1e-9 * T:
        n_post = max(int(round(tail / config.bin_width)), 1)
        parts.append(np.linspace(win[-1], T, n_post + 1)[1:])
    edges = np.concatenate(parts)
    if tail <= 1e-9 * T:
        edges[-1] = T  # window ends at the period (within round-off)
    n_before = 0 if win[0] <= 0 else parts[0].size
    n_cells = edges.size - 1
    cell_bin = np.full(n_cells, -1, dtype=np.int64)
    cell_bin[n_before:n_before + bins] = np.arange(bins)
    bg = config.background_rate * np.diff(edges) * gate_fraction(edges, config.gate)
    q = np.broadcast_to(bg, (r2.shape[0], n_cells)).copy()
    q[:, n_before:n_before + bins] = r2
    return edges, q, cell_bin


class _Chain:
    """Discretised free-running chain on the detection phase for a batch of pixels (Rapp et al. 2019).

    Cells j (avalanches q_j per cycle) cover the period.  A detection in cell j is taken at the cell centre,
    so the detector is live again at centre_j + τ: inside cell a_j, with a live fraction φ_j of that cell.
    From there the next detection is the first avalanche of the periodic Poisson process: in cell a_j with
    probability 1 − e^{−φ_j q_a}, otherwise distributed by the full-period kernel
    F(b, j') = e^{−(C_{j'} − C_b)} (1 − e^{−q_{j'}}) / (1 − e^{−Λ}) from b = a_j + 1 (whole empty periods
    summed geometrically).  Afterpulsing (a pending afterpulse at live + Exp(τ_ap), cancelled by the next
    detection) splits the survival from the live point into the branch without one (weight 1 − P_ap, decay C) and
    the pending one (weight P_ap, decay C + t/τ_ap): K = (1−P)e^{−ΔC}q + P e^{−ΔC−Δt/τ_ap}(q + 1/τ_ap), cell-exact.
    The factors, the transition (O(cells) per pixel: decayed prefix sums), the power iteration and the window mass
    are compiled in datagen/spad/markov_kernel.py (:func:`~datagen.spad.markov_kernel.chain_factors`)."""

    def __init__(self, q: np.ndarray, edges: np.ndarray, dead_time: float, p_ap: float = 0.0, tau_ap: float = 0.0):
        self.q, self.edges, self.dead_time, self.p_ap, self.tau_ap = q, edges, dead_time, p_ap, tau_ap
        self.M = q.shape[1]
        self.a, self.b, self.lam, self._all, self._ap_only = chain_factors(
            np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(edges, dtype=np.float64),
            float(dead_time), float(p_ap), float(tau_ap))

    def arguments(self, ap_only: bool = False) -> tuple:
        """The compiled transition's arguments after the row distributions (markov_kernel.transition_rows):
        all detections, or only the afterpulses when ``ap_only``."""
        return (self.a, self.b, *(self._ap_only if ap_only else self._all))

    def step(self, pi: np.ndarray, ap_only: bool = False) -> np.ndarray:
        """One transition of a batch of row distributions pi (pixels, cells): all detections, or only the
        afterpulses when ``ap_only``."""
        return transition_rows(np.ascontiguousarray(pi, dtype=np.float64), *self.arguments(ap_only))

    def window_mass(self, pi: np.ndarray) -> np.ndarray:
        """(Wπ)_j: mass of detections in (centre_j − τ, centre_j], periodic, π uniform within cells."""
        return window_mass_rows(np.ascontiguousarray(pi), self.edges, float(self.dead_time))


def _stationary(chain: _Chain) -> np.ndarray:
    """Stationary detection-phase distribution (pixels, cells): power iteration of each pixel started from the
    low-flux guess π ∝ q (compiled: markov_kernel.power_rows), then ARPACK for any pixel whose chain mixes too
    slowly."""
    q = chain.q
    pi = q / np.where(chain.lam[:, None] > 0, chain.lam[:, None], 1.0)
    done = power_rows(pi, *chain.arguments(), MARKOV_TOL, MARKOV_MAX_ITER)
    todo = np.flatnonzero(~done)
    if todo.size == 0:
        return pi
    from scipy.sparse.linalg import LinearOperator, eigs

    for k in todo:  # only for slowly mixing, nearly periodic chains
        one = _Chain(q[k:k + 1], chain.edges, chain.dead_time, chain.p_ap, chain.tau_ap)
        op = LinearOperator((chain.M, chain.M), matvec=lambda x, c=one: c.step(np.real(x).reshape(1, -1))[0],
                            dtype=np.float64)
        _, vec = eigs(op, k=1, which="LR", v0=pi[k], tol=1e-14, maxiter=100_000)
        vec = np.abs(vec[:, 0].real)
        pi[k] = vec / vec.sum()
    return pi


def _refine_cells(edges: np.ndarray, q: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if factor == 1:
        return edges, q, np.arange(q.shape[1])
    frac = np.arange(factor) / factor
    fine = (edges[:-1, None] + frac[None, :] * np.diff(edges)[:, None]).ravel()
    fine = np.append(fine, edges[-1])
    return fine, np.repeat(q / factor, factor, axis=1), np.repeat(np.arange(q.shape[1]), factor)


def _oversample(q: np.ndarray, edges: np.ndarray, config: DetectorConfig) -> np.ndarray:
    """Markov cells per period cell, per pixel (pixels,) int64: ``config.markov_oversample`` when given, else each
    pixel's own automatic factor (at least 4; its brightest cell below ``MARKOV_CELL_HAZARD`` avalanches per Markov
    cell, the dead time at least 8 cells of the longest period cell and, with afterpulsing, the afterpulse time
    constant at least 1 / ``MARKOV_CELL_HAZARD`` of them; rounded up to 2^k or 3·2^(k−1); at most
    ``MARKOV_MAX_STATES`` cells in all), so that a pixel's discretisation does not depend on the pixels it is
    computed with."""
    if config.markov_oversample:
        return np.full(q.shape[0], int(config.markov_oversample), dtype=np.int64)
    widest = float(np.diff(edges).max())
    need = 4
    if config.dead_time > 0:
        need = max(need, math.ceil(8.0 * widest / config.dead_time))
    if config.afterpulse_probability > 0 and config.afterpulse_time_constant > 0:
        need = max(need, math.ceil(widest / (MARKOV_CELL_HAZARD * config.afterpulse_time_constant)))
    factor = np.maximum(np.ceil(q.max(axis=1, initial=0.0) / MARKOV_CELL_HAZARD), need)
    # rounded up to 2^k or 3·2^(k−1) (4, 6, 8, 12, 16, …): a few chains per batch, however varied its pixels
    k = np.floor(np.log2(factor))
    factor = np.where(factor <= 2.0 ** k, 2.0 ** k, np.where(factor <= 1.5 * 2.0 ** k, 1.5 * 2.0 ** k, 2.0 ** (k + 1)))
    return np.minimum(max(1, MARKOV_MAX_STATES // q.shape[1]), factor).astype(np.int64)


def _free_running_nonparalyzable(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    edges, q, cell_bin = period_cells(r2, config)
    factors = _oversample(q, edges, config)
    hist = np.zeros_like(r2)
    rho = np.zeros(r2.shape[0])
    for factor in np.unique(factors):                 # the pixels of one factor together (the chain is per pixel)
        rows = np.flatnonzero(factors == factor)
        hist[rows], rho[rows] = _chain_expected(q[rows], edges, cell_bin, int(factor), r2.shape[1], config)
    return hist, rho


def _chain_expected(q: np.ndarray, edges: np.ndarray, cell_bin: np.ndarray, factor: int, bins: int,
                    config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """(expected detections per cycle per bin (pixels, ``bins``), per cycle (pixels,)), float64, of the pixels
    ``q`` (pixels, cells) on the period cells ``edges`` / ``cell_bin`` (:func:`period_cells`), each cell cut into
    ``factor`` Markov cells: the non-paralyzable chain of :func:`free_running_rate`'s doc."""
    fine_edges, fine_q, parent = _refine_cells(edges, q, factor)
    p_ap = config.afterpulse_probability
    chain = _Chain(fine_q, fine_edges, config.dead_time, p_ap, config.afterpulse_time_constant)
    pi = _stationary(chain)
    wpi = chain.window_mass(pi) if config.dead_time > 0 else np.zeros_like(pi)
    # detections per cycle (dead-fraction identity: photon detections = Λ − ρ·Σ q·Wπ = ρ·(1 − afterpulse fraction))
    live_photons = 1.0 if p_ap == 0 else 1.0 - chain.step(pi, ap_only=True).sum(axis=1)
    rho = chain.lam / (live_photons + np.sum(fine_q * wpi, axis=1))
    per_cell = rho[:, None] * pi
    fine_bin = cell_bin[parent]
    hist = np.zeros((q.shape[0], bins))
    inside = fine_bin >= 0
    np.add.at(hist, (slice(None), fine_bin[inside]), per_cell[:, inside])
    return hist, rho


def _free_running_paralyzable(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Closed form: an avalanche at t is counted iff no avalanche in (t − τ, t), so the stationary detection
    density is λ(t)·exp(−∫_{t−τ}^{t} λ); integrated exactly over sub-intervals on which both ends are linear."""
    edges, q, cell_bin = period_cells(r2, config)
    T, tau = config.period, config.dead_time
    cum = np.zeros((q.shape[0], q.shape[1] + 1))
    np.cumsum(q, axis=1, out=cum[:, 1:])
    lam = cum[:, -1:]
    # E(t) = R(t) − R(t − τ) is linear between cell edges and the points where t − τ crosses an edge
    breaks = np.unique(np.concatenate([edges, np.mod(edges + tau, T)]) if tau > 0 else edges)
    breaks = breaks[(breaks >= 0) & (breaks <= T)]
    breaks = np.unique(np.concatenate([[0.0, T], breaks]))
    lo, hi = breaks[:-1], breaks[1:]
    keep = hi - lo > 1e-12 * T
    lo, hi = lo[keep], hi[keep]

    def big_r(t):  # cumulative intensity on the unrolled time axis, (pixels, len(t))
        k = np.floor(t / T)
        u = t - k * T
        idx = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, q.shape[1] - 1)
        frac = (u - edges[idx]) / (edges[idx + 1] - edges[idx])
        return k, cum[:, idx] + frac[None, :] * q[:, idx]

    def exposure_term(t):  # ∫_{t−τ}^{t} λ
        k1, r1 = big_r(t)
        k0, r0 = big_r(t - tau)
        return (k1 - k0)[None, :] * lam + r1 - r0

    e_lo, e_hi = exposure_term(lo), exposure_term(hi)
    mid = 0.5 * (lo + hi)
    cell = np.clip(np.searchsorted(edges, mid, side="right") - 1, 0, q.shape[1] - 1)
    density = q[:, cell] / (edges[cell + 1] - edges[cell])[None, :]
    x = e_hi - e_lo
    small = np.abs(x) < 1e-8
    safe_x = np.where(small, 1.0, x)
    phi = np.where(small, 1.0 - 0.5 * x, -np.expm1(-x) / safe_x)
    piece = density * (hi - lo)[None, :] * np.exp(-e_lo) * phi
    hist = np.zeros_like(r2)
    b = cell_bin[cell]
    inside = b >= 0
    np.add.at(hist, (slice(None), b[inside]), piece[:, inside])
    return hist, piece.sum(axis=1)


MARKOV_CHUNK_ELEMENTS = 4_000_000
"""Pixels are chained in chunks sized by the batch's brightest pixel (the largest automatic oversampling), so that
each (pixels × Markov cells) float64 array of a chunk holds at most half this many elements; the chain keeps about
a dozen of them at once, so a chunk peaks near 200 MB."""


def free_running_expected(r2: np.ndarray, config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """(per-cycle expected histogram (pixels, bins), detections per cycle (pixels,)), in pixel chunks.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle per bin, ≥ 0.
        config: detector description with ``model="free_running"`` (dead_time in s, paralyzable,
            markov_oversample, period, gate, background_rate).
    Returns:
        ``(hist, rho)``: float64 (pixels, bins) expected detections per laser cycle in each bin (multiply by
        ``config.cycles`` for the exposure), and float64 (pixels,) detections per cycle at all phases.
    Raises:
        ValueError: the histogram window exceeds the laser period.
        NotImplementedError: afterpulsing with a gate (afterpulses outside the gate are lost, which this chain
            does not model).
    """
    if config.afterpulse_probability > 0 and config.gate is not None:
        raise NotImplementedError(f"afterpulse_probability={config.afterpulse_probability!r} with gate="
                                  f"{list(config.gate)!r}: the expected histogram models afterpulsing without a "
                                  "gate only; average sample_histogram draws")
    solver = _free_running_paralyzable if config.paralyzable else _free_running_nonparalyzable
    hist = np.zeros_like(r2)
    rho = np.zeros(r2.shape[0])
    if r2.shape[0] == 0:
        return hist, rho
    # the batch's brightest pixel has the largest automatic factor (its cells are the others' but for the window,
    # which is its row of r2), so chunks sized by its chain hold every pixel's within the budget
    brightest = int(np.argmax(r2.max(axis=1)))
    edges, q, _ = period_cells(r2[brightest:brightest + 1], config)
    states = q.shape[1] * (1 if config.paralyzable else int(_oversample(q, edges, config)[0]))
    chunk = max(1, MARKOV_CHUNK_ELEMENTS // (2 * states))     # memory only: each pixel's chain is its own
    for start in range(0, r2.shape[0], chunk):
        hist[start:start + chunk], rho[start:start + chunk] = solver(r2[start:start + chunk], config)
    return hist, rho


def free_running_rate(rates: Any, config: DetectorConfig) -> np.ndarray:
    """Stationary detections per laser cycle of a free-running SPAD (all phases, in or out of the window).

    Non-paralyzable: from the Markov chain on the detection phase (Rapp et al. 2019) and the exact identity
    ``ρ = Λ / (1 + Σ_j q_j (Wπ)_j)`` (the detector is dead at t iff it detected in (t − τ, t]); for a constant
    rate it reduces to the counter law m = n/(1 + nτ).  Paralyzable: closed form (m = n·e^{−nτ} for a
    constant rate).

    Args:
        rates: (..., bins) expected avalanches per cycle per bin; config with ``model="free_running"``.
    Returns:
        float64 (...,) detections per cycle (multiply by ``repetition_rate`` for Hz).
    Raises:
        ValueError: invalid rates, another model, or a histogram window longer than the period.
    """
    r = as_rates(rates)
    _require_model(config, "free_running")
    _, rho = free_running_expected(r.reshape(-1, r.shape[-1]), config)
    return rho.reshape(r.shape[:-1])


def event_simulation(r2: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Exact continuous-time simulation of a free-running SPAD over ``n_cycles`` periods, vectorised over pixels
    (one round = one avalanche per pixel).  Used when afterpulsing is on (afterpulses depend on the recorded
    history); otherwise :func:`event_simulation_batched` simulates the same process faster.  The avalanche
    intensity is piecewise constant on the period cells;
    the next avalanche after time s is found by inverting the cumulative intensity with an Exp(1) draw,
    skipping whole empty periods in O(1).  Non-paralyzable: the detector is live again at t + τ.  Paralyzable:
    every avalanche restarts the dead time and is recorded only if the previous one is ≥ τ earlier.
    Afterpulses: each recorded avalanche schedules, with probability P_ap, an afterpulse at
    t + τ + Exp(afterpulse_time_constant) and cancels any pending one (one trap per pixel); afterpulses falling
    outside the gate are lost.  The detector starts live at t = 0; time stamps are phases modulo the period.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle in each histogram bin (window
            ``config.bin_edges(bins)``, s; outside it the rate is ``background_rate`` × gate), ≥ 0 (not checked).
        config: detector description (period, cycles, dead_time in s, paralyzable, afterpulse_probability,
            afterpulse_time_constant in s, gate).
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) recorded detections per bin over ``config.cycles`` laser periods.
    Raises:
        ValueError: the histogram window exceeds the laser period; more expected avalanches than
            MAX_SIMULATED_EVENTS in all, or than MAX_SIMULATED_EVENTS / 100 in one pixel (one Python step each;
            :func:`datagen.spad.arrays.check_event_count`).
    """
    edges, q, cell_bin = period_cells(r2, config)
    n_pix, n_cells = q.shape
    bins = r2.shape[1]
    T, tau, n = config.period, config.dead_time, config.cycles
    per_pixel = q.sum(axis=1) * n
    check_event_count(float(per_pixel.sum()), "free_running event simulation (afterpulsing)",
                      float(per_pixel.max(initial=0.0)))
    widths = np.diff(edges)
    cum = np.zeros((n_pix, n_cells + 1))
    np.cumsum(q, axis=1, out=cum[:, 1:])
    lam = cum[:, -1].copy()
    gate_ok = gate_fraction(edges, config.gate) > 0
    p_ap, tau_ap = config.afterpulse_probability, config.afterpulse_time_constant
    paralyzable = config.paralyzable
    tiny = np.finfo(np.float64).tiny
    never = np.iinfo(np.int64).max
    last_phase_value = np.nextafter(T, 0.0)

    cycle = np.zeros(n_pix, dtype=np.int64)   # where the search for the next avalanche starts
    phase = np.zeros(n_pix)
    last_cycle = np.full(n_pix, -1, dtype=np.int64)   # paralyzable: previous avalanche (-1: none yet)
    last_phase = np.zeros(n_pix)
    ap_cycle = np.full(n_pix, never, dtype=np.int64)  # pending afterpulse
    ap_phase = np.zeros(n_pix)
    active = lam > 0
    buffers: list[np.ndarray] = []
    buffered = 0
    hist = np.zeros(n_pix * bins, dtype=np.int64)

    def add_time(c, u, dt):
        total = u + dt
        k = np.floor(total / T)
        u2 = total - k * T
        wrap = u2 >= T
        return c + (k + wrap).astype(np.int64), np.clip(np.where(wrap, u2 - T, u2), 0.0, last_phase_value)

    while True:
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        c0, u0, lam_i = cycle[idx], phase[idx], lam[idx]
        cell0 = np.clip(np.searchsorted(edges, u0, side="right") - 1, 0, n_cells - 1)
        r_start = cum[idx, cell0] + (u0 - edges[cell0]) / widths[cell0] * q[idx, cell0]
        target = r_start + rng.standard_exponential(idx.size)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            same = target <= lam_i
            rem = target - lam_i
            skip = np.where(same, 0.0, np.floor(rem / lam_i))
            inner = np.where(same, target, rem - skip * lam_i)
            inner = np.where(np.isfinite(inner), inner, lam_i)
            over = (~same) & (inner > lam_i)
            inner = np.where(over, inner - lam_i, inner)
            new_cycle = c0 + np.where(same, 0.0, 1.0 + skip + over)
        inner = np.clip(inner, tiny, lam_i)
        beyond = ~(new_cycle < n)
        b = row_search(cum, idx, inner)
        with np.errstate(divide="ignore", invalid="ignore"):
            u1 = edges[b] + (inner - cum[idx, b]) / q[idx, b] * widths[b]
        u1 = np.where(beyond, 0.0, np.clip(u1, edges[b], np.nextafter(edges[b + 1], 0.0)))
        c1 = np.where(beyond, float(n), new_cycle).astype(np.int64)
        is_ap = np.zeros(idx.size, dtype=bool)
        if p_ap > 0:
            apc, apu = ap_cycle[idx], ap_phase[idx]
            is_ap = (apc < c1) | ((apc == c1) & (apu < u1))
            c1 = np.where(is_ap, apc, c1)
            u1 = np.where(is_ap, apu, u1)
        done = c1 >= n
        active[idx[done]] = False
        go = ~done
        idx, c1, u1, is_ap = idx[go], c1[go], u1[go], is_ap[go]
        if idx.size == 0:
            continue
        cell1 = np.clip(np.searchsorted(edges, u1, side="right") - 1, 0, n_cells - 1)
        if paralyzable:
            lc, lp = last_cycle[idx], last_phase[idx]
            gap = (c1 - lc).astype(np.float64) * T + (u1 - lp)
            record = (lc < 0) | (gap >= tau)
            last_cycle[idx], last_phase[idx] = c1, u1
            cycle[idx], phase[idx] = c1, u1
        else:
            lost = is_ap & ~gate_ok[cell1]
            record = ~lost
            nc, nu = add_time(c1, u1, tau)
            cycle[idx] = np.where(lost, c1, nc)
            phase[idx] = np.where(lost, u1, nu)
        if p_ap > 0:
            ap_cycle[idx[record | is_ap]] = never
            spawn = record & (rng.random(idx.size) < p_ap)
            if spawn.any():
                delay = tau + tau_ap * rng.standard_exponential(int(spawn.sum()))
                ac, au = add_time(c1[spawn], u1[spawn], delay)
                ap_cycle[idx[spawn]], ap_phase[idx[spawn]] = ac, au
        hist_bin = cell_bin[cell1]
        keep = record & (hist_bin >= 0)
        if keep.any():
            buffers.append(idx[keep] * bins + hist_bin[keep])
            buffered += int(keep.sum())
            if buffered >= EVENT_FLUSH:
                hist += np.bincount(np.concatenate(buffers), minlength=n_pix * bins)
                buffers, buffered = [], 0
    if buffers:
        hist += np.bincount(np.concatenate(buffers), minlength=n_pix * bins)
    return hist.reshape(n_pix, bins)


def _require_model(config: DetectorConfig, model: str) -> None:
    if config.model != model:
        raise ValueError(f"this function needs model={model!r}, got model={config.model!r}")

