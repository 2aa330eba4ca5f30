"""Interoperability with y-tal (PyPI ``y-tal``, import ``tal``): its render YAML → a datagen scene.

Its HDF5 capture files (reading, writing, a datagen result as tal's fields) are :mod:`datagen.io.tal_hdf5`.

**Render YAML** (``tal render CONFIG.yaml``, which drives mitransient). :func:`load_tal_config` merges a config
with tal's defaults and validates it; :func:`scene_from_tal_config` turns it into a datagen :class:`Scene` with a
``capture`` block (point-radiance convention) and a :class:`TalCapture` that says how to lay the result out and
scale it so it matches what ``tal render`` writes. Frames and units: tal's frame is ours (right-handed; the
relay wall is tal's ``rectangle``, the plane z = displacement_z, 2·scale_x × 2·scale_y metres, normal ±z).
Time: OPL metres in tal, seconds in datagen (t = OPL / c).

**Radiometry of tal render** (read from mitransient 1.3's ``transient_nlos_path`` with laser sampling and
checked against it, see docs/tal.md): H is the radiance leaving the wall point toward the sensor, binned by
path length (bins sum to the steady-state radiance), where the laser is a Mitsuba ``projector`` of intensity
π·e W/sr (e = ``laser_emission``) whose spot is treated as a 1 m² patch. So, with datagen's point radiance
per unit power delivered to the spot, L_pr,

    H_tal = K_l · L_pr,   K_l = π · e_sum · cos θ_e / d_e²,

d_e the emitter→spot distance, θ_e the angle between the wall normal and the spot→emitter direction, e_sum
the emission summed over the channels tal adds up (rgb variants: R+G+B; mono variants: the luminance).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Callable, Literal

import numpy as np
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, ValidationError,
                      ValidationInfo, field_validator, model_validator)

from ..scene import Material, Scene, SceneObject, scene_from_dict
from ..errors import SceneError
from ..scene.load import format_validation_error, read_yaml, short_repr
from ..units import SPEED_OF_LIGHT

__all__ = [
    "TAL_DEFAULTS", "TAL_KEYS", "TalCapture", "TalGeometry", "TalMaterial", "TalMesh", "TalRenderConfig",
    "load_tal_config", "scene_from_tal_config", "scene_from_tal_yaml", "tal_transform",
]


# ---------------------------------------------------------------------------------------------------------
# tal render YAML: the schema (tal 0.20's render options and defaults, and what datagen supports of them)

LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)
"""Mitsuba's RGB → luminance weights (sRGB/Rec. 709 Y), used by its mono variants for RGB inputs."""


def _yaml_number(value: Any) -> Any:
    """Numbers only: pydantic's lax mode would also read "16" and true as numbers."""
    if isinstance(value, (bool, str)):
        raise ValueError("Input should be a valid number")
    return value


def _or(default: Any) -> BeforeValidator:
    """tal reads some options as ``value or default``: 0, null (and any other falsy value) mean the default."""
    return BeforeValidator(lambda value: value or default)


def _only(ok: Callable[[Any], bool], message: str) -> AfterValidator:
    """Refuse a value with datagen's reason (what it supports of tal's options)."""
    def check(value: Any) -> Any:
        if not ok(value):
            raise ValueError(message)
        return value
    return AfterValidator(check)


_Float = Annotated[float, BeforeValidator(_yaml_number)]
_Int = Annotated[int, BeforeValidator(_yaml_number)]
_Count = Annotated[_Int, Field(ge=1)]
_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=True)


def _channels(value: Any) -> list[float]:
    """'1.0, 1.0, 1.0' / 0.5 / [1, 1, 1] → list of floats (tal writes RGB values as comma-separated text);
    ValueError unless they are finite and non-negative."""
    parts = value.replace(",", " ").split() if isinstance(value, str) else \
        list(value) if isinstance(value, (list, tuple)) else [value]
    try:
        out = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise ValueError("expected a number or 'r, g, b'") from None
    if not out or not all(math.isfinite(v) and v >= 0 for v in out):
        raise ValueError("expected non-negative numbers")
    return out


