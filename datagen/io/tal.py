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

import copy
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..scene import Material, Scene, SceneError, SceneObject, read_yaml, scene_from_dict
from ..units import SPEED_OF_LIGHT

__all__ = [
    "TAL_DEFAULTS", "TAL_KEYS", "TalCapture", "load_tal_config", "scene_from_tal_config", "scene_from_tal_yaml",
    "tal_transform",
]


# ---------------------------------------------------------------------------------------------------------
# tal render YAML

TAL_DEFAULTS: dict[str, Any] = {
    "name": "tal_scene",
    "mitsuba_variant": "llvm_ad_rgb",
    "integrator_max_depth": -1,
    "integrator_filter_bounces": -1,
    "integrator_discard_direct_paths": False,
    "integrator_nlos_laser_sampling": True,
    "integrator_nlos_hidden_geometry_sampling": False,
    "integrator_nlos_hidden_geometry_sampling_do_rroulette": False,
    "integrator_nlos_hidden_geometry_sampling_includes_relay_wall": True,
    "sample_count": 1_000_000,
    "account_first_and_last_bounces": False,
    "num_bins": 4096,
    "bin_width_opl": 0.003,
    "start_opl": 0.0,
    "auto_detect_bins": False,
    "histogram_mode": "time",
    "wl_mean": None,
    "wl_sigma": None,
    "scan_type": "single",
    "sensor_x": -0.5, "sensor_y": 0.0, "sensor_z": 0.25,
    "laser_x": -0.5, "laser_y": 0.0, "laser_z": 0.25,
    "sensor_width": 256, "sensor_height": 256,
    "laser_lookat_x": None, "laser_lookat_y": None,
    "laser_width": 32, "laser_height": 32,
    "laser_aperture_start_x": 0, "laser_aperture_start_y": 0,
    "laser_aperture_end_x": 1, "laser_aperture_end_y": 1,
    "laser_emission_mode": "rgb",
    "laser_emission": "1.0, 1.0, 1.0",
    "relay_wall": "relay_wall",
}
"""tal 0.20's ``render/scene_defaults.yaml`` (without its example ``geometry``, which a config replaces)."""

TAL_KEYS = frozenset(TAL_DEFAULTS) | {"geometry", "datagen"}
"""Top-level keys accepted in a tal render YAML. ``datagen`` is ours: a mapping of datagen simulation options
(lookins, pixels, seed, …) that tal ignores."""

_GEOMETRY_KEYS = frozenset({"name", "description", "mesh", "material", "displacement_x", "displacement_y",
                            "displacement_z", "rot_degrees_x", "rot_degrees_y", "rot_degrees_z", "scale_x",
                            "scale_y", "scale_z"})
_MESH_TYPES = ("rectangle", "obj", "ply")
_IGNORED_MC_KEYS = ("integrator_nlos_laser_sampling", "integrator_nlos_hidden_geometry_sampling",
                    "integrator_nlos_hidden_geometry_sampling_do_rroulette",
                    "integrator_nlos_hidden_geometry_sampling_includes_relay_wall", "sample_count",
                    "integrator_discard_direct_paths")
"""Monte Carlo knobs of mitransient: they change its noise, not the quantity estimated, so datagen ignores them
(datagen never renders the direct wall→sensor light that discard_direct_paths removes)."""

LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)
"""Mitsuba's RGB → luminance weights (sRGB/Rec. 709 Y), used by its mono variants for RGB inputs."""


class _Where:
    """Prefix for error messages: the config file, if any."""

    def __init__(self, source: str | None):
        self.prefix = f"{source}: " if source else ""

    def error(self, message: str) -> SceneError:
        return SceneError(self.prefix + message)


def _number(value: Any, key: str, where: _Where, *, integer: bool = False, minimum: float | None = None) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise where.error(f"{key}: expected a {'whole ' if integer else ''}number, got {value!r}")
    if integer and float(value) != int(value):
        raise where.error(f"{key}: expected a whole number, got {value!r}")
    if minimum is not None and value < minimum:
        raise where.error(f"{key}: must be >= {minimum}, got {value!r}")
    return int(value) if integer else float(value)


