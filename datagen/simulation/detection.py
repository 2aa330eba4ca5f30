"""The detector stage of a simulation: binned transport output → pile-up decision → SPAD counts → :class:`Result`
(scene → sampling → transport → timing → **detector**; docs/physics.md §6, docs/planner.md "Pile-up").

:func:`make_result` is the last step of :func:`datagen.simulate` and of the tolerance loop; :func:`detector_model`
decides pile-up from the envelope itself; :func:`detector_counts` draws the histogram;
:func:`zero_envelope_warning` says when the light arrives outside the window; :func:`direct_times` and
:func:`attenuate_direct` model ``detector.direct`` (the direct light attenuated by a stated factor, at every time or
under a time gate, docs/detector.md).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
import numpy as np

from .. import spad
from ..errors import ConfigError
from ..planner import Plan
from ..planner.orders import orders_record
from ..scene import Scene
from ..spad.maps import check_map_shape, direct_factor
from ..spad.pileup import counting_detector, pile_up_from_envelope
from ..units import SPEED_OF_LIGHT
from ..transport.base import Estimator
from .config import STREAM_NOISE, SimulationConfig, stream_rng
from .fov_sampling import zero_reason
from .provenance import library_versions


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


@dataclass
class Transported:
    """Binned transport output before the detector: per-component envelopes and bookkeeping.

    Attributes:
        names: component names; binned: (n_components, n_channels, n_bins) float64; outside: same without
        the bin axis (energy outside the window); transport: the estimator used (capture, settings, stats);
        plan: the effect :class:`~datagen.planner.Plan`; seconds: setup / transport / binning wall times.
    """

    names: list[str]
    binned: np.ndarray
    outside: np.ndarray
    transport: Estimator
    plan: Plan
    seconds: dict


def detector_model(envelope: np.ndarray, config: SimulationConfig, plan_attrs: dict,
                   rates: np.ndarray | None = None) -> tuple[spad.DetectorConfig, dict]:
    """The detector stage's pile-up decision: the detector model to draw the counts with, and the result's
    ``attrs["plan"]`` with its ``pile_up`` entry from that decision.

    Unless ``config.effects.pile_up`` is forced, pile-up is decided from the envelope itself (exact Λ:
    :func:`datagen.spad.pileup.pile_up_from_envelope`, tolerance ``config.effect_threshold``), replacing the
    planner's preview; a forced value stands as the plan recorded it. The effect planner is not consulted.

    Args:
        envelope: (..., n_bins) float64 expected detected photons per pulse per bin.
        config: the simulation config (detector, effects, tolerance).
        plan_attrs: the plan's record (:meth:`datagen.planner.Plan.to_attrs`), effect → {on, forced, reason,
            numbers}.
        rates: the envelope's avalanche rates under the configured detector when the caller has them
            (:func:`datagen.spad.rates_from_envelope`; the Poisson version of a detector has the same).
    Returns:
        (:class:`~datagen.spad.DetectorConfig`: the configured one, or its Poisson version when pile-up is off;
        the plan record with ``pile_up`` as decided here).
    Raises:
        ValueError: an envelope the detector refuses (:func:`datagen.spad.rates_from_envelope`).
    """
    detector = config.detector_config()
    forced = config.effects.get("pile_up")
    if isinstance(forced, bool):
        on = forced
    else:
        d = pile_up_from_envelope(envelope, detector, config.effect_threshold, rates)
        on = d.on
        plan_attrs = {**plan_attrs, "pile_up": {"on": bool(d.on), "forced": False, "reason": d.reason,
                                                "numbers": dict(d.numbers)}}
    return counting_detector(detector, on), plan_attrs


def detector_counts(envelope: np.ndarray, config: SimulationConfig, plan_attrs: dict,
                    noise_rng: np.random.Generator, where: str = "") -> tuple[np.ndarray, spad.DetectorConfig, dict]:
    """The detector stage on an envelope (..., n_bins) float64 of expected detected photons per pulse per bin: one
    rates array (:func:`datagen.spad.rates_from_envelope`; the counting detector's are the configured one's) for
    the pile-up decision (:func:`detector_model`) and the draw (:func:`datagen.spad.sample_histogram`). Returns
    (counts (..., n_bins) int64, the detector drawn with, the plan record with its ``pile_up`` entry).

    Raises:
        ConfigError: an envelope or exposure the detector refuses (e.g. too long to event-simulate), one line
            prefixed ``where`` (the scene file).
    """
    try:
        rates = spad.rates_from_envelope(envelope, config.detector_config())
        detector, plan_attrs = detector_model(envelope, config, plan_attrs, rates)
        counts = spad.sample_histogram(rates, detector, noise_rng)
    except ValueError as exc:
        raise ConfigError(f"{where}detector: {' '.join(str(exc).split())}") from None
    return counts, detector, plan_attrs


def direct_times(capture, config: SimulationConfig) -> np.ndarray:
    """(ny, nx) s: each confocal scan point's direct return on the simulation's time axis, the wall legs it counts
    (emitter → point with ``count_laser_leg``, point → sensor with ``count_sensor_leg``, docs/physics.md §1).

    Raises:
        ConfigError: a capture other than a confocal scan (its direct return is not one time per channel).
    """
    if capture.kind != "confocal" or capture.legacy_single_pixel:
        raise ConfigError(f"detector.direct: the direct light is gated per scan point of a confocal scan; this capture "
                          f"is {capture.kind!r} (drop detector.direct, or scan confocally)")
    points = capture.sensor_points()
    legs = np.zeros(points.shape[:-1])
    if config.count_laser_leg:
        legs += np.linalg.norm(points - capture.emitter, axis=-1)
    if config.count_sensor_leg:
        legs += np.linalg.norm(points - capture.sensor, axis=-1)
    return legs / SPEED_OF_LIGHT


def attenuate_direct(envelope: np.ndarray, components: dict[str, np.ndarray], capture,
                     config: SimulationConfig, where: str = "") -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The envelope and components as the detector sees them with ``detector.direct`` applied (docs/detector.md):
    without ``until``, the ``first_bounce`` component times ``attenuation`` at every time and the envelope less the
    light removed (the other components untouched); with ``until``, every array's light before ``until`` after each
    scan point's direct return (:func:`direct_times`) times ``attenuation`` (:func:`datagen.spad.maps.direct_factor`);
    with ``counts_map``, the ``first_bounce`` component first given that pattern over the scan
    (:func:`_direct_counts_map`). Unchanged (the same objects) when ``detector.direct`` is not set.

    Raises:
        ConfigError: a direct attenuation without ``until``, or a ``counts_map``, where the simulation computes no
            direct light (``effects.first_bounce`` off; one line prefixed ``where``, the scene file); a
            ``counts_map`` or ``gain_map`` whose shape is not the scan's; a gate on a capture other than a confocal
            scan.
    """
    detector = config.detector_config()
    direct = detector.direct
    if direct is None:
        return envelope, components
    if "first_bounce" not in components and (direct.until is None or direct.counts_map is not None):
        what = (f"{{attenuation: {direct.attenuation:g}}} attenuates" if direct.counts_map is None
                else "counts_map shapes")
        raise ConfigError(f"{where}detector.direct: {what} the direct light (the first_bounce component), which "
                          "this simulation does not compute; set simulation.effects.first_bounce: true"
                          + (", or give detector.direct.until for a time gate" if direct.counts_map is None else ""))
    if direct.counts_map is not None:
        try:
            envelope, components = _direct_counts_map(envelope, components, detector, where)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if direct.until is None:
        first = components["first_bounce"]
        kept = first * direct.attenuation
        return envelope - (first - kept), {**components, "first_bounce": kept}
    factor = direct_factor(config.time.edges, direct_times(capture, config), direct)
    return envelope * factor, {name: a * factor for name, a in components.items()}