def _albedo(text: Any) -> float:
    """Albedo of tal's ``custom`` material: Mitsuba XML of a diffuse BSDF (optionally inside ``twosided``) with
    a grey ``rgb``/``float``/``spectrum`` reflectance ≤ 1; ValueError for anything else."""
    if not isinstance(text, str):
        raise ValueError("a custom material needs Mitsuba XML text")
    try:
        node = ET.fromstring(text.strip())
    except ET.ParseError as exc:
        raise ValueError(f"not valid XML: {exc}") from None
    while node.tag == "bsdf" and node.get("type") == "twosided":
        inner = node.find("bsdf")
        if inner is None:
            raise ValueError("twosided BSDF without an inner <bsdf>")
        node = inner
    if node.tag != "bsdf" or node.get("type") != "diffuse":
        raise ValueError(f"BSDF type {node.get('type')!r} is not supported (diffuse)")
    refl = [c for c in node if c.get("name") == "reflectance"]
    if not refl:
        return 0.5   # Mitsuba's diffuse default reflectance
    if refl[0].tag not in ("rgb", "float", "spectrum") or refl[0].get("value") is None:
        raise ValueError(f"reflectance <{refl[0].tag}> is not supported (rgb, float, spectrum value)")
    values = _channels(refl[0].get("value"))
    if max(values) - min(values) > 1e-9 * max(max(values), 1e-300):
        raise ValueError(f"reflectance {values} is not grey; datagen albedos are one number")
    if values[0] > 1:
        raise ValueError(f"reflectance {values[0]} > 1 does not conserve energy")
    return values[0]


class TalMesh(BaseModel):
    """``geometry[i].mesh``: a tal ``rectangle`` (2 × 2 m in z = 0, normal +z) or an obj/ply file."""

    model_config = _STRICT
    type: Literal["rectangle", "obj", "ply"]
    filename: str | None = None

    @model_validator(mode="after")
    def _needs_file(self) -> TalMesh:
        if self.type != "rectangle" and self.filename is None:
            raise ValueError(f"an {self.type} mesh needs a filename")
        return self


class TalMaterial(BaseModel):
    """``geometry[i].material``: ``white`` (albedo 1) or ``custom`` Mitsuba XML of a grey diffuse BSDF."""

    model_config = _STRICT
    id: Literal["white", "custom"]
    text: str | None = None

    @field_validator("text")
    @classmethod
    def _diffuse(cls, text: str | None, info: ValidationInfo) -> str | None:
        if info.data.get("id") == "custom":
            _albedo(text)
        return text

    @property
    def albedo(self) -> float:
        return 1.0 if self.id == "white" else _albedo(self.text)


class TalGeometry(BaseModel):
    """One ``geometry`` entry. Transform as Mitsuba applies tal's XML (:func:`tal_transform`)."""

    model_config = _STRICT
    name: Annotated[str, Field(min_length=1)]
    description: str | None = None
    mesh: TalMesh
    material: TalMaterial
    displacement_x: _Float | None = None
    displacement_y: _Float | None = None
    displacement_z: _Float | None = None
    rot_degrees_x: _Float | None = None
    rot_degrees_y: _Float | None = None
    rot_degrees_z: _Float | None = None
    scale_x: _Float | None = None
    scale_y: _Float | None = None
    scale_z: _Float | None = None


def _bad(path: str, message: str, value: Any) -> ValueError:
    """A cross-field problem, worded like a field's (``path: message (got value)``)."""
    return ValueError(f"{path}: {message} (got {short_repr(value)})")


