"""The light tracer's options and its orders decision: the ``multibounce:`` block of a simulation config
(:class:`MultibounceOptions`) with the light paths it defaults to, and :class:`OrdersChoice`, the planner's typed
decision on which orders the tracer carries (made by :func:`datagen.planner.orders.decide_orders`, read by the
front door :func:`~datagen.transport.multibounce.orders.beside`)."""
from __future__ import annotations

from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

PATHS_PER_SAMPLE = 4
"""Default light paths of one replica of the order ≥ 3 tracer per hidden sample of the area sampler's replica. How
many tracer replicas go with the area sampler's is decided as the run goes, from both parts' measured spread and
counted work (:func:`datagen.simulation.replicas.tracer_replicas_wanted`; docs/accuracy.md, "Light of every
order", gives the ratios measured); replicas this large keep the fixed cost of each order's array passes small."""

DEFAULT_PATHS = 262144
"""Default light paths per laser point of the order ≥ 3 tracer beside estimators without a ``samples`` count."""

MIN_SCAN_PATHS = 64
"""Fewest default light paths per laser point of a scan (:meth:`MultibounceOptions.paths_per_laser`)."""


class MultibounceOptions(BaseModel):
    """The ``multibounce:`` block of a simulation config: the order ≥ 3 tracer (docs/accuracy.md, "Light of every
    order").

    Attributes:
        paths: light paths per laser point, split over the replicas as the estimator's sampling is; unset:
            :data:`PATHS_PER_SAMPLE` × the estimator's ``samples`` (the area sampler; :data:`DEFAULT_PATHS` for the
            others), the split that spends about as much time on the tracer as on orders 1–2, which the error of
            their sum asks for.
        smoothing: deposit the orders ≥ 3 smoothed in time, with the bias estimated and counted in the stated error;
            False: every order as impulses (unbiased: what a converged reference uses).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    paths: int | None = Field(None, ge=1, description="light paths per laser point (unset: 4 x the area samples)")
    smoothing: bool = Field(True, description="deposit the orders >= 3 smoothed in time, the bias counted")

    def paths_per_laser(self, samples: int | None, n_lasers: int = 1) -> int:
        """Light paths per laser point of one run: ``paths``, or its default for an estimator of ``samples`` hidden
        samples per run (None: no such count), which a scan of ``n_lasers`` laser points shares among them (at
        least :data:`MIN_SCAN_PATHS` per point: the tail varies slowly across the scan, and every point's paths
        are traced together)."""
        if self.paths is not None:
            return int(self.paths)
        total = int(PATHS_PER_SAMPLE * samples) if samples else DEFAULT_PATHS
        return total if n_lasers <= 1 else max(MIN_SCAN_PATHS, -(-total // int(n_lasers)))


@dataclass(frozen=True)
class OrdersChoice:
    """Which orders of light a run simulates beyond its estimator's own (docs/planner.md, "Orders").

    Attributes:
        setting: the config's ``orders`` (an int ≥ 1 or "auto").
        on: whether the light tracer runs.
        min_order: the tracer's lowest order: 3 beside an estimator that computes order 2, 2 beside one without.
        max_order: its highest order, 0 for every order.
        residual: the share of the in-window energy the run leaves out (the pilot's estimate; 0 when every order
            is simulated or nothing was estimated), counted in the stated error.
        pilot_shares: each order's share of the in-window energy from the pilot ("order_1", …, "order_N_up"), or
            None when no pilot ran.
        pilot_paths: the pilot's light paths (0: none ran).
    """

    setting: int | str
    on: bool
    min_order: int
    max_order: int
    residual: float
    pilot_shares: dict[str, float] | None = None
    pilot_paths: int = 0

    def numbers(self) -> dict:
        """The JSON form recorded with the plan (``Decision.numbers``)."""
        out = {"orders": self.setting, "min_order": self.min_order, "max_order": self.max_order,
               "residual": self.residual}
        if self.pilot_shares is not None:
            out["pilot_paths"] = self.pilot_paths
            out["pilot_shares"] = dict(self.pilot_shares)
        return out

    def simulated(self, secondary_on: bool) -> str:
        """The orders a result holds: "1", "1..2", "1..N" or "1..all" (``secondary_on``: the estimator computes
        order 2 itself)."""
        if self.on:
            return f"1..{self.max_order or 'all'}"
        return "1" if self.setting == 1 or not secondary_on else "1..2"
