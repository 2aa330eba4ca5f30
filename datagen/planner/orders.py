"""How many orders of light a scene calls for: a pilot of the order ≥ 3 tracer (docs/physics.md §2, "Orders";
docs/planner.md).

``simulation.orders`` is an integer ≥ 1 (1: primary only, 2: primary and secondary, N ≥ 3: every order up to N) or
``auto``. With ``auto`` the planner traces :data:`PILOT_PATHS` light paths from the laser spot (the centre laser
point of a scan) with the tracer of :mod:`datagen.transport.multibounce` from order 1 up, and measures each order's
share of the in-window energy. Orders ≥ 3 are simulated when their share exceeds :data:`RESIDUAL_FRACTION` of the
tolerance; otherwise they are left out and their share is the *residual*, which the result's stated error includes
(``attrs["error"]["omitted_orders"]``). The energy share bounds the relative L2 distance it makes: the omitted light
is a smooth late tail, whose L2 norm is a smaller fraction of the envelope's than its energy is (docs/accuracy.md).
The pilot draws from its own stream (:data:`PILOT_STREAM`), so it changes no other random number.

A config that *fixes* ``orders`` at 1 or 2 (written in the file or given with ``--orders``) runs the same pilot:
the share of the orders it leaves out is its residual, counted in the stated error, and an
:class:`OmittedOrdersWarning` names it when it exceeds :data:`RESIDUAL_FRACTION` of the tolerance. An ``orders``
left unset is "auto", except beside ``secondary: none`` (the old spelling of orders 1): orders 1, no pilot. A fixed
``orders: 2`` beside an estimator without its secondary has the tracer carry order 2 alone.
"""
from __future__ import annotations

import numpy as np

from ..errors import DatagenWarning
from ..scene import RayCaster, Scene
from ..scene.capture import Capture
from ..transport.multibounce import MultibounceSettings
from ..transport.multibounce.options import OrdersChoice
from ..transport.multibounce.tracer import build_tracer
from ..transport.physics import LegPhysics, PhysicsSettings

PILOT_PATHS = 4096
"""Light paths of the pilot (one laser point): the share of orders ≥ 3 to a few per cent of itself."""

PILOT_STREAM = 5701
"""Spawn key of the pilot's random stream under the config's seed."""

RESIDUAL_FRACTION = 0.25
"""Orders ≥ 3 are left out only when their share of the in-window energy is below this fraction of the tolerance."""


class OmittedOrdersWarning(DatagenWarning):
    """``orders`` is fixed below what the scene calls for: the orders left out carry more than
    :data:`RESIDUAL_FRACTION` of the tolerance (the CLI prints it as one ``warning: …`` line)."""


class _Discard:
    """A sink that keeps nothing (the pilot reads the tracer's own per-order tally)."""

    def add(self, times, weights, component) -> None:
        pass


def order_shares(scene: Scene, capture: Capture, caster: RayCaster, physics: PhysicsSettings,
                 window: tuple[float, float], seed: int, paths: int = PILOT_PATHS) -> np.ndarray:
    """Each order's share of the in-window energy at the centre laser point, from ``paths`` traced light paths.

    Returns:
        (:data:`~datagen.transport.multibounce.tracer.ORDER_TALLY`,) float64 shares summing to 1 (index k−1 for order
        k; the last entry holds every higher order); zeros when no light reaches the FoV inside the window.
    """
    legs = LegPhysics(scene, capture, caster, physics)
    tracer = build_tracer(capture, caster, legs, MultibounceSettings(paths=paths, min_order=1), window=window)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PILOT_STREAM,)))
    laser = capture.n_lasers // 2
    tracer.run_laser(_Discard(), rng, laser)
    total = tracer.order_energy.sum()
    return tracer.order_energy / total if total > 0 else tracer.order_energy