class TalRenderConfig(BaseModel):
    """A tal render YAML: tal 0.20's keys with its defaults, restricted to what datagen translates.

    ``integrator_nlos_*``, ``sample_count`` and ``integrator_discard_direct_paths`` are mitransient's Monte Carlo
    knobs: they change its noise, not the quantity estimated, so datagen checks and ignores them (it never
    renders the direct wall→sensor light that discard_direct_paths removes). ``datagen`` is ours: a mapping of
    datagen simulation options (lookins, pixels, seed, …) that tal ignores.
    """

    model_config = _STRICT
    name: str | None = Field("tal_scene", coerce_numbers_to_str=True)
    mitsuba_variant: Annotated[str, _only(lambda v: v.startswith(("llvm_", "cuda_")) and "spectral" not in v
                                          and "polarized" not in v, "not supported (llvm_/cuda_ … rgb or mono "
                                          "variants only)")] = "llvm_ad_rgb"
    integrator_max_depth: Annotated[_Int, _only(lambda d: d == -1 or d >= 3, "renders no light from the hidden "
                                                "scene (datagen needs -1 or >= 3)")] = -1
    integrator_filter_bounces: Annotated[_Int, _only(lambda b: b == -1, "not supported (-1; use "
                                                     "integrator_max_depth: 3 for third-bounce light only)")] = -1
    integrator_discard_direct_paths: StrictBool = False
    integrator_nlos_laser_sampling: StrictBool = True
    integrator_nlos_hidden_geometry_sampling: StrictBool = False
    integrator_nlos_hidden_geometry_sampling_do_rroulette: StrictBool = False
    integrator_nlos_hidden_geometry_sampling_includes_relay_wall: StrictBool = True
    sample_count: _Count = 1_000_000
    account_first_and_last_bounces: StrictBool = False
    num_bins: _Count = 4096
    bin_width_opl: Annotated[_Float, Field(gt=0)] = 0.003
    start_opl: _Float = 0.0
    auto_detect_bins: Annotated[StrictBool | None, _only(lambda a: not a, "true is not supported (give num_bins "
                                                         "and start_opl)")] = False
    histogram_mode: Literal["time"] = "time"
    wl_mean: _Float | None = None
    wl_sigma: _Float | None = None
    scan_type: Literal["single", "confocal", "exhaustive"] = "single"
    sensor_x: _Float = -0.5
    sensor_y: _Float = 0.0
    sensor_z: _Float = 0.25
    laser_x: _Float = -0.5
    laser_y: _Float = 0.0
    laser_z: _Float = 0.25
    sensor_width: _Count = 256
    sensor_height: _Count = 256
    laser_lookat_x: _Float | None = None     # tal: `laser_lookat_x or sensor_width / 2` (single scans)
    laser_lookat_y: _Float | None = None
    laser_width: _Count = 32
    laser_height: _Count = 32
    laser_aperture_start_x: Annotated[_Float, Field(ge=0, lt=1), _or(0.0)] = 0    # fractions of the wall
    laser_aperture_start_y: Annotated[_Float, Field(ge=0, lt=1), _or(0.0)] = 0
    laser_aperture_end_x: Annotated[_Float, Field(gt=0, le=1), _or(1.0)] = 1      # so an end of 0 means 1
    laser_aperture_end_y: Annotated[_Float, Field(gt=0, le=1), _or(1.0)] = 1
    laser_emission_mode: Annotated[Literal["rgb", "mono"], _or("rgb")] = "rgb"
    laser_emission: Annotated[list[float], BeforeValidator(_channels), _or("1.0, 1.0, 1.0")] = "1.0, 1.0, 1.0"
    relay_wall: str = "relay_wall"
    geometry: Annotated[list[TalGeometry], Field(min_length=1)]
    datagen: dict | None = None

    @model_validator(mode="after")
    def _consistent(self) -> TalRenderConfig:
        names = [g.name for g in self.geometry]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise _bad(f"geometry.{i}.name", f"repeats geometry.{names.index(name)}.name; names must be unique",
                           name)
        if self.relay_wall not in names:
            raise _bad("relay_wall", f"not one of the geometry names {names}", self.relay_wall)
        i = names.index(self.relay_wall)
        wall = self.geometry[i]
        if wall.mesh.type != "rectangle":
            raise _bad(f"geometry.{i}.mesh.type", "the relay wall must be a rectangle (tal's sensor grid follows "
                       "the rectangle's UV)", wall.mesh.type)
        for axis in "xyz":
            if getattr(wall, f"rot_degrees_{axis}"):
                raise _bad(f"geometry.{i}.rot_degrees_{axis}", "relay wall rotation is not supported (tal: NYI)",
                           getattr(wall, f"rot_degrees_{axis}"))
        if wall.scale_z not in (None, 1.0, -1.0, 0.0):
            raise _bad(f"geometry.{i}.scale_z", "the relay wall's scale_z must be 1 or -1 (its normal)", wall.scale_z)
        for a in "xy":
            start, end = getattr(self, f"laser_aperture_start_{a}"), getattr(self, f"laser_aperture_end_{a}")
            if start >= end:
                raise _bad(f"laser_aperture_end_{a}", f"must be > laser_aperture_start_{a} {start}", end)
        sensor, laser = [self.sensor_width, self.sensor_height], [self.laser_width, self.laser_height]
        if self.scan_type == "confocal" and sensor != laser:
            raise _bad("laser_width", f"scan_type confocal needs [laser_width, laser_height] == [sensor_width, "
                       f"sensor_height] = {sensor}", laser)
        mono = self.laser_emission_mode == "mono"
        if len(self.laser_emission) not in ((1,) if mono else (1, 3)):
            raise _bad("laser_emission", "mono mode needs one value" if mono else "rgb mode needs 1 or 3 values",
                       self.laser_emission)
        return self


