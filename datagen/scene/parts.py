"""Scene parts: the error type, the labelled mesh and the capture devices a :class:`~datagen.scene.model.Scene`
is made of.

World frame right-handed, z up, metres (docs/physics.md §1). A :class:`SceneObject` is a triangle mesh with a
semantic ``label`` (wall, floor, ceiling, relay_wall, pillar, box, mesh…) and a
:class:`~datagen.scene.materials.Material`; a :class:`Laser` is the emitter position and the laser spot on the
relay wall; a :class:`Sensor` is the sensor position, its collection aperture and field of view
(:class:`FieldOfView`) on the relay wall; a :class:`CaptureSpec` is the scan pattern (grids of
:class:`WallGrid` points). The pydantic models validate themselves on construction (the YAML schema of
:mod:`datagen.scene.load` is built from them).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .materials import Material
from .motion import FrameSpec
from ..errors import SceneError
from ..units import parse_energy, parse_length, photons_per_pulse

ROOM_LABELS = ("wall", "floor", "ceiling", "relay_wall")
"""Labels of the extended surfaces; lookins on them form the paper's 'walls, roof and floor' component."""

Vec3 = tuple[float, float, float]

MAX_EXTENT = 1.0e7
"""Largest |coordinate| and size a scene accepts, metres (10 000 km, beyond the Earth's radius). It keeps every
product of lengths (areas, squared distances, path lengths) far from float64 overflow: a 1e308 m box would
otherwise reach the ray caster as inf and surface as a misleading 'laser spot off every surface'."""

MAX_APERTURE_RADIUS = 10.0
"""Largest collection aperture radius, metres (the largest telescopes are ~5 m in radius)."""

WAVELENGTH_RANGE = (1e-9, 1e-3)
"""Accepted laser wavelengths, metres: 1 nm (soft X-ray) to 1 mm (far infrared)."""

MAX_PHOTONS_PER_PULSE = 1e30
"""Most photons per pulse a laser may emit (the largest laser pulses, ~2 MJ, hold ~4e24). Products of Φ with
the transport's weights, the cycles of an exposure (≤ 2⁶²) and their squares stay finite in float64."""

MAX_PULSE_ENERGY = 1e8
"""Most energy per pulse, J (100 MJ, 50× the largest laser pulses): at the longest accepted wavelength (1 mm)
it is 5e29 photons, within :data:`MAX_PHOTONS_PER_PULSE`; 1e308 J would overflow Φ = E·λ/(h·c) to inf."""

RESERVED_NAMES = ("room", "secondary", "first_bounce", "total")
"""Object names that would collide with envelope components ('room' sums the walls, floor, ceiling and relay
wall; 'secondary' and 'first_bounce' are the transport's extra components) or with the 'total' row of the
simulate summary: an object of that name would merge into, or hide, another component."""

_NAME = re.compile(r"^\w[\w.+-]{0,63}$")


def check_finite(v: Vec3) -> Vec3:
    """Pydantic validator body: every coordinate finite and within ±:data:`MAX_EXTENT` metres (names no field;
    pydantic adds it)."""
    if not np.all(np.isfinite(v)):
        raise ValueError(f"must be finite, got {list(v)}")
    if np.max(np.abs(v)) > MAX_EXTENT:
        raise ValueError(f"must lie within ±{MAX_EXTENT:g} m, got {list(v)}")
    return v


def check_object_name(name: str) -> str:
    """An object name usable as an envelope component and as a file name in result stores: 1–64 letters,
    digits, ``_ . + -`` starting with a letter, digit or ``_`` (not ``__``), not ``zarr.json`` and not one of
    :data:`RESERVED_NAMES` (in any case).

    Raises:
        SceneError: the message names the value and the rule it breaks.
    """
    if not isinstance(name, str) or not _NAME.match(name) or name.startswith("__"):
        raise SceneError(f"object name {name!r} is not allowed: use 1-64 letters, digits, '_', '.', '+' or '-', "
                         "starting with a letter or digit (no path separators, spaces or '..')")
    if name.lower() in RESERVED_NAMES or name.lower() == "zarr.json":
        raise SceneError(f"object name {name!r} is reserved ('room', 'secondary' and 'first_bounce' name envelope "
                         "components, 'total' the summary's total, 'zarr.json' a store's metadata): rename the object")
    return name


def check_sizes(sizes, what: str) -> None:
    """Every size finite, > 0 and ≤ :data:`MAX_EXTENT` metres (SceneError naming ``what`` and the values)."""
    v = np.asarray(sizes, dtype=np.float64)
    if not (np.all(np.isfinite(v)) and np.all(v > 0) and np.all(v <= MAX_EXTENT)):
        raise SceneError(f"{what} must be > 0 and <= {MAX_EXTENT:g} m, got {v.tolist()}")


def check_counts(v: tuple[int, int], what: str) -> tuple[int, int]:
    """Pydantic validator body: both grid counts >= 1 (``what`` names them in the message)."""
    if min(v) < 1:
        raise ValueError(f"{what} must be >= 1, got {list(v)}")
    return v