def decide_orders(orders: int | str, shares: np.ndarray | None, tol: float, secondary_on: bool = True,
                  secondary_forced_off: bool = False) -> tuple[OrdersChoice, str]:
    """Which orders the run simulates beyond its estimator's own, and why.

    The tracer carries every order from ``min_order`` up: 3 beside an estimator with its secondary, 2 beside one
    without (``secondary: none``, or the planner turned it off: the confocal scans' quadrature); a fixed
    ``orders: 2`` beside one whose secondary the user switched off has it carry order 2 alone (``min_order`` =
    ``max_order`` = 2); beside one whose secondary the planner skipped, the skipped share joins the residual.

    Args:
        orders: the config's ``orders`` (an int ≥ 1 or "auto"); shares: :func:`order_shares` (None when not run);
        tol: the tolerance; secondary_on: whether the estimator computes order 2 itself; secondary_forced_off:
            its order 2 is off by the user's ``effects`` (the confocal configs' quadrature), not because the planner
            found it below the tolerance: a fixed ``orders: 2`` then has the tracer carry it.
    Returns:
        (:class:`~datagen.transport.multibounce.options.OrdersChoice`, one sentence with the numbers). Its residual
        is the estimated share of the in-window energy left out (0 when every order is simulated or nothing was
        estimated).
    """
    lowest = 3 if secondary_on else 2
    pilot = ({f"order_{k + 1}" if k + 1 < len(shares) else f"order_{k + 1}_up": float(v) for k, v in enumerate(shares)}
             if shares is not None else None)

    def choice(on: bool, min_order: int, max_order: int, residual: float) -> OrdersChoice:
        return OrdersChoice(orders, on, min_order, max_order, residual, pilot, PILOT_PATHS if pilot else 0)

    if orders != "auto":
        n = int(orders)
        if n == 2 and secondary_forced_off:         # order 2 from the tracer: the same light as any estimator's
            left = float(shares[2:].sum()) if shares is not None else 0.0
            return choice(True, 2, 2, left), (
                "orders: 2 (fixed by the config; the tracer carries order 2 beside an estimator without its "
                "secondary)" + (f"; the pilot finds orders ≥ 3 carry {left:.2%} of the in-window energy: counted in "
                                "the stated error" if shares is not None else ""))
        if n <= 2:
            reason = f"orders: {n} (fixed by the config)"
            if shares is None:
                return choice(False, lowest, 0, 0.0), reason
            left = float(shares[n:].sum()) + (float(shares[1]) if n == 2 and not secondary_on else 0.0)
            return choice(False, lowest, 0, left), (f"{reason}; the pilot finds the orders the run leaves out carry "
                                                    f"{left:.2%} of the in-window energy: counted in the stated error")
        return choice(True, lowest, n, 0.0), f"orders: {n} (fixed by the config)"
    beyond = float(shares[lowest - 1:].sum())
    threshold = RESIDUAL_FRACTION * tol
    which = "orders ≥ 3" if secondary_on else "orders ≥ 2 (the estimator runs without its secondary)"
    if beyond <= threshold:
        return choice(False, lowest, 0, beyond), (
            f"the pilot finds {which} carry {beyond:.2%} of the in-window energy, below {RESIDUAL_FRACTION:g} × the "
            f"tolerance ({threshold:.2%}): left out, counted in the stated error")
    return choice(True, lowest, 0, 0.0), (f"the pilot finds {which} carry {beyond:.2%} of the in-window energy, "
                                          f"above {RESIDUAL_FRACTION:g} × the tolerance ({threshold:.2%}): every "
                                          "order simulated")


def orders_record(plan, tracer, n_lasers: int) -> dict:
    """``attrs["orders"]`` of a result: the orders asked for and simulated ("1", "1..2", "1..N" or "1..all"), the
    residual share left out, the decision's reason, the pilot's shares and, when the tracer ran, its per-order
    in-window energy (photons per pulse, mean over its runs).

    Args:
        plan: the run's :class:`~datagen.planner.Plan` (with its ``multibounce`` decision); tracer: the run's
            :class:`~datagen.transport.multibounce.MultibounceTracer` or None; n_lasers: laser points per run.
    """
    d = plan.decisions["multibounce"]
    c = d.choice
    out = {"setting": c.setting, "simulated": c.simulated(plan.on("secondary")), "residual_share": c.residual,
           "reason": d.reason, **({"pilot_shares": dict(c.pilot_shares)} if c.pilot_shares is not None else {})}
    if tracer is not None:
        runs = max(1, tracer.stats.paths // max(1, tracer.settings.paths * n_lasers))
        out["energy_by_order"] = {f"order_{k + 3}": float(v) / runs for k, v in enumerate(tracer.order_energy[2:])}
    return out