def _direct_counts_map(envelope: np.ndarray, components: dict[str, np.ndarray], detector,
                       where: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The ``first_bounce`` component scaled point by point so that what the detector sees of it (times
    ``detector.gain_map``, G) follows ``detector.direct.counts_map`` (M), its scan total seen unchanged: with F_p
    the component's total at point p, F_p·G_p becomes M_p·Σ(F·G)/ΣM (docs/detector.md, "The direct light,
    attenuated"). Points where no direct light was simulated stay dark."""
    first = components["first_bounce"]
    lead = first.shape[:-1]
    target = check_map_shape(detector.direct.counts_map, "direct.counts_map", lead, f"{where}detector.")
    gain = detector.scan_map("gain_map")
    gain = np.ones(lead) if gain is None else check_map_shape(gain, "gain_map", lead, f"{where}detector.")
    seen = first.sum(axis=-1) * gain
    if not seen.any() or not target.any():
        return envelope, components
    wanted = target * (seen.sum() / target.sum())
    scale = np.divide(wanted, seen, out=np.zeros(lead), where=seen > 0)
    shaped = first * scale[..., None]
    return envelope - first + shaped, {**components, "first_bounce": shaped}


def zero_envelope_warning(envelope: np.ndarray, outside: np.ndarray, config: SimulationConfig, target: str,
                          why: Callable[[], str] | None = None) -> list[str]:
    """[] when the envelope holds light, else one warning saying why it is zero: the light reaching ``target``
    ("the FoV", "the zones") arrives outside the time window (``outside``: the transport's weight outside it), or
    no sample found light at all, with ``why()`` saying what was sampled and what that can mean
    (:func:`datagen.simulation.fov_sampling.zero_reason`)."""
    if np.any(envelope):
        return []
    if float(np.sum(outside)) > 0:
        edges = config.time.edges
        return [f"the envelope is zero: the light that reaches {target} arrives outside the time window "
                f"{edges[0] * 1e9:.4g}..{edges[-1] * 1e9:.4g} ns; widen simulation.time (t_start, bin_width, n_bins)"]
    reason = why() if why is not None else "no sample found a path from the laser to the sensor grid"
    return [f"the envelope of {target} is zero: {reason}; counts hold background only"]


def sampling_words(config: SimulationConfig) -> str:
    """The estimator's sampling setting in words (its registry entry's ``describe``), or its name."""
    from ..transport import estimator
    entry = estimator(config.estimator.kind)
    return entry.describe(config.estimator) if entry.describe is not None else config.estimator.kind


def make_result(scene: Scene, config: SimulationConfig, tr: Transported,
                noise_rng: np.random.Generator | None, t0: float, extra_attrs: dict | None = None) -> Result:
    """Detector draw and metadata around binned transport output (the last steps of :func:`simulate`): the
    detector model from the envelope (:func:`detector_model`), the counts, the attributes."""
    transport, names = tr.transport, tr.names
    capture = transport.capture
    shape = capture.channel_shape() + (config.time.n_bins,)
    components = {name: tr.binned[i].reshape(shape) for i, name in enumerate(names)}
    envelope = tr.binned.sum(axis=0).reshape(shape)
    where = f"{scene.source} (simulation): " if scene.source else ""
    if config.detector.get("direct") is not None:         # the direct light attenuated: what the detector sees
        envelope, components = attenuate_direct(envelope, components, capture, config, where)
    warnings = list(scene.notes) + zero_envelope_warning(envelope, tr.outside, config, "the FoV",
                                                         lambda: zero_reason(scene, transport, sampling_words(config)))
    t3 = time.perf_counter()
    noise_rng = noise_rng if noise_rng is not None else stream_rng(config.seed, STREAM_NOISE)
    counts, detector, plan_attrs = detector_counts(envelope, config, tr.plan.to_attrs(), noise_rng, where)
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
        "plan": plan_attrs,
        "warnings": warnings,
        "effects": {
            "primary": True,
            "estimator": config.estimator.kind,
            "secondary": settings.secondary,
            "top_k": getattr(settings, "top_k", None) if settings.secondary == "optimized" else None,
            "sensor_sampling": transport.sensor_sampling,
            "shadow_rays": {"spot": settings.shadow_spot, "sensor": settings.shadow_sensor},
            "non_lambertian_brdfs": sorted({o.material.kind for o in scene.objects} - {"lambertian"}),
            "atmospheric_attenuation": settings.attenuation > 0,
            "first_bounce": settings.first_bounce,
            "emitter_to_spot_leg_in_time": config.count_laser_leg,
            "fov_to_sensor_leg_in_time": config.count_sensor_leg,
            "detector_model": detector.model,
        },
        **({"orders": orders_record(tr.plan, getattr(tr.transport, "tracer", None), capture.n_lasers)}
           if "multibounce" in tr.plan.decisions else {}),
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