@dataclass(frozen=True)
class SceneObject:
    """One labelled mesh.

    Attributes:
        name: unique name, used for the object's envelope component (rules: :func:`check_object_name`).
        label: semantic class (wall, floor, ceiling, relay_wall, pillar, box, mesh, …).
        material: its BRDF and albedo.
        vertices: (V, 3) float64 metres.
        faces: (F, 3) int64 vertex indices.

    Raises:
        SceneError: a reserved or unsafe name, a vertex not finite or beyond ±:data:`MAX_EXTENT` m, a face
            index out of range, no faces.
    """

    name: str
    label: str
    material: Material
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        check_object_name(self.name)
        vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if bad.size:
            raise SceneError(f"object {self.name!r}: vertex {bad[0]} is not finite: {vertices[bad[0]].tolist()}")
        far = np.flatnonzero(np.abs(vertices).max(axis=1, initial=0.0) > MAX_EXTENT)
        if far.size:
            raise SceneError(f"object {self.name!r}: vertex {far[0]} at {vertices[far[0]].tolist()} m lies beyond "
                             f"±{MAX_EXTENT:g} m (the scene's extent limit): check its sizes, scale and position")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise SceneError(f"object {self.name!r}: face index out of range 0..{len(vertices) - 1}")
        if len(faces) == 0:
            raise SceneError(f"object {self.name!r} has no faces")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)


class Laser(BaseModel):
    """Pulsed laser: emitter position, laser spot on the relay wall, photons per pulse.

    Photons per pulse Φ come from ``photons_per_pulse`` directly (at most :data:`MAX_PHOTONS_PER_PULSE`) or
    from ``pulse_energy`` (J, or "1nJ"; at most :data:`MAX_PULSE_ENERGY`) and ``wavelength`` (m, or "532nm")
    as E·λ/(h·c).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    emitter: Vec3 = (0.0, 0.0, 1.0)
    spot: Vec3
    photons_per_pulse: float | None = Field(None, gt=0, allow_inf_nan=False)
    pulse_energy: float | None = Field(None, gt=0, allow_inf_nan=False)
    wavelength: float = Field(532e-9, ge=WAVELENGTH_RANGE[0], le=WAVELENGTH_RANGE[1], allow_inf_nan=False)

    @field_validator("pulse_energy", mode="before")
    @classmethod
    def _energy(cls, v: Any) -> Any:
        return None if v is None else parse_energy(v)

    @field_validator("pulse_energy")
    @classmethod
    def _energy_bound(cls, v: float | None) -> float | None:
        if v is not None and v > MAX_PULSE_ENERGY:
            raise ValueError(f"at most {MAX_PULSE_ENERGY:g} J per pulse (more would overflow the photons per "
                             f"pulse E·λ/(h·c) and the counts)")
        return v

    @field_validator("photons_per_pulse")
    @classmethod
    def _photon_bound(cls, v: float | None) -> float | None:
        if v is not None and v > MAX_PHOTONS_PER_PULSE:
            raise ValueError(f"at most {MAX_PHOTONS_PER_PULSE:g} photons per pulse (more would overflow the "
                             "envelope's products in float64)")
        return v

    @field_validator("wavelength", mode="before")
    @classmethod
    def _wavelength(cls, v: Any) -> Any:
        return parse_length(v)

    @field_validator("emitter", "spot")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @model_validator(mode="after")
    def _one_source(self) -> "Laser":
        if self.photons_per_pulse is not None and self.pulse_energy is not None:
            raise ValueError("give photons_per_pulse or pulse_energy, not both")
        return self

    @property
    def photons(self) -> float:
        """Φ, photons per pulse (1.0 when neither photons_per_pulse nor pulse_energy is given)."""
        if self.photons_per_pulse is not None:
            return self.photons_per_pulse
        if self.pulse_energy is not None:
            return photons_per_pulse(self.pulse_energy, self.wavelength)
        return 1.0


class FieldOfView(BaseModel):
    """The rectangle of the relay wall the sensor images: centre, size (width, height) in metres.

    ``width`` runs along the wall's horizontal tangent (n × z normalised), ``height`` along the wall's
    in-plane up direction. ``pixels`` (nx, ny) splits it into a sensor array; (1, 1) is the paper's single
    pixel.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    center: Vec3
    size: tuple[float, float]
    pixels: tuple[int, int] = (1, 1)

    @field_validator("center")
    @classmethod
    def _finite_center(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @field_validator("size")
    @classmethod
    def _positive(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) > 0 and max(v) <= MAX_EXTENT):
            raise ValueError(f"both sizes must be positive and <= {MAX_EXTENT:g} m, got {list(v)}")
        return v

    @field_validator("pixels")
    @classmethod
    def _pixels(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "pixel counts")