TAL_DEFAULTS: dict[str, Any] = {k: f.default for k, f in TalRenderConfig.model_fields.items()
                                if k not in ("geometry", "datagen")}
"""tal 0.20's ``render/scene_defaults.yaml`` (without its example ``geometry``, which a config replaces)."""

TAL_KEYS = frozenset(TalRenderConfig.model_fields)
"""Top-level keys accepted in a tal render YAML (``datagen`` is ours, see :class:`TalRenderConfig`)."""


def _validated(config: dict, source: str | None) -> TalRenderConfig:
    try:
        return TalRenderConfig.model_validate(config)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, source)) from None


def load_tal_config(path: str | Path) -> dict:
    """Read a tal render YAML, merge it over tal 0.20's defaults (as ``tal render`` does) and validate it
    (:class:`TalRenderConfig`).

    ``path`` may be the YAML file or tal's scene folder holding ``<folder>/<folder>.yaml``.

    Returns:
        the merged config dict as written (tal's keys; ``geometry`` a list of dicts) and ``_source``, the file.
    Raises:
        SceneError: missing file, YAML syntax error, not a mapping, or an invalid or unsupported option (one
        line: file, field, value).
    """
    path = Path(path)
    if path.is_dir() and (path / f"{path.name}.yaml").is_file():
        path = path / f"{path.name}.yaml"
    data = read_yaml(path, "tal config") or {}
    if not isinstance(data, dict):
        raise SceneError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    merged = {**TAL_DEFAULTS, **data}
    _validated(merged, str(path))
    merged["_source"] = str(path)
    return merged


def tal_transform(entry: dict) -> np.ndarray:
    """4×4 to-world matrix of a tal geometry entry, as tal writes it into Mitsuba's XML.

    Mitsuba applies the XML's ``<scale/>``, ``<rotate x/>``, ``<rotate y/>``, ``<rotate z/>`` and
    ``<translate/>`` in that order, so M = T · R_z · R_y · R_x · S (angles in degrees, right-handed). A
    missing key, or 0/None for a scale (tal writes ``scale or 1``), takes tal's default.
    """
    def g(key, default):
        v = entry.get(key)
        return default if v is None or (default == 1.0 and v == 0) else float(v)

    s = np.diag([g("scale_x", 1.0), g("scale_y", 1.0), g("scale_z", 1.0), 1.0])

    def rot(axis: int, deg: float) -> np.ndarray:
        a = np.deg2rad(deg)
        c, sn = np.cos(a), np.sin(a)
        i, j = (axis + 1) % 3, (axis + 2) % 3     # cyclic, so every rotation is right-handed
        m = np.eye(4)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -sn, sn, c
        return m

    t = np.eye(4)
    t[:3, 3] = [g("displacement_x", 0.0), g("displacement_y", 0.0), g("displacement_z", 0.0)]
    return t @ rot(2, g("rot_degrees_z", 0.0)) @ rot(1, g("rot_degrees_y", 0.0)) @ rot(0, g("rot_degrees_x", 0.0)) @ s


