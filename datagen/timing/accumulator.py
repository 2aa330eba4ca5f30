"""Time binning of path impulses into envelopes (docs/physics.md §5).

Transport produces path impulses: an arrival time ``tau`` (seconds, float64) and a weight ``w`` (expected
detected photons per laser pulse, float64), each belonging to a component (room, box, pillar, secondary...).
The envelope this module returns holds, for every output bin ``[e_b, e_{b+1})`` of a ``TimeAxis``,

    out_b = sum_i w_i * integral_{e_b}^{e_{b+1}} h(t - tau_i) dt
          = sum_i w_i * [F(e_{b+1} - tau_i) - F(e_b - tau_i)]

with ``h`` the IRF density and ``F`` its CDF (:class:`~datagen.timing.irf.Irf`; for a Gaussian of width sigma,
``F(x) = Phi(x / sigma)``, so a bin is a difference of normal CDFs). Bins are integrals, never the density
sampled at the bin centre (docs/physics.md §5): summing bins gives expected detections per pulse.

Method (docs/physics.md §5), used by :class:`EnvelopeAccumulator`:

1. Impulses are splatted onto a fine grid of nodes (step ``delta = bin_width / oversample``) by linear
   ("cloud-in-cell") weights: an impulse between nodes ``g`` and ``g+1`` at fraction ``u`` gives
   ``w*(1-u)`` to ``g`` and ``w*u`` to ``g+1``. Total weight and the mean time are conserved exactly; the
   only error is an extra variance ``u(1-u)*delta**2 <= delta**2/4`` per impulse, so the relative error of
   the envelope falls as ``(delta/sigma)**2`` (measured in tests/test_irf.py).
2. The fine histogram is convolved ONCE with the fine-cell-integrated IRF ``p_n = F((n+1/2)delta) -
   F((n-1/2)delta)`` (FFT, overlap-add), giving the exact integral of the envelope over each fine cell for
   impulses sitting on nodes; ``oversample`` consecutive cells are summed into one output bin.
3. Narrow IRF (``MARGIN_SIGMAS * sigma`` each side within one bin: sigma <= bin_width / 8.5), where a fine grid
   would need ``oversample >= 34``: each impulse puts its *exact* bin integrals into its bin ``b`` and the two
   neighbours, ``w*F(e_b - tau)`` into ``b-1``, ``w*P(X >= e_{b+1} - tau)`` into ``b+1``, the rest into ``b``
   ("direct" mode: two CDF evaluations per impulse, no splatting error, memory O(n_components * n_bins)).
4. Tents (:meth:`EnvelopeAccumulator.add_tents`, used by the hidden-surface quadrature of
   ``datagen.transport.quadrature``): the pushforward of the area measure of a triangle under a path length that is
   linear on it is a piecewise-linear "tent" density between the sorted vertex times t0 <= t1 <= t2 (peak 2w/(t2-t0)
   at t1). Its deposits are exact: fine-grid nodes receive the tent's integral against their splatting weight (the
   limit of infinitely many impulses splatted as in point 1; delta IRF: over the fine cell) from its closed-form
   second antiderivative; direct-mode bins the tent convolved with the IRF, from the IRF's partial moments
   E[(c-X)_+] and E[(c-X)_+^2]/2 (:mod:`datagen.timing.tents`). A tent of zero span is an impulse.
   :meth:`EnvelopeAccumulator.add_fine` adds node values computed once (a tent's shape) to many components.

Cost is O(paths + fine_nodes * log(kernel)) in time, O(n_components * fine_nodes) in memory; :func:`bin_impulses`
is the exact per-impulse reference (O(paths * bins)). Times in seconds (docs/physics.md §1), weights in photons per
pulse. ``X`` is the IRF delay (detection time minus impulse time); ``Irf.cdf(x)`` is ``P(X < x)``, so half-open bins
``[e_b, e_{b+1})`` are exact, also for the delta IRF.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..threads import threads_for
from .impulses import bin_impulses, check_finite, check_weights, times_weights
from .irf import Irf, TimeAxis
from .curvature import deposit_curvature
from .fold_kernel import bin_weights, convolve_rows, fold_rows, full_bounds, rows_dot
from .splat_kernel import splat_nodes
from .tent_kernel import TentGrid
from .tents import tent_cdf, tent_cdf2, tent_irf_cdf

__all__ = [
    "STEPS_PER_SIGMA",
    "MAX_FINE_NODES",
    "NEGATIVE_CLAMP_RTOL",
    "CURVATURE_MIN_NODES",
    "PARALLEL_MIN_NODES",
    "EnvelopeAccumulator",
    "bin_impulses",
]

STEPS_PER_SIGMA = 4
"""Default fine steps per sigma: linear splatting then broadens by <= (delta/sigma)^2/8 relative (~0.8 %)."""

MAX_FINE_NODES = 1 << 24
"""Cap on fine nodes per component (128 MiB of float64 each) so a bad axis/IRF pair fails loudly, not by OOM."""

NEGATIVE_CLAMP_RTOL = 1e-12
"""FFT round-off is ~1e-16 of the convolution's input, the fine histogram, whose largest node can exceed the
window's envelope by many orders (returns before a gate sit in its guard nodes); negatives within this fraction
of max(|fine histogram|, |envelope|) of their row are set to 0."""

CURVATURE_MIN_NODES = 4.0
"""Fine-grid mode: tents spanning at least this many fine nodes are deposited through their second differences
(:func:`datagen.timing.tents.tent_curvature`, 16 values per tent instead of one evaluation per node covered,
compiled: :func:`datagen.timing.curvature.deposit_curvature`), summed twice along the nodes when the histogram is
read; the same deposits up to round-off (~1e-16 of a tent's weight per node summed, ≤ 1e-11 relative on scans),
so rows holding them clamp negatives within CURVATURE_CLAMP_RTOL of their maximum instead of NEGATIVE_CLAMP_RTOL."""

CURVATURE_CLAMP_RTOL = 1e-9

_CHUNK = 1 << 18     # impulses per internal chunk of EnvelopeAccumulator.add (temporaries of a few MiB)

_DIRECT_KERNEL_MAX = 256
"""Kernels up to this length are convolved directly over each row's non-zero nodes (compiled,
:func:`datagen.timing.fold_kernel.bin_rows`; exact, no FFT noise); longer ones by overlap-add FFT."""

PARALLEL_MIN_NODES = 1 << 25
"""Fine grids of at least this many nodes (all components; 256 MiB of float64: the 128 × 128 scans) fold, bin and
sum their rows on numba's threads (:func:`datagen.threads.threads_for`), smaller ones on one: the same result."""

