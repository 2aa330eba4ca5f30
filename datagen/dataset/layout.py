"""The reconstruction networks' tensor layout of a scanned sample (``NLOSDataset(..., layout="network")``).

LFE, NLOST, LEAP and Mu et al. feed a scan as a (1, T, H, W) float tensor (channel, time, scan rows, scan
columns) and their labels as (1, H, W) images. :func:`network_shapes` checks a split's stored fields and gives
their network shapes; :func:`to_network` moves the axes of one sample (numpy, before the tensors are made):

- ``envelope``, ``counts``: stored (H, W, T) for confocal scans, sensor grids and a flood's zones (Z_y, Z_x, T)
  → (1, T, H, W) float32; an exhaustive scan with one sensor point, (Ly, Lx, 1, 1, T) → (1, T, Ly, Lx). Other
  shapes (the paper's single pixel (T,), exhaustive scans with a sensor grid) have no such layout and are refused.
- ``components`` (C, H, W, T) → (C, T, H, W) float32.
- ``wall_depth``, ``wall_albedo`` (H, W) → (1, H, W); ``wall_normal`` (H, W, 3) → (3, H, W); ``wall_mask``
  (K, H, W) unchanged.

Row h grows up the relay wall and column w along its horizontal tangent (docs/datasets.md, "Scanned captures"),
for the scan and the wall-view labels alike: pixel (h, w) of a label belongs to scan point (h, w).
:func:`axis_names` names the axes of the stored per-sample arrays (recorded in the card and on each array).
"""
from __future__ import annotations

import numpy as np

SCAN_FIELDS = ("envelope", "counts")

FRAME_FIELDS = ("envelope", "counts", "frame_error", "frame_times", "track_position", "track_velocity", "track_box",
                "depth", "normal", "wall_depth", "wall_normal", "wall_albedo", "wall_mask")
"""The fields a capture sequence stores per frame (leading frame axis; datagen/dataset/sequences.py): a clip of the
loader (``NLOSDataset(..., clip=L)``) slices them."""


def axis_names(name: str, ndim: int, capture_kind: str | None) -> list[str] | None:
    """Axis names of stored field ``name`` (per sample, ``ndim`` axes) for a capture of ``capture_kind``
    (``"confocal"``, ``"exhaustive"``, ``"single"`` with a sensor grid, ``"multizone"`` a flood's zones; None: the
    paper's single pixel, whose (T,) arrays need no names). ``*_y`` axes grow up the relay wall (v), ``*_x`` along its horizontal tangent
    u = n × z; None for fields without names."""
    lead = {"confocal": ["scan_y", "scan_x"], "exhaustive": ["laser_y", "laser_x", "sensor_y", "sensor_x"],
            "single": ["pixel_y", "pixel_x"], "multizone": ["zone_y", "zone_x"]}.get(capture_kind or "", [])
    if name == "node_envelope":         # a multi-zone capture's per-node envelope (datagen/dataset/zones.py)
        return ["node_y", "node_x", "zone_y", "zone_x", "time"] if ndim == 5 else None
    if name in ("envelope", "counts"):
        if ndim == len(lead) + 2:        # a capture sequence's frames (datagen/dataset/sequences.py)
            return ["frame"] + lead + ["time"]
        return lead + ["time"] if lead and ndim == len(lead) + 1 else None
    if name == "components":
        inner = axis_names("envelope", ndim - 1, capture_kind)
        return None if inner is None else ["component"] + inner
    view = {"wall_depth": ["view_y", "view_x"], "wall_albedo": ["view_y", "view_x"],
            "wall_normal": ["view_y", "view_x", "xyz"], "wall_mask": ["object", "view_y", "view_x"],
            "frame_error": ["frame"], "frame_times": ["frame"], "track_position": ["frame", "walker", "xyz"],
            "track_velocity": ["frame", "walker", "xyz"], "track_box": ["frame", "walker", "corner", "xyz"]}
    names = view.get(name)
    if names is not None and name.startswith("wall_") and ndim == len(names) + 1:
        return ["frame"] + names           # a sequence's wall-view labels, per frame
    return names


def capture_kind(scene) -> str | None:
    """The capture kind :func:`axis_names` takes for a :class:`~datagen.scene.Scene`: None for the paper's single
    pixel (no capture block, or one that gives only ``frames``, and one FoV pixel), else the capture's type
    ("single" for a sensor grid without a capture block)."""
    cap = scene.capture
    given = cap is not None and bool(cap.model_fields_set - {"frames"})
    if given:
        return cap.type
    return None if scene.sensor.fov.pixels == (1, 1) else "single"


def array_axes(arrays: dict, capture_kind: str | None) -> dict[str, list[str]]:
    """Axis names (:func:`axis_names`) of every named array of a sample (name → per-sample array)."""
    return {name: names for name, value in arrays.items()
            if (names := axis_names(name, np.ndim(value), capture_kind)) is not None}


def _scan_shape(shape: tuple[int, ...]) -> tuple[int, int] | None:
    """(H, W) of a stored per-sample scan shape, or None when it has no (1, T, H, W) layout."""
    if len(shape) == 3:
        return shape[0], shape[1]
    if len(shape) == 5 and shape[2:4] == (1, 1):
        return shape[0], shape[1]
    return None


def network_shapes(fields: dict[str, dict]) -> dict[str, tuple[int, ...]]:
    """Network shape of every stored field of a split (the card's ``splits[s]["fields"]``: name → {shape, ...}).

    Raises:
        ValueError: the scan (envelope or counts) has no (1, T, H, W) layout, naming its shape.
    """
    out = {}
    for name in SCAN_FIELDS:
        if name in fields:
            shape = tuple(fields[name]["shape"])
            hw = _scan_shape(shape)
            if hw is None:
                raise ValueError(f"layout='network' needs a scanned capture (stored {name} (H, W, T) or an "
                                 f"exhaustive scan with one sensor point), got {name} of shape {shape}")
            out[name] = (1, shape[-1]) + hw
    if "components" in fields:
        shape = tuple(fields["components"]["shape"])
        out["components"] = (shape[0], shape[-1]) + _scan_shape(shape[1:])
    for name, channels in (("wall_depth", 1), ("wall_albedo", 1), ("wall_normal", 3)):
        if name in fields:
            out[name] = (channels,) + tuple(fields[name]["shape"][:2])
    return out


def to_network(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One sample's arrays in the network layout (module doc); other fields are returned unchanged."""
    out = dict(arrays)
    for name in SCAN_FIELDS:
        if name in arrays:
            a = np.asarray(arrays[name])
            h, w = _scan_shape(a.shape)
            out[name] = np.ascontiguousarray(np.moveaxis(a.reshape(h, w, a.shape[-1]), -1, 0)[None],
                                             dtype=np.float32)
    if "components" in arrays:
        c = np.asarray(arrays["components"])
        h, w = _scan_shape(c.shape[1:])
        out["components"] = np.ascontiguousarray(np.moveaxis(c.reshape(len(c), h, w, c.shape[-1]), -1, 1),
                                                 dtype=np.float32)
    for name in ("wall_depth", "wall_albedo"):
        if name in arrays:
            out[name] = np.asarray(arrays[name])[None]
    if "wall_normal" in arrays:
        out["wall_normal"] = np.ascontiguousarray(np.moveaxis(np.asarray(arrays["wall_normal"]), -1, 0))
    return out
