"""What ``simulate`` needs besides the scene: the validated simulation config and the random streams.

:class:`SimulationConfig` (pydantic) merges a scene file's ``simulation`` block with overrides
(:func:`resolve_config`); durations accept strings such as "600ps". Random streams come from
``SeedSequence(seed, spawn_key=(stream,))`` (docs/physics.md §7): stream 0 samples the scene, stream 1 the
detector noise, so re-drawing noise never changes the envelope.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, SerializeAsAny, ValidationError, field_validator, model_validator

from ..errors import ConfigError
from .. import spad
from ..planner import EFFECTS
from ..spad.maps import maps_relative_to
from ..scene import Scene
from ..scene.load import format_validation_error, short_repr
from ..scene.parts import MAX_EXTENT
from ..timing import Irf, TimeAxis
from .confidence import CONFIDENCE
from ..transport import EstimatorOptions, LookinSettings, PhysicsSettings, estimator, estimator_names
from ..transport.base import estimator_options
from ..transport.lookin.estimator import LookinOptions
from ..transport.multibounce.options import MultibounceOptions

STREAM_SAMPLING, STREAM_NOISE = 0, 1
"""spawn_key entries of the random streams (docs/physics.md §7)."""

def stream_rng(seed: int, stream: int) -> np.random.Generator:
    """Generator of random stream ``stream`` under root ``seed``: SeedSequence(seed, spawn_key=(stream,))."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))


MAX_TIME_WINDOW_S = 1.0
"""The time axis lies within ±1 s: the longest light path of a scene within ±``MAX_EXTENT`` m (four legs along the
box's diagonal, 4·2·√3·1e7 m) lasts 0.46 s, so later bins hold nothing, and t_start + n_bins × bin_width stays
finite (a 1e308 s bin overflowed it to inf)."""


class LegacyKeysWarning(FutureWarning):
    """Old simulation keys were translated to the new form (:func:`translate_legacy`); the CLI prints it as one
    ``note: …`` line."""


RENAMED = {"tolerance": "effect_threshold"}
"""Shared simulation keys renamed (old → new): ``tolerance`` was both the planner's threshold and the adaptive
target; in a simulation config it is the planner's :attr:`SimulationConfig.effect_threshold`."""

ERROR_KEYS = {"replicas": "replicas", "error_confidence": "confidence"}
"""Flat keys of the stated error's settings (old key → its field in the ``error`` block, :class:`ErrorOptions`)."""


class ErrorOptions(BaseModel):
    """How a Monte Carlo result's stated error is made: the ``error`` block of a simulation config
    (docs/accuracy.md, "What the stated error is, and how often it bounds").

    Attributes:
        replicas: R, independent replicas a Monte Carlo estimator's sampling is split into (the registry's
            ``replica`` hook, e.g. ``samples`` / R hidden samples, or lookin grids of side / √R, each); their mean
            is the envelope and their spread its error (``attrs["error"]``, :mod:`datagen.simulation.replicas`).
            ``simulate_to_tolerance`` starts from them and adds replicas of the same size. Old flat key
            ``replicas``.
        confidence: the probability q with which the stated error bounds the actual one (the replicas' standard
            error times √F_q(d, ν), :mod:`datagen.simulation.confidence`); a tolerance is met by that bound. None:
            the standard error itself, an RMS estimate that the actual error exceeds about half the time (the
            frozen ``-v1``/``-v2`` suites were built with it). Old flat key ``error_confidence``.
        common_random_numbers: every path draws its random numbers from a slot of its own (the tracer's paths,
            the area sampler's back connections and secondary partners), so that two runs of scenes that differ in
            one object trace the paths that never meet it identically and the error of their *difference* is the
            changed light's alone (capture sequences, docs/motion.md); off: draws for the live paths only (cheaper).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    replicas: int = Field(8, ge=2, le=4096)
    confidence: float | None = Field(CONFIDENCE, ge=0.5, lt=1)
    common_random_numbers: bool = False


def legacy_keys() -> dict[str, dict[str, str]]:
    """Flat keys of the estimators' old settings: old key → {estimator kind: its field}."""
    out: dict[str, dict[str, str]] = {}
    for name in estimator_names():
        for old, new in estimator(name).options.LEGACY.items():
            out.setdefault(old, {})[name] = new
    return out


def _kind_of(value: Any, default: str | None) -> str | None:
    if isinstance(value, str):
        return value
    if isinstance(value, EstimatorOptions):
        return value.kind
    if isinstance(value, dict):
        return value.get("kind", default)
    return default


