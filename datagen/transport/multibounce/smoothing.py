"""The tracer's smoothing of the smooth orders (:class:`~datagen.transport.multibounce.tracer.MultibounceTracer`):
a kernel estimate in time, and across a confocal scan's points, with its bias estimated and counted
(docs/physics.md §2, "Light of every order"; docs/accuracy.md).

- :func:`default_smoothing`: the node spacing Δ for a bin width and a tolerance (Δ ∝ √tolerance).
- :class:`SmoothingBands`: one :class:`DeepSmoothing` per band of orders, Δ doubling as the order doubles.
- :class:`DeepSmoothing`: linear binning on nodes Δ apart, tents deposited per run, the bias by Richardson (and, at
  tolerances of 1 % and below, its smooth part subtracted: :func:`smoothed_correction`); across a scan,
  :func:`spread_scan` (a separable tent of :func:`tent_weights`) with its own bias from :func:`tent_variance`.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..base import Sink
from .scan_spread import neighbourhood_max, spread_scan, tent_variance, tent_weights

SMOOTH_ORDER = 3
"""Orders from this one up are deposited smoothed in time (:class:`DeepSmoothing`) by default."""

SMOOTH_WIDTH = 2e-9
"""Δ, the node spacing of the lowest smoothed orders, s, at a tolerance of :data:`SMOOTH_TOLERANCE`: the bias of a
kernel estimate grows as Δ² and its noise falls as 1/Δ, so Δ scales as √tolerance (the bias stays the same
fraction of the tolerance), and never above this (docs/accuracy.md, "The smoothing's constants, measured")."""

SMOOTH_TOLERANCE = 0.01

SMOOTH_MIN_WIDTH = 0.5e-9
"""The narrowest Δ, s (tolerances below 0.06 %)."""

SMOOTH_BANDS = 2
"""Bands of orders with their own Δ: orders s..2s−2 at Δ, deeper orders at 2Δ (:class:`SmoothingBands`)."""

SCAN_SMOOTHING = 3
"""h, the half-width in scan pitches of the smoothing across a confocal scan (weights 1, 2, 3, 2, 1 over 9 per axis,
:func:`spread_scan`: 18 times less variance), its bias estimated and counted (:meth:`DeepSmoothing.bias`); why 3:
docs/accuracy.md, "The smoothing's constants, measured"."""

SHAPE_NODES_MAX = 1 << 23
"""Most fine nodes (nodes × the fine grid's) of the accumulator that bins the nodes' unit tents once
(:meth:`DeepSmoothing.binned_shapes`, 64 MiB); longer grids deposit tent by tent."""

BINNED_SHAPES_BYTES = 1 << 26
"""Bytes of binned unit tents kept across tracers (:meth:`DeepSmoothing.binned_shapes`, oldest dropped first): a
capture sequence builds a tracer per frame, each with the same nodes on the same grid."""

_BINNED_SHAPES: dict[tuple, np.ndarray] = {}
"""(axis, IRF, direct, oversample, first node s, Δ s, nodes) → the read-only (nodes, n_bins) binned unit tents."""

SMOOTH_MIN_BINS = 4
"""No smoothing when the output bins are not at least this many times finer than Δ (nothing to gain)."""

CORRECT_TOLERANCE = SMOOTH_TOLERANCE
"""The smooth part of the estimated bias is subtracted (:func:`smoothed_correction`) at tolerances up to this one,
where Δ follows √tolerance and the bias is a fixed share of the tolerance; above it Δ stays at :data:`SMOOTH_WIDTH`,
the bias is a smaller share of the tolerance and the added variance does not pay (docs/accuracy.md, "The smoothing's
constants, measured")."""

CORRECTION_COARSENING = 1
"""The correction is the Richardson bias estimate binned onto nodes 2^k Δ apart (k = this) and spread back: the
estimate's noise lies at the finest spacings, its expectation (Δ² L'') is smooth; k = 1 costs least
(docs/accuracy.md, "The smoothing's constants, measured")."""


ONSET_NARROWING = 0.25
"""κ: an impulse t − onset after its channel's onset (and less than 2Δ) is deposited as a tent of half-width at most
κ (t − onset) (:class:`DeepSmoothing`, "Causal"): light reaches back at most κ of its distance to the onset. An order's
light rises steeply after the onset, so a kernel reaching back to the onset (κ = 1) piles light into the first
nanosecond (docs/accuracy.md, "The smoothing's constants, measured")."""


def default_smoothing(bin_width: float, tolerance: float, first_order: int = SMOOTH_ORDER,
                      confocal: bool = False) -> dict:
    """The smoothing fields of :class:`~datagen.transport.multibounce.tracer.MultibounceSettings` (``smooth_order``,
    ``smooth_width``, ``smooth_max_width``, ``smooth_scan``) for output bins of ``bin_width`` seconds and a target
    relative error ``tolerance``: Δ = :data:`SMOOTH_WIDTH` · √(tolerance / :data:`SMOOTH_TOLERANCE`) within
    [:data:`SMOOTH_MIN_WIDTH`, :data:`SMOOTH_WIDTH`], the deeper band at 2Δ, from order ``first_order`` (the
    tracer's lowest); across a ``confocal`` scan's points a tent of half-width :data:`SCAN_SMOOTHING` pitches; the
    bias's smooth part subtracted (``smooth_correct``) at tolerances up to :data:`CORRECT_TOLERANCE`; no smoothing
    when the bins are not :data:`SMOOTH_MIN_BINS` times finer than Δ."""
    width = float(np.clip(SMOOTH_WIDTH * np.sqrt(tolerance / SMOOTH_TOLERANCE), SMOOTH_MIN_WIDTH, SMOOTH_WIDTH))
    order = first_order if SMOOTH_MIN_BINS * bin_width <= width else 0
    # Δ belongs to orders SMOOTH_ORDER..2·SMOOTH_ORDER−2; a lower first order starts a band below at Δ/2 (order 2's
    # transient has a sharp first hump: docs/accuracy.md, "The smoothing's constants, measured")
    first = width * max(first_order - 1, 1) / (SMOOTH_ORDER - 1) if first_order < SMOOTH_ORDER else width
    return {"smooth_order": order, "smooth_width": first, "smooth_max_width": width * 2 ** (SMOOTH_BANDS - 1),
            "smooth_scan": SCAN_SMOOTHING if confocal and order else 0,
            "smooth_correct": bool(order) and tolerance <= CORRECT_TOLERANCE}


RICHARDSON = 4.0 / 3.0
"""(L_Δ − L_Δ/2)·4/3 is a kernel estimate's bias where it grows as Δ² (a smooth transient): 1/(1 − 2^−2)."""

RICHARDSON_KINK = 2.0
"""(L_Δ − L_Δ/2)·2 is its bias where it grows as Δ (next to the kink of an order's onset): 1/(1 − 2^−1); between the
two the bias grows as Δ^p, 1 ≤ p ≤ 2, so this factor bounds it (the stated error as a bound, docs/accuracy.md)."""


class SmoothingBands:
    """The time smoothing of the deep orders, one :class:`DeepSmoothing` per band of orders whose node spacing
    doubles each time the order doubles: order k ≥ s = ``first_order`` in band ⌊log2((k − 1)/(s − 1))⌋ (orders 3–4, 5–8,
    9–16, … for s = 3), the last band taking every deeper order, up to ``max_width``.

    Order k's part of the transient is k chord lengths convolved: it spreads in time and its curvature L_k''
    falls as k grows, so the bias Δ² L_k'' of a kernel of width Δ stays small for a wider kernel on deeper orders,
    while the noise of a kernel estimate falls as 1/Δ. Each band estimates its own bias (Richardson,
    :meth:`DeepSmoothing.bias`); their sum is the bias of the smoothed orders.

    Args:
        first_order: the lowest smoothed order (≥ 2); width: Δ of the band that starts there, s; max_width: the
            widest Δ, s; t_start, t_stop: the window, s; n_channels: output channels; scan: (ny, nx, h) to spread
            over a scan grid too (:class:`DeepSmoothing`), or None; narrow: n, the lowest band's Δ divided by 2ⁿ (its
            bias was too large for the tolerance: ``Replicas.narrow_smoothing``); correct: every band subtracts the
            smooth part of its estimated bias (:class:`DeepSmoothing`, :func:`smoothed_correction`); onset: (n_channels,)
            s, the earliest time any light reaches each channel (:func:`~.onset.earliest_arrival`), or None (no bound:
            every impulse in the window is smoothed). Each band keeps its kernels after it (:class:`DeepSmoothing`).
    Attributes:
        margin: how far past the window's end paths are followed, s (the widest band's reach).
    """

    def __init__(self, first_order: int, width: float, max_width: float, t_start: float, t_stop: float,
                 n_channels: int, scan: tuple[int, int, int] | None = None, narrow: int = 0, correct: bool = False,
                 onset: np.ndarray | None = None):
        self.first_order = int(first_order)
        self.widths: list[float] = []
        w = float(width)
        while True:
            self.widths.append(min(w, max_width))
            if w >= max_width:
                break
            w *= 2.0
        self.widths[0] /= 2 ** int(narrow)
        self.bands = [DeepSmoothing(w, t_start, t_stop, n_channels, scan, correct, onset) for w in self.widths]
        self.margin = max(b.margin for b in self.bands)

    def band(self, order: int) -> DeepSmoothing | None:
        """The band that smooths order ``order``, or None below :attr:`first_order`."""
        if order < self.first_order:
            return None
        j = int(np.floor(np.log2((order - 1) / max(self.first_order - 1, 1)) + 1e-12))
        return self.bands[min(j, len(self.bands) - 1)]

    def flush(self, sink: Sink, component: int, order2_component: int | None = None) -> None:
        """:meth:`DeepSmoothing.flush` of every band into ``component``; with ``first_order`` 2, the first band
        (order 2 alone) into ``order2_component`` when given."""
        for j, b in enumerate(self.bands):
            own = order2_component is not None and j == 0 and self.first_order == 2
            b.flush(sink, order2_component if own else component)

    def bias(self, edges: np.ndarray, runs: int, factor: float = RICHARDSON) -> np.ndarray:
        """The sum of the bands' :meth:`DeepSmoothing.bias`, (n_channels, n_bins) photons per pulse."""
        return sum(b.bias(edges, runs, factor) for b in self.bands)

    def bias_halves(self, edges: np.ndarray, factor: float = RICHARDSON) -> tuple[np.ndarray, np.ndarray] | None:
        """The sums of the bands' :meth:`DeepSmoothing.bias_halves` (even runs, odd runs), or None before the
        second run; computed once per state of the runs, ``edges`` and ``factor`` (a tolerance round reads them two
        or three times: 80 ms each on a 32 × 32 scan)."""
        key = (tuple(b.runs for b in self.bands), len(edges), float(edges[0]), float(edges[-1]), factor)
        if getattr(self, "_halves_key", None) != key:
            halves = [b.bias_halves(edges, factor) for b in self.bands]
            value = None if any(h is None for h in halves) else (sum(h[0] for h in halves), sum(h[1] for h in halves))
            self._halves_key, self._halves = key, value
        return self._halves


class DeepSmoothing:
    """Orders that are smooth in time, deposited smoothed: a kernel estimate with its bias estimated and counted.

    Impulses inside the window are linearly binned onto nodes Δ apart (t_start + jΔ: the mass splits between the
    two nearest nodes, which keeps it and its mean time); :meth:`flush` deposits each node's mass as a tent of
    half-width Δ centred on it (:meth:`~datagen.timing.EnvelopeAccumulator.add_tents`), i.e. the piecewise-linear
    density through the node masses. The deep orders of a closed room are a long tail that changes over many
    nanoseconds, so the smoothing removes the noise of single paths at a bias of order Δ² L''.

    **Its bias** (:meth:`bias`, :meth:`bias_halves`) is estimated from the same impulses binned at Δ/2 too:
    (L_Δ − L_Δ/2) · 4/3 (Richardson: the bias of a kernel estimate grows as Δ² where the transient is smooth). Next
    to the sharp onset of an order it grows more slowly (a kink or a jump in L), and the finer pair is then the
    closer one (docs/physics.md §2; docs/accuracy.md, "The smoothing's constants, measured").

    The nodes reach :attr:`margin` (2Δ) beyond both ends of the window, and the tracer follows paths that far past
    its end, so that the kernels near the ends receive from outside the mass they spread out of the window: an
    impulse 2Δ or more past the end is binned onto nodes whose tents (and those of the Δ/2 nodes) end past it.

    **Its bias, corrected** (``correct``): each run deposits its node masses less C = S((L_Δ − L_Δ/2)·4/3), the
    Richardson estimate of the bias smoothed by :func:`smoothed_correction` (binned onto nodes 2Δ apart and spread
    back: its noise lies at the finest spacings, its expectation Δ² L'' is smooth), clipped so that no node mass falls
    below zero. What is left is the bias's rough part, (I − S)·bias, and the clipping's: the estimate below subtracts
    the correction the runs applied from the Richardson estimate, so it reads the bias of what was deposited (what
    it leaves, measured: docs/accuracy.md). The correction is linear in the runs' impulses (a kernel with smooth
    negative lobes), so the replicas' spread sees its noise.

    **Causal** (``onset``: per channel the earliest time any light can arrive, :mod:`.onset`): a node's tent starts
    less than 2Δ before an impulse binned onto it, so an impulse is binned onto the nodes only when it lies at least
    2Δ after the latest onset among the channels its masses reach (itself; across a scan, the points within h − 1
    pitches: :func:`~.scan_spread.neighbourhood_max`), and nodes within Δ of that take no correction (below). An
    earlier impulse is deposited by itself (:meth:`onset_tents`, at :meth:`flush`) as a tent of half-width h = min(κ τ,
    √2 Δ), τ its delay after its channel's onset (κ = :data:`ONSET_NARROWING`; across a scan, spread over the
    neighbouring points at the same delay after each one's onset): the kernel narrows towards the onset, so no light
    lands before it and none is moved from the steep rise of an order onto the onset; √2 Δ matches the nodes' kernel
    in variance. The Richardson estimate below reads every impulse binned onto the nodes, near the onset too: it
    estimates the bias of the plain smoothing, meant to bound that of the narrower tents (estimating the split parts
    apart would read their cut as a bias; how far it falls short under the demo room's primary peak:
    docs/accuracy.md, "What the stated error is").

    **Across a scan** (``scan``: the channels are the points of an (ny, nx) scan grid, as a confocal scan's are),
    the node masses are also spread over neighbouring scan points by a separable tent of half-width h pitches
    (:func:`spread_scan`; h = 3: weights 1, 2, 3, 2, 1 over 9 per axis, 18 times less variance): the light of
    orders ≥ 2 changes over many scan pitches. Its bias, ∝ h² ∇²L, is estimated from the spread at 2h (p = 2, with
    the tents' variances) and added.

    Args:
        width: Δ, s; t_start, t_stop: the window, s; n_channels: output channels; scan: (ny, nx, h) of a scan
            grid whose points are the channels, or None; correct: subtract the smooth part of the bias (above);
            onset: (n_channels,) s, the time before which no kernel may reach, per channel (above), or None.
    """

    def __init__(self, width: float, t_start: float, t_stop: float, n_channels: int,
                 scan: tuple[int, int, int] | None = None, correct: bool = False, onset: np.ndarray | None = None):
        self.width, self.n_channels = float(width), int(n_channels)
        self.onset = None if onset is None else np.asarray(onset, dtype=np.float64).reshape(self.n_channels)
        self.correct = bool(correct)
        self.scan = tuple(int(v) for v in scan) if scan is not None and scan[2] > 1 else None
        # the latest onset among the points a channel's node masses are spread to: the nodes start Δ after it
        self.reach_onset = (self.onset if self.onset is None or self.scan is None
                            else neighbourhood_max(self.onset, self.scan))
        self.margin = 2 * self.width                  # (the reach of linear binning and a tent) the nodes cover the
                                                      # window and this
        self.t_start = float(t_start) - self.margin   # node 0
        self.t_end = float(t_stop) + self.margin
        self.nodes = int(np.ceil((self.t_end - self.t_start) / self.width)) + 2
        self.node_times = self.t_start + self.width * np.arange(self.nodes)      # t_j, s
        # node masses at Δ (deposited) and at Δ/2 (the bias estimate), photons: this run's, every run's, and
        # the even runs' (0, 2, …: two independent halves for the bias without the runs' noise, bias_halves)
        self.spacings = (1.0, 0.5)
        shapes = [(self.n_channels, self.nodes if k == 1 else int(np.ceil(self.nodes / k)) + 2) for k in self.spacings]
        self.pending_levels = [np.zeros(shape) for shape in shapes]
        self.total_levels = [np.zeros(shape) for shape in shapes]
        self.even_levels = [np.zeros(shape) for shape in shapes]
        # the correction subtracted from the node masses at Δ (correct): this run's (None until computed), every
        # run's, the even runs'
        self._applied: np.ndarray | None = None
        self._scratch: list | None = None
        self.applied_total = np.zeros(shapes[0]) if self.correct else None
        self.applied_even = np.zeros(shapes[0]) if self.correct else None
        # this run's node masses at Δ of the impulses deposited through the nodes (not those near the onset)
        self.deposit_pending = np.zeros(shapes[0]) if self.onset is not None else None
        self._early: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []      # this run's onset tents
        self.runs = 0

    @property
    def pending(self) -> np.ndarray:
        """This run's node masses at Δ, (n_channels, nodes) photons (every impulse added: the bias estimate's)."""
        return self.pending_levels[0]

    @property
    def deposit(self) -> np.ndarray:
        """This run's node masses at Δ that :meth:`flush` deposits, (n_channels, nodes) photons: :attr:`pending` less
        the impulses near the onset (class doc, "Causal")."""
        return self.pending_levels[0] if self.deposit_pending is None else self.deposit_pending

    @property
    def total(self) -> np.ndarray:
        """Every finished run's node masses at Δ, (n_channels, nodes) photons."""
        return self.total_levels[0]

    def covers(self, t: np.ndarray) -> np.ndarray:
        """(n,) bool: the times t (n,) s that the nodes cover (the window widened by the margin on both sides)."""
        return (t >= self.t_start) & (t < self.t_end)

    def add(self, t: np.ndarray, weight: np.ndarray, channel: np.ndarray) -> None:
        """Linearly bin impulses at times t (n,) s inside :meth:`covers`, weights (n,) photons, channels (n,) int;
        those :meth:`near_onset` only into the bias estimate's levels, their :meth:`onset_tents` kept for
        :meth:`flush`. Raises ValueError for a channel outside [0, n_channels)."""
        if self._scratch is None:                 # per level: two sums and the nodes they touch (kept zeroed)
            self._scratch = [(np.zeros(out.size), np.zeros(out.size), np.zeros(out.size, np.bool_),
                              np.empty(out.size, np.int64)) for out in self.pending_levels]
        t = np.ascontiguousarray(t, dtype=np.float64)
        weight = np.ascontiguousarray(weight, dtype=np.float64)
        channel = np.ascontiguousarray(channel, dtype=np.int64)
        if channel.size and (channel.min() < 0 or channel.max() >= self.n_channels):   # (the pass does not check)
            raise ValueError(f"channels must be in [0, {self.n_channels}), got {channel.min()} … {channel.max()}")
        for out, k, scratch in zip(self.pending_levels, self.spacings, self._scratch):
            _bin_linear(out.reshape(-1), out.shape[1], t, weight, channel, self.t_start, k * self.width, *scratch)
        if self.deposit_pending is not None:
            early = self.near_onset(t, channel)
            if early.any():
                self._early.append(self.onset_tents(t[early], weight[early], channel[early]))
            late = ~early
            out = self.deposit_pending
            _bin_linear(out.reshape(-1), out.shape[1], t[late], weight[late], channel[late], self.t_start, self.width,
                        *self._scratch[0])

    def flush(self, sink: Sink, component: int) -> None:
        """Deposit this run's node masses into ``sink`` as tents (component ``component * n_channels +
        channel``) and start the next run."""
        masses = self.deposit
        if self.correct:
            masses = masses - self.applied_now()
        # (the spread's point reflection can leave a node within h − 1 of an edge below zero: photons are not)
        if self.scan is not None:
            masses = np.maximum(spread_scan(masses, self.scan), 0.0)
        if self._early:
            self._flush_early(sink, component)
        shapes = self.binned_shapes(sink) if hasattr(sink, "add_binned") else None
        if shapes is not None:                  # node masses × binned unit tents: the same bins, no fine grid
            sink.add_binned(masses @ shapes, component * self.n_channels + np.arange(self.n_channels),
                            masses.sum(axis=1))
            self.end_run()
            return
        if hasattr(sink, "add_fine"):
            masses = self._flush_edges(sink, masses, component)
        ch, j = np.nonzero(masses)
        if len(ch):
            t = self.node_times[j]
            sink.add_tents(np.stack([t - self.width, t, t + self.width], axis=1), masses[ch, j],
                           component * self.n_channels + ch)
        self.end_run()

    def near_onset(self, t: np.ndarray, channel: np.ndarray) -> np.ndarray:
        """(n,) bool: which impulses at times t (n,) s on channels (n,) int lie less than 2Δ after the latest onset
        their node masses would reach (deposited as :meth:`onset_tents` instead of through the nodes; class doc,
        "Causal"; only with an onset)."""
        return t < self.reach_onset[channel] + 2.0 * self.width

    def onset_tents(self, t: np.ndarray, weight: np.ndarray, channel: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The deposits of impulses at t (n,) s, weights (n,) photons, on channels (n,) int that :meth:`near_onset`
        selected (class doc, "Causal"): tents [t − h, t, t + h], h = min(κ τ, √2 Δ) with τ = t − onset (κ =
        :data:`ONSET_NARROWING`); across a scan, spread over the neighbouring points by the scan tent (weights
        renormalised inside the grid), each at the same delay τ after that point's own onset. Returns (tents (m, 3)
        s, weights (m,) photons, channels (m,) int64)."""
        tau = np.clip(t - self.onset[channel], 0.0, None)
        weight = np.asarray(weight, dtype=np.float64)
        channel = np.asarray(channel, dtype=np.int64)
        if self.scan is not None:
            ny, nx, h = self.scan
            k = np.arange(-h + 1, h)
            dy, dx = (a.ravel() for a in np.meshgrid(k, k, indexing="ij"))
            w2 = np.outer(tent_weights(h), tent_weights(h)).ravel()
            iy, ix = np.divmod(channel, nx)
            ty, tx = iy[:, None] + dy[None, :], ix[:, None] + dx[None, :]
            inside = (ty >= 0) & (ty < ny) & (tx >= 0) & (tx < nx)
            share = np.where(inside, w2[None, :], 0.0)
            share /= share.sum(axis=1, keepdims=True)
            rows, cols = np.nonzero(inside)
            weight = weight[rows] * share[rows, cols]
            channel = (ty * nx + tx)[rows, cols]
            tau = tau[rows]
        centre = self.onset[channel] + tau
        h = np.minimum(ONSET_NARROWING * tau, np.sqrt(2.0) * self.width)
        return np.stack([centre - h, centre, centre + h], axis=1), weight, channel

    def applied_now(self) -> np.ndarray:
        """The correction this run's node masses at Δ are deposited less (``correct``), (n_channels, nodes) photons:
        :func:`smoothed_correction` of its two levels, clipped so that no mass falls below zero."""
        if self._applied is None:
            raw = self.deposit
            correction = smoothed_correction(*self.pending_levels)
            if self.onset is not None:            # no kernel before the onset (class doc, "Causal")
                correction[self.node_times[None, :] < (self.reach_onset + self.width)[:, None]] = 0.0
            self._applied = raw - np.maximum(raw - correction, 0.0)
        return self._applied

    def end_run(self) -> None:
        """Add this run's node masses to the totals (the even runs' apart) and start the next run."""
        if self.correct:
            applied = self.applied_now()
            self.applied_total += applied
            if self.runs % 2 == 0:
                self.applied_even += applied
            self._applied = None
        for now, every, even in zip(self.pending_levels, self.total_levels, self.even_levels):
            every += now
            if self.runs % 2 == 0:
                even += now
            now[:] = 0.0
        if self.deposit_pending is not None:
            self.deposit_pending[:] = 0.0
        self.runs += 1

    def _flush_edges(self, sink: Sink, masses: np.ndarray, component: int) -> np.ndarray:
        """Deposit the nodes whose tents cross an end of ``sink``'s fine grid as one shape per node times each
        channel's mass (:meth:`~datagen.timing.EnvelopeAccumulator.add_fine`; the shape is a unit tent deposited
        once, so the result is the same as depositing every tent): a tent cut by the grid's end is deposited node
        by node, one that lies inside it in O(1) (its curvature), and the cut ones of a thousand scan points would
        cost more than every other part of the tracer. Returns the masses with those nodes zeroed (a copy)."""
        shapes = self.edge_shapes(sink)
        if not shapes:
            return masses
        masses = masses.copy()
        for j, (start, shape, lost) in shapes.items():
            rows = np.flatnonzero(masses[:, j])
            if len(rows):
                m = masses[rows, j]
                sink.add_fine(m[:, None] * shape[None, :], component * self.n_channels + rows, start, m, m * lost)
                masses[rows, j] = 0.0
        return masses

    def edge_shapes(self, sink: Sink) -> dict:
        """{node j: (first fine node, (m,) fine-histogram values of a unit tent at node j, the share of it beyond
        the grid)} for the nodes whose tents cross an end of ``sink``'s fine grid (computed once per grid)."""
        key = (sink.n_fine, float(sink.fine_step), float(sink.axis.t_start))
        if getattr(self, "_shapes_key", None) == key:
            return self._shapes
        times = sink.fine_times
        lo, hi = times[0] - 2 * sink.fine_step, times[-1] + 2 * sink.fine_step
        t = self.node_times
        cut = np.flatnonzero((t + self.width > lo) & (t - self.width < hi)
                             & ((t - self.width <= lo) | (t + self.width >= hi)))
        shapes = {}
        for j in cut:
            one = sink.spawn(1)
            one.add_tents(np.array([[t[j] - self.width, t[j], t[j] + self.width]]), 1.0, 0)
            row = one.fine_histogram()[0]
            nz = np.flatnonzero(row)
            if len(nz):
                shapes[int(j)] = (int(nz[0]), row[nz[0]:nz[-1] + 1].copy(), max(0.0, 1.0 - float(row.sum())))
            else:
                shapes[int(j)] = (0, np.zeros(0), 1.0)
        self._shapes_key, self._shapes = key, shapes
        return shapes

    def _flush_early(self, sink: Sink, component: int) -> None:
        """Deposit this run's :meth:`onset_tents` as tents (they reach a scan's fine grid, which the nodes' binned
        shapes otherwise spare: docs/accuracy.md)."""
        tents, weights, channels = (np.concatenate(a) for a in zip(*self._early))
        self._early = []
        sink.add_tents(tents, weights, component * self.n_channels + channels)

    def binned_shapes(self, sink: Sink) -> np.ndarray | None:
        """(nodes, n_bins) float64: node j's unit tent deposited on ``sink``'s grid and binned with its IRF (one
        accumulator of a component per node, once per grid), or None when that accumulator would exceed
        :data:`SHAPE_NODES_MAX` fine nodes. A node mass m deposits m × its row: what :meth:`flush` deposits tent by
        tent, up to round-off (:class:`~datagen.timing.binned_sink.BinnedSink`)."""
        key = (sink.n_fine, float(sink.fine_step), float(sink.axis.t_start), sink.axis.n_bins)
        if getattr(self, "_binned_key", None) != key:
            shapes = None
            if self.nodes * sink.n_fine <= SHAPE_NODES_MAX:
                fine = getattr(sink, "fine", sink)        # the grid the shapes are binned on, and its IRF
                memo = (fine.axis, fine.irf, fine.direct, fine.oversample, self.t_start, self.width, self.nodes)
                shapes = _BINNED_SHAPES.get(memo)
                if shapes is None:
                    one = sink.spawn(self.nodes)
                    t = self.node_times
                    one.add_tents(np.stack([t - self.width, t, t + self.width], axis=1), np.ones(self.nodes),
                                  np.arange(self.nodes))
                    shapes = one.binned()
                    shapes.flags.writeable = False
                    while _BINNED_SHAPES and sum(a.nbytes for a in _BINNED_SHAPES.values()) + shapes.nbytes > \
                            BINNED_SHAPES_BYTES:
                        _BINNED_SHAPES.pop(next(iter(_BINNED_SHAPES)))
                    if shapes.nbytes <= BINNED_SHAPES_BYTES:
                        _BINNED_SHAPES[memo] = shapes
            self._binned_key, self._binned_shapes = key, shapes
        return self._binned_shapes

    def bias(self, edges: np.ndarray, runs: int, factor: float = RICHARDSON) -> np.ndarray:
        """The estimated bias of the smoothed orders' mean over ``runs`` runs per output bin of ``edges``
        (n_bins + 1,) s: (n_channels, n_bins) photons per pulse (class doc: (L_Δ − L_Δ/2)·``factor`` and the scan
        spread's; ``factor`` :data:`RICHARDSON` where the transient is smooth, :data:`RICHARDSON_KINK` to bound it
        next to an onset too)."""
        return self._bias(self.total_levels, edges, self.applied_total, factor) / max(runs, 1)

    def bias_halves(self, edges: np.ndarray, factor: float = RICHARDSON) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`bias` (at ``factor``) of the even runs' mean and of the odd runs' mean, each (n_channels, n_bins) photons per
        pulse, or None before the second run. Their noise is independent and their expectation the same, so Σ a·b
        estimates ‖bias‖² without the noise that inflates ‖bias‖² of few runs."""
        if self.runs < 2:
            return None
        n_even = self.runs - self.runs // 2
        odd_applied = self.applied_total - self.applied_even if self.correct else None
        return (self._bias(self.even_levels, edges, self.applied_even, factor) / n_even,
                self._bias([a - b for a, b in zip(self.total_levels, self.even_levels)], edges, odd_applied, factor)
                / (self.runs - n_even))

    def _bias(self, levels: list[np.ndarray], edges: np.ndarray, applied: np.ndarray | None = None,
              factor: float = 4.0 / 3.0) -> np.ndarray:
        """From node sums at Δ and Δ/2 (``levels``, as :attr:`total_levels`), per output bin of ``edges``: (L_Δ −
        L_Δ/2)·``factor`` plus the scan spread's bias, less the correction the same runs were deposited less (``applied``,
        node sums at Δ, or None), (n_channels, n_bins) photons (not divided by the runs)."""
        centres = 0.5 * (edges[1:] + edges[:-1])
        widths = np.diff(edges)
        raw = levels[0]
        if self.scan is not None:
            levels = [spread_scan(level, self.scan) for level in levels]
        fine, half = (_interpolate(level / (k * self.width), self.t_start, k * self.width, centres) * widths
                      for level, k in zip(levels, self.spacings))
        out = (fine - half) * factor
        if applied is not None:
            spread = applied if self.scan is None else spread_scan(applied, self.scan)
            out -= _interpolate(spread / self.width, self.t_start, self.width, centres) * widths
        if self.scan is not None:                 # the spread's own bias: (S_2h − S_h) var_h / (var_2h − var_h)
            ny, nx, h = self.scan
            ratio = tent_variance(h) / (tent_variance(2 * h) - tent_variance(h))
            twice = _interpolate(spread_scan(raw, (ny, nx, 2 * h)) / self.width, self.t_start, self.width, centres)
            out += (twice * widths - fine) * ratio
        return out


@njit(cache=True)
def _bin_linear(flat, nodes, t, weight, channel, t_start, step, below, above, touched, rows):
    """Linear binning of impulses onto node masses ``flat`` (channels × ``nodes``, flattened) in place: an impulse at
    f = (t − t_start)/step goes to node ⌊f⌋ (at most nodes − 2) with weight·(1 − frac) and to the next with
    weight·frac, frac = f − ⌊f⌋. Each node gets the sum of the call's masses for it added once, the two sums in turn
    ((node + below) + above: what two ``numpy.bincount`` sums added to the nodes give, bit for bit); ``below``,
    ``above`` (zeros), ``touched`` (False) and ``rows`` are scratch of the nodes' size, left as they came."""
    m = 0
    for i in range(t.shape[0]):
        f = (t[i] - t_start) / step
        j = min(np.int64(f), nodes - 2)
        frac = f - j
        b = channel[i] * nodes + j
        for node in (b, b + 1):
            if not touched[node]:
                touched[node] = True
                rows[m] = node
                m += 1
        below[b] += weight[i] * (1.0 - frac)
        above[b + 1] += weight[i] * frac
    for q in range(m):
        node = rows[q]
        flat[node] = (flat[node] + below[node]) + above[node]
        below[node], above[node], touched[node] = 0.0, 0.0, False