def _bool(value: Any, key: str, where: _Where) -> bool:
    if not isinstance(value, bool):
        raise where.error(f"{key}: expected true or false, got {value!r}")
    return value


def _channels(value: Any, key: str, where: _Where) -> list[float]:
    """'1.0, 1.0, 1.0' / 0.5 / [1, 1, 1] → list of floats (tal writes RGB values as comma-separated text)."""
    if isinstance(value, str):
        parts = [p for p in value.replace(",", " ").split()]
    elif isinstance(value, (list, tuple)):
        parts = list(value)
    else:
        parts = [value]
    try:
        out = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise where.error(f"{key}: expected a number or 'r, g, b', got {value!r}") from None
    if not out or not all(math.isfinite(v) and v >= 0 for v in out):
        raise where.error(f"{key}: expected non-negative numbers, got {value!r}")
    return out


def load_tal_config(path: str | Path) -> dict:
    """Read a tal render YAML and merge it over tal 0.20's defaults (as ``tal render`` does).

    ``path`` may be the YAML file or tal's scene folder holding ``<folder>/<folder>.yaml``.

    Returns:
        the merged config dict (tal's keys; ``geometry`` a list of dicts), validated by
        :func:`scene_from_tal_config` later.
    Raises:
        SceneError: missing file, YAML syntax error, not a mapping, or an unknown top-level key.
    """
    path = Path(path)
    if path.is_dir() and (path / f"{path.name}.yaml").is_file():
        path = path / f"{path.name}.yaml"
    data = read_yaml(path, "tal config") or {}
    if not isinstance(data, dict):
        raise SceneError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    unknown = sorted(set(data) - TAL_KEYS)
    if unknown:
        raise SceneError(f"{path}: unknown tal option {unknown[0]!r} (tal 0.20 render keys: see "
                         "tal/render/scene_defaults.yaml)")
    merged = {**copy.deepcopy(TAL_DEFAULTS), **data}
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


def _albedo(material: Any, key: str, where: _Where) -> float:
    """Albedo of a tal material entry: ``white`` (reflectance 1) or ``custom`` Mitsuba XML of a diffuse BSDF
    (optionally inside ``twosided``) with a grey ``rgb``/``float``/``spectrum`` reflectance."""
    if not isinstance(material, dict) or "id" not in material:
        raise where.error(f"{key}: expected a mapping with an 'id' (white or custom), got {material!r}")
    mid = material["id"]
    if mid == "white":
        return 1.0
    if mid != "custom":
        raise where.error(f"{key}.id {mid!r} is not supported (white, custom with a diffuse BSDF)")
    text = material.get("text")
    if not isinstance(text, str):
        raise where.error(f"{key}.text: a custom material needs Mitsuba XML text, got {text!r}")
    try:
        node = ET.fromstring(text.strip())
    except ET.ParseError as exc:
        raise where.error(f"{key}.text: not valid XML: {exc}") from None
    while node.tag == "bsdf" and node.get("type") == "twosided":
        inner = node.find("bsdf")
        if inner is None:
            raise where.error(f"{key}.text: twosided BSDF without an inner <bsdf>")
        node = inner
    if node.tag != "bsdf" or node.get("type") != "diffuse":
        raise where.error(f"{key}.text: BSDF type {node.get('type')!r} is not supported (diffuse)")
    refl = [c for c in node if c.get("name") == "reflectance"]
    if not refl:
        return 0.5   # Mitsuba's diffuse default reflectance
    if refl[0].tag not in ("rgb", "float", "spectrum") or refl[0].get("value") is None:
        raise where.error(f"{key}.text: reflectance <{refl[0].tag}> is not supported (rgb, float, spectrum value)")
    values = _channels(refl[0].get("value"), f"{key}.text reflectance", where)
    if max(values) - min(values) > 1e-9 * max(max(values), 1e-300):
        raise where.error(f"{key}.text: reflectance {values} is not grey; datagen albedos are one number")
    if values[0] > 1:
        raise where.error(f"{key}.text: reflectance {values[0]} > 1 does not conserve energy")
    return values[0]


