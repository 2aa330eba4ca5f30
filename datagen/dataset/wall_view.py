"""Labels in the reconstruction networks' convention: the hidden objects seen orthographically from the wall.

LFE (Chen et al. 2020), NLOST (Li et al. 2023) and LEAP (Cho et al. 2024) train on orthographic depth and
intensity images of the hidden object seen from the scanned relay-wall rectangle, on the same grid as the scan.
:func:`wall_view_labels` renders them with the Embree ray caster (:class:`datagen.scene.RayCaster`): one ray per
pixel, from the pixel centre on the wall (stepped off it by the caster's offset) along the wall normal n into the
hidden side.

Pixel grid: the rectangle (centre c, size w × h) of the scan's laser grid (or the FoV of a single-spot capture)
on the relay wall, H × W pixels; pixel (i, j) is the cell centre c + ((j + ½)/W − ½)·w·u + ((i + ½)/H − ½)·h·v
with u = n × z (the wall's horizontal tangent) and v = u × n (up). With the default resolution (the scan grid),
``wall_depth[i, j]`` belongs to the scan point of ``envelope[i, j]`` (datagen.dataset.scan: row i grows upward,
plot with ``origin="lower"``). Only hidden objects count: a ray whose first hit is a room surface (wall, floor,
ceiling) or nothing gives background (depth 0, normal 0, albedo 0, no mask).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..scene import RayCaster
from ..vectors import norm

WALL_VIEW_FIELDS = ("wall_depth", "wall_normal", "wall_albedo", "wall_mask")
"""Names of the arrays :func:`wall_view_labels` returns."""


def view_rectangle(params: dict) -> tuple[np.ndarray, tuple[float, float], tuple[int, int]]:
    """Centre (3,) m, size (w, h) m and grid points (nx, ny) of the wall rectangle a sample's labels view: the
    scan's laser grid, else the FoV (a room's ``params``, :class:`datagen.dataset.sampler.SampledRoom`).

    Raises:
        ConfigError: the params hold neither a scan nor a FoV.
    """
    sensor = params["sensor"]
    scan = sensor.get("scan")
    grid = scan["laser_grid"] if scan is not None else sensor.get("fov")
    if grid is None:
        raise ConfigError("labels: the sample has neither a scan nor a FoV to view from")
    points = tuple(grid.get("points") or grid.get("pixels"))
    return np.asarray(grid["center"], dtype=np.float64), tuple(grid["size"]), points


def wall_frame(caster: RayCaster, sensor: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray]:
    """(u, v, n) unit vectors of the relay wall at ``center``: n its normal facing the sensor (the first hit
    along sensor → centre), u = n × z (n × y for a horizontal wall), v = u × n — the frame of
    :func:`datagen.scene.resolve_capture`."""
    d = center - sensor
    hit = caster.intersect(sensor[None], (d / norm(d))[None])
    n = hit.normals[0] if hit.hit[0] else -d / norm(d)
    u = np.cross(n, [0.0, 0.0, 1.0])
    if norm(u) < 1e-9:
        u = np.cross(n, [0.0, 1.0, 0.0])
    u /= norm(u)
    return u, np.cross(u, n), n


def wall_view_labels(room, caster: RayCaster, pixels: tuple[int, int], max_objects: int) -> dict[str, np.ndarray]:
    """Orthographic labels of ``room`` (a :class:`~datagen.dataset.sampler.SampledRoom`) from its wall rectangle.

    Args:
        room: the sampled room (scene, params, objects).
        caster: a ray caster of ``room.scene``.
        pixels: (H, W) label pixels over the rectangle of :func:`view_rectangle`.
        max_objects: K, the length of the per-object mask axis.
    Returns:
        wall_depth: float32 (H, W) m, distance along n from the wall to the first hidden-object surface, 0 for
        background; wall_normal: float32 (H, W, 3) unit world normals facing the wall, 0 for background;
        wall_albedo: float32 (H, W) the hit object's albedo ρ (the networks' intensity image), 0 for background;
        wall_mask: uint8 (K, H, W), 1 where hidden object k (``room.objects`` order) is the first hit.
    """
    h, w = pixels
    center, size, _ = view_rectangle(room.params)
    sensor = np.asarray(room.scene.sensor.position, dtype=np.float64)
    u, v, n = wall_frame(caster, sensor, center)
    a = ((np.arange(w) + 0.5) / w - 0.5) * size[0]
    b = ((np.arange(h) + 0.5) / h - 0.5) * size[1]
    origins = center + b[:, None, None] * v + a[None, :, None] * u + caster.offset * n      # (H, W, 3)
    hits = caster.intersect(origins, np.broadcast_to(n, origins.shape))
    names = [o.name for o in room.scene.objects]
    index = np.full(len(names) + 1, -1, dtype=np.int64)       # scene object id → hidden object k (−1: room)
    for k, obj in enumerate(room.objects):
        index[names.index(obj["name"])] = k
    k_hit = np.where(hits.hit, index[hits.object_id], -1)
    hidden = k_hit >= 0
    albedo = np.array([o["material"]["albedo"] for o in room.objects] + [0.0], dtype=np.float64)
    mask = np.zeros((max_objects, h, w), dtype=np.uint8)
    for k in range(len(room.objects)):
        mask[k] = k_hit == k
    return {"wall_depth": np.where(hidden, hits.distance + caster.offset, 0.0).astype(np.float32),
            "wall_normal": np.where(hidden[..., None], hits.normals, 0.0).astype(np.float32),
            "wall_albedo": np.where(hidden, albedo[k_hit], 0.0).astype(np.float32),
            "wall_mask": mask}
