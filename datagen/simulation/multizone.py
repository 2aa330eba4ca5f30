"""Flood-illuminated multi-zone captures (consumer direct-ToF sensors, ams TMF8828 class): the simulation part.

:func:`simulate_multizone` runs the configured estimator once on the scene's exhaustive capture of flood
nodes × zones (:func:`datagen.scene.flood.flood_capture`), then composes the multi-zone envelope

    E_z(t) = Σ_l w_l · E_{l,z}(t),

w_l the fraction of the pulse the node's cell receives (:func:`datagen.scene.flood.flood_weights`), E_{l,z} the
envelope of zone z lit by the full pulse at node l. The transport is linear in the source, so this is the flood's
envelope up to the midpoint quadrature of the lit patch (docs/multizone.md shows its convergence); the zone's
integral over its patch of the wall is the aperture convention's pixel region, exact as for any sensor grid. The
detector then draws one histogram per zone from E_z (pile-up decided on E_z, as :func:`datagen.simulate` does).
:func:`compose_zones` is the composition alone, for envelopes already computed; :func:`zone_result` turns the
:class:`~datagen.simulation.detection.Result` of a flood's exhaustive capture (a dataset sample's, whose laser grid is the
flood's nodes) into the zones' result, composed by it and counted as here.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from ..errors import SceneError
from ..scene import Scene
from ..scene.flood import (FloodProfile, MultizoneSpec, ZoneCoverageWarning, flood_capture, flood_field_names,
                           flood_weights, node_weights, with_flood, zone_coverage_warning)
from .config import STREAM_NOISE, STREAM_SAMPLING, SimulationConfig, resolve_config, stream_rng
from .provenance import library_versions
from .detection import Result, detector_counts, sampling_words, zero_envelope_warning
from .fov_sampling import zone_sampling, zero_reason
from .run import Replicas


ZONE_UNITS = {"time_edges": "s", "envelope": "expected detected photons per laser pulse per bin, per zone",
              "counts": "detections over the exposure per zone (int64)"}
"""``attrs["units"]`` of a multi-zone result."""


def compose_zones(binned: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Σ_l w_l · E_{l,z}: the flood's zone envelopes from per-node envelopes.

    Args:
        binned: (..., L, Z, T) float envelopes of the exhaustive capture (L flood nodes, Z zones, T bins).
        weights: (L,) float64 node weights (:func:`datagen.scene.flood.flood_weights`, summing to 1).
    Returns:
        (..., Z, T) float64.
    Raises:
        ValueError: ``weights`` does not match the node axis.
    """
    binned = np.asarray(binned, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if binned.ndim < 3 or weights.shape != (binned.shape[-3],):
        raise ValueError(f"weights of shape {weights.shape} do not match the node axis of envelopes shaped "
                         f"{binned.shape} (..., nodes, zones, bins)")
    return np.einsum("l,...lzt->...zt", weights, binned)


def simulate_multizone(scene: Scene, spec: MultizoneSpec, config: SimulationConfig | None = None,
                       sampling_rng: np.random.Generator | None = None,
                       noise_rng: np.random.Generator | None = None, progress: bool = False) -> Result:
    """Simulate a flood-illuminated multi-zone capture: zone envelopes and one SPAD histogram per zone.

    A zone grid the flood lights over less than :data:`~datagen.scene.flood.MIN_ZONE_COVERAGE` of its area is
    warned about (:class:`~datagen.scene.flood.ZoneCoverageWarning`) before the transport starts, and the warning
    is kept in ``attrs["warnings"]``.

    Args:
        scene: the scene; its capture is replaced by the flood's (:func:`datagen.scene.flood.with_flood`) unless
            it is that capture already (:func:`datagen.scene.flood.load_multizone_scene`).
        spec: the flood and the zones (:class:`~datagen.scene.flood.MultizoneSpec`).
        config: as for :func:`datagen.simulate` (default: the scene's ``simulation`` block).
        sampling_rng, noise_rng: as for :func:`datagen.simulate`.
        progress: show a tqdm bar over the transport.
    Returns:
        :class:`~datagen.simulation.detection.Result` with ``envelope`` and ``counts`` shaped (Z_y, Z_x, T) (expected
        detected photons per pulse per bin, int64 detections), ``components`` likewise, ``laser_points`` the
        flood nodes (n_y, n_x, 3), ``sensor_points`` the zone centres (Z_y, Z_x, 3) and ``attrs["multizone"]``
        (the spec, the node weights (n_y, n_x)); ``attrs["error"]`` is the error estimate of the per-node
        transport (:func:`datagen.simulate`'s, on the nodes' envelopes; the patch quadrature's is not included).
    Raises:
        SceneError: the capture cannot be resolved, or no node receives light; ConfigError: as
            :func:`datagen.simulate`.
    """
    t0 = time.perf_counter()
    if scene.capture != flood_capture(spec):
        scene = with_flood(scene, spec)
    config = config or resolve_config(scene)
    rng = sampling_rng if sampling_rng is not None else stream_rng(config.seed, STREAM_SAMPLING)
    try:
        runs = Replicas(scene, config, rng)
    except SceneError as exc:       # a capture error names the multizone block's fields
        raise SceneError(flood_field_names(str(exc))) from None
    coverage = zone_coverage_warning(runs.transport.capture, spec)
    if coverage is not None:
        warnings.warn(ZoneCoverageWarning(coverage), stacklevel=2)
    sampled = zone_sampling(runs.transport, runs.planned.caster, "multizone.zones",
                            f"{scene.source}: " if scene.source else "")
    if sampled is not None:
        warnings.warn(ZoneCoverageWarning(sampled), stacklevel=2)
    runs.run(config.error.replicas, progress)
    tr = runs.transported()
    capture = tr.transport.capture
    weights = flood_weights(capture, spec.flood.profile)
    n_bins = config.time.n_bins
    zx, zy = capture.fov_pixels
    per_node = tr.binned.reshape(len(tr.names), capture.n_lasers, capture.n_pixels, n_bins)
    zones = compose_zones(per_node, weights).reshape(len(tr.names), zy, zx, n_bins)
    components = {name: zones[i] for i, name in enumerate(tr.names)}
    envelope = zones.sum(axis=0)
    noise_rng = noise_rng if noise_rng is not None else stream_rng(config.seed, STREAM_NOISE)
    counts, detector, plan_attrs = detector_counts(envelope, config, tr.plan.to_attrs(), noise_rng,
                                                   f"{scene.source} (simulation): " if scene.source else "")
    nx, ny = capture.laser_shape
    attrs = {
        "scene": scene.name, "scene_file": scene.source,
        "config": config.model_dump(mode="json"), "detector": detector.model_dump(mode="json"),
        "n_cycles": int(detector.cycles), "component_names": list(tr.names), "plan": plan_attrs,
        "multizone": {"spec": spec.model_dump(mode="json"), "weights": weights.reshape(ny, nx).tolist(),
                      "nodes": [nx, ny], "zones": [zx, zy]},
        "error": runs.error_attrs(tr, rng),
        "units": ZONE_UNITS,
        "photons_per_pulse": capture.photons,
        "warnings": (list(scene.notes) + [w for w in (coverage, sampled) if w is not None]
                     + zero_envelope_warning(envelope, tr.outside, config, "the zones", lambda: zero_reason(
                         scene, tr.transport, sampling_words(config)))),
        "timings_s": {**tr.seconds, "total": time.perf_counter() - t0},
        "versions": library_versions(),
    }
    return Result(config.time.edges, envelope, components, counts, attrs,
                  laser_points=capture.spots.reshape(ny, nx, 3), sensor_points=capture.sensor_points(),
                  wall_normal=capture.fov_normal.copy())


def zone_result(result: Result, emitter, profile: FloodProfile, config: SimulationConfig,
                noise_rng: np.random.Generator, where: str = "") -> Result:
    """The zones' result of a flood's exhaustive capture: its laser grid the flood's nodes (midpoints of equal
    cells of the lit patch), its sensor grid the zones.

    The envelope and every component are :func:`compose_zones` of the per-node ones with
    :func:`datagen.scene.flood.node_weights` of the laser points (the relay wall planar: every node has
    ``result.wall_normal``); the counts are drawn per zone from the composed envelope with ``config``'s detector
    (pile-up decided on it) and ``noise_rng``, as :func:`simulate_multizone` draws them.

    Args:
        result: an exhaustive capture's :class:`~datagen.simulation.detection.Result`: ``envelope`` (L_y, L_x, Z_y, Z_x,
            T) float64, ``laser_points`` (L_y, L_x, 3) m, ``wall_normal`` (3,).
        emitter: (3,) the flood's emitter position (m); profile: its :class:`~datagen.scene.flood.FloodProfile`.
        config: the simulation config the result was computed with (its detector draws the counts).
        noise_rng: generator of the zones' counts. where: prefix of error messages (e.g. the sample).
    Returns:
        :class:`~datagen.simulation.detection.Result` with ``envelope``, ``components`` (Z_y, Z_x, T) float64 expected
        detected photons per pulse per bin and ``counts`` (Z_y, Z_x, T) int64; ``attrs`` those of ``result``
        (its ``error`` and ``tolerance`` are the per-node envelope's) with ``plan["pile_up"]``, ``detector`` and
        ``n_cycles`` of the zones' draw and ``multizone`` {profile, weights (L_y, L_x), nodes, zones}.
    Raises:
        ValueError: ``result`` is not an exhaustive capture with laser points. SceneError: no node receives
            light. ConfigError: the detector refuses the envelope.
    """
    env = np.asarray(result.envelope)
    if env.ndim != 5 or result.laser_points is None or result.wall_normal is None:
        raise ValueError(f"{where}a flood needs an exhaustive capture's result (envelope (L_y, L_x, Z_y, Z_x, T) "
                         f"and its laser points), got an envelope shaped {env.shape}")
    ly, lx, zy, zx, n_t = env.shape
    weights = node_weights(result.laser_points.reshape(-1, 3), np.broadcast_to(result.wall_normal, (ly * lx, 3)),
                           emitter, profile)

    def zones(a: np.ndarray) -> np.ndarray:
        return compose_zones(np.asarray(a).reshape(ly * lx, zy * zx, n_t), weights).reshape(zy, zx, n_t)

    envelope = zones(env)
    components = {name: zones(c) for name, c in result.components.items()}
    counts, detector, plan = detector_counts(envelope, config, result.attrs.get("plan", {}), noise_rng, where)
    attrs = {**result.attrs, "plan": plan, "detector": detector.model_dump(mode="json"),
             "n_cycles": int(detector.cycles), "units": ZONE_UNITS,
             "multizone": {"profile": profile.model_dump(mode="json"), "weights": weights.reshape(ly, lx).tolist(),
                           "nodes": [lx, ly], "zones": [zx, zy]}}
    return Result(result.time_edges, envelope, components, counts, attrs, laser_points=result.laser_points,
                  sensor_points=result.sensor_points, wall_normal=result.wall_normal)
