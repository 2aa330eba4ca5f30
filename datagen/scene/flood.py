"""Flood illumination and multi-zone sensors (consumer direct-ToF, ams TMF8828 class): the scene-stage part.

A consumer multi-zone sensor floods a patch of the relay wall with a diffused VCSEL pulse and records one
histogram per *zone*, each zone integrating the light of its own patch of the wall (docs/multizone.md). Both
are compositions of what the transport already computes, so no estimator changes:

- the **flood** is a set of laser points on the relay wall, the nodes of a midpoint quadrature of the lit patch
  (:class:`FloodSpec`: centre, size, ``nodes``), each carrying the fraction w_l of the pulse its cell receives,
  w_l ∝ I(ω_l)·cos θ_l / r_l² · ΔA (the irradiance of an extended source at the node times the cell's area,
  I the emitter's radiant-intensity profile, θ_l the incidence angle, r_l the emitter leg), normalised so that
  Σ w_l = 1 (the whole pulse lands on the patch) (:func:`flood_weights`);
- a **zone** is a pixel region of the sensor grid (the aperture convention already integrates each region:
  docs/physics.md §2), so a Z × Z sensor of zones is a ``sensor_grid`` of Z × Z points over the zones' FoV
  (:class:`ZoneSpec`).

:func:`flood_capture` turns a :class:`MultizoneSpec` into the scene's exhaustive
:class:`~datagen.scene.parts.CaptureSpec` (every flood node × every zone); the simulation layer
(:mod:`datagen.simulation.multizone`) sums the exhaustive envelope over the nodes with the weights. A scene file
describes a multi-zone capture with a top-level ``multizone`` block (:func:`load_multizone_scene`;
configs/rooms/multizone_scene.yaml).
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import DatagenWarning, SceneError
from ..vectors import matmul, unit
from .capture import Capture
from .load import format_validation_error, read_yaml, scene_from_dict
from .model import Scene
from .parts import MAX_EXTENT, CaptureSpec, Vec3, check_counts, check_finite

MAX_FLOOD_NODES = 64
"""Most quadrature nodes per side of the lit patch (64 × 64 = 4096 laser points: the exhaustive capture's
cost grows with their number; docs/multizone.md shows 8 × 8 converged to 0.1 % on the small room)."""

MAX_ZONES = 16
"""Most zones per side (the TMF8828 has at most 8 × 8; configs/detectors/tmf8828.yaml)."""


class FloodProfile(BaseModel):
    """Relative radiant intensity I(ω) of the emitter over the lit patch (its integral is normalised away).

    ``kind``:
        - ``uniform_irradiance``: a diffuser shaped for a flat target: the same irradiance on every point of
          the patch (w_l = ΔA / A);
        - ``uniform_intensity``: a flat-top diffuser in angle: I constant, the irradiance falls as cos θ / r²;
        - ``gaussian``: I ∝ exp(−α² / (2 σ²)) with α the angle from the axis emitter → patch centre and
          σ = ``sigma_deg``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["uniform_irradiance", "uniform_intensity", "gaussian"] = "uniform_intensity"
    sigma_deg: float = Field(20.0, gt=0.0, le=180.0)


class FloodSpec(BaseModel):
    """The lit patch on the relay wall: ``center``, ``size`` (w, h) m in the wall frame of
    :class:`~datagen.scene.parts.WallGrid`, ``nodes`` (nx, ny) of its midpoint quadrature (``size`` [0, 0] and
    ``nodes`` [1, 1]: a laser spot at ``center``) and the emitter's ``profile``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    center: Vec3
    size: tuple[float, float]
    nodes: tuple[int, int] = (8, 8)
    profile: FloodProfile = FloodProfile()

    @field_validator("center")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @field_validator("size")
    @classmethod
    def _size(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) >= 0 and max(v) <= MAX_EXTENT):
            raise ValueError(f"both sizes must be >= 0 and <= {MAX_EXTENT:g} m, got {list(v)}")
        return v

    @field_validator("nodes")
    @classmethod
    def _nodes(cls, v: tuple[int, int]) -> tuple[int, int]:
        v = check_counts(v, "node counts")
        if max(v) > MAX_FLOOD_NODES:
            raise ValueError(f"at most {MAX_FLOOD_NODES} nodes per side, got {list(v)}")
        return v


class ZoneSpec(BaseModel):
    """The zones' FoV on the relay wall: ``center``, ``size`` (w, h) m and ``zones`` (Z_x, Z_y); zone (iy, ix) is
    the cell of the sensor grid at that index (docs/multizone.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    center: Vec3
    size: tuple[float, float]
    zones: tuple[int, int] = (4, 4)

    @field_validator("center")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @field_validator("size")
    @classmethod
    def _size(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) > 0 and max(v) <= MAX_EXTENT):
            raise ValueError(f"both sizes must be > 0 and <= {MAX_EXTENT:g} m, got {list(v)}")
        return v

    @field_validator("zones")
    @classmethod
    def _zones(cls, v: tuple[int, int]) -> tuple[int, int]:
        v = check_counts(v, "zone counts")
        if max(v) > MAX_ZONES:
            raise ValueError(f"at most {MAX_ZONES} zones per side, got {list(v)}")
        return v


