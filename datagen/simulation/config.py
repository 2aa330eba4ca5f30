"""What ``simulate`` needs besides the scene: the validated simulation config and the random streams.

:class:`SimulationConfig` (pydantic) merges a scene file's ``simulation`` block with overrides
(:func:`resolve_config`); durations accept strings such as "600ps". Random streams come from
``SeedSequence(seed, spawn_key=(stream,))`` (docs/physics.md §7): stream 0 samples the scene, stream 1 the
detector noise, so re-drawing noise never changes the envelope.
"""
from __future__ import annotations

import re
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .. import spad
from ..planner import EFFECTS
from ..scene import MAX_EXTENT, Scene, SceneError, format_validation_error, short_repr
from ..timing import Irf, TimeAxis
from ..transport import QUADRATURE_EDGE, TransportSettings, estimator_names

STREAM_SAMPLING, STREAM_NOISE = 0, 1
"""spawn_key entries of the random streams (docs/physics.md §7)."""

def stream_rng(seed: int, stream: int) -> np.random.Generator:
    """Generator of random stream ``stream`` under root ``seed``: SeedSequence(seed, spawn_key=(stream,))."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))


MAX_TIME_WINDOW_S = 1.0
"""The time axis lies within ±1 s: the longest light path of a scene within ±``MAX_EXTENT`` m (four legs along the
box's diagonal, 4·2·√3·1e7 m) lasts 0.46 s, so later bins hold nothing, and t_start + n_bins × bin_width stays
finite (a 1e308 s bin overflowed it to inf)."""

_GRID = re.compile(r"^\s*(\d+)\s*[x×X]\s*(\d+)\s*$")


def parse_grid(value: Any, field_name: str) -> tuple[int, int]:
    """Read a grid size from ``"10x10"``, ``10`` (→ 10×10) or ``[10, 10]``; both counts ≥ 1."""
    if isinstance(value, str):
        m = _GRID.match(value)
        if not m:
            raise ValueError(f"{field_name} must look like '10x10', got {value!r}")
        grid = (int(m.group(1)), int(m.group(2)))
    elif isinstance(value, int) and not isinstance(value, bool):
        grid = (value, value)
    elif isinstance(value, (list, tuple)) and len(value) == 2:
        grid = (int(value[0]), int(value[1]))
    else:
        raise ValueError(f"{field_name} must look like '10x10', got {value!r}")
    if min(grid) < 1:
        raise ValueError(f"{field_name} counts must be >= 1, got {value!r}")
    return grid


class SimulationConfig(BaseModel):
    """Everything ``simulate`` needs besides the scene. Durations accept strings such as "600ps".

    Attributes:
        lookins, pixels: lookin grid √N×√N and camera l×p ("10x10", "60x60" are the paper's).
        lookin_pdf: hemisphere sampling at the spot ("cosine" or "uniform").
        jitter: stratified jitter of lookin rays and camera pixels (False: the paper's regular grids).
        secondary: "none", "optimized" (paper §4, strongest ``top_k`` per lookin and FoV point), "full"
            (every pair, O(Ñ²) per lookin) or "exact" (the same sum factorised, O(Ñ) per lookin, docs/physics.md §3).
        estimator: "lookin" (the paper's sampler: lookins and hemispherical cameras), "area" (hidden-surface
            area sampling with next-event connections to the spot and the FoV, datagen.transport.area; ``area_samples``
            hidden points; its secondary is "full" whenever ``secondary`` is not "none") or "quadrature" (the
            deterministic hidden-surface quadrature of datagen.transport.quadrature: sub-triangles of edge
            ``quadrature_edge`` metres with exact time binning; aperture captures integrate each pixel region
            with ``quadrature_fov`` × ``quadrature_fov`` FoV cells (None: cells no larger than the edge); a
            planned secondary comes from the area sampler with ``area_samples`` hidden samples per laser point);
            ``quadrature_grading`` r (None: off) first cuts hidden triangles into 4 while longer than r × their
            distance to the scanned points, so sub-triangles near the scan are finer (datagen.transport.quad_grading).
        sensor_sampling: "camera" (the paper: FoV points from the lookin cameras) or "connect" (next-event
            connections to ``connect_samples`` stratified points per sensor pixel; forced for point radiance).
        conv_refine: the exact secondary's profile grid is this many times finer than the envelope's grid.
        workers: processes sharing the lookins (1 = in process; the result does not depend on it).
        replicas: R, independent replicas a Monte Carlo estimator's sampling is split into (``area_samples`` /
            R hidden samples, or lookin grids of side / √R, each); their mean is the envelope and their spread
            its error estimate (``attrs["error"]``, :mod:`datagen.simulation.replicas`). ``simulate_to_tolerance``
            starts from them and adds replicas of the same size.
        tolerance: relative accuracy the effect planner works to (effects below it are skipped).
        effects: per effect "auto" (the planner decides) or true/false (forced); see datagen.planner.
        seed: root of every random stream.
        time: output time axis (t_start, bin_width, n_bins); irf: Gaussian IRF (fwhm or sigma).
        attenuation: atmospheric extinction μ in 1/m (C_atm = e^{−μR}).
        count_laser_leg / count_sensor_leg: whether the emitter→spot / FoV→sensor legs count in the time of
            flight (docs/physics.md §1; default False / True as in the paper's code).
        detector: SPAD parameters (datagen.spad.DetectorConfig); its pde scales the envelope.
        batch: lookins per batch (memory bound).
        split_components: one envelope per primary component (the room, each hidden object: ``Result.components``);
            False: the primary summed into one component, "primary" (:meth:`datagen.scene.Scene.with_summed_primary`;
            "secondary" and "first_bounce" stay apart), which spares a fine histogram and an IRF convolution per
            object (a dataset that stores no components sets it False; the envelope is the same sum).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    secondary: Literal["none", "optimized", "full", "exact"] = "full"
    top_k: int = Field(1, ge=1)
    estimator: str = "lookin"
    area_samples: int = Field(65536, ge=16)
    quadrature_edge: float = Field(QUADRATURE_EDGE, gt=0.0, allow_inf_nan=False)
    quadrature_fov: int | None = Field(None, ge=1)
    quadrature_grading: float | None = Field(None, gt=0, allow_inf_nan=False)
    sensor_sampling: Literal["camera", "connect"] = "camera"
    connect_samples: tuple[int, int] = (4, 4)
    conv_refine: int = Field(1, ge=1, le=64)
    workers: int = Field(1, ge=1)
    replicas: int = Field(8, ge=2, le=4096)
    tolerance: float = Field(0.01, gt=0, lt=1)
    effects: dict[str, bool | Literal["auto"]] = Field(default_factory=dict)
    seed: int = Field(0, ge=0)
    time: TimeAxis = TimeAxis(t_start=0.0, bin_width=20e-12, n_bins=5000)
    irf: Irf = Irf(fwhm=600e-12)
    attenuation: float = Field(0.0, ge=0.0)
    count_laser_leg: bool = False
    count_sensor_leg: bool = True
    detector: dict = Field(default_factory=dict)
    batch: int = Field(32, ge=1)
    split_components: bool = True

    @field_validator("effects")
    @classmethod
    def _effects(cls, value: dict) -> dict:
        unknown = sorted(set(value) - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; known: {list(EFFECTS)}")
        return value

    @field_validator("estimator")
    @classmethod
    def _estimator(cls, value: str) -> str:
        if value not in estimator_names():
            raise ValueError(f"unknown estimator {value!r}; known: {list(estimator_names())}")
        return value

    @field_validator("time")
    @classmethod
    def _window(cls, value: TimeAxis) -> TimeAxis:
        if not -MAX_TIME_WINDOW_S <= value.t_start < value.t_stop <= MAX_TIME_WINDOW_S:
            raise ValueError(f"the window t_start .. t_start + n_bins × bin_width = {value.t_start:.3g} .. "
                             f"{value.t_stop:.3g} s must lie within ±{MAX_TIME_WINDOW_S:g} s (no light path in a "
                             f"scene within ±{MAX_EXTENT:g} m lasts longer than 0.5 s)")
        return value

    @field_validator("lookins", "pixels", "connect_samples", mode="before")
    @classmethod
    def _grid(cls, value: Any, info) -> tuple[int, int]:
        return parse_grid(value, info.field_name)

    def detector_config(self) -> "spad.DetectorConfig":
        """The detector config with the TDC bin width and start taken from the time axis unless given
        (:data:`TIME_AXIS_FIELDS`; an invalid one is the time axis's fault: :func:`detector_error`)."""
        data = {"bin_width": self.time.bin_width, "t_start": self.time.t_start, **self.detector}
        return spad.DetectorConfig.model_validate(data)

    def transport_settings(self) -> TransportSettings:
        forced = {k: v for k, v in self.effects.items() if isinstance(v, bool)}
        secondary = self.secondary if forced.get("secondary", True) else "none"
        attenuation = self.attenuation if forced.get("attenuation", True) else 0.0
        return TransportSettings(lookins=self.lookins, pixels=self.pixels, lookin_pdf=self.lookin_pdf,
                                 jitter=self.jitter, secondary=secondary, top_k=self.top_k,
                                 sensor_sampling=self.sensor_sampling, connect_samples=self.connect_samples,
                                 attenuation=attenuation, pde=self.detector_config().pde,
                                 count_laser_leg=self.count_laser_leg, count_sensor_leg=self.count_sensor_leg,
                                 shadow_spot=forced.get("shadow_spot", True),
                                 shadow_sensor=forced.get("shadow_sensor", True),
                                 first_bounce=forced.get("first_bounce", False),
                                 brdf_angles=forced.get("brdf_angles", False),
                                 conv_refine=self.conv_refine, batch=self.batch, workers=self.workers)


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
    """Merge the scene file's ``simulation`` block with ``overrides`` (e.g. CLI options) and validate.

    Raises:
        SceneError: an invalid value, naming the scene file, the field and the value.
    """
    data = {**scene.defaults, **{k: v for k, v in (overrides or {}).items() if v is not None}}
    where = f"{scene.source} (simulation)" if scene.source else "simulation"
    try:
        config = SimulationConfig.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, where)) from None
    try:
        config.detector_config()
    except ValidationError as exc:
        raise SceneError(detector_error(exc, config, where)) from None
    return config