def _apply(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


@dataclass(frozen=True)
class TalCapture:
    """A tal capture as ``tal render`` would lay it out (tal's order and units), for a datagen scene.

    Attributes:
        scan_type: "single" | "confocal" | "exhaustive".
        sensor_grid_xyz: (Sx, Sy, 3) float64 metres, tal's order (x grows with the first index).
        laser_grid_xyz: (Lx, Ly, 3) float64 metres; (1, 1, 3) for single scans.
        normal: (3,) relay-wall normal (toward the hidden scene).
        sensor_xyz, laser_xyz: (3,) sensor and laser-emitter positions.
        delta_t, t_start: bin width and first edge, OPL metres.
        t_accounts_first_and_last_bounces: bool.
        laser_scale: (Lx, Ly) float64 K_l = π·e_sum·cos θ_e/d_e² (module docstring), the factor from
            datagen's point radiance per unit power to tal render's H.
        config: the merged tal config (tal's keys), recorded in ``scene_info['config']``.
        notes: what datagen does differently from mitransient for this config.
    """

    scan_type: str
    sensor_grid_xyz: np.ndarray
    laser_grid_xyz: np.ndarray
    normal: np.ndarray
    sensor_xyz: np.ndarray
    laser_xyz: np.ndarray
    delta_t: float
    t_start: float
    t_accounts_first_and_last_bounces: bool
    laser_scale: np.ndarray
    config: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def _tal_grid(nx: int, ny: int, sx: float, sy: float, ax=(0.0, 1.0), ay=(0.0, 1.0)) -> np.ndarray:
    """tal.render.util.get_grid_xyz in float64: (nx, ny, 3) cell centres of [−sx, sx]×[−sy, sy] cut to the
    aperture (fractions ax, ay of the wall, 0 = −s side), z = 0."""
    x0, x1 = -sx + 2 * sx * ax[0], sx - 2 * sx * (1 - ax[1])
    y0, y1 = -sy + 2 * sy * ay[0], sy - 2 * sy * (1 - ay[1])
    xs = x0 + (np.arange(nx) + 0.5) / nx * (x1 - x0)
    ys = y0 + (np.arange(ny) + 0.5) / ny * (y1 - y0)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx, gy, np.zeros_like(gx)], axis=-1)