class MultizoneSpec(BaseModel):
    """A scene file's ``multizone`` block: the ``flood`` (:class:`FloodSpec`) and the ``zones``
    (:class:`ZoneSpec`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    flood: FloodSpec
    zones: ZoneSpec


def flood_capture(spec: MultizoneSpec) -> CaptureSpec:
    """The exhaustive :class:`~datagen.scene.parts.CaptureSpec` of ``spec``: laser grid = the flood's nodes,
    sensor grid = the zones (aperture convention)."""
    f, z = spec.flood, spec.zones
    return CaptureSpec(type="exhaustive", convention="aperture",
                       laser_grid={"center": f.center, "size": f.size, "points": f.nodes},
                       sensor_grid={"center": z.center, "size": z.size, "points": z.zones})


def flood_field_names(message: str) -> str:
    """A capture error's message in the multi-zone block's words: ``capture.laser_grid point i`` → ``multizone.flood
    node i``, ``capture.sensor_grid`` → ``multizone.zones`` (the fields the user wrote)."""
    return (message.replace("capture.laser_grid point", "multizone.flood node")
            .replace("capture.sensor_grid", "multizone.zones"))


def with_flood(scene: Scene, spec: MultizoneSpec) -> Scene:
    """``scene`` with the capture of ``spec`` (:func:`flood_capture`); the laser spot moves to the flood's
    centre (the scene's other checks are those of :class:`~datagen.scene.model.Scene`)."""
    laser = scene.laser.model_copy(update={"spot": spec.flood.center})
    return Scene(scene.objects, laser, scene.sensor, scene.name, scene.source, scene.defaults, flood_capture(spec))


def node_weights(spots: np.ndarray, normals: np.ndarray, emitter: np.ndarray, profile: FloodProfile) -> np.ndarray:
    """Fraction of the pulse each flood node's cell receives (the midpoint rule of the patch's irradiance).

    w_l = I(ω_l) · cos θ_l / r_l² · ΔA / Σ_k (same), with ω_l the direction emitter → node l, θ_l its incidence
    angle on the wall (``normals``), r_l the emitter leg and ΔA the (equal) cell area; ``uniform_irradiance`` gives
    w_l = 1/L. One node gives [1.0].

    Args:
        spots: (L, 3) float64 node positions (m); normals: (L, 3) unit wall normals there; emitter: (3,) m.
        profile: the emitter's :class:`FloodProfile`.
    Returns:
        (L,) float64 weights summing to 1.
    Raises:
        SceneError: no node receives light (every node at grazing incidence or outside the profile).
    """
    spots = np.asarray(spots, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    emitter = np.asarray(emitter, dtype=np.float64)
    d = spots - emitter
    r = np.linalg.norm(d, axis=1)
    w_in = d / r[:, None]
    if profile.kind == "uniform_irradiance":
        raw = np.ones(len(spots))
    else:
        raw = np.abs(np.einsum("ij,ij->i", w_in, normals)) / r ** 2
        if profile.kind == "gaussian":
            axis = unit(spots.mean(axis=0) - emitter)
            alpha = np.arccos(np.clip(matmul(w_in, axis), -1.0, 1.0))
            raw = raw * np.exp(-0.5 * (alpha / np.radians(profile.sigma_deg)) ** 2)
    total = float(raw.sum())
    if not total > 0:
        raise SceneError("multizone.flood: no flood node receives light from the emitter (all at grazing "
                         "incidence or outside the profile)")
    return raw / total


def flood_weights(capture: Capture, profile: FloodProfile) -> np.ndarray:
    """:func:`node_weights` of a resolved flood capture (:func:`flood_capture`; its laser points are the nodes):
    (L,) float64 in the order of ``capture.spots`` (row-major over (ny, nx)). Raises as :func:`node_weights`."""
    return node_weights(capture.spots, capture.spot_normals, capture.emitter, profile)


def multizone_from_dict(data: dict, source: str | None = None, base: Path | None = None
                        ) -> tuple[Scene, MultizoneSpec]:
    """A scene mapping with a top-level ``multizone`` block → (the scene with the flood capture, the spec).

    The rest of the mapping is an ordinary scene (:func:`~datagen.scene.load.scene_from_dict`); its ``capture``
    block, if any, is replaced by :func:`flood_capture` and ``laser.spot`` by the flood's centre (optional here).

    Raises:
        SceneError: no ``multizone`` block, an invalid one (naming file, field and value), or scene errors.
    """
    where = source or "scene"
    if not isinstance(data, dict) or "multizone" not in data:
        raise SceneError(f"{where}: no multizone block (a multi-zone scene has multizone: {{flood: ..., zones: ...}})")
    data = dict(data)
    block = data.pop("multizone")
    try:
        spec = MultizoneSpec.model_validate(block)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, source, head="multizone")) from None
    if data.get("capture") is not None:
        raise SceneError(f"{where}: capture: a multi-zone scene takes its capture from multizone (flood nodes × "
                         "zones); drop the capture block")
    laser = dict(data.get("laser") or {})
    laser.setdefault("spot", list(spec.flood.center))
    sensor = dict(data.get("sensor") or {})
    sensor.pop("fov", None)
    data.update(laser=laser, sensor=sensor, capture=flood_capture(spec).model_dump())
    return scene_from_dict(data, source, base), spec