def _block(value: Any) -> dict:
    """A settings block as a plain mapping (a model dumped; anything else that is not a mapping: empty, for the
    validator to name)."""
    return value.model_dump() if isinstance(value, BaseModel) else dict(value) if isinstance(value, dict) else {}


def _old_name(field: str) -> str:
    return next(old for old, new in ERROR_KEYS.items() if new == field)


def translate_legacy(data: dict, default_kind: str = "lookin") -> tuple[dict, list[str]]:
    """``data`` (a simulation mapping) in the new form, and the old → new moves made (empty: nothing old).

    Flat estimator keys (``lookins``, ``area_samples``, ``quadrature_edge``, …: each estimator's
    :attr:`~datagen.transport.EstimatorOptions.LEGACY`) move into the ``estimator`` block of the chosen kind
    (``estimator`` as a name or a mapping; ``default_kind`` when absent), where the block's own values win; keys of
    another estimator are dropped (a scene's lookin settings under ``--estimator area``). Renamed shared keys
    (:data:`RENAMED`) take their new name; the stated error's flat keys (:data:`ERROR_KEYS`) move into the
    ``error`` block.
    """
    table = legacy_keys()
    old = [k for k in data if k in table or k in RENAMED or k in ERROR_KEYS]
    if not old:
        return data, []
    data, moves = dict(data), []
    for key in [k for k in old if k in RENAMED]:
        value = data.pop(key)
        data.setdefault(RENAMED[key], value)
        moves.append(f"{key} -> {RENAMED[key]}")
    flat_error = {ERROR_KEYS[k]: data.pop(k) for k in old if k in ERROR_KEYS}
    if flat_error:
        block = _block(data.get("error"))
        for field, value in flat_error.items():
            if field in block and block[field] != value:
                raise ValueError(f"{_old_name(field)} {value!r} and error.{field} {block[field]!r} are both given: "
                                 f"keep error.{field}")
            block.setdefault(field, value)
            moves.append(f"{_old_name(field)} -> error.{field}")
        data["error"] = block
    flat = {k: data.pop(k) for k in old if k in table}
    if flat:
        est = data.get("estimator")
        kind = _kind_of(est, default_kind)
        block = (est.model_dump() if isinstance(est, EstimatorOptions) else dict(est) if isinstance(est, dict)
                 else {})
        for key, value in flat.items():
            field = table[key].get(kind)
            if field is None:
                moves.append(f"{key} dropped (not used by the {kind} estimator)")
            elif field in block and block[field] != value:
                raise ValueError(f"{key} {value!r} and estimator.{field} {block[field]!r} are both given: keep "
                                 f"estimator.{field}")
            else:
                block.setdefault(field, value)
                moves.append(f"{key} -> estimator.{field}")
        data["estimator"] = {**block, "kind": kind}
    return data, moves


def legacy_note(moves: list[str], where: str = "simulation") -> str:
    """The one-line deprecation note of :func:`translate_legacy`'s moves."""
    return (f"{where}: old keys translated ({', '.join(moves)}); write the estimator's settings under "
            "estimator: {kind: ..., ...} (docs/accuracy.md)")