def smoothed_correction(coarse: np.ndarray, fine: np.ndarray, coarsening: int = CORRECTION_COARSENING) -> np.ndarray:
    """The smooth part of the Richardson bias estimate, as node masses at Δ: S((L_Δ − L_Δ/2)·4/3) (:class:`DeepSmoothing`).

    L_Δ and L_Δ/2 are the piecewise-linear densities through node masses ``coarse`` (c, n) at t_0 + jΔ and ``fine``
    (c, m ≥ 2n − 1) at t_0 + iΔ/2 (photons). L_Δ is written on the Δ/2 nodes exactly (:func:`_prolong`), the difference
    is linearly binned back onto the Δ nodes (:func:`_restrict`), then ``coarsening`` times onto nodes twice as far
    apart and spread back (S). Every step keeps the mass, so the correction's total is the bias estimate's (zero
    for a smooth density). Returns (c, n) photons.
    """
    n = coarse.shape[1]
    out = _restrict(_prolong(coarse, fine.shape[1]) - fine, n) * (4.0 / 3.0)
    sizes = [n]
    for _ in range(coarsening):
        sizes.append((sizes[-1] + 1) // 2 + 1)
        out = _restrict(out, sizes[-1])
    for size in reversed(sizes[:-1]):
        out = _prolong(out, size)
    return out


def _prolong(masses: np.ndarray, size: int) -> np.ndarray:
    """Node masses (c, n) at spacing h as masses (c, ``size``) at h/2 with the same piecewise-linear density: node j's
    tent of half-width h is the tents of half-width h/2 at 2j − 1, 2j, 2j + 1 with a quarter, a half, a quarter of its
    mass (the one at −1 is dropped)."""
    n = masses.shape[1]
    out = np.zeros((masses.shape[0], size))
    k = min(n, (size + 1) // 2)
    out[:, 0:2 * k:2] += 0.5 * masses[:, :k]
    k = min(n, size // 2)
    out[:, 1:2 * k:2] += 0.25 * masses[:, :k]
    k = min(n - 1, size // 2)
    out[:, 1:2 * k:2] += 0.25 * masses[:, 1:k + 1]
    return out


def _restrict(masses: np.ndarray, size: int) -> np.ndarray:
    """Node masses (c, m) at spacing h/2 linearly binned onto (c, ``size``) nodes h apart: node 2j's mass goes to j,
    node 2j + 1's half to j and half to j + 1."""
    m = masses.shape[1]
    out = np.zeros((masses.shape[0], size))
    k = min(size, (m + 1) // 2)
    out[:, :k] += masses[:, 0:2 * k:2]
    k = min(size, m // 2)
    out[:, :k] += 0.5 * masses[:, 1:2 * k:2]
    k = min(size - 1, m // 2)
    out[:, 1:k + 1] += 0.5 * masses[:, 1:2 * k:2]
    return out


def _interpolate(values: np.ndarray, t0: float, step: float, t: np.ndarray) -> np.ndarray:
    """Rows of ``values`` (n, m), samples at t0 + k·step, linearly interpolated at times t (p,) s (held at the end
    values outside, as :func:`numpy.interp`): (n, p)."""
    f = (t - t0) / step
    j = np.clip(np.floor(f).astype(np.int64), 0, values.shape[1] - 2)
    frac = np.clip(f - j, 0.0, 1.0)
    return _lerp_rows(np.ascontiguousarray(values, dtype=np.float64), j, 1.0 - frac, frac)


@njit(cache=True)
def _lerp_rows(values, j, below, above):
    """out[r, k] = values[r, j_k] · below_k + values[r, j_k + 1] · above_k (the numpy expression it replaces, in one
    pass: a 32 × 32 scan's bias reads interpolate a thousand rows several times per round)."""
    out = np.empty((values.shape[0], j.shape[0]))
    for r in range(values.shape[0]):
        for k in range(j.shape[0]):
            out[r, k] = values[r, j[k]] * below[k] + values[r, j[k] + 1] * above[k]
    return out