_TENT_ROWS = 1 << 21     # evaluation rows (tents × nodes they cover) processed at once by add_tents

_DIRECT_GUARD_BINS = 2
"""Direct (narrow-IRF) mode: bins kept each side of the window (an impulse in bin b touches b-1..b+1)."""


# ------------------------------------------------------------------------------------------------- tents


def _rows(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flattened (owner, k) rows: owner i repeated counts[i] times, k = 0 .. counts[i]-1."""
    owner = np.repeat(np.arange(len(counts)), counts)
    start = np.cumsum(counts) - counts
    return owner, np.arange(int(counts.sum()), dtype=np.int64) - start[owner]


class EnvelopeAccumulator:
    """Accumulate path impulses of several components into binned envelopes (docs/physics.md §5).

    Holds a float64 fine histogram, shape (n_components, n_fine), of node step ``fine_step = bin_width /
    oversample``. Node ``g`` sits at ``t_start + (g - n_left + 1/2) * fine_step``, i.e. at the centres of
    fine cells that tile the axis exactly; the grid extends ``n_left`` nodes before the window (the IRF's
    ``after`` support, so tails of earlier impulses reach in) and ``n_right`` nodes after it (its
    ``before`` support). Impulses farther outside are counted wholly in :meth:`outside` and their IRF tails
    are ignored: their true in-window mass is below Phi(-MARGIN_SIGMAS) of their weight (< 1e-15).

    Splatting is linear (cloud-in-cell) between nodes for sigma > 0, nearest-cell for the delta IRF (so an
    impulse lands exactly in the bin that contains it, up to float rounding of the edges).

    Narrow IRFs (``max(irf.support) <= bin_width`` and ``oversample`` not given; see the module doc, point
    3) use the exact *direct* mode instead (:attr:`direct` is True): then ``oversample == 1``, the "fine"
    nodes are the bin centres with two guard bins on each side (``n_left == n_right == 2``), the histogram
    holds exact bin integrals and the kernel is the identity.

    Args:
        axis: output time axis.
        irf: instrument response.
        n_components: number of components (ids 0 .. n_components-1), >= 1.
        oversample: fine nodes per output bin (int >= 1). Default: the smallest value giving
            ``fine_step <= sigma / STEPS_PER_SIGMA`` (1 for the delta IRF). Linear splatting makes the
            envelope's relative error ~ (fine_step / sigma)^2 (see tests/test_irf.py for measured values).

    Raises:
        ValueError: n_components < 1, oversample < 1, or the fine grid would exceed MAX_FINE_NODES nodes per
            component (the message names the axis, the IRF and the oversample).
    """

    def __init__(self, axis: TimeAxis, irf: Irf, n_components: int, oversample: int | None = None) -> None:
        if isinstance(n_components, bool) or int(n_components) != n_components or n_components < 1:
            raise ValueError(f"n_components must be an integer >= 1, got n_components={n_components!r}")
        self.direct, self.oversample, self.n_left, self.n_right = self.fine_grid(axis, irf, oversample)
        self.axis = axis
        self.irf = irf
        self.n_components = int(n_components)
        self.fine_step = axis.bin_width / self.oversample
        self.n_cells = axis.n_bins * self.oversample
        self.n_fine = self.n_cells + self.n_left + self.n_right
        if self.n_fine > MAX_FINE_NODES:
            raise ValueError(
                f"fine grid too large: {self.n_fine} nodes per component > MAX_FINE_NODES={MAX_FINE_NODES} for "
                f"axis(t_start={axis.t_start!r}, bin_width={axis.bin_width!r}, n_bins={axis.n_bins}), "
                f"irf(kind={irf.kind!r}, sigma={irf.sigma!r}, tail={irf.tail!r}), oversample={self.oversample} "
                f"(margins {self.n_left}+{self.n_right} nodes); use wider bins, a shorter axis or a smaller "
                f"oversample"
            )
        offsets = np.arange(-self.n_right, self.n_left + 1, dtype=np.float64)
        if self.direct:  # the histogram already holds bin integrals
            self._kernel = (offsets == 0).astype(np.float64)
        else:
            # Fine-cell-integrated IRF: p[n + n_right] = P((n - 1/2) delta <= X < (n + 1/2) delta).
            self._kernel = irf.interval_mass((offsets - 0.5) * self.fine_step, (offsets + 0.5) * self.fine_step)
        # the binning weights of the compiled direct convolution (long kernels take the FFT instead)
        self._bin_table = (bin_weights(self._kernel, self.oversample) if self._kernel.size <= _DIRECT_KERNEL_MAX
                           else None)
        self._hist = np.zeros((self.n_components, self.n_fine), dtype=np.float64)
        # per row the nodes [lo, hi) outside which it holds zeros (widened by the compiled deposits, the whole row
        # after any other deposit): the fold, binning and sums read only inside it (datagen.timing.fold_kernel)
        self._bound = np.zeros((self.n_components, 2), dtype=np.int64)
        self._bound[:, 0] = self.n_fine                     # empty: [n_fine, 0)
        self._total = np.zeros(self.n_components, dtype=np.float64)
        self._beyond = np.zeros(self.n_components, dtype=np.float64)
        self._binned: np.ndarray | None = None
        self._curvature: np.ndarray | None = None          # second differences of wide tents' deposits
        self._clamp_rtol = NEGATIVE_CLAMP_RTOL
        self.curvature_min_nodes = CURVATURE_MIN_NODES      # inf: every tent by its per-node closed form

    @classmethod
    def fine_grid(cls, axis: TimeAxis, irf: Irf, oversample: int | None = None) -> tuple[bool, int, int, int]:
        """(direct mode?, oversample, n_left, n_right) for ``axis`` and ``irf``: the fine grid holds
        ``axis.n_bins * oversample + n_left + n_right`` nodes per component (resource estimates call this before
        allocating). Raises ValueError: ``oversample`` not an integer >= 1."""
        before, after = irf.support
        # Narrow IRF: exact per-bin deposit instead of an oversample >= 34 fine grid (module doc, point 3).
        direct = oversample is None and not irf.is_delta and max(before, after) <= axis.bin_width
        if oversample is None:
            oversample = 1 if direct else cls.default_oversample(axis, irf)
        if isinstance(oversample, bool) or int(oversample) != oversample or oversample < 1:
            raise ValueError(f"oversample must be an integer >= 1, got oversample={oversample!r}")
        oversample = int(oversample)
        if direct:
            return True, oversample, _DIRECT_GUARD_BINS, _DIRECT_GUARD_BINS
        fine_step = axis.bin_width / oversample
        return False, oversample, int(math.ceil(after / fine_step)), int(math.ceil(before / fine_step))

    @staticmethod
    def default_oversample(axis: TimeAxis, irf: Irf) -> int:
        """Smallest oversample with ``bin_width / oversample <= sigma / STEPS_PER_SIGMA`` (1 if sigma = 0)."""
        if irf.is_delta:
            return 1
        ratio = axis.bin_width * STEPS_PER_SIGMA / irf.sigma
        return max(1, int(math.ceil(ratio * (1.0 - 1e-12))))

    @property
    def fine_times(self) -> np.ndarray:
        """Fine node times, shape (n_fine,), float64 seconds."""
        g = np.arange(self.n_fine, dtype=np.float64)
        return self.axis.t_start + (g - self.n_left + 0.5) * self.fine_step

    def _components(self, component: Any, n: int) -> int | np.ndarray:
        if np.ndim(component) == 0:
            c = component
            if isinstance(c, (bool, np.bool_)) or not isinstance(c, (int, np.integer)):
                raise ValueError(f"component must be an integer id, got component={component!r}")
            if not 0 <= int(c) < self.n_components:
                raise ValueError(f"component must be in [0, {self.n_components}), got component={int(c)}")
            return int(c)
        c = np.asarray(component).reshape(-1)
        if not np.issubdtype(c.dtype, np.integer):
            raise ValueError(f"component array must have an integer dtype, got {c.dtype}")
        if c.size != n:
            raise ValueError(f"component array must have the same length as times, got {c.size} and {n}")
        return c

    def add(self, times: Any, weights: Any, component: int | np.ndarray = 0) -> None:
        """Add impulses: arrival ``times`` (s) with ``weights`` (photons per pulse) to ``component``.

        Args:
            times: any length, float64-convertible seconds (flattened).
            weights: same length (or a scalar), >= 0; zero weights are ignored.
            component: one integer id for all impulses, or an integer array of ids, one per impulse.

        Accumulates with ``np.add.at`` in float64, in internal chunks of ``_CHUNK`` impulses, so temporary
        memory is bounded whatever the input length. The whole input is validated before anything is added,
        so a rejected call leaves the accumulator unchanged.

        Raises:
            ValueError: NaN/inf in times or weights (message names which, the count and the first index),
                negative weights, mismatched lengths, component ids out of range or not integers.
        """
        t, w = times_weights(times, weights)
        comp = self._components(component, t.size)
        for start in range(0, t.size, _CHUNK):
            check_finite(np.asarray(t[start : start + _CHUNK], dtype=np.float64), "times", start)
            check_weights(np.asarray(w[start : start + _CHUNK], dtype=np.float64), start)
            if not isinstance(comp, int):
                cb = comp[start : start + _CHUNK]
                if cb.size and (cb.min() < 0 or cb.max() >= self.n_components):
                    bad = int(cb[(cb < 0) | (cb >= self.n_components)][0])
                    raise ValueError(f"component ids must be in [0, {self.n_components}), got {bad}")
        if t.size == 0:
            return
        self._binned = None
        self._unbound()
        flat = self._hist.reshape(-1)
        for start in range(0, t.size, _CHUNK):
            tb = np.asarray(t[start : start + _CHUNK], dtype=np.float64)
            wb = np.asarray(w[start : start + _CHUNK], dtype=np.float64)
            cb = comp if isinstance(comp, int) else comp[start : start + _CHUNK].astype(np.int64, copy=False)
            if self.direct:                       # the compiled splat skips zero weights itself
                keep = wb != 0
                tb, wb, cb = tb[keep], wb[keep], (cb if isinstance(cb, int) else cb[keep])
                if tb.size == 0:
                    continue
            self._splat(flat, tb, wb, cb)

    def _component_sums(self, w: np.ndarray, c: int | np.ndarray) -> np.ndarray:
        if isinstance(c, int):
            sums = np.zeros(self.n_components, dtype=np.float64)
            sums[c] = w.sum()
            return sums
        return np.bincount(c, weights=w, minlength=self.n_components)

    def _splat_direct(self, flat: np.ndarray, t: np.ndarray, w: np.ndarray, c: int | np.ndarray) -> None:
        """Direct mode: exact bin integrals into the containing bin b and its neighbours (module doc, 3)."""
        t0, width = self.axis.t_start, self.axis.bin_width
        with np.errstate(over="ignore", invalid="ignore"):
            b = np.floor((t - t0) / width)
        inside = (b >= -1) & (b <= self.axis.n_bins)
        if not inside.all():
            out = ~inside
            self._beyond += self._component_sums(w[out], c if isinstance(c, int) else c[out])
            t, w, b = t[inside], w[inside], b[inside]
            if not isinstance(c, int):
                c = c[inside]
        # Same edge formula as TimeAxis.edges, so a rounded floor() is corrected by the CDFs themselves.
        left = w * self.irf.cdf(t0 + b * width - t)              # X < e_b - tau: bin b-1
        right = w * self.irf.sf(t0 + (b + 1.0) * width - t)      # X >= e_{b+1} - tau: bin b+1
        idx = c * self.n_fine + b.astype(np.int64) + self.n_left
        np.add.at(flat, idx - 1, left)
        np.add.at(flat, idx, w - left - right)
        np.add.at(flat, idx + 1, right)

    def _splat(self, flat: np.ndarray, t: np.ndarray, w: np.ndarray, c: int | np.ndarray) -> None:
        if self.direct:
            self._total += self._component_sums(w, c)
            self._splat_direct(flat, t, w, c)
            return
        per_impulse = np.zeros(0, np.int64) if isinstance(c, int) else np.ascontiguousarray(c, dtype=np.int64)
        splat_nodes(flat, self._total, self._beyond, np.ascontiguousarray(t, dtype=np.float64),
                    np.ascontiguousarray(w, dtype=np.float64), per_impulse, c if isinstance(c, int) else 0,
                    float(self.axis.t_start), float(self.fine_step), self.n_left, self.n_fine, self.irf.is_delta)

    def add_tents(self, times: Any, weights: Any, component: int | np.ndarray = 0) -> None:
        """Add tent densities: for each row of ``times`` (n, 3), the path times (s) at a triangle's vertices,
        the pushforward of a uniform density of total ``weights`` (photons per pulse) over the triangle when
        the path time is linear on it (module doc, point 4), to ``component``.

        The deposits are the exact limit of infinitely many impulses spread over the tent and added with
        :meth:`add`: per fine node the integral of the tent against its linear splatting weight (the delta IRF:
        over its fine cell); in the direct mode the exact bin integrals of the tent convolved with the IRF. A
        row with t0 = t1 = t2 is an impulse. Mass beyond the fine grid (direct mode: the guard bins) is counted
        in :meth:`outside`, as for impulses.

        Args:
            times: (n, 3) float64-convertible seconds, the vertex times in any order.
            weights: (n,) or a scalar, >= 0 (photons per pulse); zero weights are ignored.
            component: one integer id for all tents, or an integer array of ids, one per tent.

        Raises:
            ValueError: times not of shape (n, 3), NaN/inf in times or weights, negative weights, mismatched
                lengths, component ids out of range or not integers (as :meth:`add`).
        """
        t = np.asarray(times)
        if t.ndim != 2 or t.shape[1] != 3:
            raise ValueError(f"times must have shape (n, 3) (vertex times of each triangle), got {t.shape}")
        _, w = times_weights(t[:, 0], weights)
        comp = self._components(component, len(t))
        t = t.astype(np.float64)
        check_finite(t.reshape(-1), "times")
        check_weights(np.asarray(w, dtype=np.float64))
        if not isinstance(comp, int) and comp.size and (comp.min() < 0 or comp.max() >= self.n_components):
            bad = int(comp[(comp < 0) | (comp >= self.n_components)][0])
            raise ValueError(f"component ids must be in [0, {self.n_components}), got {bad}")
        keep = np.asarray(w, dtype=np.float64) != 0
        if not keep.any():
            return
        self._binned = None
        self._unbound()
        t = np.sort(t[keep], axis=1)
        w = np.asarray(w, dtype=np.float64)[keep]
        comp = comp if isinstance(comp, int) else comp[keep].astype(np.int64)
        self._total += self._component_sums(w, comp)
        flat = self._hist.reshape(-1)
        with np.errstate(over="ignore", invalid="ignore"):
            if self.direct:
                before, after = self.irf.support
                lo = np.floor((t[:, 0] - before - self.axis.t_start) / self.axis.bin_width) + self.n_left
                hi = np.floor((t[:, 2] + after - self.axis.t_start) / self.axis.bin_width) + self.n_left
                coord = None
            else:
                shift = self.n_left if self.irf.is_delta else self.n_left - 0.5
                coord = (t - self.axis.t_start) / self.fine_step + shift         # node / cell coordinates
                lo = np.floor(coord[:, 0])
                hi = np.floor(coord[:, 2]) if self.irf.is_delta else np.ceil(coord[:, 2])
        # tents wholly outside the grid (or absurdly far: overflowing coordinates) count as beyond
        inside = np.isfinite(lo) & np.isfinite(hi) & (hi >= 0) & (lo <= self.n_fine - 1)
        if not inside.all():
            out = ~inside
            self._beyond += self._component_sums(w[out], comp if isinstance(comp, int) else comp[out])
            t, w, lo, hi = t[inside], w[inside], lo[inside], hi[inside]
            coord = None if coord is None else coord[inside]
            if not isinstance(comp, int):
                comp = comp[inside]
        clipped = (lo < 0) | (hi > self.n_fine - 1)
        if coord is not None and not self.irf.is_delta:             # wide tents: O(1) curvature deposits
            wide = (coord[:, 2] - coord[:, 0] >= self.curvature_min_nodes) & (lo >= 1) & (hi + 2 <= self.n_fine - 1)
            if wide.any():
                self._add_curvature(coord[wide], w[wide], comp if isinstance(comp, int) else comp[wide])
                keep = ~wide
                t, w, lo, hi, coord, clipped = t[keep], w[keep], lo[keep], hi[keep], coord[keep], clipped[keep]
                comp = comp if isinstance(comp, int) else comp[keep]
        first = np.maximum(lo, 0).astype(np.int64)
        last = np.minimum(hi, self.n_fine - 1).astype(np.int64)
        # evaluation points per tent: edges first..last+1 (cells, bins) or nodes first-1..last+1 (splat weights)
        extra = 2 if (self.direct or self.irf.is_delta) else 3
        counts = last - first + extra
        ends = np.cumsum(counts)
        group = 0
        while group < len(counts):
            base = ends[group - 1] if group else 0
            stop = max(group + 1, int(np.searchsorted(ends, base + _TENT_ROWS, side="right")))
            sel = slice(group, stop)
            self._tent_rows(flat, t[sel], w[sel], comp if isinstance(comp, int) else comp[sel], first[sel],
                            counts[sel], None if coord is None else coord[sel], clipped[sel])
            group = stop

    def tent_grid(self) -> TentGrid | None:
        """The fine grid as arrays for compiled tent deposits (:func:`datagen.timing.tent_kernel.deposit_tent`,
        the same deposits as :meth:`add_tents`), or None in the direct and delta-IRF modes. The views stay valid
        until the histogram is read (:meth:`binned`, :meth:`fine_histogram`, :meth:`outside`, :meth:`merge`)."""
        if self.direct or self.irf.is_delta:
            return None
        if self._curvature is None:
            self._curvature = np.zeros(self._hist.shape)     # calloc: pages untouched until written
        self._binned = None
        return TentGrid(float(self.axis.t_start), float(self.fine_step), self.n_left - 0.5, int(self.n_fine),
                        float(self.curvature_min_nodes), self._hist.reshape(-1), self._curvature.reshape(-1),
                        self._total, self._beyond, self._bound)

    def _unbound(self) -> None:
        """Every row read whole from now on (a deposit that does not widen :attr:`_bound`)."""
        self._bound[:, 0] = 0
        self._bound[:, 1] = self.n_fine

    def _add_curvature(self, coord: np.ndarray, w: np.ndarray, c: int | np.ndarray) -> None:
        if self._curvature is None:
            self._curvature = np.zeros(self._hist.shape)     # calloc: pages untouched until written
        comp = np.full(len(w), c, dtype=np.int64) if isinstance(c, int) else c
        deposit_curvature(coord, w, comp, self.n_fine, self._curvature.reshape(-1))

    def _fold(self) -> np.ndarray:
        """The fine histogram with the pending curvature deposits summed in (twice along the nodes)."""
        if self._curvature is not None:
            with threads_for(self._hist.size, PARALLEL_MIN_NODES):
                fold_rows(self._hist, self._curvature, self._bound)   # each row over its pending second differences
            self._curvature = None
            self._clamp_rtol = CURVATURE_CLAMP_RTOL
        return self._hist

    def _tent_rows(self, flat: np.ndarray, t: np.ndarray, w: np.ndarray, c: int | np.ndarray, first: np.ndarray,
                   counts: np.ndarray, coord: np.ndarray | None, clipped: np.ndarray) -> None:
        """Deposit tents (sorted times t (n, 3), weights w (n,)) onto the nodes first .. first+counts-extra.

        A cumulative quantity C is evaluated at consecutive positions p of each tent and node p receives
        w·(C(p+1) − C(p)): C is the unit tent's P(T < edge) at cell edges (delta IRF), P(T + X < e_b) at bin
        edges (direct mode), or the first difference D(p) = F2(p) − F2(p−1) of the tent's second antiderivative
        at node coordinates (linear splatting: D(g+1) − D(g) = ∫ tent(y) max(0, 1 − |y − g|) dy).
        """
        owner, k = _rows(counts)
        pos = first[owner] + k
        if self.direct:
            # node g's lower edge is bin (g − n_left)'s, at t_start + b·bin_width as in TimeAxis.edges
            edge = self.axis.t_start + (pos - self.n_left).astype(np.float64) * self.axis.bin_width
            ta, tb, tc = t[owner, 0], t[owner, 1], t[owner, 2]
            before, after = self.irf.support
            cum = np.where(edge <= ta - before, 0.0,
                           np.where(edge >= tc + after, 1.0, tent_irf_cdf(self.irf, edge, ta, tb, tc)))
        else:
            base = np.floor(coord[:, 0])
            a = coord - base[:, None]                                  # local coordinates: small numbers
            if self.irf.is_delta:
                cum = tent_cdf((pos - base[owner]).astype(np.float64), a[owner, 0], a[owner, 1], a[owner, 2])
            else:
                pos = pos - 1
                f2 = tent_cdf2((pos - base[owner]).astype(np.float64), a[owner, 0], a[owner, 1], a[owner, 2])
                later = k > 0                                          # D(p) needs F2 at p − 1 of the same tent
                cum = (f2 - np.concatenate([[0.0], f2[:-1]]))[later]
                owner, pos = owner[later], pos[later]
        same = owner[1:] == owner[:-1]
        mass = np.maximum((cum[1:] - cum[:-1])[same], 0.0)             # round-off below 0 (~1e-17 w) → 0
        node, own = pos[:-1][same], owner[:-1][same]
        mass = mass * w[own]
        idx = (c if isinstance(c, int) else c[own]) * self.n_fine + node
        if len(idx):
            lo = int(idx.min())
            part = np.bincount(idx - lo, weights=mass)
            flat[lo:lo + len(part)] += part
        if clipped.any():
            deposited = np.bincount(own, weights=mass, minlength=len(w))
            lost = np.where(clipped, np.maximum(w - deposited, 0.0), 0.0)
            self._beyond += self._component_sums(lost, c)

    def __setstate__(self, state: dict) -> None:
        """Unpickling (a replica sent to or from a worker process): numpy gives each unpickled array a fresh dtype
        instance (numpy/numpy#32298), which takes ``np.add.at`` off its fast path; arrays are re-viewed with the
        canonical dtype (no copy)."""
        self.__dict__.update({k: v.view(np.dtype(v.dtype.str)) if isinstance(v, np.ndarray) else v
                              for k, v in state.items()})

    def spawn(self, n_components: int | None = None) -> "EnvelopeAccumulator":
        """An empty accumulator on the same axis, IRF and fine grid (a partial sum), with n_components or these."""
        return EnvelopeAccumulator(self.axis, self.irf, n_components or self.n_components,
                                   None if self.direct else self.oversample)

    def add_fine(self, rows: np.ndarray, component: np.ndarray, start: int, total: np.ndarray,
                 beyond: np.ndarray) -> None:
        """Add ``rows`` (k, m) float64, this grid's own node values (e.g. a weight × a :meth:`fine_histogram` row of a
        :meth:`spawn` that received one unit tent), to nodes ``start … start + m − 1`` of the distinct components
        ``component`` (k,) int, standing for ``total`` (k,) photons of which ``beyond`` (k,) lie outside the grid.
        Raises ValueError for shapes that do not fit, repeated or out-of-range components."""
        rows = np.asarray(rows, dtype=np.float64)
        component = np.asarray(component, dtype=np.int64)
        if (rows.ndim != 2 or len(component) != len(rows) or start < 0 or start + rows.shape[1] > self.n_fine
                or len(component) and (component.min() < 0 or component.max() >= self.n_components
                                       or len(np.unique(component)) != len(component))):
            raise ValueError(f"add_fine: rows {rows.shape} at node {start} need distinct components in [0, "
                             f"{self.n_components}) and nodes in [0, {self.n_fine})")
        self._binned = None
        self._unbound()
        c0 = int(component[0]) if len(component) else 0            # consecutive components: a block, no gather
        at = slice(c0, c0 + len(component)) if np.array_equal(component, c0 + np.arange(len(component))) else component
        self._hist[at, start:start + rows.shape[1]] += rows
        self._total += np.bincount(component, weights=total, minlength=self.n_components)
        self._beyond += np.bincount(component, weights=beyond, minlength=self.n_components)

    def clear(self, components: np.ndarray) -> None:
        """Remove everything added to ``components`` (k,) int (a restarted estimator's rows), as if never added."""
        rows = np.asarray(components, dtype=np.int64)
        self._fold()
        self._binned = None
        self._hist[rows], self._total[rows], self._beyond[rows] = 0.0, 0.0, 0.0
        self._bound[rows] = (self.n_fine, 0)

    def merge(self, other: "EnvelopeAccumulator") -> None:
        """Add a partial accumulator from :meth:`spawn` (same grid) into this one.

        Raises:
            ValueError: the grids differ.
        """
        if (other._hist.shape != self._hist.shape or other.fine_step != self.fine_step
                or other.direct != self.direct):
            raise ValueError(f"cannot merge accumulators with different grids: {other._hist.shape} vs "
                             f"{self._hist.shape}")
        self._binned = None
        self._fold()
        self._hist += other._fold()
        self._bound[:, 0] = np.minimum(self._bound[:, 0], other._bound[:, 0])
        self._bound[:, 1] = np.maximum(self._bound[:, 1], other._bound[:, 1])
        self._clamp_rtol = max(self._clamp_rtol, other._clamp_rtol)
        self._total += other._total
        self._beyond += other._beyond

    def total_weight(self) -> np.ndarray:
        """Everything added per component (inside the window or not), shape (n_components,), float64 photons."""
        return self._total.copy()

    def fine_histogram(self) -> np.ndarray:
        """Copy of the splatted fine histogram, shape (n_components, n_fine), float64 photons per node.

        In direct mode (narrow IRF) the nodes are the bin centres (2 guard bins each side) and each holds the
        exact integral of the envelope over its bin.
        """
        return self._fold().copy()

    def binned(self, copy: bool = True) -> np.ndarray:
        """Binned envelopes, shape (n_components, n_bins), float64 photons per pulse per bin.

        Each bin holds the integral over its edges of sum_i w_i h(t - tau_i) (docs/physics.md §5), exact for
        impulses on fine nodes; for others the linear-splatting error is ~ (fine_step / sigma)^2 relative.
        The convolution runs by overlap-add FFT (direct for kernels <= _DIRECT_KERNEL_MAX taps), whose
        round-off is ~1e-16 of the component's maximum: bins far below that in a tail are not accurate.
        Negative round-off no larger than NEGATIVE_CLAMP_RTOL * max (CURVATURE_CLAMP_RTOL after wide tents) is
        set to 0. ``copy`` False: the accumulator's own array (read only: it is kept for later calls). Raises
        RuntimeError for a value more negative than the clamp threshold (impossible for weights >= 0: a bug).
        """
        if self._binned is None:
            self._binned = self._convolve_rows(self._fold(), self._bound)
        return self._binned.copy() if copy else self._binned

    def binned_total(self, n_channels: int = 1, channels: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n_channels, n_bins) ``binned()`` summed over components (ids ``component * n_channels + channel``),
        one convolution per channel, rows ``channels`` (an index array or a slice) only. With one component per
        channel the rows are binned where they are (no summed copy: a sum of one term is that term). Raises
        ValueError if ``n_channels`` does not divide ``n_components``."""
        if n_channels < 1 or self.n_components % n_channels:
            raise ValueError(f"n_channels {n_channels} does not divide the {self.n_components} components")
        hist = self._fold()
        rows = np.arange(n_channels)[channels]
        if self.n_components == n_channels and np.all(np.diff(rows) > 0):
            return self._convolve_rows(hist, self._bound, rows)
        summed = hist.reshape(-1, n_channels, self._hist.shape[-1])[:, channels].sum(0)
        return self._convolve_rows(summed, full_bounds(len(summed), summed.shape[-1]))

    def _convolve_rows(self, hist: np.ndarray, bound: np.ndarray, select: np.ndarray | None = None) -> np.ndarray:
        """Rows (rows, n_fine) of fine histograms binned as :meth:`binned` describes
        (:func:`datagen.timing.fold_kernel.convolve_rows`: the compiled direct convolution for kernels up to
        ``_DIRECT_KERNEL_MAX`` taps, else overlap-add FFT), each read within its ``bound``; ``select``: ascending
        distinct row indices, the output's rows (default: every row)."""
        with threads_for(hist.size, PARALLEL_MIN_NODES):   # the compiled row kernels' threads
            return convolve_rows(hist, bound, self._kernel, self._bin_table, self.oversample, self.axis.n_bins,
                                 self._clamp_rtol, select)

    def outside(self) -> np.ndarray:
        """Weight per component whose IRF-smeared mass falls outside the window, shape (n_components,).

        Sum of (a) the weight of impulses beyond the fine grid (wholly counted, tails ignored; see class
        doc) and (b) for each fine node g, s_g * [P(X < t_start - t_g) + P(X >= t_stop - t_g)] computed
        exactly from the IRF CDF / survival function. Hence ``binned().sum(-1) + outside() ==
        total_weight()`` up to float round-off and the IRF mass beyond its support (< 1e-15 relative).
        """
        result = self._beyond.copy()
        self._fold()
        if self.direct:  # guard bins hold exact out-of-window bin integrals
            return result + self._hist[:, : self.n_left].sum(1) + self._hist[:, self.n_left + self.n_cells :].sum(1)
        # the same fraction for node g in every component: one evaluation per node (nodes with no weight add 0)
        g = np.arange(self.n_fine)
        # Offsets in fine steps from node g to the window edges (exact integers before scaling).
        lo = (self.n_left - 0.5 - g) * self.fine_step
        hi = (self.n_cells + self.n_left - 0.5 - g) * self.fine_step
        frac = self.irf.cdf(lo) + self.irf.sf(hi)
        with threads_for(self._hist.size, PARALLEL_MIN_NODES):
            return result + rows_dot(self._hist, frac, self._bound)

