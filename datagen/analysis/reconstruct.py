"""Baseline reconstructions of a confocal scan, what ``datagen reconstruct`` runs: LCT, phasor fields or filtered
backprojection, and the depth map of what they find.

:func:`confocal_volume` takes a scan on the hidden round-trip axis (:func:`~datagen.analysis.confocal.align_confocal`),
sums pairs of bins until at most ``max_bins`` remain (the LCT release's script sums 4 ps bins to 16 ps), zeroes the
direct light (:func:`~datagen.analysis.confocal.direct_light_bins`, or a given duration), pads the time axis to a
power of two and runs one method:

- "lct": :func:`~datagen.analysis.lct.lct_volume`, the Wiener-deconvolved light-cone transform (O'Toole, Lindell &
  Wetzstein 2018);
- "fbp": the same transform's backprojection (the kernel's conjugate, the release's ``isbackprop``) filtered by the
  Laplacian −∇² (:func:`~datagen.analysis.backprojection.laplacian_filter`; the f-k release's script filters its
  backprojection with a Laplacian of Gaussian);
- "phasor": :func:`~datagen.analysis.phasor.phasor_rsd` (Liu et al. 2019) with a virtual wavelength of
  :data:`PHASOR_PITCHES` grid pitches (the larger of a rectangle's two; at least 4 bins of path), on planes every
  eighth of it.

The radiometric falloff (t² retroreflective, the release script's default, or t⁴ diffuse) applies to "lct" and
"fbp". Depths no farther than the trimmed round trip are set to 0 (their light was zeroed). :func:`depth_map` gives each scan point the depth of its strongest voxel where the volume's front view (its
maximum over depth) reaches ``level`` of its maximum, NaN elsewhere. Volumes keep the scan's orientation: row up
the wall, column to the right as the wall sees the hidden scene (docs/capture_io.md, "Orientation").
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from ..units import SPEED_OF_LIGHT
from .backprojection import laplacian_filter
from .confocal import direct_light_bins
from .lct import depth_from_volume, lct_volume
from .phasor import phasor_rsd

METHODS = ("lct", "phasor", "fbp")
"""The baselines :func:`confocal_volume` runs."""

MAX_BINS = 512
"""Most time bins reconstructed: the LCT release's 2048 bins of 4 ps become 512 of 16 ps, as its script sums them
(the padded 3-D FFT of a 64 × 64 scan then holds 1024 × 128 × 128 values)."""

FOUND_LEVEL = 0.25
"""Default share of the front view's maximum above which a scan point counts as having found something."""

PHASOR_PITCHES = 4
"""The phasor method's virtual wavelength in grid pitches (benchmarks/tal/recon_side.py's choice)."""


def coarsen(scan: np.ndarray, bin_width: float, max_bins: int) -> tuple[np.ndarray, float]:
    """Sum pairs of neighbouring bins until at most ``max_bins`` remain (zeros appended to an odd count).

    Args:
        scan: (..., M) transients; bin_width: their bin width in s; max_bins: ≥ 1.
    Returns:
        ((..., M') float64 with M' ≤ max_bins, the new bin width in s).
    """
    out = np.asarray(scan, dtype=np.float64)
    while out.shape[-1] > max_bins:
        if out.shape[-1] % 2:
            out = np.concatenate([out, np.zeros(out.shape[:-1] + (1,))], axis=-1)
        out = out[..., 0::2] + out[..., 1::2]
        bin_width *= 2
    return out, bin_width