class Sensor(BaseModel):
    """SPAD sensor: position, circular collection aperture (radius, m), field of view on the relay wall.

    The aperture faces the FoV centre; its area πr² enters the envelope (docs/physics.md §2, A_ap). ``fov`` may be
    omitted when the scene has a ``capture`` block with a sensor or laser grid.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    position: Vec3 = (0.0, 0.0, 1.0)
    aperture_radius: float = Field(0.02, gt=0, le=MAX_APERTURE_RADIUS, allow_inf_nan=False)
    fov: FieldOfView | None = None

    @field_validator("aperture_radius", mode="before")
    @classmethod
    def _radius(cls, v: Any) -> Any:
        return parse_length(v)

    @field_validator("position")
    @classmethod
    def _finite(cls, v: Vec3) -> Vec3:
        return check_finite(v)

    @property
    def aperture_area(self) -> float:
        return float(np.pi * self.aperture_radius ** 2)


class WallGrid(BaseModel):
    """A grid of nx×ny points on the relay wall: cell centres of a w×h rectangle around ``center``.

    Point (iy, ix) sits at center + ((ix+½)/nx − ½)·w·u + ((iy+½)/ny − ½)·h·v with u the wall's horizontal
    tangent (n × z normalised) and v = u × n, as for :class:`FieldOfView`.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    center: Vec3
    size: tuple[float, float]
    points: tuple[int, int] = (1, 1)

    @field_validator("size")
    @classmethod
    def _nonnegative(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (np.all(np.isfinite(v)) and min(v) >= 0 and max(v) <= MAX_EXTENT):
            raise ValueError(f"both sizes must be >= 0 and <= {MAX_EXTENT:g} m, got {list(v)}")
        return v

    @field_validator("points")
    @classmethod
    def _points(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "point counts")


class CaptureSpec(BaseModel):
    """Scan pattern over the relay wall (the tal capture types) and the sensor convention.

    - ``single``: one laser spot (``laser.spot``) and a sensor grid (``sensor_grid``, or ``sensor.fov``).
    - ``confocal``: the laser visits each point of ``laser_grid`` and the sensor looks at that same point.
    - ``exhaustive``: every laser point of ``laser_grid`` × every sensor point of ``sensor_grid``.

    Conventions: ``aperture`` (default): each sensor point is the centre of a pixel region (cell of the grid)
    imaged through the aperture; the envelope is expected detected photons per pulse per bin (docs/physics.md §2).
    ``point_radiance`` (tal / mitransient): radiance leaving the wall point toward ``sensor.position`` per
    unit power delivered to the laser spot, per bin, in 1/(m²·sr); no PDE, aperture or sensor visibility.

    ``frames`` (:class:`~datagen.scene.motion.FrameSpec`) makes the capture a sequence of frames (scenes whose
    objects move, docs/motion.md).

    ``detector_fov`` (confocal, aperture convention): the SPAD's field of view on the relay wall at each scan point,
    a square of this side (m, or a length string such as ``"30mm"``) or a ``[w, h]`` rectangle centred on the laser
    point; unset: the scan's cell (its pitch). A real confocal scanner's detector may see a larger patch of wall
    than the scan's pitch; a retroreflector returns its light around the laser point, so how much of it is collected
    depends on this size (docs/physics.md, "Retroreflective"; docs/real.md).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    type: Literal["single", "confocal", "exhaustive"] = "single"
    convention: Literal["aperture", "point_radiance"] = "aperture"
    laser_grid: WallGrid | None = None
    sensor_grid: WallGrid | None = None
    frames: FrameSpec | None = None
    detector_fov: tuple[float, float] | None = None

    @field_validator("detector_fov", mode="before")
    @classmethod
    def _fov(cls, v: Any) -> Any:
        if v is None:
            return v
        sides = [v, v] if isinstance(v, (int, float, str)) else list(v)
        if len(sides) != 2:
            raise ValueError(f"give one side or [w, h], got {v!r}")
        sides = [parse_length(x) for x in sides]
        if not all(np.isfinite(x) and 0 < x <= MAX_EXTENT for x in sides):
            raise ValueError(f"both sides must be > 0 and <= {MAX_EXTENT:g} m, got {v!r}")
        return tuple(sides)

    @model_validator(mode="after")
    def _grids(self) -> "CaptureSpec":
        if self.type in ("confocal", "exhaustive") and self.laser_grid is None:
            raise ValueError(f"capture type {self.type!r} needs a laser_grid")
        if self.type == "confocal" and self.sensor_grid is not None:
            raise ValueError("confocal captures use laser_grid for the sensor points too; drop sensor_grid")
        if self.type == "single" and self.laser_grid is not None:
            raise ValueError("single captures use laser.spot; laser_grid needs type confocal or exhaustive")
        if self.detector_fov is not None and (self.type != "confocal" or self.convention != "aperture"):
            raise ValueError(f"detector_fov is the field of view at each scan point of a confocal capture "
                             f"(aperture convention), not of type {self.type!r} ({self.convention})")
        return self