def load_multizone_scene(path: str | Path) -> tuple[Scene, MultizoneSpec]:
    """Load a multi-zone scene YAML (a scene file with a ``multizone`` block; :func:`multizone_from_dict`).

    Raises:
        SceneError: as :func:`~datagen.scene.load.load_scene` and :func:`multizone_from_dict`.
    """
    path = Path(path)
    return multizone_from_dict(read_yaml(path, "scene file"), str(path), path.parent)


MIN_ZONE_COVERAGE = 0.25
"""Below this fraction of the zone grid's area lit by the flood, a multi-zone run warns
(:class:`ZoneCoverageWarning`): a multi-zone sensor's zones tile its flood, and the run's time grows with the zone
grid's area."""


class ZoneCoverageWarning(DatagenWarning):
    """The flood lights less than :data:`MIN_ZONE_COVERAGE` of the zone grid (``multizone.zones`` far larger than,
    or away from, ``multizone.flood``)."""


def zone_coverage(capture: Capture, spec: MultizoneSpec) -> float:
    """Fraction of the zone grid's area (``spec.zones``) that the lit patch (``spec.flood``) covers, in the relay
    wall's frame of the resolved ``capture`` (``fov_u``, ``fov_v``), in [0, 1] (0 for a point flood)."""
    d = np.asarray(spec.zones.center, np.float64) - np.asarray(spec.flood.center, np.float64)
    du, dv = float(np.dot(d, capture.fov_u)), float(np.dot(d, capture.fov_v))
    (fw, fh), (zw, zh) = spec.flood.size, spec.zones.size

    def overlap(offset, a, b):        # length of [−a/2, a/2] ∩ [offset − b/2, offset + b/2]
        return max(0.0, min(a / 2, offset + b / 2) - max(-a / 2, offset - b / 2))

    return overlap(du, fw, zw) * overlap(dv, fh, zh) / (zw * zh)


def zone_coverage_warning(capture: Capture, spec: MultizoneSpec) -> str | None:
    """The warning's text when a flood of non-zero area lights less than :data:`MIN_ZONE_COVERAGE` of the zone
    grid, else None (a point flood, the single-spot limit, is not warned about)."""
    (fw, fh), (zw, zh) = spec.flood.size, spec.zones.size
    coverage = zone_coverage(capture, spec)
    if fw * fh <= 0 or coverage >= MIN_ZONE_COVERAGE:
        return None
    return (f"multizone.flood ({fw:g} x {fh:g} m) lights {coverage:.1%} of multizone.zones ({zw:g} x {zh:g} m, "
            f"{zw * zh / (fw * fh):.3g}x its area): a multi-zone sensor's zones tile its flood, and the run's time "
            "grows with the zone grid's area (docs/multizone.md)")


def flood_corners(capture: Capture, spec: MultizoneSpec) -> np.ndarray:
    """(4, 3) float64 corners (m), in order, of the lit patch on the relay wall, in the wall frame of the resolved
    ``capture`` (its ``fov_u``, ``fov_v``: the frame every grid of a planar relay wall shares)."""
    c = np.asarray(spec.flood.center, dtype=np.float64)
    hu = 0.5 * spec.flood.size[0] * capture.fov_u
    hv = 0.5 * spec.flood.size[1] * capture.fov_v
    return c + np.array([-hu - hv, hu - hv, hu + hv, -hu + hv])
