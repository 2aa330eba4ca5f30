"""Filtered backprojection of confocal scans: a small reconstruction to check where a scan puts a hidden object.

For a confocal scan H[p, t] (laser point = sensor point p on the relay wall) a hidden point x contributes at the
round-trip time τ(x, p) = 2·|x − p|/c (+ the emitter → p and p → sensor legs when the time axis counts them,
docs/physics.md §1). Backprojection (Velten et al. 2012) sums every transient at that time,

    B(x) = Σ_p w_p · H[p, bin(τ(x, p))],

with per-point weights w_p that undo the radiometric fall-off of the wall → sensor leg (the sensor's collection
from p is ∝ cos θ_s / d_s², the aperture facing p, docs/physics.md §2; :func:`wall_leg_weights`). Filtered
backprojection applies the discrete Laplacian of B (the 3-D 7-point stencil, −∇²), which sharpens the backprojected ellipsoid shells to the surfaces they meet
(Arellano et al. 2017; tal.reconstruct.fbp with a Laplacian filter). :func:`locate` returns the magnitude-weighted
centroid of the voxels above half the maximum, the position estimate docs/tal.md uses for tal's reconstructions.
"""
from __future__ import annotations

import numpy as np

from ..units import SPEED_OF_LIGHT

VOXEL_CHUNK = 4096
"""Voxels per backprojection block (bounds the (voxels, points) distance array)."""


def wall_leg_weights(points: np.ndarray, normal: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """(P,) weights d_s² / cos θ_s that undo the sensor leg's fall-off at each scan point ((P, 3) m; ``normal``
    the wall normal facing the sensor at ``sensor`` (3,)), for the aperture convention (docs/physics.md §2). A
    confocal scan's aperture follows the laser (cos θ_ap = 1 at each scan point, docs/scans.md), so only the
    wall's cosine and the distance remain. The laser leg needs none there: the beam delivers its photons to
    every laser point whatever its distance (tal's point-radiance files carry an extra cos θ_e/d_e²,
    tal.reconstruct.compensate_laser_cos_dsqr)."""
    points = np.asarray(points, float).reshape(-1, 3)
    to_s = sensor - points
    d_s = np.linalg.norm(to_s, axis=1)
    cos_s = to_s @ normal / d_s
    return d_s ** 2 / np.maximum(cos_s, 1e-12)


def backproject(h: np.ndarray, time_edges: np.ndarray, points: np.ndarray, voxels: np.ndarray,
                offsets: np.ndarray | None = None, weights: np.ndarray | None = None) -> np.ndarray:
    """Confocal backprojection B(x) at ``voxels``.

    Args:
        h: (P, T) transients (any units), one per scan point; time_edges: (T+1,) s, uniform bins.
        points: (P, 3) scan points (m); voxels: (..., 3) positions (m).
        offsets: (P,) seconds added to each round trip (the counted wall legs), default 0.
        weights: (P,) per-point weights (:func:`wall_leg_weights`), default 1.
    Returns:
        (...) float64 volume; voxels whose round trip falls outside the window get nothing from that point.
    """
    h = np.asarray(h, dtype=np.float64).reshape(len(points), -1)
    t0, dt = float(time_edges[0]), float(time_edges[1] - time_edges[0])
    n_bins = h.shape[1]
    w = np.ones(len(points)) if weights is None else np.asarray(weights, float)
    hw = h * w[:, None]
    off = np.zeros(len(points)) if offsets is None else np.asarray(offsets, float)
    flat = np.asarray(voxels, float).reshape(-1, 3)
    out = np.empty(len(flat))
    rows = np.arange(len(points))
    for start in range(0, len(flat), VOXEL_CHUNK):
        v = flat[start:start + VOXEL_CHUNK]
        r = np.linalg.norm(v[:, None, :] - points[None], axis=-1)                   # (B, P)
        b = np.floor((2.0 * r / SPEED_OF_LIGHT + off - t0) / dt).astype(np.int64)
        ok = (b >= 0) & (b < n_bins)
        out[start:start + len(v)] = np.where(ok, hw[rows[None, :], np.clip(b, 0, n_bins - 1)], 0.0).sum(axis=1)
    return out.reshape(np.shape(voxels)[:-1])


def laplacian_filter(volume: np.ndarray) -> np.ndarray:
    """−∇² of a (nx, ny, nz) volume by the 7-point stencil (edges replicated), the filter of filtered
    backprojection."""
    v = np.pad(volume, 1, mode="edge")
    lap = (v[2:, 1:-1, 1:-1] + v[:-2, 1:-1, 1:-1] + v[1:-1, 2:, 1:-1] + v[1:-1, :-2, 1:-1]
           + v[1:-1, 1:-1, 2:] + v[1:-1, 1:-1, :-2] - 6.0 * v[1:-1, 1:-1, 1:-1])
    return -lap


def voxel_grid(lo, hi, step: float) -> np.ndarray:
    """(nx, ny, nz, 3) voxel centres of the box [lo, hi] (m) at pitch ``step``."""
    axes = [np.arange(a + step / 2, b, step) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def locate(volume: np.ndarray, voxels: np.ndarray, level: float = 0.5) -> np.ndarray:
    """(3,) magnitude-weighted centroid of the voxels whose value exceeds ``level`` × the volume's maximum."""
    v = np.maximum(np.asarray(volume, float), 0.0)
    keep = v > level * v.max()
    return (voxels[keep] * v[keep, None]).sum(0) / v[keep].sum()


def locate_confocal(h: np.ndarray, time_edges: np.ndarray, points: np.ndarray, box_lo, box_hi,
                    coarse: float = 0.04, fine: float = 0.02, window: float = 1.0, offsets=None,
                    weights=None) -> tuple[np.ndarray, dict]:
    """Where filtered backprojection puts the hidden object of a confocal scan: a ``coarse`` pass over the box
    [box_lo, box_hi], then a ``fine`` one over a cube of side ``window`` around the coarse maximum (large enough
    to hold the whole object: a smaller one keeps only the part around the brightest feature, e.g. one bar of
    an H); the :func:`locate` centroid of the fine filtered volume.

    Returns:
        ((3,) position in m, {"coarse": (volume, voxels), "fine": (volume, voxels)}).
    """
    vox = voxel_grid(box_lo, box_hi, coarse)
    vol = laplacian_filter(backproject(h, time_edges, points, vox, offsets, weights))
    peak = vox[np.unravel_index(np.argmax(vol), vol.shape)]
    lo = np.maximum(peak - window / 2, box_lo)
    hi = np.minimum(peak + window / 2, box_hi)
    fine_vox = voxel_grid(lo, hi, fine)
    fine_vol = laplacian_filter(backproject(h, time_edges, points, fine_vox, offsets, weights))
    return locate(fine_vol, fine_vox), {"coarse": (vol, vox), "fine": (fine_vol, fine_vox)}
