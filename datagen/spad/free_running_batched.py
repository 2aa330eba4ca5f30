"""Batched exact simulation of a free-running SPAD without afterpulsing (docs/physics.md §6): the same process
as :func:`datagen.spad.free_running.event_simulation`, vectorised over all avalanches of a segment of cycles."""
from __future__ import annotations

import numpy as np

from .arrays import check_event_count
from .config import DetectorConfig
from .free_running import event_simulation, free_running_expected, period_cells
from .models import DetectorModel, register_model

__all__ = ["TICKS_PER_PERIOD", "EVENT_SEGMENT_ARRIVALS", "event_simulation_batched"]


TICKS_PER_PERIOD = 1 << 24
"""Time resolution of the batched free-running simulator: the period is split into 2**24 integer ticks
(3 fs at 20 MHz), so that sorting and dead-time comparisons are exact integer operations."""

EVENT_SEGMENT_ARRIVALS = 4_000_000
"""Expected avalanches (all pixels) generated per segment of the batched free-running simulator."""


def _dead_time_path(key: np.ndarray, pix: np.ndarray, dead: int, start: np.ndarray) -> np.ndarray:
    """Indices of the avalanches recorded by a non-paralyzable detector.

    ``key`` (A,) int64 sorted times (pixel-offset ticks), ``pix`` (A,) pixel of each, ``start`` (pixels,) index
    of each pixel's first recorded avalanche (A: none).  next[k] = first avalanche of the same pixel at or after
    key[k] + dead; the recorded ones are the path start → next → next …, enumerated for all pixels at once by
    pointer doubling (level m adds the nodes 2^m steps further), O(A log L)."""
    size = key.size
    nxt = np.searchsorted(key, key + dead, side="left")
    bad = nxt >= size
    nxt[bad] = size
    ok = ~bad
    ok[ok] = pix[nxt[ok]] == pix[ok]
    nxt[~ok] = size
    jump = np.append(nxt, size)
    nodes = start[start < size]
    while True:
        add = jump[nodes]
        add = add[add < size]
        if add.size == 0:
            return nodes
        nodes = np.concatenate([nodes, add])
        jump = jump[jump]


