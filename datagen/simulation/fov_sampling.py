"""What a run sampled of the sensor grid, said before the work and after a zero result (simulation stage).

An estimator reaches each pixel region (a zone of a multi-zone sensor) through FoV points. The quadrature's are
fixed before it runs — ``fov_cells`` × ``fov_cells`` cell centres per region, one per region on a scan or a flood
(``targets``, ``target_pixel``) — so a zone larger than the relay wall can be sampled only where no surface is:
its envelope is zero, or the whole zone is counted as wall, though the sensor sees something else there.

- :func:`zone_sampling` compares, zone by zone, the share of its FoV points on a surface the sensor sees with the
  share of its area that is (a :data:`PROBE_CELLS`² grid of rays from the sensor): all points off every surface
  while the zones hold some is refused before the transport (the run would write a zero with no true reason),
  zones whose shares differ by more than :data:`ZONE_SHARE_TOL` of the area's are warned about; both name the
  ``fov_cells`` that would resolve them.
- :func:`zero_reason` says, when an envelope is zero, what was sampled and what the zero can and cannot mean:
  FoV points off every surface, glossy lobes narrower than :data:`NARROW_LOBE_EXPONENT`, or no sampled path.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..scene import Scene
from ..scene.capture import FOV_PLANE_TOL, Capture
from ..vectors import unit

__all__ = ["PROBE_CELLS", "ZONE_SHARE_TOL", "NARROW_LOBE_EXPONENT", "seen_from_sensor", "zone_sampling",
           "zero_reason"]

PROBE_CELLS = 32
"""Rays per zone side probing what the sensor sees in a zone (1024 per zone; 16 × 16 zones: 262 144 rays, a
fraction of a second), twice the finest of :data:`REFINE_CELLS`."""

ZONE_SHARE_TOL = 0.5
"""A zone whose FoV points' share on a surface the sensor sees is off its area's share by more than this fraction
of it is not resolved: its envelope is off by as much (a zone a fifth on the wall sampled only off it is zero)."""

REFINE_CELLS = (2, 4, 8, 16)
"""``fov_cells`` tried, in order, for the one a refusal or warning suggests."""

NARROW_LOBE_EXPONENT = 1e3
"""Phong exponents from here up make lobes of about 1/√n ≤ 0.03 rad (2π/n ≤ 6e-3 sr), as narrow as the cells of a
60 × 60 hemispherical camera: a zero envelope of a scene made of them may be the sampling's, not the scene's."""


def seen_from_sensor(caster, capture: Capture, points: np.ndarray) -> np.ndarray:
    """(n,) bool: whether the sensor sees a surface at each point of (n, 3) on the FoV plane (the first hit of the
    ray from the sensor toward the point lies at the point, within the capture's plane tolerance)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = points - capture.sensor
    dist = np.linalg.norm(d, axis=-1)
    hits = caster.intersect(np.broadcast_to(capture.sensor, points.shape), unit(d))
    return np.asarray(hits.hit & (np.abs(hits.distance - dist) <= FOV_PLANE_TOL * caster.offset))


def _cell_points(capture: Capture, k: int) -> np.ndarray:
    """(n_pixels, k·k, 3) centres of k × k cells in each pixel region, row-major over (v, u) as the pixels."""
    nx, _ = capture.fov_pixels
    g = (np.arange(k) + 0.5) / k
    gu, gv = np.meshgrid(g, g, indexing="xy")
    iy, ix = np.divmod(np.arange(capture.n_pixels), nx)
    return capture.region_points(ix[:, None], iy[:, None], gu.reshape(1, -1), gv.reshape(1, -1))


def _shares(caster, capture: Capture, k: int) -> np.ndarray:
    """(n_pixels,) share of each pixel region's k × k cell centres on a surface the sensor sees."""
    pts = _cell_points(capture, k)
    return seen_from_sensor(caster, capture, pts.reshape(-1, 3)).reshape(pts.shape[:2]).mean(axis=1)


def _unresolved(sampled: np.ndarray, area: np.ndarray) -> np.ndarray:
    """(n_pixels,) bool: the share ``sampled`` is off the share ``area`` by more than :data:`ZONE_SHARE_TOL` of it
    (any sampled share of a zone the sensor sees no surface in)."""
    return np.where(area > 0, np.abs(sampled - area) > ZONE_SHARE_TOL * area, sampled > 0)


def _fixed_targets(transport):
    """(targets (n, 3), their pixel (n,)) of an estimator that samples the FoV at fixed points (the quadrature;
    beside the order ≥ 3 tracer, its base), else None."""
    base = getattr(transport, "base", transport)
    targets, pixel = getattr(base, "targets", None), getattr(base, "target_pixel", None)
    return None if targets is None or pixel is None else (np.asarray(targets), np.asarray(pixel))


def zone_sampling(transport, caster, field: str, where: str = "") -> str | None:
    """Check that an estimator's fixed FoV points resolve the pixel regions (``field``, e.g. "multizone.zones")
    before it runs. Estimators that draw their FoV points anew each run pass unchecked.

    Returns:
        None, or one warning line naming the zones whose FoV points' share on a surface differs from their
        area's by more than :data:`ZONE_SHARE_TOL`, and the ``fov_cells`` that resolves them.
    Raises:
        ConfigError: no FoV point lies on a surface the sensor sees while some zones hold one (the envelope
        would be zero for no reason of the scene's): the zones, what was sampled, and what to set.
    """
    fixed = _fixed_targets(transport)
    capture = transport.capture
    if fixed is None or capture.convention != "aperture":
        return None
    targets, pixel = fixed
    n = capture.n_pixels
    seen = seen_from_sensor(caster, capture, targets)
    sampled = np.bincount(pixel, weights=seen, minlength=n) / np.maximum(np.bincount(pixel, minlength=n), 1)
    area = _shares(caster, capture, PROBE_CELLS)
    held = area > 0
    off = _unresolved(sampled, area)
    if not off.any() and (seen.any() or not held.any()):
        return None
    k = int(round(np.sqrt(len(targets) / n)))
    finer = {c: _shares(caster, capture, c) for c in REFINE_CELLS if c > k}
    resolved = next((c for c, share in finer.items() if not _unresolved(share, area).any()), None)
    reached = next((c for c, share in finer.items() if (share[held] > 0).all()), None)
    (zw, zh), (zx, zy) = capture.fov_size, capture.fov_pixels
    what = (f"{zx} x {zy} zones of {zw / zx:.3g} x {zh / zy:.3g} m sampled at {k} x {k} point(s) each (the "
            "quadrature's FoV cells at their centres)")
    if resolved is not None:
        todo = (f"set simulation.estimator.fov_cells: {resolved} ({(resolved / k) ** 2:g}x the FoV points and the "
                "transport's time)")
    elif reached is not None:
        todo = (f"simulation.estimator.fov_cells: {reached} puts points on the surface in every such zone "
                f"({(reached / k) ** 2:g}x the time) but resolves them only to within {ZONE_SHARE_TOL:.0%}; smaller "
                "zones resolve them")
    else:
        todo = "give smaller zones"
    if not seen.any():
        raise ConfigError(f"{where}{field}: {what}: none of the {len(targets)} points lies on a surface the sensor "
                          f"sees, while {int(held.sum())} zones hold one ({area[held].min():.0%} .. "
                          f"{area[held].max():.0%} of their area): the envelope would be zero though light reaches "
                          f"them; {todo}, or zones that tile the flood ({field}.size)")
    return (f"{field}: {what}: in {int(off.sum())} of {n} zones the share of the points on a surface the sensor "
            f"sees is off that of the zone's area by more than {ZONE_SHARE_TOL:.0%} of it (a zone partly on the "
            f"wall is counted as all wall or as empty): their envelopes are off by as much; {todo}")


def zero_reason(scene: Scene, transport, sampling: str = "") -> str:
    """Why a run whose envelope is zero (and holds no light outside its window) found no light, in words: what
    was sampled (``sampling``, the estimator's setting) and what the zero can mean.

    - FoV points fixed before the run (the quadrature's) that all lie off every surface the sensor sees (seen with
      the estimator's ray caster);
    - glossy (Phong) materials of exponent ≥ :data:`NARROW_LOBE_EXPONENT`, whose lobes may be narrower than the
      sampling resolves: paths may exist that no sample found;
    - otherwise no sampled path reached the FoV (the lit surfaces face away from it or are blocked, or the
      sampling is too coarse).
    """
    what = f" ({sampling})" if sampling else ""
    fixed = _fixed_targets(transport)
    caster = getattr(getattr(transport, "base", transport), "caster", None)
    if fixed is not None and caster is not None and not seen_from_sensor(caster, transport.capture, fixed[0]).any():
        return (f"no sample{what} found a path: its {len(fixed[0])} FoV points all lie off every surface the sensor "
                "sees, so the sampling does not resolve the sensor grid (refine estimator.fov_cells)")
    glossy = sorted({o.name for o in scene.objects if o.material.kind == "phong" and o.material.specular > 0
                     and o.material.exponent >= NARROW_LOBE_EXPONENT})
    if glossy:
        top = max(o.material.exponent for o in scene.objects if o.name in glossy)
        names = ", ".join(glossy[:4]) + (f" (+{len(glossy) - 4} more)" if len(glossy) > 4 else "")
        return (f"no sample{what} found a path; the glossy lobes of {names} (phong exponent up to {top:.3g}, about "
                f"{1 / np.sqrt(top):.2g} rad wide) may be narrower than the sampling resolves, so paths may exist "
                "that it missed: sample more finely or broaden the lobes")
    return (f"no sampled path{what} from the laser reached the sensor grid: the surfaces the laser lights face away "
            "from it or are blocked from it, or the sampling is too coarse to find the paths")