class SimulationConfig(BaseModel):
    """Everything ``simulate`` needs besides the scene: the shared physics and the estimator's own settings.
    Durations accept strings such as "600ps".

    Attributes:
        estimator: the estimator and its settings, a mapping with ``kind`` ("lookin", "area", "quadrature" or any
            registered estimator) validated by that estimator's model
            (:class:`datagen.transport.lookin.estimator.LookinOptions`, :class:`~datagen.transport.area.estimator.AreaOptions`,
            :class:`~datagen.transport.quadrature.options.QuadratureOptions`); a bare name means its defaults. Old flat keys (``lookins``, ``area_samples``, ``quadrature_edge``, …) are
            translated with one :class:`LegacyKeysWarning` (:func:`translate_legacy`).
        secondary: "none", "optimized" (the lookin estimator's strongest ``top_k`` per lookin and FoV point),
            "full" (every pair) or "exact" (the same sum factorised, O(Ñ) per lookin, docs/physics.md §3); the
            area sampler and the quadrature compute it in full whenever it is not "none".
        orders: how many hidden vertices a path may have (docs/physics.md §2, "Orders"): 1 (primary only, the
            same as ``secondary: none``), 2 (primary and secondary), N ≥ 3 (every order up to N: the component
            ``multibounce`` holds orders 3..N) or "auto" (the effect planner's pilot decides whether orders ≥ 3 are
            simulated, :mod:`datagen.planner.orders`). Unset: "auto", except with ``secondary: none`` (the old
            spelling of orders 1, which the frozen suites use): 1.
        multibounce: the order ≥ 3 tracer's settings (:class:`MultibounceOptions`), used when orders ≥ 3 are
            simulated.
        workers: processes sharing the work (1 = in process; the result does not depend on it).
        error: how the stated Monte Carlo error is made (:class:`ErrorOptions`): ``replicas`` R and the
            ``confidence`` with which it bounds the actual error (old flat keys ``replicas``, ``error_confidence``).
        effect_threshold: relative change of the envelope below which the effect planner skips an effect (old key
            ``tolerance``; ``simulate_to_tolerance`` sets it to its target).
        effects: per effect "auto" (the planner decides) or true/false (forced); see datagen.planner.
        seed: root of every random stream.
        time: output time axis (t_start, bin_width, n_bins); irf: Gaussian IRF (fwhm or sigma).
        attenuation: atmospheric extinction μ in 1/m (C_atm = e^{−μR}).
        count_laser_leg / count_sensor_leg: whether the emitter→spot / FoV→sensor legs count in the time of
            flight (docs/physics.md §1; default False / True as in the paper's code).
        detector: SPAD parameters (datagen.spad.DetectorConfig); its pde scales the envelope.
        split_components: one envelope per primary component (the room, each hidden object: ``Result.components``);
            False: the primary summed into one component, "primary" (:meth:`datagen.scene.Scene.with_summed_primary`;
            "secondary" and "first_bounce" stay apart), which spares a fine histogram and an IRF convolution per
            object (a dataset that stores no components sets it False; the envelope is the same sum).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    estimator: SerializeAsAny[EstimatorOptions] = Field(default_factory=lambda: estimator_options("lookin"))
    secondary: Literal["none", "optimized", "full", "exact"] = "full"
    orders: int | Literal["auto"] | None = None
    multibounce: MultibounceOptions = Field(default_factory=lambda: MultibounceOptions())
    workers: int = Field(1, ge=1)
    error: ErrorOptions = Field(default_factory=lambda: ErrorOptions())
    effect_threshold: float = Field(0.01, gt=0, lt=1)
    effects: dict[str, bool | Literal["auto"]] = Field(default_factory=dict)
    seed: int = Field(0, ge=0)
    time: TimeAxis = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=5000)
    irf: Irf = Irf(fwhm=600e-12)
    attenuation: float = Field(0.0, ge=0.0)
    count_laser_leg: bool = False
    count_sensor_leg: bool = True
    detector: dict = Field(default_factory=dict)
    split_components: bool = True

    @model_validator(mode="before")
    @classmethod
    def _legacy(cls, data: Any) -> Any:
        if isinstance(data, dict):
            data, moves = translate_legacy(data)
            if moves:
                warnings.warn(legacy_note(moves), LegacyKeysWarning, stacklevel=2)
        return data

    @field_validator("estimator", mode="before")
    @classmethod
    def _estimator(cls, value: Any) -> EstimatorOptions:
        return estimator_options(value)

    @field_validator("orders", mode="before")
    @classmethod
    def _orders(cls, value: Any) -> Any:
        if value is None or value == "auto":
            return value
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"orders must be an integer >= 1 or 'auto', got {value!r}")
        return int(value)

    @model_validator(mode="after")
    def _orders_and_secondary(self) -> "SimulationConfig":
        if self.orders == 1:                   # primary only: no secondary, whatever its mode
            self.secondary = "none"
        elif self.orders is not None and self.secondary == "none":
            raise ValueError(f"orders: {self.orders} asks for the secondary but secondary is 'none' (its old spelling "
                             "of orders: 1): drop secondary: none, or write orders: 1")
        return self

    def tracer_paths(self, n_lasers: int = 1) -> int:
        """Light paths per laser point of the order ≥ 3 tracer's run (:meth:`MultibounceOptions.paths_per_laser` of
        ``multibounce`` for this estimator's ``samples``, shared by ``n_lasers`` laser points)."""
        return self.multibounce.paths_per_laser(getattr(self.estimator, "samples", None), n_lasers)

    def orders_setting(self) -> int | str:
        """The orders asked for: ``orders``, or when unset 1 with ``secondary: none`` and "auto" otherwise."""
        if self.orders is not None:
            return self.orders
        return 1 if self.secondary == "none" else "auto"

    @field_validator("effects")
    @classmethod
    def _effects(cls, value: dict) -> dict:
        unknown = sorted(set(value) - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; known: {list(EFFECTS)}")
        return value

    @field_validator("time")
    @classmethod
    def _window(cls, value: TimeAxis) -> TimeAxis:
        if not -MAX_TIME_WINDOW_S <= value.t_start < value.t_stop <= MAX_TIME_WINDOW_S:
            raise ValueError(f"the window t_start .. t_start + n_bins × bin_width = {value.t_start:.3g} .. "
                             f"{value.t_stop:.3g} s must lie within ±{MAX_TIME_WINDOW_S:g} s (no light path in a "
                             f"scene within ±{MAX_EXTENT:g} m lasts longer than 0.5 s)")
        return value

    def with_estimator(self, **updates: Any) -> "SimulationConfig":
        """A copy whose estimator settings have ``updates`` (e.g. a replica's ``samples``)."""
        return self.model_copy(update={"estimator": self.estimator.model_copy(update=updates)})

    def detector_config(self) -> "spad.DetectorConfig":
        """The detector config with the TDC bin width and start taken from the time axis unless given
        (:data:`TIME_AXIS_FIELDS`; an invalid one is the time axis's fault: :func:`detector_error`)."""
        data = {"bin_width": self.time.bin_width, "t_start": self.time.t_start, **self.detector}
        return spad.DetectorConfig.model_validate(data)

    def physics_settings(self) -> PhysicsSettings:
        """The estimator-neutral physics the effect planner decides on (:meth:`datagen.planner.Plan.apply`): μ
        (0 when ``effects.attenuation`` is forced off), the detector's PDE, the leg switches, and the shadow-ray,
        first-bounce and BRDF switches at the value ``effects`` forces or their default (shadow rays on, first
        bounce and full BRDF angles off). No estimator's sampling fields: each estimator builds its own settings
        from these (its registry entry's ``from_config``)."""
        forced = {k: v for k, v in self.effects.items() if isinstance(v, bool)}
        attenuation = self.attenuation if forced.get("attenuation", True) else 0.0
        return PhysicsSettings(attenuation=attenuation, pde=self.detector_config().pde,
                               count_laser_leg=self.count_laser_leg, count_sensor_leg=self.count_sensor_leg,
                               shadow_spot=forced.get("shadow_spot", True),
                               shadow_sensor=forced.get("shadow_sensor", True),
                               first_bounce=forced.get("first_bounce", False),
                               brdf_angles=forced.get("brdf_angles", False))

    def transport_settings(self) -> LookinSettings:
        """Lookin settings from this config, unplanned, for the sampling figures and the analyses that run an
        estimator directly (:func:`datagen.analysis.accuracy.run_estimator`, the converged reference): the
        physics of :meth:`physics_settings`, the secondary mode (``secondary``, "none" when ``effects.secondary``
        is forced off), the lookin sampling of a lookin ``estimator`` block
        (:meth:`~datagen.transport.lookin.LookinOptions.transport_fields`; the lookin defaults for any other
        estimator), and ``workers``. ``simulate`` does not use them."""
        forced = {k: v for k, v in self.effects.items() if isinstance(v, bool)}
        secondary = self.secondary if forced.get("secondary", True) else "none"
        sampling = self.estimator.transport_fields() if isinstance(self.estimator, LookinOptions) else {}
        return LookinSettings(**self.physics_settings().switches(), **sampling, secondary=secondary,
                              workers=self.workers)


def merge_simulation(base: dict, overrides: dict) -> dict:
    """``overrides`` over ``base`` (both simulation mappings in the new form, :func:`translate_legacy`): the
    ``error`` block is merged key by key, the estimator block when ``overrides`` keeps its kind (or gives none), and replaced when it
    names another estimator (whose defaults then apply)."""
    out = {**base, **overrides}
    if "error" in base and "error" in overrides:
        out["error"] = {**_block(base["error"]), **_block(overrides["error"])}
    if "estimator" in base and "estimator" in overrides:
        old, new = base["estimator"], overrides["estimator"]
        old = old.model_dump() if isinstance(old, EstimatorOptions) else {"kind": old} if isinstance(old, str) else old
        new = new.model_dump() if isinstance(new, EstimatorOptions) else {"kind": new} if isinstance(new, str) else new
        if isinstance(old, dict) and isinstance(new, dict) and new.get("kind", old.get("kind")) == old.get("kind"):
            out["estimator"] = {**old, **new}
    return out


def orders_option(value: str | None, name: str = "") -> int | str | None:
    """A command-line ``orders`` value: None, "auto", or an integer >= 1 (a string). Raises ValueError (ConfigError
    when ``name``, the option, is given: the message names it) for anything else."""
    if value is None or value.strip().lower() == "auto":
        return None if value is None else "auto"
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        message = f"give an integer >= 1 or auto, got {value!r}"
        raise ConfigError(f"{name} must be an integer >= 1 or auto, got {value!r}") if name else ValueError(message)
    return n


def merge_overrides(defaults: dict, overrides: dict) -> tuple[dict, list[str]]:
    """``overrides`` (None values left out) over ``defaults`` (a scene's or room's ``simulation`` block), both
    possibly in the old flat form, merged in the new form (:func:`merge_simulation`), and the old → new moves
    made in ``defaults`` (the old keys of ``overrides``, the command-line flags' names, are the documented way
    to override one knob and make none). As the old flat merge did, a ``defaults`` block without an estimator
    mapping takes the estimator ``overrides`` name, and its flat keys apply to that estimator. An ``orders`` of
    ``overrides`` (other than 1) beats the old spelling ``secondary: none`` (= orders 1) of ``defaults``."""
    given = {k: v for k, v in overrides.items() if v is not None}
    if given.get("orders", 1) != 1 and "secondary" not in given and (defaults or {}).get("secondary") == "none":
        given["secondary"] = "full"
    base = dict(defaults)
    kind = _kind_of(base.get("estimator"), "lookin")
    final = _kind_of(given.get("estimator"), kind)
    moves = []
    if final != kind:       # the flat keys of defaults apply to the estimator overrides choose
        table = legacy_keys()
        flat = {k: base.pop(k) for k in list(base) if k in table}
        flat, moves = translate_legacy({**flat, "estimator": final})
        given = merge_simulation(flat, translate_legacy(given, final)[0])
    base, more = translate_legacy(base)
    given, _ = translate_legacy(given, kind)
    return merge_simulation(base, given), moves + more


TIME_AXIS_FIELDS = ("t_start", "bin_width")
"""Detector fields that default to the simulation time axis's (``time.t_start``, ``time.bin_width``)."""


def detector_error(exc: ValidationError, config: SimulationConfig, source: str | None, head: str = "detector",
                   time_head: str = "time") -> str:
    """One line for a failed :meth:`SimulationConfig.detector_config`: a problem with a field the detector took
    from the time axis (:data:`TIME_AXIS_FIELDS` not in ``config.detector``) names ``time_head``.field (e.g.
    ``time.t_start``, which the user wrote), not the detector's; others are :func:`format_validation_error`'s
    lines under ``head``."""
    inherited = set(TIME_AXIS_FIELDS) - set(config.detector)
    for err in exc.errors():
        name = err["loc"][0] if err["loc"] else None
        if name in inherited:
            msg = " ".join(str(err["msg"]).split()).removeprefix("Value error, ")
            what = "bins start at" if name == "t_start" else "bin width is"
            where = f"{source}: " if source else ""
            return (f"{where}{time_head}.{name}: {msg} (got {short_repr(err.get('input'))}): the detector's TDC "
                    f"{what} {time_head}.{name} (within the laser cycle) unless {head}.{name} is given")
    return format_validation_error(exc, source or None, head=head)


def resolve_config(scene: Scene, overrides: dict | None = None) -> SimulationConfig:
    """Merge the scene file's ``simulation`` block with ``overrides`` (e.g. CLI options; None values are left out)
    and validate (:func:`merge_simulation`). The map paths of the scene's ``detector`` block (``gain_map``,
    ``background_map``) are relative to the scene file.

    ``overrides`` may use the flat keys the command-line flags set (``lookins``, ``area_samples``,
    ``quadrature_edge``, …): they are translated silently for the estimator ``overrides`` or the scene chooses. Old
    keys in the scene's block are translated with one :class:`LegacyKeysWarning` naming the scene file.

    Raises:
        ConfigError: an invalid value, naming the scene file, the field and the value.
    """
    where = f"{scene.source} (simulation)" if scene.source else "simulation"
    overrides = dict(overrides or {})
    defaults = scene.defaults
    if scene.source and isinstance(defaults.get("detector"), dict):      # its map paths: from the scene file's folder
        defaults = {**defaults, "detector": maps_relative_to(defaults["detector"], Path(scene.source).parent)}
    try:
        data, moves = merge_overrides(defaults, overrides)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if moves:
        warnings.warn(legacy_note(moves, where), LegacyKeysWarning, stacklevel=2)
    try:
        config = SimulationConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, where)) from None
    try:
        config.detector_config()
    except ValidationError as exc:
        raise ConfigError(detector_error(exc, config, where)) from None
    return config