def event_simulation_batched(r2: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    """Exact free-running simulation without afterpulsing, in segments of whole cycles, vectorised over all
    avalanches.  Avalanche counts per (pixel, cell, segment) are Poisson(S·q); positions are uniform within the
    cell (constant intensity there) and the cycle uniform within the segment; times are integer ticks
    (TICKS_PER_PERIOD per period).  Non-paralyzable dead time: :func:`_dead_time_path`; paralyzable: an avalanche
    is recorded iff the previous avalanche of that pixel is ≥ τ earlier.  State (live-from / last avalanche)
    carries across segments, so the result is the same process as :func:`event_simulation`.

    Args:
        r2: float64 (pixels, bins) expected avalanches per laser cycle in each histogram bin (window
            ``config.bin_edges(bins)``, s; outside it the rate is ``background_rate`` × gate), ≥ 0 (not checked).
        config: detector description (period, cycles, dead_time in s, paralyzable, gate); afterpulsing is
            ignored (use :func:`event_simulation`).
        rng: numpy Generator (advanced by the call).
    Returns:
        int64 (pixels, bins) recorded detections per bin over ``config.cycles`` laser periods.
    Raises:
        ValueError: the histogram window exceeds the laser period; more expected avalanches than
            MAX_SIMULATED_EVENTS (:func:`datagen.spad.arrays.check_event_count`).
    """
    edges, q, cell_bin = period_cells(r2, config)
    n_pix, n_cells = q.shape
    bins = r2.shape[1]
    n, T = config.cycles, config.period
    check_event_count(float(q.sum()) * n, "free_running event simulation")
    dead = int(round(config.dead_time / T * TICKS_PER_PERIOD))
    total_rate = float(q.sum())
    hist = np.zeros(n_pix * bins, dtype=np.int64)
    if total_rate == 0.0 or n_pix == 0:
        return hist.reshape(n_pix, bins)
    max_cycles_by_overflow = (np.iinfo(np.int64).max // 4) // (max(n_pix, 1) * TICKS_PER_PERIOD) - 2
    seg = int(max(1, min(n, EVENT_SEGMENT_ARRIVALS / total_rate, max_cycles_by_overflow)))
    cell_lo = np.floor(edges[:-1] / T * TICKS_PER_PERIOD).astype(np.int64)
    cell_span = np.maximum(np.floor(edges[1:] / T * TICKS_PER_PERIOD).astype(np.int64) - cell_lo, 1)
    never = np.iinfo(np.int64).min // 4
    carry = np.full(n_pix, never, dtype=np.int64)  # live-from (non-paralyzable) or last avalanche, in ticks
    paralyzable = config.paralyzable
    pix_ids = np.arange(n_pix, dtype=np.int64)
    done = 0
    while done < n:
        s = min(seg, n - done)
        span = s * TICKS_PER_PERIOD
        big = span + TICKS_PER_PERIOD
        counts = rng.poisson(s * q).ravel()
        flat = np.repeat(np.arange(counts.size, dtype=np.int64), counts)
        pix, cell = np.divmod(flat, n_cells)
        local = (rng.integers(0, s, flat.size, dtype=np.int64) * TICKS_PER_PERIOD + cell_lo[cell]
                 + (rng.random(flat.size) * cell_span[cell]).astype(np.int64))
        key = pix * big + local
        order = np.argsort(key, kind="stable")
        key, pix, cell, local = key[order], pix[order], cell[order], local[order]
        if paralyzable:
            prev = np.empty_like(local)
            prev[1:] = local[:-1]
            first = np.ones(key.size, dtype=bool)
            first[1:] = pix[1:] != pix[:-1]
            prev[first] = carry[pix[first]]
            recorded = np.flatnonzero((local - prev) >= dead)
            if key.size:
                last = np.ones(key.size, dtype=bool)
                last[:-1] = pix[1:] != pix[:-1]
                carry[pix[last]] = local[last]
        else:
            start = np.searchsorted(key, pix_ids * big + np.maximum(carry, 0), side="left")
            valid = start < key.size
            valid[valid] = pix[start[valid]] == pix_ids[valid]
            start[~valid] = key.size
            recorded = _dead_time_path(key, pix, dead, start)
            if recorded.size:
                rec_pix = pix[recorded]
                last_local = np.full(n_pix, never, dtype=np.int64)
                np.maximum.at(last_local, rec_pix, local[recorded])
                has = last_local > never
                carry[has] = last_local[has] + dead
        carry = np.where(carry > never, carry - span, never)
        carry = np.maximum(carry, never)
        hb = cell_bin[cell[recorded]]
        inside = hb >= 0
        hist += np.bincount(pix[recorded][inside] * bins + hb[inside], minlength=n_pix * bins)
        done += s
    return hist.reshape(n_pix, bins)


# -- registry entry (datagen/spad/models.py), where both samplers are in reach: (..., T) rates in and out -----

def _expected(rates: np.ndarray, config: DetectorConfig) -> np.ndarray:
    per_cycle, _ = free_running_expected(rates.reshape(-1, rates.shape[-1]), config)
    return (config.cycles * per_cycle).reshape(rates.shape)


def _sample(rates: np.ndarray, config: DetectorConfig, rng: np.random.Generator) -> np.ndarray:
    rows = rates.reshape(-1, rates.shape[-1])
    if config.afterpulse_probability > 0:
        return event_simulation(rows, config, rng).reshape(rates.shape)
    return event_simulation_batched(rows, config, rng).reshape(rates.shape)


register_model(DetectorModel("free_running", _expected, _sample, dead_time="free_running", fittable=True,
                             paralyzable=True, afterpulsing=True,
                             description="dead time across laser cycles (Rapp et al. 2019), afterpulsing"))