def scene_from_tal_config(config: dict, base: str | Path | None = None,
                          source: str | None = None) -> tuple[Scene, TalCapture]:
    """Translate a tal render config (:func:`load_tal_config`; keys it lacks take tal's defaults) into a datagen
    scene and its tal layout.

    What is supported is :class:`TalRenderConfig` (the table in docs/tal.md). obj/ply files are read by trimesh,
    relative to ``base`` or the working directory. ``integrator_max_depth`` d is ``orders`` d − 2 (3: primary only,
    4: + secondary, d ≥ 5: every order up to d − 2), −1 is ``orders: auto`` (every order the scene calls for; the
    order ≥ 3 light runs beside the area and lookin estimators, with the quadrature it is counted as left out).
    The estimator defaults to the hidden-surface quadrature (``estimator: quadrature``; deterministic, the fastest to 1 % on tal's captures,
    docs/tal.md).

    Returns:
        (scene, capture): the datagen Scene (capture block with ``convention: point_radiance``, simulation
        defaults: time axis, ideal IRF, legs, secondary) and the :class:`TalCapture`.
    Raises:
        SceneError: an unsupported or invalid option, on one line naming the file, the field and the value,
        e.g. "scene.yaml: geometry.2.mesh.type: Input should be 'rectangle', 'obj' or 'ply' (got 'sphere')"; a
        mesh file that is missing or unreadable; a laser behind the relay wall or on a laser grid point.
    """
    source = source or config.get("_source")
    prefix = f"{source}: " if source else ""
    base = Path(base) if base is not None else (Path(source).parent if source else None)
    cfg = {**TAL_DEFAULTS, **{k: v for k, v in config.items() if k != "_source"}}
    tc = _validated(cfg, source)

    # -- integrator ----------------------------------------------------------------------------------------
    notes = []
    # Mitsuba's path depth d counts the relay-wall vertices at both ends: d − 2 hidden vertices (docs/physics.md §2,
    # "Orders"): 3 → primary only, 4 → + secondary, d ≥ 5 → every order up to d − 2, −1 (unbounded) → every order
    # the scene calls for (the planner's pilot decides)
    depth = tc.integrator_max_depth
    orders: int | str = "auto" if depth == -1 else depth - 2
    secondary = "none" if orders == 1 else "full"
    mono = "mono" in tc.mitsuba_variant        # e_sum: the laser emission summed as tal sums H's channels
    if tc.laser_emission_mode == "rgb":
        rgb = tc.laser_emission * 3 if len(tc.laser_emission) == 1 else tc.laser_emission
        e_sum = float(np.dot(LUMINANCE_WEIGHTS, rgb)) if mono else float(sum(rgb))
    else:
        e_sum = tc.laser_emission[0] if mono else 3.0 * tc.laser_emission[0]

    # -- geometry ----------------------------------------------------------------------------------------
    objects_dict, meshes = [], []
    for i, entry in enumerate(tc.geometry):
        material = {"kind": "lambertian", "albedo": entry.material.albedo}
        m = tal_transform(entry.model_dump())
        is_relay = entry.name == tc.relay_wall
        if is_relay:
            sz = entry.scale_z
            relay = {"center": m[:3, 3].copy(), "sx": abs(m[0, 0]), "sy": abs(m[1, 1]),
                     "normal": np.array([0.0, 0.0, 1.0 if (sz is None or sz >= 0) else -1.0])}
        label = "relay_wall" if is_relay else "mesh"
        if entry.mesh.type == "rectangle":
            corner = _apply(m, np.array([-1.0, -1.0, 0.0]))
            eu = _apply(m, np.array([1.0, -1.0, 0.0])) - corner
            ev = _apply(m, np.array([-1.0, 1.0, 0.0])) - corner
            if np.linalg.norm(np.cross(eu, ev)) == 0:
                raise SceneError(f"{prefix}geometry.{i}: the rectangle has zero area (check scale_x/scale_y)")
            objects_dict.append({"builder": "quad", "name": entry.name, "label": label,
                                 "corner": corner.tolist(), "edge_u": eu.tolist(), "edge_v": ev.tolist(),
                                 "material": material})
        else:
            meshes.append((i, entry, m, Material(**material), label))

    # -- capture -----------------------------------------------------------------------------------------
    scan, start, bin_width, num_bins = tc.scan_type, tc.start_opl, tc.bin_width_opl, tc.num_bins
    legs = tc.account_first_and_last_bounces
    sw, sh, lw, lh = tc.sensor_width, tc.sensor_height, tc.laser_width, tc.laser_height
    sensor_xyz = np.array([tc.sensor_x, tc.sensor_y, tc.sensor_z])
    laser_xyz = np.array([tc.laser_x, tc.laser_y, tc.laser_z])
    ap = {"start_x": tc.laser_aperture_start_x, "end_x": tc.laser_aperture_end_x,
          "start_y": tc.laser_aperture_start_y, "end_y": tc.laser_aperture_end_y}
    c, sx, sy, n = relay["center"], relay["sx"], relay["sy"], relay["normal"]
    sensor_grid = _tal_grid(sw, sh, sx, sy) + c
    if scan == "single":
        lx = tc.laser_lookat_x or sw / 2      # tal: `laser_lookat_x or sensor_width / 2`
        ly = tc.laser_lookat_y or sh / 2
        spot = c + np.array([sx * (2 * lx / sw - 1), sy * (2 * ly / sh - 1), 0.0])
        laser_grid = spot.reshape(1, 1, 3)
    else:
        laser_grid = _tal_grid(lw, lh, sx, sy, (ap["start_x"], ap["end_x"]), (ap["start_y"], ap["end_y"])) + c
        if scan == "confocal":
            sensor_grid = laser_grid     # the points actually measured (tal writes the full-wall grid here)
        spot = laser_grid[lw // 2, lh // 2]
    to_emitter = laser_xyz - laser_grid
    d_e = np.linalg.norm(to_emitter, axis=-1)
    if np.any(d_e == 0):
        raise SceneError(f"{prefix}laser position {laser_xyz.tolist()} lies on a laser grid point")
    cos_e = (to_emitter @ n) / d_e
    if np.any(cos_e <= 0):
        raise SceneError(f"{prefix}laser position {laser_xyz.tolist()} is behind the relay wall (normal "
                         f"{n.tolist()})")
    laser_scale = np.pi * e_sum * cos_e / d_e ** 2

    def cell_grid(nx: int, ny: int, ax, ay) -> dict:
        """The grid as a datagen WallGrid: centre and size of the (aperture) rectangle, nx × ny cells."""
        w = 2 * sx * (ax[1] - ax[0])
        h = 2 * sy * (ay[1] - ay[0])
        ctr = c + np.array([-sx + 2 * sx * ax[0] + w / 2, -sy + 2 * sy * ay[0] + h / 2, 0.0])
        return {"center": ctr.tolist(), "size": [float(w), float(h)], "points": [nx, ny]}

    full = ((0.0, 1.0), (0.0, 1.0))
    aperture = ((ap["start_x"], ap["end_x"]), (ap["start_y"], ap["end_y"]))
    capture: dict[str, Any] = {"type": scan, "convention": "point_radiance"}
    if scan in ("single", "exhaustive"):
        capture["sensor_grid"] = cell_grid(sw, sh, *full)
    if scan in ("confocal", "exhaustive"):
        capture["laser_grid"] = cell_grid(lw, lh, *aperture)

    extra = tc.datagen or {}
    simulation = {
        "time": {"t_start": start / SPEED_OF_LIGHT, "bin_width": bin_width / SPEED_OF_LIGHT, "n_bins": num_bins},
        "irf": {"sigma": 0.0},
        "count_laser_leg": legs,
        "count_sensor_leg": legs,
        "secondary": secondary,
        "orders": orders,
        # the hidden-surface quadrature (datagen.transport.quadrature) reaches 1 % sooner than the area sampler and
        # the lookin estimator on tal's captures (docs/tal.md); a YAML `datagen:` block or the CLI can change it
        "estimator": "quadrature",
        # tal has no detector: H is radiance. datagen still draws a histogram from the envelope; make it a
        # harmless single-cycle Poisson draw whose period covers the window.
        "detector": {"model": "poisson", "n_cycles": 1,
                     "repetition_rate": min(1e7, 0.5 * SPEED_OF_LIGHT / (start + bin_width * num_bins))},
        **extra,
    }
    data = {
        "name": str(tc.name or "tal_scene"),
        "objects": objects_dict,
        "laser": {"emitter": laser_xyz.tolist(), "spot": np.asarray(spot, dtype=float).tolist()},
        "sensor": {"position": sensor_xyz.tolist()},
        "capture": capture,
        "simulation": simulation,
    }
    # the relay wall is always a rectangle, so the dict has an object; obj/ply meshes (arbitrary tal transforms,
    # which no scene-file builder expresses) join as SceneObjects, in the config's order
    mesh_objects = [_load_mesh(i, entry, m, material, label, base, prefix) for i, entry, m, material, label in meshes]
    scene = scene_from_dict(data, source)
    if mesh_objects:
        order = {e.name: k for k, e in enumerate(tc.geometry)}
        scene = replace(scene, objects=sorted(list(scene.objects) + mesh_objects, key=lambda o: order[o.name]))
    tal_cap = TalCapture(scan, sensor_grid, laser_grid, n, sensor_xyz, laser_xyz, bin_width, start, legs,
                         laser_scale, cfg, tuple(notes))
    return scene, tal_cap


def _load_mesh(i: int, entry: TalGeometry, m: np.ndarray, material: Material, label: str, base: Path | None,
               prefix: str) -> SceneObject:
    import trimesh

    key, filename = f"{prefix}geometry.{i}.mesh.filename", entry.mesh.filename
    path = Path(filename)
    candidates = [path] if path.is_absolute() else ([base / path] if base is not None else []) + [path]
    found = next((p for p in candidates if p.is_file()), None)
    if found is None:
        raise SceneError(f"{key}: not found (looked in {', '.join(str(p) for p in candidates)}) (got {filename!r})")
    try:
        loaded = trimesh.load(found, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise SceneError(f"{key}: cannot read the mesh: {' '.join(str(exc).split())} (got {filename!r})") from None
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if len(faces) == 0:
        raise SceneError(f"{key}: the mesh holds no triangles (got {filename!r})")
    vertices = _apply(m, np.asarray(loaded.vertices, dtype=np.float64))
    if np.linalg.det(m[:3, :3]) < 0:
        faces = faces[:, ::-1]   # a mirroring transform flips the winding; keep the outward side outward
    return SceneObject(entry.name, label, material, vertices, faces)


def scene_from_tal_yaml(path: str | Path) -> tuple[Scene, TalCapture]:
    """:func:`load_tal_config` then :func:`scene_from_tal_config` (mesh paths relative to the YAML's folder).

    Raises:
        SceneError: as those two (one line naming the file, the field and the value).
    """
    config = load_tal_config(path)
    return scene_from_tal_config(config, Path(config["_source"]).parent, config["_source"])
