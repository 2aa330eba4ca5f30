"""A replica's sink that takes deposits already binned (docs/physics.md §5): :class:`BinnedSink`.

The light tracer's smoothed orders reach a replica as node masses, each deposited as a tent (docs/physics.md §2,
"Light of every order"). Every tent of a node has the same binned shape (the tent convolved with the IRF and
integrated over the bins), so a replica's smoothed light is its node masses times one matrix of binned unit tents
(:meth:`datagen.transport.multibounce.smoothing.DeepSmoothing.flush`), and never needs the fine grid: on a 32 × 32
confocal scan of 512 bins that grid holds 3 × 1024 rows of 5194 nodes (127 MB), which a replica would otherwise
fill, fold, merge and bin.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .accumulator import EnvelopeAccumulator
from .impulses import check_finite, check_weights, times_weights

__all__ = ["BinnedSink"]


class BinnedSink:
    """An :class:`~datagen.timing.EnvelopeAccumulator` (:attr:`fine`) for impulses and tents, beside binned rows
    (:meth:`add_binned`). Impulses beyond the fine grid's reach (more than one fine step outside its first or last
    node, where the accumulator would count them wholly outside the window) are tallied here without touching it, so
    a replica whose every in-window deposit comes binned never allocates, folds or reads its fine grid.

    Args:
        fine: an empty accumulator (a :meth:`~datagen.timing.EnvelopeAccumulator.spawn` of the run's total).
    Attributes:
        fine: the accumulator; binned_rows: (n_components, n_bins) float64 photons per pulse per bin of the binned
            deposits; outside: (n_components,) photons of what was added here (binned deposits and impulses beyond
            the grid) that lie outside the window: binned_rows' row sums plus outside are what was added here.
    """

    def __init__(self, fine: EnvelopeAccumulator):
        self.fine = fine
        self.binned_rows = np.zeros((fine.n_components, fine.axis.n_bins))
        self.outside = np.zeros(fine.n_components)
        times = fine.fine_times
        self._reach = (float(times[0] - fine.fine_step), float(times[-1] + fine.fine_step))

    # the fine grid's geometry, for deposits that compute their shapes on it (DeepSmoothing)
    @property
    def axis(self):
        return self.fine.axis

    @property
    def n_fine(self) -> int:
        return self.fine.n_fine

    @property
    def fine_step(self) -> float:
        return self.fine.fine_step

    @property
    def fine_times(self) -> np.ndarray:
        return self.fine.fine_times

    def spawn(self, n_components: int | None = None) -> EnvelopeAccumulator:
        """:meth:`~datagen.timing.EnvelopeAccumulator.spawn` of :attr:`fine`."""
        return self.fine.spawn(n_components)

    def add(self, times: Any, weights: Any, component: int | np.ndarray = 0) -> None:
        """:meth:`~datagen.timing.EnvelopeAccumulator.add` of the impulses within the fine grid's reach; the rest
        (times (n,) s, weights (n,) photons, component ids (n,) or one) are tallied as outside the window. Raises
        ValueError as :meth:`~datagen.timing.EnvelopeAccumulator.add` does (non-finite times, negative or
        non-finite weights, ids out of range)."""
        t, w = times_weights(times, weights)
        t, w = np.asarray(t, dtype=np.float64), np.asarray(w, dtype=np.float64)
        check_finite(t, "times")                                 # the whole call, so that the indices are its own
        check_weights(w)
        c = np.broadcast_to(np.asarray(component, dtype=np.int64), t.shape)
        if c.size and (c.min() < 0 or c.max() >= len(self.outside)):
            raise ValueError(f"component ids must be in [0, {len(self.outside)}), got {int(c.max())}")
        near = (t >= self._reach[0]) & (t <= self._reach[1])
        if near.any():
            self.fine.add(t[near], w[near], c[near])
        if not near.all():
            self.outside += np.bincount(c[~near], weights=w[~near], minlength=len(self.outside))

    def add_tents(self, times: Any, weights: Any, component: int | np.ndarray = 0) -> None:
        """:meth:`~datagen.timing.EnvelopeAccumulator.add_tents` of :attr:`fine`."""
        self.fine.add_tents(times, weights, component)

    def add_fine(self, rows: np.ndarray, component: np.ndarray, start: int, total: np.ndarray,
                 beyond: np.ndarray) -> None:
        """:meth:`~datagen.timing.EnvelopeAccumulator.add_fine` of :attr:`fine`."""
        self.fine.add_fine(rows, component, start, total, beyond)

    def add_binned(self, values: np.ndarray, component: np.ndarray, total: np.ndarray) -> None:
        """Add ``values`` (k, n_bins) photons per pulse per bin, already convolved with the IRF and binned, to the
        distinct components ``component`` (k,) int, standing for ``total`` (k,) photons, of which the rest of
        ``values``' row sums lies outside the window. Raises ValueError for shapes that do not fit."""
        component = np.asarray(component, dtype=np.int64)
        if values.shape != (len(component), self.binned_rows.shape[1]) or len(np.unique(component)) != len(component):
            raise ValueError(f"add_binned: values {values.shape} need one row of {self.binned_rows.shape[1]} bins per "
                             "distinct component")
        self.binned_rows[component] += values
        self.outside[component] += total - values.sum(axis=1)

    def holds_fine(self) -> bool:
        """Whether anything reached :attr:`fine` (else it is all zeros and need not be read)."""
        return bool(self.fine.total_weight().any())

    def binned_total(self, n_channels: int = 1) -> np.ndarray:
        """(n_channels, n_bins) every component's bins summed per channel (ids ``component * n_channels + channel``):
        the binned rows and, when it holds anything, :attr:`fine`'s
        :meth:`~datagen.timing.EnvelopeAccumulator.binned_total`."""
        out = self.binned_rows.reshape(-1, n_channels, self.binned_rows.shape[1]).sum(axis=0)
        return out + self.fine.binned_total(n_channels) if self.holds_fine() else out