def confocal_volume(scan: np.ndarray, bin_width: float, pitch: float | tuple[float, float], method: str = "lct",
                    falloff: Literal["diffuse", "retroreflective"] = "retroreflective", snr: float = 0.8,
                    trim: float | Literal["auto"] | None = "auto", max_bins: int = MAX_BINS
                    ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Reconstruct an aligned confocal scan with one of :data:`METHODS`.

    Args:
        scan: (ny, nx, M) transients ≥ 0 on the hidden round-trip axis from t = 0 (:func:`align_confocal`), row
            up the wall, column along u; pitch: the grid's spacing (m), or (between rows, between columns)
            (:func:`~datagen.analysis.confocal.grid_pitches`).
        bin_width: s; method: "lct", "phasor" or "fbp"; falloff, snr: :func:`~datagen.analysis.lct.lct_volume`'s
            (the release script's defaults: t², 0.8; its diffuse "S" used t⁴ and 0.08).
        trim: the direct light to zero: "auto" (:func:`direct_light_bins`), a duration in s, or None.
        max_bins: the time axis is summed to at most this many bins (:func:`coarsen`).
    Returns:
        volume (ny, nx, Z) float64 ≥ 0 in the scan's orientation; depths (Z,) float64 m from the wall of its last
        axis; info {"bin_width": s reconstructed, "trim_bins": bins zeroed, "trim": s zeroed, "wavelength": m or
        None}.
    Raises:
        ValueError: an unknown method, a scan that is not (ny, nx, M), or what
            :func:`~datagen.analysis.lct.lct_volume` refuses.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    data = np.array(scan, dtype=np.float64)                   # a copy: the trim below must not zero the caller's
    if data.ndim != 3:
        raise ValueError(f"a confocal scan is (ny, nx, M); got shape {data.shape}")
    ny, nx = data.shape[:2]
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    data, dt = coarsen(data, float(bin_width), max_bins)
    if trim == "auto":
        n_trim = direct_light_bins(data, dt)
    elif trim:
        n_trim = int(np.ceil(float(trim) / dt - 1e-9))
    else:
        n_trim = 0
    data[..., :n_trim] = 0.0
    m = 1 << max(1, int(np.ceil(np.log2(data.shape[-1]))))
    data = np.concatenate([data, np.zeros(data.shape[:2] + (m - data.shape[-1],))], axis=-1)
    info = {"bin_width": dt, "trim_bins": n_trim, "trim": n_trim * dt, "wavelength": None}
    if method == "phasor":
        wavelength = max(PHASOR_PITCHES * max(pitch_y, pitch_x), 4 * SPEED_OF_LIGHT * dt)
        step = max(SPEED_OF_LIGHT * dt / 2, wavelength / 8)
        depths = np.arange(step, m * SPEED_OF_LIGHT * dt / 2, step)
        info["wavelength"] = wavelength
        vol = phasor_rsd(data, dt, (pitch_y, pitch_x), depths, wavelength)
    else:
        half = (pitch_y * (ny - 1) / 2, pitch_x * (nx - 1) / 2)           # the release's width, per axis
        vol = lct_volume(data, dt, half[0] if half[0] == half[1] else half, snr=snr, falloff=falloff, trim=None,
                         backprojection=method == "fbp")
        if method == "fbp":
            vol = np.maximum(laplacian_filter(vol), 0.0)
        depths = (np.arange(m) + 0.5) * SPEED_OF_LIGHT * dt / 2
    vol[..., depths <= SPEED_OF_LIGHT * info["trim"] / 2] = 0.0      # their light was zeroed: nothing is seen there
    return vol, depths, info


def depth_map(volume: np.ndarray, depths: np.ndarray, level: float = FOUND_LEVEL) -> tuple[np.ndarray, np.ndarray]:
    """Depth of what a reconstruction found at each scan point.

    Args:
        volume: (ny, nx, Z) reconstruction (its magnitude is used); depths: (Z,) m of its last axis.
        level: a scan point has found something where its front-view value (the maximum over depth) reaches
            ``level`` × the front view's maximum (0 < level ≤ 1).
    Returns:
        ((ny, nx) float64 depth in m of the strongest voxel, NaN where nothing is found; (ny, nx) front view).
    Raises:
        ValueError: level outside (0, 1].
    """
    if not 0 < level <= 1:
        raise ValueError(f"level must be in (0, 1], got {level}")
    depth, front = depth_from_volume(volume, depths)
    found = front >= level * front.max() if front.max() > 0 else np.zeros(front.shape, bool)
    return np.where(found, depth, np.nan), front
