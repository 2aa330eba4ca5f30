"""What ``datagen view`` adds for a multi-zone scene (docs/multizone.md): the lit patch of the flood (outline and
its quadrature nodes' weights in the legend) and the zones (numbered in the legend), as extra
:class:`~datagen.plot.view_geometry.Drawables` for :func:`datagen.plot.render_scene` (``extra``)."""
from __future__ import annotations

import numpy as np

from ..scene import RayCaster, Scene, resolve_capture
from ..errors import SceneError
from ..scene.flood import MultizoneSpec, flood_corners, flood_field_names, flood_weights
from .view_geometry import Drawables

FLOOD_COLOR = (0.93, 0.33, 0.05)
"""Outline of the lit patch (a darker orange than the laser's)."""

ZONE_COLOR = (0.10, 0.45, 0.20)
"""Outlines of the zones."""


def flood_drawables(scene: Scene, spec: MultizoneSpec) -> Drawables:
    """The lit patch (outline, ``FLOOD_COLOR``) and the zones' outlines (``ZONE_COLOR``) of ``scene``'s flood
    capture, with their legend entries.

    Returns:
        :class:`~datagen.plot.view_geometry.Drawables` (lines and legend only; world metres).
    Raises:
        SceneError: the capture cannot be resolved.
    """
    try:
        cap = resolve_capture(scene, RayCaster(scene))
    except SceneError as exc:       # a capture error names the multizone block's fields
        raise SceneError(flood_field_names(str(exc))) from None
    d = Drawables()
    patch = flood_corners(cap, spec)
    d.lines.append(("lit patch", np.stack([patch, np.roll(patch, -1, axis=0)], axis=1), FLOOD_COLOR, 4.0))
    w = flood_weights(cap, spec.flood.profile)
    nx, ny = spec.flood.nodes
    f = spec.flood
    d.legend.append((f"lit patch (flood) {f.size[0]:.3g}×{f.size[1]:.3g} m, {f.profile.kind} profile, {nx}×{ny} "
                     f"quadrature nodes (dots; weights {w.min():.3g}–{w.max():.3g} of the pulse)", "line",
                     FLOOD_COLOR))
    zx, zy = cap.fov_pixels
    c, u, v, fs = cap.fov_center, cap.fov_u, cap.fov_v, cap.fov_size
    segs = []
    for iy in range(zy):
        for ix in range(zx):
            a0, a1 = (ix / zx - 0.5) * fs[0], ((ix + 1) / zx - 0.5) * fs[0]
            b0, b1 = (iy / zy - 0.5) * fs[1], ((iy + 1) / zy - 0.5) * fs[1]
            q = c + np.array([a0 * u + b0 * v, a1 * u + b0 * v, a1 * u + b1 * v, a0 * u + b1 * v])
            segs.append(np.stack([q, np.roll(q, -1, axis=0)], axis=1))
    d.lines.append(("zones", np.concatenate(segs), ZONE_COLOR, 2.0))
    d.legend.append((f"{zx}×{zy} zones, one histogram each (zone (0, 0) at the lower left, rows up)", "line",
                     ZONE_COLOR))
    return d