def _emission_sum(config: dict, where: _Where) -> float:
    """e_sum: the laser emission summed as tal sums H's channels (see the module docstring)."""
    variant = config["mitsuba_variant"]
    if not isinstance(variant, str) or not variant.startswith(("llvm_", "cuda_")):
        raise where.error(f"mitsuba_variant {variant!r} is not supported (llvm_/cuda_ … rgb or mono)")
    if "spectral" in variant or "polarized" in variant:
        raise where.error(f"mitsuba_variant {variant!r} is not supported (rgb or mono variants only)")
    mono = "mono" in variant
    mode = config["laser_emission_mode"] or "rgb"
    value = config["laser_emission"] or "1.0, 1.0, 1.0"
    if mode == "rgb":
        rgb = _channels(value, "laser_emission", where)
        if len(rgb) == 1:
            rgb = rgb * 3
        if len(rgb) != 3:
            raise where.error(f"laser_emission: rgb mode needs 3 values, got {value!r}")
        return float(np.dot(LUMINANCE_WEIGHTS, rgb)) if mono else float(sum(rgb))
    if mode == "mono":
        v = _channels(value, "laser_emission", where)
        if len(v) != 1:
            raise where.error(f"laser_emission: mono mode needs one value, got {value!r}")
        return v[0] if mono else 3.0 * v[0]
    raise where.error(f"laser_emission_mode {mode!r} is not supported (rgb, mono)")


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
    """Translate a merged tal render config (:func:`load_tal_config`) into a datagen scene and its tal layout.

    Supported: ``geometry`` entries with ``mesh.type`` rectangle/obj/ply (obj/ply read by trimesh, paths
    relative to ``base`` or the working directory) with displacement/rotation/scale, materials ``white`` and
    ``custom`` diffuse (grey albedo); ``relay_wall`` (a rectangle, not rotated; scale_z = ±1 picks the normal);
    ``scan_type`` single/confocal/exhaustive with sensor/laser grid sizes, ``laser_lookat_*`` and the laser
    aperture bounds; ``num_bins``, ``bin_width_opl``, ``start_opl``, ``account_first_and_last_bounces``; laser and
    sensor positions; ``laser_emission`` (rgb/mono) with rgb/mono variants; ``integrator_max_depth`` −1 or ≥ 3
    (3: primary only; otherwise datagen adds its one-more-bounce secondary and omits longer paths, noted).
    datagen's estimator defaults to the hidden-surface quadrature (``estimator: quadrature``, sub-triangles of
    ``quadrature_edge`` metres; deterministic, the fastest to 1 % on tal's captures, docs/tal.md).

    Returns:
        (scene, capture): the datagen Scene (capture block with ``convention: point_radiance``, simulation
        defaults: time axis, ideal IRF, legs, secondary) and the :class:`TalCapture`.
    Raises:
        SceneError: an unsupported or invalid option, naming it, e.g. "geometry[2].mesh.type 'sphere' is not
        supported (rectangle, obj, ply)".
    """
    source = source or config.get("_source")
    where = _Where(source)
    base = Path(base) if base is not None else (Path(source).parent if source else None)
    cfg = {k: v for k, v in config.items() if k != "_source"}
    unknown = sorted(set(cfg) - TAL_KEYS)
    if unknown:
        raise where.error(f"unknown tal option {unknown[0]!r}")

    # -- histogram / integrator options ------------------------------------------------------------------
    if cfg["histogram_mode"] != "time":
        raise where.error(f"histogram_mode {cfg['histogram_mode']!r} is not supported (time)")
    if cfg["auto_detect_bins"]:
        raise where.error("auto_detect_bins: true is not supported (give num_bins and start_opl)")
    if _number(cfg["integrator_filter_bounces"], "integrator_filter_bounces", where, integer=True) != -1:
        raise where.error(f"integrator_filter_bounces {cfg['integrator_filter_bounces']} is not supported "
                          "(-1; use integrator_max_depth: 3 for third-bounce light only)")
    max_depth = _number(cfg["integrator_max_depth"], "integrator_max_depth", where, integer=True)
    notes = []
    if max_depth == 3:
        secondary = "none"
    elif max_depth == -1 or max_depth >= 4:
        secondary = "full"
        if max_depth != 4:
            notes.append(f"integrator_max_depth {max_depth}: datagen simulates third- and fourth-bounce light "
                         "(primary + secondary), not longer paths")
    else:
        raise where.error(f"integrator_max_depth {max_depth} renders no light from the hidden scene "
                          "(datagen needs -1 or >= 3)")
    for key in _IGNORED_MC_KEYS:       # validated like tal would use them, then ignored
        if key == "sample_count":
            _number(cfg[key], key, where, minimum=1)
        else:
            _bool(cfg[key], key, where)
    num_bins = _number(cfg["num_bins"], "num_bins", where, integer=True, minimum=1)
    bin_width = _number(cfg["bin_width_opl"], "bin_width_opl", where)
    if bin_width <= 0:
        raise where.error(f"bin_width_opl: must be > 0, got {cfg['bin_width_opl']!r}")
    start = _number(cfg["start_opl"], "start_opl", where)
    legs = _bool(cfg["account_first_and_last_bounces"], "account_first_and_last_bounces", where)
    e_sum = _emission_sum(cfg, where)

    # -- geometry ----------------------------------------------------------------------------------------
    geometry = cfg.get("geometry")
    if not isinstance(geometry, list) or not geometry:
        raise where.error("geometry: expected a list of geometry entries")
    names = []
    for i, entry in enumerate(geometry):
        if not isinstance(entry, dict):
            raise where.error(f"geometry[{i}]: expected a mapping, got {entry!r}")
        bad = sorted(set(entry) - _GEOMETRY_KEYS)
        if bad:
            raise where.error(f"geometry[{i}].{bad[0]} is not a tal geometry option")
        if not isinstance(entry.get("name"), str) or not entry["name"]:
            raise where.error(f"geometry[{i}].name: expected a name, got {entry.get('name')!r}")
        names.append(entry["name"])
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise where.error(f"geometry names must be unique; repeated: {dup}")
    rw_name = cfg["relay_wall"]
    if rw_name not in names:
        raise where.error(f"relay_wall {rw_name!r} is not one of the geometry names {names}")

    objects_dict, meshes = [], []
    relay = None
    for i, entry in enumerate(geometry):
        key = f"geometry[{i}]"
        mesh = entry.get("mesh")
        if not isinstance(mesh, dict) or "type" not in mesh:
            raise where.error(f"{key}.mesh: expected a mapping with a 'type', got {mesh!r}")
        mtype = mesh["type"]
        if mtype not in _MESH_TYPES:
            raise where.error(f"{key}.mesh.type {mtype!r} is not supported ({', '.join(_MESH_TYPES)})")
        for k in _GEOMETRY_KEYS - {"name", "description", "mesh", "material"}:
            if entry.get(k) is not None:
                _number(entry[k], f"{key}.{k}", where)
        albedo = _albedo(entry.get("material"), f"{key}.material", where)
        material = {"kind": "lambertian", "albedo": albedo}
        m = tal_transform(entry)
        is_relay = entry["name"] == rw_name
        if is_relay:
            if mtype != "rectangle":
                raise where.error(f"{key}.mesh.type {mtype!r}: the relay wall must be a rectangle (tal's sensor "
                                  "grid follows the rectangle's UV)")
            for axis in "xyz":
                if entry.get(f"rot_degrees_{axis}"):
                    raise where.error(f"{key}.rot_degrees_{axis}: relay wall rotation is not supported (tal: NYI)")
            sz = entry.get("scale_z")
            if sz is not None and float(sz) not in (1.0, -1.0, 0.0):
                raise where.error(f"{key}.scale_z {sz}: the relay wall's scale_z must be 1 or -1 (its normal)")
            sx, sy = abs(m[0, 0]), abs(m[1, 1])
            if sx == 0 or sy == 0:
                raise where.error(f"{key}: the relay wall has zero size (scale_x {sx}, scale_y {sy})")
            relay = {"center": m[:3, 3].copy(), "sx": sx, "sy": sy,
                     "normal": np.array([0.0, 0.0, 1.0 if (sz is None or float(sz) >= 0) else -1.0])}
        label = "relay_wall" if is_relay else "mesh"
        if mtype == "rectangle":
            corner = _apply(m, np.array([-1.0, -1.0, 0.0]))
            eu = _apply(m, np.array([1.0, -1.0, 0.0])) - corner
            ev = _apply(m, np.array([-1.0, 1.0, 0.0])) - corner
            if np.linalg.norm(np.cross(eu, ev)) == 0:
                raise where.error(f"{key}: the rectangle has zero area (check scale_x/scale_y)")
            objects_dict.append({"builder": "quad", "name": entry["name"], "label": label,
                                 "corner": corner.tolist(), "edge_u": eu.tolist(), "edge_v": ev.tolist(),
                                 "material": material})
        else:
            meshes.append((i, entry, m, Material(**material), label))

    # -- capture -----------------------------------------------------------------------------------------
    scan = cfg["scan_type"]
    if scan not in ("single", "confocal", "exhaustive"):
        raise where.error(f"scan_type {scan!r} is not supported (single, confocal, exhaustive)")
    sw = _number(cfg["sensor_width"], "sensor_width", where, integer=True, minimum=1)
    sh = _number(cfg["sensor_height"], "sensor_height", where, integer=True, minimum=1)
    lw = _number(cfg["laser_width"], "laser_width", where, integer=True, minimum=1)
    lh = _number(cfg["laser_height"], "laser_height", where, integer=True, minimum=1)
    sensor_xyz = np.array([_number(cfg[f"sensor_{a}"], f"sensor_{a}", where) for a in "xyz"])
    laser_xyz = np.array([_number(cfg[f"laser_{a}"], f"laser_{a}", where) for a in "xyz"])
    ap = {}
    for k in ("start_x", "start_y", "end_x", "end_y"):
        key = f"laser_aperture_{k}"
        # tal reads these as `value or default`, so 0 (or null) for an end means 1
        v = cfg[key]
        ap[k] = (1.0 if k.startswith("end") else 0.0) if not v else _number(v, key, where)
    for a in "xy":
        if not 0 <= ap[f"start_{a}"] < ap[f"end_{a}"] <= 1:
            raise where.error(f"laser_aperture_start_{a} {ap[f'start_{a}']} / laser_aperture_end_{a} "
                              f"{ap[f'end_{a}']}: need 0 <= start < end <= 1")
    c, sx, sy, n = relay["center"], relay["sx"], relay["sy"], relay["normal"]
    sensor_grid = _tal_grid(sw, sh, sx, sy) + c
    if scan == "single":
        lx = cfg["laser_lookat_x"] or sw / 2      # tal: `laser_lookat_x or sensor_width / 2`
        ly = cfg["laser_lookat_y"] or sh / 2
        lx = _number(lx, "laser_lookat_x", where)
        ly = _number(ly, "laser_lookat_y", where)
        spot = c + np.array([sx * (2 * lx / sw - 1), sy * (2 * ly / sh - 1), 0.0])
        laser_grid = spot.reshape(1, 1, 3)
    else:
        if scan == "confocal" and (lw, lh) != (sw, sh):
            raise where.error(f"scan_type confocal needs sensor_width/height == laser_width/height, got "
                              f"{sw}x{sh} and {lw}x{lh}")
        laser_grid = _tal_grid(lw, lh, sx, sy, (ap["start_x"], ap["end_x"]), (ap["start_y"], ap["end_y"])) + c
        if scan == "confocal":
            sensor_grid = laser_grid     # the points actually measured (tal writes the full-wall grid here)
        spot = laser_grid[lw // 2, lh // 2]
    to_emitter = laser_xyz - laser_grid
    d_e = np.linalg.norm(to_emitter, axis=-1)
    if np.any(d_e == 0):
        raise where.error(f"laser position {laser_xyz.tolist()} lies on a laser grid point")
    cos_e = (to_emitter @ n) / d_e
    if np.any(cos_e <= 0):
        raise where.error(f"laser position {laser_xyz.tolist()} is behind the relay wall (normal {n.tolist()})")
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

    extra = cfg.get("datagen") or {}
    if not isinstance(extra, dict):
        raise where.error(f"datagen: expected a mapping of datagen simulation options, got {extra!r}")
    simulation = {
        "time": {"t_start": start / SPEED_OF_LIGHT, "bin_width": bin_width / SPEED_OF_LIGHT, "n_bins": num_bins},
        "irf": {"sigma": 0.0},
        "count_laser_leg": legs,
        "count_sensor_leg": legs,
        "secondary": secondary,
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
        "name": str(cfg.get("name") or "tal_scene"),
        "objects": objects_dict,
        "laser": {"emitter": laser_xyz.tolist(), "spot": np.asarray(spot, dtype=float).tolist()},
        "sensor": {"position": sensor_xyz.tolist()},
        "capture": capture,
        "simulation": simulation,
    }
    # the relay wall is always a rectangle, so the dict has an object; obj/ply meshes (arbitrary tal transforms,
    # which no scene-file builder expresses) join as SceneObjects, in the config's order
    mesh_objects = [_load_mesh(i, entry, m, material, label, base, where) for i, entry, m, material, label in meshes]
    scene = scene_from_dict(data, source)
    if mesh_objects:
        order = {e["name"]: k for k, e in enumerate(geometry)}
        scene = replace(scene, objects=sorted(list(scene.objects) + mesh_objects, key=lambda o: order[o.name]))
    tal_cap = TalCapture(scan, sensor_grid, laser_grid, n, sensor_xyz, laser_xyz, bin_width, start, legs,
                         laser_scale, {k: v for k, v in cfg.items()}, tuple(notes))
    return scene, tal_cap


def _load_mesh(i: int, entry: dict, m: np.ndarray, material: Material, label: str, base: Path | None,
               where: _Where) -> SceneObject:
    import trimesh

    key = f"geometry[{i}]"
    filename = entry["mesh"].get("filename")
    if not isinstance(filename, str):
        raise where.error(f"{key}.mesh.filename: an {entry['mesh']['type']} mesh needs a filename")
    path = Path(filename)
    candidates = [path] if path.is_absolute() else ([base / path] if base is not None else []) + [path]
    found = next((p for p in candidates if p.is_file()), None)
    if found is None:
        raise where.error(f"{key}.mesh.filename {filename!r} not found (looked in "
                          f"{', '.join(str(p) for p in candidates)})")
    try:
        loaded = trimesh.load(found, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise where.error(f"{key}.mesh.filename {filename!r}: cannot read mesh: {exc}") from None
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if len(faces) == 0:
        raise where.error(f"{key}.mesh.filename {filename!r} holds no triangles")
    vertices = _apply(m, np.asarray(loaded.vertices, dtype=np.float64))
    if np.linalg.det(m[:3, :3]) < 0:
        faces = faces[:, ::-1]   # a mirroring transform flips the winding; keep the outward side outward
    return SceneObject(entry["name"], label, material, vertices, faces)


def scene_from_tal_yaml(path: str | Path) -> tuple[Scene, TalCapture]:
    """:func:`load_tal_config` then :func:`scene_from_tal_config` (mesh paths relative to the YAML's folder)."""
    config = load_tal_config(path)
    return scene_from_tal_config(config, Path(config["_source"]).parent, config["_source"])
