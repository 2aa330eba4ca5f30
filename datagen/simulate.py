"""The main job: scene → lookins and observed points → transport → envelope L(t) → SPAD histogram.

``simulate(scene, config)`` returns a :class:`Result` holding the binned envelope (expected detected photons
per laser pulse per time bin), its components (room, each object, secondary) and a finite-exposure SPAD
histogram drawn from it. Random streams come from ``SeedSequence(seed, spawn_key=(stream,))`` (DESIGN.md §7):
stream 0 samples the scene, stream 1 the detector noise, so re-drawing noise never changes the envelope.
"""
from __future__ import annotations

import platform
import re
import time
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from . import spad
from .irf import EnvelopeAccumulator, Irf, TimeAxis
from .planner import EFFECTS, plan_effects
from .quadrature import QUADRATURE_EDGE, Quadrature, QuadratureSettings
from .raycast import RayCaster
from .scene import Scene, SceneError, format_validation_error
from .transport import Transport, TransportSettings


STREAM_SAMPLING, STREAM_NOISE = 0, 1
"""spawn_key entries of the random streams (DESIGN.md §7)."""

def stream_rng(seed: int, stream: int) -> np.random.Generator:
    """Generator of random stream ``stream`` under root ``seed``: SeedSequence(seed, spawn_key=(stream,))."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))


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
            (every pair, O(Ñ²) per lookin) or "exact" (the same sum factorised, O(Ñ) per lookin, DESIGN.md §3).
        estimator: "lookin" (the paper's sampler: lookins and hemispherical cameras), "area" (hidden-surface
            area sampling with next-event connections to the spot and the FoV, datagen.area; ``area_samples``
            hidden points; its secondary is "full" whenever ``secondary`` is not "none") or "quadrature" (the
            deterministic hidden-surface quadrature of datagen.quadrature: sub-triangles of edge
            ``quadrature_edge`` metres with exact time binning; aperture captures integrate each pixel region
            with ``quadrature_fov`` × ``quadrature_fov`` FoV cells (None: cells no larger than the edge); a
            planned secondary comes from the area sampler with ``area_samples`` hidden samples per laser point).
        sensor_sampling: "camera" (the paper: FoV points from the lookin cameras) or "connect" (next-event
            connections to ``connect_samples`` stratified points per sensor pixel; forced for point radiance).
        conv_refine: the exact secondary's profile grid is this many times finer than the envelope's grid.
        workers: processes sharing the lookins (1 = in process; the result does not depend on it).
        tolerance: relative accuracy the effect planner works to (effects below it are skipped).
        effects: per effect "auto" (the planner decides) or true/false (forced); see datagen.planner.
        seed: root of every random stream.
        time: output time axis (t_start, bin_width, n_bins); irf: Gaussian IRF (fwhm or sigma).
        attenuation: atmospheric extinction μ in 1/m (C_atm = e^{−μR}).
        count_laser_leg / count_sensor_leg: whether the emitter→spot / FoV→sensor legs count in the time of
            flight (DESIGN.md §1; default False / True as in the paper's code).
        detector: SPAD parameters (datagen.spad.DetectorConfig); its pde scales the envelope.
        batch: lookins per batch (memory bound).
    """

    model_config = ConfigDict(extra="forbid")

    lookins: tuple[int, int] = (10, 10)
    pixels: tuple[int, int] = (60, 60)
    lookin_pdf: Literal["cosine", "uniform"] = "cosine"
    jitter: bool = True
    secondary: Literal["none", "optimized", "full", "exact"] = "full"
    top_k: int = Field(1, ge=1)
    estimator: Literal["lookin", "area", "quadrature"] = "lookin"
    area_samples: int = Field(65536, ge=16)
    quadrature_edge: float = Field(QUADRATURE_EDGE, gt=0.0, allow_inf_nan=False)
    quadrature_fov: int | None = Field(None, ge=1)
    sensor_sampling: Literal["camera", "connect"] = "camera"
    connect_samples: tuple[int, int] = (4, 4)
    conv_refine: int = Field(1, ge=1, le=64)
    workers: int = Field(1, ge=1)
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

    @field_validator("effects")
    @classmethod
    def _effects(cls, value: dict) -> dict:
        unknown = sorted(set(value) - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; known: {list(EFFECTS)}")
        return value

    @field_validator("lookins", "pixels", "connect_samples", mode="before")
    @classmethod
    def _grid(cls, value: Any, info) -> tuple[int, int]:
        return parse_grid(value, info.field_name)

    def detector_config(self) -> "spad.DetectorConfig":
        """The detector config with the TDC bin width taken from the time axis unless given."""
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


def resolve_config(scene: Scene, overrides: dict | None = None) -> SimulationConfig:
    """Merge the scene file's ``simulation`` block with ``overrides`` (e.g. CLI options) and validate.

    Raises:
        SceneError: an invalid value, naming the scene file, the field and the value.
    """
    data = {**scene.defaults, **{k: v for k, v in (overrides or {}).items() if v is not None}}
    try:
        config = SimulationConfig.model_validate(data)
        config.detector_config()
    except ValidationError as exc:
        where = f"{scene.source} (simulation)" if scene.source else "simulation"
        raise SceneError(format_validation_error(exc, where)) from None
    return config


@dataclass
class Result:
    """Output of :func:`simulate`.

    Attributes:
        time_edges: (n_bins+1,) float64 seconds.
        envelope: float64 expected detected photons per pulse per bin (point radiance: 1/(m²·sr) per unit
            power at the spot, per bin), shaped ``channel_shape + (n_bins,)``: (n_bins,) for the paper's
            single-pixel FoV, (ny, nx, n_bins) for a sensor grid / SPAD array / confocal scan, (ly, lx, ny,
            nx, n_bins) for an exhaustive scan.
        components: name → array shaped like ``envelope``; they sum to ``envelope``.
        counts: int64 SPAD histogram over the exposure, shaped like ``envelope``.
        attrs: JSON-able metadata (resolved config, capture, effect plan, timings, versions, statistics).
        laser_points: (ly, lx, 3) float64 laser points on the relay wall (m); sensor_points: (ny, nx, 3);
        wall_normal: (3,) relay-wall normal facing the sensor.
    """

    time_edges: np.ndarray
    envelope: np.ndarray
    components: dict[str, np.ndarray]
    counts: np.ndarray
    attrs: dict = field(default_factory=dict)
    laser_points: np.ndarray | None = None
    sensor_points: np.ndarray | None = None
    wall_normal: np.ndarray | None = None

    @property
    def time_centers(self) -> np.ndarray:
        return 0.5 * (self.time_edges[1:] + self.time_edges[:-1])

    def peak_time(self, name: str | None = None) -> float:
        """Time (s) of the maximum of the envelope or of a component (summed over channels)."""
        y = self.envelope if name is None else self.components[name]
        return float(self.time_centers[int(np.argmax(y.reshape(-1, y.shape[-1]).sum(0)))])

    def area(self, name: str | None = None) -> float:
        """Expected detections per pulse in the window (sum of bins) of the envelope or a component."""
        y = self.envelope if name is None else self.components[name]
        return float(y.sum())


def library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("datagen", "numpy", "scipy", "trimesh", "embreex", "zarr", "pydantic", "torch"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _plan(scene: Scene, config: SimulationConfig, transport: Transport):
    """Run the effect planner (datagen.planner) and apply its decisions to the transport settings.

    Returns the :class:`datagen.planner.Plan`.
    """
    plan = plan_effects(scene, config, transport.capture, transport.caster)
    transport.configure(plan.apply(transport.settings))
    return plan


@dataclass
class Transported:
    """Binned transport output before the detector: per-component envelopes and bookkeeping.

    Attributes:
        names: component names; binned: (n_components, n_channels, n_bins) float64; outside: same without
        the bin axis (energy outside the window); transport: the :class:`Transport` used (capture, settings,
        stats); plan: the effect plan's attributes; seconds: setup / transport / binning wall times.
    """

    names: list[str]
    binned: np.ndarray
    outside: np.ndarray
    transport: Transport
    plan: Any
    seconds: dict


def run_transport(scene: Scene, config: SimulationConfig, rng: np.random.Generator,
                  progress: bool = False) -> Transported:
    """Plan the effects, run the estimator and bin its impulses (scene → transport → envelope)."""
    t0 = time.perf_counter()
    caster = RayCaster(scene)
    transport = Transport(scene, config.transport_settings(), caster)
    plan = _plan(scene, config, transport)
    if config.estimator == "area":
        from .area import AreaSampler, AreaSettings
        ts = transport.settings
        # the planner's shadow_spot decision is about the lookin sampler's secondary; the area sampler's hidden
        # points always need their laser shadow ray (lookins are visible from the spot by construction)
        area = AreaSampler(scene, AreaSettings.from_transport(
            ts, samples=config.area_samples, secondary="none" if ts.secondary == "none" else "full",
            shadow_spot=config.effects.get("shadow_spot") is not False), caster)
        transport = area
    elif config.estimator == "quadrature":
        # shadow rays on the laser and FoV legs: the quadrature's own exact occluder test unless the user forces
        # shadow_spot (the planner's shadow_spot decision concerns the lookin sampler's secondary)
        forced_spot = config.effects.get("shadow_spot")
        transport = Quadrature(scene, QuadratureSettings.from_transport(
            transport.settings, edge=config.quadrature_edge, fov_cells=config.quadrature_fov,
            secondary_samples=config.area_samples,
            shadow_spot=forced_spot if isinstance(forced_spot, bool) else None), caster)
    t_setup = time.perf_counter() - t0
    capture = transport.capture
    names = transport.component_names
    n_ch = capture.n_channels
    acc = EnvelopeAccumulator(config.time, config.irf, len(names) * n_ch)
    bar = None
    if progress:
        from tqdm.auto import tqdm
        if config.estimator == "quadrature":
            total, unit = transport.total_rows, "pair"
        else:
            per = config.area_samples if config.estimator == "area" else config.lookins[0] * config.lookins[1]
            total, unit = per * capture.n_lasers, "sample" if config.estimator == "area" else "lookin"
        bar = tqdm(total=total, unit=unit, desc="transport", leave=False)
    t1 = time.perf_counter()
    transport.run(acc, rng, progress=(bar.update if bar is not None else None))
    if bar is not None:
        bar.close()
    t_transport = time.perf_counter() - t1
    t2 = time.perf_counter()
    binned = acc.binned().reshape(len(names), n_ch, -1)
    outside = acc.outside().reshape(len(names), n_ch)
    seconds = {"setup": t_setup, "transport": t_transport, "binning": time.perf_counter() - t2}
    return Transported(names, binned, outside, transport, plan, seconds)


def simulate(scene: Scene, config: SimulationConfig | None = None, progress: bool = False,
             sampling_rng: np.random.Generator | None = None,
             noise_rng: np.random.Generator | None = None) -> Result:
    """Simulate the envelope and a SPAD histogram for ``scene``.

    Args:
        scene: the scene (see :func:`datagen.load_scene`).
        config: sampling, time axis, IRF and detector; default: the scene's ``simulation`` block.
        progress: show a tqdm bar over lookins.
        sampling_rng, noise_rng: the scene-sampling and detector-noise streams; default
            ``stream_rng(config.seed, STREAM_SAMPLING)`` and ``stream_rng(config.seed, STREAM_NOISE)``. Dataset
            builds pass streams keyed by (dataset seed, split, index, stream) (DESIGN.md §7).
    Returns:
        :class:`Result`.
    Raises:
        SceneError: invalid scene/config (laser spot off every surface, FoV sees no surface, …).
    """
    config = config or resolve_config(scene)
    t0 = time.perf_counter()
    rng = sampling_rng if sampling_rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    tr = run_transport(scene, config, rng, progress)
    return make_result(scene, config, tr, noise_rng, t0)


def make_result(scene: Scene, config: SimulationConfig, tr: Transported,
                noise_rng: np.random.Generator | None, t0: float, extra_attrs: dict | None = None) -> Result:
    """Detector draw and metadata around binned transport output (the last steps of :func:`simulate`)."""
    transport, names = tr.transport, tr.names
    capture = transport.capture
    shape = capture.channel_shape() + (config.time.n_bins,)
    components = {name: tr.binned[i].reshape(shape) for i, name in enumerate(names)}
    envelope = tr.binned.sum(axis=0).reshape(shape)
    detector = config.detector_config()
    plan = tr.plan.refine_pile_up(envelope, detector)
    detector = plan.detector(detector)
    warnings = list(scene.notes)                 # what loading changed (e.g. duplicate faces removed)
    if not envelope.any():
        warnings.append("no light path reaches the FoV: the envelope is zero (no path from the laser spot "
                        "reaches the sensor grid within the time window; counts hold background only)")
    t3 = time.perf_counter()
    noise_rng = noise_rng if noise_rng is not None else stream_rng(config.seed, STREAM_NOISE)
    counts = spad.sample_histogram(spad.rates_from_envelope(envelope, detector), detector, noise_rng)
    t_detect = time.perf_counter() - t3
    st = transport.stats
    settings = transport.settings
    attrs = {
        "scene": scene.name,
        "scene_file": scene.source,
        "config": config.model_dump(mode="json"),
        "detector": detector.model_dump(mode="json"),
        "n_cycles": int(detector.cycles),
        "component_names": names,
        "capture": {"type": capture.kind, "convention": capture.convention,
                    "laser_grid": list(capture.laser_shape), "sensor_grid": list(capture.fov_pixels),
                    "sensor_grid_size": list(capture.fov_size), "sensor_position": capture.sensor.tolist(),
                    "emitter_position": capture.emitter.tolist(), "channel_shape": list(capture.channel_shape())},
        "units": {"time_edges": "s",
                  "envelope": ("expected detected photons per laser pulse per bin" if capture.convention ==
                               "aperture" else "radiance toward the sensor per unit power at the laser spot, "
                               "per bin, 1/(m^2 sr)"),
                  "counts": "detections over the exposure (int64)"},
        "time_zero": "laser pulse at the laser spot" if not config.count_laser_leg else "laser pulse leaves emitter",
        "photons_per_pulse": capture.photons,
        "plan": plan.to_attrs(),
        "warnings": warnings,
        "effects": {
            "primary": True,
            "estimator": config.estimator,
            "secondary": settings.secondary,
            "top_k": config.top_k if settings.secondary == "optimized" else None,
            "sensor_sampling": getattr(settings, "sensor_sampling", None) or (
                "quadrature: sensor points / FoV cells" if config.estimator == "quadrature"
                else "area next-event connections"),
            "shadow_rays": {"spot": settings.shadow_spot, "sensor": settings.shadow_sensor},
            "non_lambertian_brdfs": sorted({o.material.kind for o in scene.objects} - {"lambertian"}),
            "atmospheric_attenuation": settings.attenuation > 0,
            "first_bounce": settings.first_bounce,
            "emitter_to_spot_leg_in_time": config.count_laser_leg,
            "fov_to_sensor_leg_in_time": config.count_sensor_leg,
            "detector_model": detector.model,
        },
        "energy_outside_window": {n: float(v) for n, v in zip(names, tr.outside.sum(1))},
        "stats": {k: int(v) for k, v in vars(st).items() if isinstance(v, (int, np.integer))},
        **({"quadrature": transport.attrs()} if hasattr(transport, "attrs") else {}),
        "timings_s": {**tr.seconds, "detector": t_detect, "total": time.perf_counter() - t0},
        "versions": library_versions(),
        **(extra_attrs or {}),
    }
    lx, ly = capture.laser_shape
    return Result(config.time.edges, envelope, components, counts, attrs,
                  laser_points=capture.spots.reshape(ly, lx, 3), sensor_points=capture.sensor_points(),
                  wall_normal=capture.fov_normal.copy())
