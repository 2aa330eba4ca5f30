"""The effect planner: before transport, decide which effects a scene calls for.

``plan_effects(scene, config, capture, caster)`` returns a :class:`Plan`: one :class:`Decision` per effect
(``on``, a human-readable ``reason`` quoting the numbers behind it, ``forced`` when the user set it, and
those ``numbers``). The plan is estimator-neutral: ``Plan.apply`` sets its decisions on a
:class:`~datagen.transport.PhysicsSettings` (the switches the chosen estimator follows, its registry entry's
``follows_plan``), ``Plan.secondary_mode`` gives the secondary mode to run, and ``Plan.to_attrs`` the JSON
stored in the result's attributes (``attrs["plan"]``); the estimator builds its own settings from those. An
effect is skipped only when simulating it cannot change the envelope by more than ``config.effect_threshold``
(relative), or when it is exactly zero. Every effect can be forced with
``config.effects[name] = True | False``; forced values always win. The rules (docs/planner.md derives them):

- ``shadow_sensor``: FoV point → sensor shadow rays. Off when no triangle except the FoV's own surface can
  meet the pyramid spanned by the sensor and the FoV rectangle (separating-plane test: the pyramid's five
  face planes and the triangle's own plane). Exact: such rays can never be blocked.
- ``shadow_spot``: laser spot → hidden point shadow rays on the laser leg of paths with two hidden vertices
  (which points the laser lights, for the secondary; an estimator whose primary hidden points need them too,
  the area sampler and the quadrature, does not follow this decision and has its own rule: docs/planner.md).
  Off when the secondary is off, or when no triangle can meet any tetrahedron spanned by the spot (the hull
  of the laser grid's corners for a scan) and a hidden triangle lit on a side the laser can reach (same
  separating-plane test, all pairs; closed meshes are seen from outside only): every segment spot →
  observable lit point is then free. Exact.
- ``secondary``: off when no two hidden triangles can exchange light on the way spot → x → x' → FoV
  (exact zero), or when a coarse area quadrature of secondary / primary energy times
  ``SECONDARY_SAFETY`` is below the tolerance (an *estimate* with a safety factor, not a bound).
- ``brdf_angles``: off when every material is Lambertian (f = ρ/π does not depend on angles). Exact.
- ``attenuation``: off when 1 − e^{−μ·L_max} < tolerance, L_max = emitter leg + 3 × scene diagonal +
  longest FoV → sensor leg bounds every simulated path, so every bin changes by less. A bound.
- ``first_bounce``: on only when the laser spot lies strictly inside the FoV, faces and sees the sensor,
  arrives inside the time window, and the detector gate leaves a bin of its IRF support open. Exact.
- ``pile_up``: off (Poisson counts) when the dead-time bound 1 − e^{−M} < tolerance, M the expected
  avalanches in the longest window that can disable the detector (Λ per cycle for pile-up and multi-stop).
  The rule is the detector's (:func:`datagen.spad.pileup.pile_up_decision`); here Λ is only estimated (coarse
  quadrature × ``PILE_UP_SAFETY``), a preview: after transport the detector stage decides from the exact Λ of the
  envelope (:func:`datagen.spad.pileup.pile_up_from_envelope`) unless the user forced the effect.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ConfigError
from .. import spad
from ..scene import RayCaster, Scene
from ..scene.capture import Capture, FOV_EDGE_REL, FOV_PLANE_TOL
from ..scene.separation import CHUNK_ELEMENTS, hull_planes, may_meet, outward_planes
from ..timing.irf import TAIL_MARGIN_TAUS
from ..spad.models import detector_model, model_names
from ..spad.pileup import pile_up_decision
from ..transport import PhysicsSettings
from ..transport.base import PLANNED_SWITCHES
from ..transport.multibounce.options import OrdersChoice
from .coarse import CoarseEnergies, coarse_energies
from .orders import RESIDUAL_FRACTION, OmittedOrdersWarning, decide_orders, order_shares
from .geometry import PlanGeometry
from ..vectors import matmul

EFFECTS = ("shadow_spot", "shadow_sensor", "secondary", "brdf_angles", "attenuation", "first_bounce", "pile_up")
"""Keys of ``SimulationConfig.effects``; each maps to True, False or "auto"."""

DEFAULT_TOLERANCE = 0.01
"""Relative change of the envelope below which an effect may be skipped (``SimulationConfig.effect_threshold``)."""

SECONDARY_SAFETY = 4.0
"""Factor on the coarse secondary/primary energy estimate before comparing with the tolerance. The coarse
quadrature is an estimate, not a bound: on the seven scenes of docs/planner.md it was 0.86–1.25 × the
converged transport ratio, so 4 leaves a margin of more than 3 against underestimates."""

PILE_UP_SAFETY = 4.0
"""Factor on the coarse estimate of detected photons per pulse (primary + secondary) used for Λ before
transport; the first bounce and the background are exact and not multiplied."""

PAIR_TEST_MAX_TRIANGLES = 2000
"""Pairwise triangle tests (shadow_spot, exact-zero secondary) cost O(F²); above this many triangles
(4e6 pairs, ~1 s when nothing blocks) the planner does not attempt them and keeps the effect on."""



# ---------------------------------------------------------------------------------------------------------
# Plan and decisions


@dataclass(frozen=True)
class Decision:
    """Whether one effect is simulated.

    Attributes:
        on: simulate the effect.
        reason: why, quoting the numbers.
        forced: set by the user (``config.effects``), not decided by the planner.
        numbers: the quantities behind the decision (floats, ints, strings; JSON-able).
    """

    on: bool
    reason: str
    forced: bool = False
    numbers: dict = field(default_factory=dict)
    blockers: tuple[int, ...] | None = field(default=None, repr=False, compare=False)
    """shadow_spot / shadow_sensor: every face that can cross a laser point → hidden point segment, or a FoV
    point → sensor segment (complete), or None when not determined; transport uses it to skip shadow rays that
    cannot be blocked (not in the attrs)."""


@dataclass(frozen=True)
class OrdersDecision(Decision):
    """The ``multibounce`` decision: which orders of light the run simulates, typed (``choice``: min and max order of
    the tracer, the residual left out, the pilot's shares); ``numbers`` is its JSON form (:mod:`.orders`)."""

    choice: OrdersChoice | None = field(default=None, compare=False)


@dataclass(frozen=True)
class Plan:
    """One :class:`Decision` per effect of :data:`EFFECTS`, and the tolerance they were made for."""

    decisions: dict[str, Decision]
    tolerance: float = DEFAULT_TOLERANCE

    def __getitem__(self, name: str) -> Decision:
        return self.decisions[name]

    def on(self, name: str) -> bool:
        """True when effect ``name`` is simulated."""
        return self.decisions[name].on

    def to_attrs(self) -> dict:
        """JSON-able form stored in ``Result.attrs["plan"]``: effect → {on, forced, reason, numbers}."""
        return {name: {"on": bool(d.on), "forced": bool(d.forced), "reason": d.reason,
                       "numbers": _jsonable(d.numbers)} for name, d in self.decisions.items()}

    def apply(self, physics: PhysicsSettings, switches: Iterable[str] = PLANNED_SWITCHES) -> PhysicsSettings:
        """``physics`` with this plan's decisions on ``switches`` (``dataclasses.replace``; same class).

        Estimator-neutral: ``physics`` is any :class:`~datagen.transport.PhysicsSettings` (usually
        :meth:`datagen.simulation.SimulationConfig.physics_settings`), and ``switches`` the planned physics
        switches the chosen estimator follows (its registry entry's ``follows_plan``; default all of
        :data:`~datagen.transport.base.PLANNED_SWITCHES`). A listed switch takes its decision (``attenuation``
        keeps μ when on and becomes 0.0 when off; the shadow switches bring their blocker lists); any other keeps
        the value ``physics`` has (the user's forced value or the default), for the estimator's own rule.

        Raises:
            ValueError: a name in ``switches`` that is not a planned switch.
        """
        names = tuple(switches)
        unknown = sorted(set(names) - set(PLANNED_SWITCHES))
        if unknown:
            raise ValueError(f"not planned physics switches: {unknown}; planned: {list(PLANNED_SWITCHES)}")
        updates: dict[str, Any] = {name: self.on(name) for name in names if name != "attenuation"}
        if "attenuation" in names:
            updates["attenuation"] = physics.attenuation if self.on("attenuation") else 0.0
        if "shadow_spot" in names:
            updates["spot_blockers"] = self.decisions["shadow_spot"].blockers
        if "shadow_sensor" in names:
            updates["sensor_blockers"] = self.decisions["shadow_sensor"].blockers
        return dataclasses.replace(physics, **updates)

    def secondary_mode(self, mode: str) -> str:
        """The secondary estimator mode to run: ``mode`` (the configured one, e.g. "full") when the secondary
        is on, "none" when the plan (or the user) turned it off."""
        return mode if self.on("secondary") else "none"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    return value if value is None or isinstance(value, str) else str(value)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


# ---------------------------------------------------------------------------------------------------------
# Entry point


def plan_effects(scene: Scene, config, capture: Capture, caster: RayCaster) -> Plan:
    """Decide which effects to simulate for ``scene`` under ``config`` (rules in the module docstring).

    Args:
        scene: the scene; config: the simulation config (:class:`datagen.simulation.SimulationConfig`, or any
            object with its fields: ``tolerance``, ``effects``, time axis, IRF, detector, ``secondary``,
            ``attenuation``, leg flags; the planner sits below the simulation layer and does not import it);
            capture: its resolved capture geometry (one laser spot, or a confocal/exhaustive laser grid);
            caster: the scene's ray caster.
    Returns:
        :class:`Plan` with a decision for every effect of :data:`EFFECTS`.
    Raises:
        ConfigError: an unknown key or value in ``config.effects``, a tolerance outside [0, 1), or a forced
            effect the configuration cannot simulate (secondary forced on with ``secondary: none``, pile-up
            forced on with a Poisson detector).
    """
    tol = float(getattr(config, "effect_threshold", DEFAULT_TOLERANCE))
    if not (math.isfinite(tol) and 0.0 <= tol < 1.0):
        raise ConfigError(f"tolerance must be in [0, 1) (a relative error of the envelope), got {tol!r}")
    forced = _forced_effects(getattr(config, "effects", None) or {})
    detector = config.detector_config()
    if forced.get("secondary") is True and config.secondary == "none":
        raise ConfigError("effects.secondary is forced on but secondary is 'none': choose an estimator "
                         "(optimized, full or exact)")
    if forced.get("pile_up") is True and detector_model(detector.model).dead_time == "none":
        raise ConfigError(f"effects.pile_up is forced on but detector.model is {detector.model!r}, which has no dead "
                          f"time: choose {', '.join(n for n in model_names() if detector_model(n).dead_time != 'none')}")
    physics = PhysicsSettings(pde=detector.pde, count_laser_leg=config.count_laser_leg,
                              count_sensor_leg=config.count_sensor_leg)
    geometry = PlanGeometry(scene, caster, capture, FOV_PLANE_TOL * caster.offset, physics)

    auto: dict[str, Decision] = {}
    auto["brdf_angles"] = _decide_brdf_angles(scene)
    auto["attenuation"] = _decide_attenuation(config.attenuation, geometry, tol)
    auto["first_bounce"] = _decide_first_bounce(config, detector, geometry)
    coarse = None
    if (forced.get("secondary") is None and config.secondary != "none") or forced.get("pile_up") is None:
        coarse = coarse_energies(geometry)
    auto["secondary"] = _decide_secondary(config.secondary, geometry, coarse, tol)
    secondary_on = _resolve("secondary", auto["secondary"], forced).on
    auto["shadow_spot"] = _decide_shadow_spot(geometry, secondary_on)
    auto["shadow_sensor"] = _decide_shadow_sensor(geometry)
    first_bounce_on = _resolve("first_bounce", auto["first_bounce"], forced).on
    auto["pile_up"] = _decide_pile_up(detector, config, coarse, secondary_on,
                                      auto["first_bounce"] if first_bounce_on else None, tol)
    plan = Plan({name: _resolve(name, auto[name], forced) for name in EFFECTS}, tol)
    orders = config.orders_setting()
    fixed = getattr(config, "orders", None) is not None           # written by the user: its residual is measured
    if orders == "auto" or orders >= 3 or fixed:
        plan.decisions["multibounce"] = plan_orders(scene, config, capture, caster, orders, tol,
                                                    plan.on("secondary"), forced.get("secondary") is False)
    return plan


def plan_orders(scene: Scene, config, capture: Capture, caster: RayCaster, orders: int | str, tol: float,
                secondary_on: bool = True, secondary_forced_off: bool = False) -> Decision:
    """The decision on the light the estimator's own orders leave out (:mod:`.orders`): the pilot's shares (``auto``
    and fixed orders ≤ 2), the tracer's lowest and highest order and the residual share left out, in its numbers.
    With the secondary off (forced, or planned off) the tracer starts at order 2, or, when it does not run, the
    pilot's order-2 share joins the residual."""
    shares = None
    if orders == "auto" or orders <= 2:                 # (orders ≤ 2 comes here only when the user fixed it)
        shares = order_shares(scene, capture, caster, config.physics_settings(),
                              (config.time.t_start, config.time.t_stop), config.seed)
    choice, reason = decide_orders(orders, shares, tol, secondary_on, secondary_forced_off)
    residual = choice.residual
    if orders != "auto" and orders <= 2 and residual > RESIDUAL_FRACTION * tol:
        warnings.warn(OmittedOrdersWarning(
            f"{scene.source or scene.name}: orders: {orders} leaves out {residual:.1%} of the in-window light (the "
            f"pilot's estimate, above {RESIDUAL_FRACTION:g} × the tolerance {tol:.2%}); the stated error includes "
            f"it, so no tolerance below {residual:.1%} can be met; orders: auto simulates what the scene calls for"),
            stacklevel=2)
    return OrdersDecision(choice.on, reason, orders != "auto", choice.numbers(), choice=choice)


def _forced_effects(effects: dict) -> dict[str, bool | None]:
    out: dict[str, bool | None] = {}
    for key, value in dict(effects).items():
        if key not in EFFECTS:
            raise ConfigError(f"effects: unknown effect {key!r}; known effects are {list(EFFECTS)}")
        if value is None or (isinstance(value, str) and value == "auto"):
            out[key] = None
        elif isinstance(value, (bool, np.bool_)):
            out[key] = bool(value)
        else:
            raise ConfigError(f"effects.{key} must be true, false or 'auto', got {value!r}")
    return out


def _resolve(name: str, auto: Decision, forced: dict[str, bool | None]) -> Decision:
    value = forced.get(name)
    if value is None:
        return auto
    planner = "on" if auto.on else "off"
    return Decision(value, f"forced {'on' if value else 'off'} by the user (the planner would say {planner}: "
                           f"{auto.reason})", True, auto.numbers, auto.blockers)


# ---------------------------------------------------------------------------------------------------------
# The decisions


def _decide_brdf_angles(scene: Scene) -> Decision:
    kinds = {o.name: (o.material.kind, o.material.is_lambertian, o.material.albedo) for o in scene.objects}
    angular = [n for n, (_, lamb, _) in kinds.items() if not lamb]
    per = {n: ("lambertian f = ρ/π = " + _fmt(rho / np.pi) if lamb else f"{kind}: depends on angles")
           for n, (kind, lamb, rho) in kinds.items()}
    numbers = {"materials": per}
    if angular:
        return Decision(False, "angle work only where needed: Lambertian materials take f = ρ/π ("
                        + ", ".join(n for n in kinds if n not in angular) + "); non-Lambertian ones are "
                        "evaluated in full: " + ", ".join(f"{n} ({kinds[n][0]})" for n in angular), False, numbers)
    return Decision(False, f"all {len(kinds)} materials are Lambertian (f = ρ/π, no angle dependence): "
                    + ", ".join(f"{n} ρ={_fmt(kinds[n][2])}" for n in kinds), False, numbers)


def _decide_attenuation(mu: float, g: PlanGeometry, tol: float) -> Decision:
    emitter_leg = float(np.max(g.capture.emitter_legs))
    longest = emitter_leg + 3.0 * g.diagonal + g.max_sensor_leg
    change = -math.expm1(-mu * longest)
    numbers = {"mu_per_m": mu, "longest_path_m": longest, "max_relative_change": change}
    what = (f"μ = {_fmt(mu)}/m over the longest path L = {_fmt(longest)} m (emitter leg {_fmt(emitter_leg)} "
            f"+ 3 × scene diagonal {_fmt(g.diagonal)} + FoV→sensor {_fmt(g.max_sensor_leg)}): "
            f"1 − e^(−μL) = {_fmt(change)}")
    if mu == 0.0:
        return Decision(False, "no atmospheric attenuation configured (μ = 0)", False, numbers)
    if change < tol:
        return Decision(False, f"{what} < tolerance {_fmt(tol)}", False, numbers)
    return Decision(True, f"{what} ≥ tolerance {_fmt(tol)}", False, numbers)


def _decide_first_bounce(config, detector: spad.DetectorConfig, g: PlanGeometry) -> Decision:
    """Direct spot → sensor return: on when some laser point is strictly inside the FoV, in a recorded
    channel, faces and sees the sensor, arrives in the window and is not gated out (bin-exact)."""
    c, tol = g.capture, g.tol
    if c.convention != "aperture":
        return Decision(False, f"the {c.convention} convention has no direct aperture return")
    rel = c.spots - c.fov_center
    a, b = matmul(rel, c.fov_u), matmul(rel, c.fov_v)
    off_plane = np.abs(matmul(rel, c.fov_normal))
    margin = c.fov_margin(c.spots)                                          # > 0: inside
    pix = c.fov_pixel(c.spots, tol)
    channel = c.channel(np.arange(c.n_lasers), pix)                       # laser point i's own pixel
    edge = FOV_EDGE_REL * max(c.fov_size)                                   # boundary points count as outside
    inside = (off_plane <= tol) & (margin > edge) & (channel >= 0)
    numbers: dict[str, Any] = {"lasers": int(c.n_lasers), "lasers_inside_fov": int(inside.sum()),
                               "inside_margin_m": float(np.max(margin))}
    if not inside.any():
        i = int(np.argmax(margin))
        where = "on the FoV boundary" if off_plane[i] <= tol and abs(margin[i]) <= edge else "outside the FoV"
        what = "laser spot" if c.n_lasers == 1 else "no laser point in a recorded channel; the closest,"
        return Decision(False, f"{what} {np.round(c.spots[i], 4).tolist()} is {where} (in-plane offset "
                        f"({_fmt(a[i])}, {_fmt(b[i])}) m from the FoV centre, half-size ({_fmt(0.5 * c.fov_size[0])}, "
                        f"{_fmt(0.5 * c.fov_size[1])}) m, {_fmt(off_plane[i])} m off its plane)", False, numbers)
    idx = np.flatnonzero(inside)
    to_sensor = c.sensor - c.spots[idx]
    d = np.linalg.norm(to_sensor, axis=1)
    w_s = to_sensor / d[:, None]
    facing = np.einsum("ij,ij->i", w_s, c.spot_normals[idx]) > 0
    seen = np.zeros(len(idx), dtype=bool)
    seen[facing] = g.caster.visible(c.spots[idx][facing], c.spot_normals[idx][facing], c.sensor, None)
    if not seen.any():
        return Decision(False, f"{len(idx)} laser point(s) lie in the FoV but none faces and sees the sensor",
                        False, numbers)
    idx = idx[seen]
    photons, _, t = g.physics.first_bounce_weight(idx)
    before, after = config.irf.support
    lo, hi = t - before, t + after
    axis = config.time
    in_window = (hi >= axis.t_start) & (lo < axis.t_stop)
    numbers.update(arrival_s=[float(t.min()), float(t.max())], detected_photons_per_pulse=float(photons.max()))
    if not in_window.any():
        return Decision(False, f"first bounce arrives at {_fmt(t.min() * 1e9)}–{_fmt(t.max() * 1e9)} ns (IRF "
                        f"support ±{_fmt(before * 1e9)} ns), outside the time window {_fmt(axis.t_start * 1e9)}–"
                        f"{_fmt(axis.t_stop * 1e9)} ns", False, numbers)
    kept = in_window
    if detector.gate is not None:
        n = axis.n_bins
        tail = TAIL_MARGIN_TAUS * detector.diffusion_tail if detector.diffusion_fraction > 0 else 0.0
        open_bin = spad.gate_fraction(detector.bin_edges(n), detector.gate) > 0
        b0 = np.clip(np.floor((lo - axis.t_start) / axis.bin_width), 0, n - 1).astype(np.int64)
        b1 = np.clip(np.ceil((hi + tail - axis.t_start) / axis.bin_width), 0, n - 1).astype(np.int64)
        cum = np.concatenate([[0], np.cumsum(open_bin)])
        kept = in_window & (cum[b1 + 1] - cum[b0] > 0)
        numbers["gate_s"] = list(detector.gate)
        if not kept.any():
            return Decision(False, f"first bounce at {_fmt(t.min() * 1e9)}–{_fmt(t.max() * 1e9)} ns (support to "
                            f"{_fmt((hi.max() + tail) * 1e9)} ns with the detector tail) is removed by the gate "
                            f"{_fmt(detector.gate[0] * 1e9)}–{_fmt(detector.gate[1] * 1e9)} ns", False, numbers)
    numbers["detected_photons_per_pulse"] = float(photons[kept].max())
    return Decision(True, f"{int(kept.sum())} laser point(s) lie in the FoV ({_fmt(margin[idx[kept]].max())} m "
                    f"inside its edge) and see the sensor: direct return of up to {_fmt(photons[kept].max())} "
                    f"detected photons/pulse at {_fmt(t[kept].min() * 1e9)} ns, not gated out", False, numbers)


def _decide_shadow_sensor(g: PlanGeometry) -> Decision:
    c = g.capture
    apex = c.sensor
    corners = g.fov_corners
    centroid = (apex + corners.sum(axis=0)) / 5.0
    faces = np.array([[apex, corners[i], corners[(i + 1) % 4]] for i in range(4)] + [corners[:3]])
    n, o, valid = outward_planes(faces, np.broadcast_to(centroid, (5, 3)))
    hull_v = np.concatenate([apex[None], corners])
    # the FoV's own surface (on or behind the FoV plane) cannot block: exclude it before the test
    front = np.flatnonzero(np.any(g.d_fov > g.tol, axis=1))
    meet = may_meet(g.tri[front], g.normal[front], g.offset[front], g.valid[front],
                     n[None], o[None], valid[None], hull_v[None], g.tol)[:, 0]
    hits = front[meet]
    numbers = {"triangles": int(len(g.tri)), "triangles_in_front_of_fov": int(len(front)),
               "triangles_may_block": int(len(hits))}
    if len(hits) == 0:
        # (no blockers, a complete list: forced on, as confocal.yaml forces it, the transport casts no ray)
        return Decision(False, f"no triangle can cross the sensor→FoV pyramid ({len(front)} triangles in front of "
                        "the FoV plane, all separated by a pyramid or triangle plane): FoV→sensor rays are never "
                        "blocked", False, numbers, ())
    numbers["objects"] = g.names(hits)
    return Decision(True, f"{len(hits)} triangles of {', '.join(g.names(hits))} may cross the sensor→FoV pyramid",
                    False, numbers, tuple(int(f) for f in hits))


def _decide_shadow_spot(g: PlanGeometry, secondary_on: bool) -> Decision:
    """Off when no triangle can meet the hull of (laser points, hidden triangle) for any hidden triangle."""
    if not secondary_on:
        return Decision(False, "only the secondary casts observed point→laser spot shadow rays, and it is off")
    c, tol = g.capture, g.tol
    apexes = c.spots[g.corners]                                             # (A, 3) hull of every laser point
    # targets: hidden-side triangles with no laser corner in their plane (else light grazes them: 0), lit on
    # their reachable side
    apex_dist = matmul(g.normal, apexes.T) - g.offset[:, None]                     # (F, A) signed
    # a shadow ray starts only where the laser lights the side the observer sees (the reachable side)
    facing = (g.side[:, None] == 0) | (g.side[:, None] * apex_dist > tol)
    targets = np.flatnonzero(g.front & g.valid & (np.abs(apex_dist) > tol).all(axis=1) & facing.all(axis=1))
    # a segment from the laser into a closed mesh first crosses a face with the laser on its reachable side
    occluders = np.flatnonzero(g.front & ((g.side == 0) | (g.side[:, None] * apex_dist > -tol).any(axis=1)))
    numbers = {"targets": int(len(targets)), "occluders": int(len(occluders)), "laser_corners": int(len(apexes))}
    if len(targets) == 0:
        return Decision(False, "no surface in front of the laser spot: nothing to shadow", False, numbers)
    if max(len(targets), len(occluders)) > PAIR_TEST_MAX_TRIANGLES:
        return Decision(True, f"{len(occluders)} triangles exceed the pairwise test limit "
                        f"{PAIR_TEST_MAX_TRIANGLES}: shadow rays kept", False, numbers)
    t = g.tri[targets]                                                       # (m, 3, 3)
    if len(apexes) == 1:
        s = np.broadcast_to(apexes[0], (len(t), 3))
        # tetrahedron faces (a,b,c), (s,a,b), (s,b,c), (s,c,a) with opposite vertices s, c, a, b
        faces = np.stack([t, np.stack([s, t[:, 0], t[:, 1]], 1), np.stack([s, t[:, 1], t[:, 2]], 1),
                          np.stack([s, t[:, 2], t[:, 0]], 1)], axis=1)       # (m, 4, 3, 3)
        opposite = np.stack([s, t[:, 2], t[:, 0], t[:, 1]], axis=1)         # (m, 4, 3)
        n, o, valid = outward_planes(faces, opposite)
        hull_v = np.concatenate([s[:, None], t], axis=1)                    # (m, 4, 3)
    else:
        hull_v = np.concatenate([np.broadcast_to(apexes, (len(t),) + apexes.shape), t], axis=1)
        n, o, valid = hull_planes(hull_v)
    # a triangle never shadows itself; stop at the first chunk of occluders that blocks something
    meet = may_meet(g.tri[occluders], g.normal[occluders], g.offset[occluders], g.valid[occluders],
                     n, o, valid, hull_v, tol, exclude=(occluders, targets))
    blockers = occluders[meet.any(axis=1)]
    shadowed = targets[meet.any(axis=0)]
    numbers.update(blocking_triangles=int(len(blockers)), shadowed_triangles=int(len(shadowed)))
    # faces that are neither targets nor occluders (behind every laser plane) cannot block either
    listed = tuple(int(f) for f in blockers)
    if len(blockers) == 0:
        return Decision(False, f"no triangle can cross any segment laser spot → hidden point ({len(targets)} "
                        f"target × {len(occluders)} occluder triangles separated): the spot sees every hidden "
                        "point, shadow rays would all pass", False, numbers, listed)
    numbers.update(blocking_objects=g.names(blockers), shadowed_objects=g.names(shadowed))
    return Decision(True, f"triangles of {', '.join(g.names(blockers))} may shadow {', '.join(g.names(shadowed))} "
                    f"from the laser spot ({len(blockers)} blocking triangles)", False, numbers, listed)


def _secondary_pairs_possible(g: PlanGeometry) -> tuple[bool | None, int]:
    """Whether two hidden triangles can carry light spot → x → x' → FoV (exact necessary condition).

    x must have the laser point strictly on one side of its plane (for some laser corner: a laser point
    inside the grid is on a corner's side), x' a vertex strictly on that side, x a vertex and the FoV a
    corner strictly on one same side of x''s plane, and x' a vertex in front of the FoV plane; the sides
    used must be reachable (closed meshes are seen from the laser's side only).
    Returns (possible, pairs found: stops at the first chunk that has one); possible is None when the scene
    is too large to test.
    """
    c, tol = g.capture, g.tol
    recv = np.flatnonzero(g.hidden & np.any(g.d_fov > tol, axis=1))
    lit = np.flatnonzero(g.hidden & g.front)
    if len(lit) == 0 or len(recv) == 0:
        return False, 0
    if max(len(lit), len(recv)) > PAIR_TEST_MAX_TRIANGLES:
        return None, 0
    spot_side = matmul(g.normal[lit], c.spots[g.corners].T) - g.offset[lit, None]  # (n_lit, A)
    corner_d = matmul(g.fov_corners, g.normal[recv].T) - g.offset[recv]            # (4, r) FoV corners vs x' plane
    fov_pos, fov_neg = (corner_d > tol).any(axis=0), (corner_d < -tol).any(axis=0)
    count = 0
    step = max(1, CHUNK_ELEMENTS // (9 * len(recv)))
    for s in range(0, len(lit), step):
        x = lit[s:s + step]
        sx = g.side[x]
        pos = (spot_side[s:s + step] > tol).any(axis=1) & (sx >= 0)      # x lit on its + side (and reachable)
        neg = (spot_side[s:s + step] < -tol).any(axis=1) & (sx <= 0)
        d_recv = np.einsum("rvk,ak->arv", g.tri[recv], g.normal[x]) - g.offset[x, None, None]
        a = (pos[:, None] & (d_recv > tol).any(axis=-1)) | (neg[:, None] & (d_recv < -tol).any(axis=-1))
        d_x = np.einsum("avk,rk->arv", g.tri[x], g.normal[recv]) - g.offset[None, recv, None]
        b = ((d_x > tol).any(-1) & (fov_pos & (g.side[recv] >= 0))[None]) \
            | ((d_x < -tol).any(-1) & (fov_neg & (g.side[recv] <= 0))[None])
        count += int((a & b & (x[:, None] != recv[None, :])).sum())
        if count:
            break
    return count > 0, count


def _decide_secondary(mode: str, g: PlanGeometry, coarse: "CoarseEnergies | None", tol: float) -> Decision:
    if mode == "none":
        return Decision(False, "config.secondary is 'none' (no secondary estimator selected)")
    possible, pairs = _secondary_pairs_possible(g)
    numbers: dict[str, Any] = {"exchanging_triangle_pairs_found": pairs}
    if possible is False:
        return Decision(False, "no two hidden surfaces can exchange light on a path laser spot → x → x' → FoV "
                        "(every pair is coplanar, back-facing or off the FoV side): the secondary is exactly 0",
                        False, numbers)
    if coarse is None:
        return Decision(True, "not estimated (the secondary is forced): kept", False, numbers)
    numbers.update(coarse_primary=coarse.primary, coarse_secondary=coarse.secondary,
                   coarse_elements=coarse.elements, safety=SECONDARY_SAFETY)
    if coarse.primary <= 0.0:
        return Decision(True, "the coarse quadrature finds no primary light to compare the secondary with; "
                        "secondary kept", False, numbers)
    ratio = coarse.ratio
    estimate = SECONDARY_SAFETY * ratio
    numbers.update(ratio=ratio, estimate=estimate)
    what = (f"coarse secondary/primary energy {_fmt(ratio)} ({coarse.elements} elements"
            f"{'' if len(g.lasers) == 1 else f', max over {len(g.lasers)} laser points'}) × safety "
            f"{_fmt(SECONDARY_SAFETY)} = {_fmt(estimate)}")
    if estimate < tol:
        return Decision(False, f"{what} < tolerance {_fmt(tol)}", False, numbers)
    return Decision(True, f"{what} ≥ tolerance {_fmt(tol)}", False, numbers)


def _pile_up(detector: spad.DetectorConfig, lam: float, window: float, tol: float, source: str) -> Decision:
    """The detector stage's rule (:func:`datagen.spad.pileup.pile_up_decision`) on a Λ known before transport."""
    d = pile_up_decision(detector, lam, window, tol, source)
    return Decision(d.on, d.reason, False, d.numbers)


def _decide_pile_up(detector: spad.DetectorConfig, config, coarse: "CoarseEnergies | None",
                    secondary_on: bool, first_bounce: Decision | None, tol: float) -> Decision:
    n = config.time.n_bins
    widths = detector.widths(n)
    gate = spad.gate_fraction(detector.bin_edges(n), detector.gate)
    background = detector.background_rate * float(np.sum(widths * gate))
    if coarse is None:
        return _pile_up(detector, math.inf, float(widths.sum()), tol, "no flux estimate was made")
    signal = coarse.signal_with_secondary if secondary_on else coarse.signal
    fb = first_bounce.numbers.get("detected_photons_per_pulse", 0.0) if first_bounce is not None else 0.0
    return _pile_up(detector, PILE_UP_SAFETY * signal + fb + background, float(widths.sum()), tol,
                    f"estimate: {_fmt(PILE_UP_SAFETY)} × coarse signal {_fmt(signal)} + first bounce {_fmt(fb)} "
                    f"+ background {_fmt(background)}")


