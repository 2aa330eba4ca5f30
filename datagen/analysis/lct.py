"""Light-cone transform (O'Toole, Lindell & Wetzstein 2018) of confocal scans: the benchmark's LCT baseline.

y-tal 0.20 (the reconstructions docs/benchmark.md runs through tal's venv) has no LCT, so this is datagen's own,
following the paper's procedure and its release's script (``cnlos_reconstruction.m``): zero the direct light,
scale the transients by (t/T)⁴ (diffuse hidden surfaces: two legs of 1/r² each) or (t/T)² (retroreflective ones,
which return the light towards its source: the paper's "minor modification"), resample time to v = t² (the light
cone becomes a shift-invariant 3-D convolution), Wiener-deconvolve with the light-cone kernel in a zero-padded 3-D
FFT (or, for backprojection, multiply by its conjugate), resample back. The scan is a regular grid (the release's
``linspace(−half_width, half_width, N)`` along each axis; a half width per axis for a grid of two pitches) with a
power-of-two number of time bins starting at t = 0, time counting both wall ↔ hidden legs (t = 2·|x − p|/c:
:func:`datagen.analysis.confocal.align_confocal`; the confocal configs' ``count_sensor_leg: false``,
docs/scans.md). The kernel is even along both scan axes, so the volume keeps the scan's orientation
(docs/capture_io.md, "Orientation").
"""
from __future__ import annotations

import functools
from typing import Literal

import numpy as np

from ..units import SPEED_OF_LIGHT
from .confocal import direct_light_bins

FALLOFF_POWER = {"diffuse": 4, "retroreflective": 2}
"""Power of t in the radiometric scaling of each hidden-surface model (O'Toole et al. 2018, Eq. 2 and Methods)."""


def light_cone_psf(n: int | tuple[int, int], m: int, slope: float | tuple[float, float]) -> np.ndarray:
    """(2m, 2ny, 2nx) light-cone kernel, normalised, centred at (0, 0, 0) of the padded lateral grid.

    Args:
        n: scan points per side, or (rows ny, columns nx); m: time bins; slope: half_width / range
            (range = m · c · Δt), or (rows', columns') for a grid of two pitches.
    """
    ny, nx = (n, n) if np.ndim(n) == 0 else n
    sy, sx = (slope, slope) if np.ndim(slope) == 0 else slope
    z = np.linspace(0, 2, 2 * m)
    gy, gx = np.meshgrid(np.linspace(-1, 1, 2 * ny), np.linspace(-1, 1, 2 * nx), indexing="ij")
    cone = (4 * sx) ** 2 * (gx ** 2 + gy ** 2) if sx == sy else (4 * sx) ** 2 * gx ** 2 + (4 * sy) ** 2 * gy ** 2
    # each column holds 1 at the z nearest its cone (both, where two are equally near): z is increasing, so the
    # nearest is one of the two z about the cone, and only those two are compared
    above = np.clip(np.searchsorted(z, cone), 1, 2 * m - 1)
    below_gap, above_gap = np.abs(cone - z[above - 1]), np.abs(cone - z[above])
    nearest = np.minimum(below_gap, above_gap)
    psf = np.zeros((2 * m, 2 * ny, 2 * nx))
    rows, cols = np.indices(cone.shape)
    psf[above - 1, rows, cols] = below_gap == nearest
    psf[above, rows, cols] = above_gap == nearest
    psf /= psf[:, ny, nx].sum()
    psf /= np.linalg.norm(psf)
    return np.roll(psf, (ny, nx), axis=(1, 2))


KERNEL_CACHE_BYTES = 256 * 2 ** 20
"""The largest inverse kernel :func:`inverse_kernel` keeps for the next call (bytes; 136 MB at 64 × 64 × 512)."""


def inverse_kernel(n: tuple[int, int], m: int, slope: float | tuple[float, float], snr: float,
                   backprojection: bool) -> np.ndarray:
    """(2m, 2ny, nx + 1) complex128, read-only: the Fourier-domain filter :func:`lct_volume` multiplies by, the
    conjugate of the light-cone kernel's real FFT (:func:`light_cone_psf`), divided by |FFT|² + 1/snr (Wiener)
    unless ``backprojection``. The two latest (arguments equal) are kept when no larger than
    :data:`KERNEL_CACHE_BYTES`: a run over many scans of one geometry (a capture's thinnings, a data set whose
    scans share one grid and time axis) builds the kernel once; the result is the same array, bit for bit, as
    building it anew."""
    if 2 * m * 2 * n[0] * (n[1] + 1) * 16 <= KERNEL_CACHE_BYTES:
        return _kept_inverse_kernel(tuple(n), m, slope, snr, backprojection)
    return _inverse_kernel(tuple(n), m, slope, snr, backprojection)


def _inverse_kernel(n, m, slope, snr, backprojection) -> np.ndarray:
    fpsf = np.fft.rfftn(light_cone_psf(n, m, slope))
    invpsf = np.conj(fpsf) if backprojection else np.conj(fpsf) / (np.abs(fpsf) ** 2 + 1.0 / snr)
    invpsf.flags.writeable = False
    return invpsf


_kept_inverse_kernel = functools.lru_cache(maxsize=2)(_inverse_kernel)


def padded_convolution(data: np.ndarray, filt: np.ndarray) -> np.ndarray:
    """(m, ny, nx) float64: ``data`` (m, ny, nx) zero-padded to (2m, 2ny, 2nx), multiplied in the Fourier domain by
    ``filt`` (2m, 2ny, nx + 1) (a real FFT's half spectrum, :func:`inverse_kernel`) and cropped back, as
    ``irfftn(rfftn(padded) · filt)[:m, :ny, :nx]``. The kernel and the data are real, so the real FFT gives the real
    part of the complex one's result. The 1-D transforms run one axis at a time in the order ``rfftn`` / ``irfftn``
    take them, each only over the rows that are not all zero (forward) or that are kept (back): the same numbers, bit
    for bit, with about half the work."""
    m, ny, nx = data.shape
    spectrum = np.fft.fft(np.fft.fft(np.fft.rfft(data, 2 * nx, axis=2), 2 * ny, axis=1), 2 * m, axis=0)
    spectrum *= filt
    kept = np.fft.ifft(np.fft.ifft(spectrum, axis=0)[:m], axis=1)[:, :ny]
    return np.fft.irfft(kept, 2 * nx, axis=2)[..., :nx]


def resampling_operator(m: int):
    """(m, m) scipy CSR matrices (float64, read-only) taking the time axis t to v = t² and back (m a power of two;
    the release's ``resamplingOperator``). Each row holds a few non-zeros (about 2m in all), so :func:`lct_volume`
    multiplies by them sparse. The latest four are kept by m (m = 2048 takes about 1 s to build).

    Raises:
        ValueError: m is not a power of two.
    """
    if m < 2 or m & (m - 1):
        raise ValueError(f"LCT needs a power-of-two number of time bins, got {m}")
    return _resampling_operator(m)


@functools.lru_cache(maxsize=4)
def _resampling_operator(m: int):
    from scipy import sparse

    x = np.arange(1, m * m + 1)
    mtx = sparse.csr_matrix((1.0 / np.sqrt(x), (x - 1, np.ceil(np.sqrt(x)).astype(np.int64) - 1)), shape=(m * m, m))
    mtxi = mtx.T.tocsr()
    for _ in range(int(round(np.log2(m)))):
        mtx = 0.5 * (mtx[0::2, :] + mtx[1::2, :])
        mtxi = 0.5 * (mtxi[:, 0::2] + mtxi[:, 1::2])
    for a in (mtx, mtxi):                        # CSR still: row / column slices and sums of CSR matrices are CSR
        a.eliminate_zeros()
        a.data.flags.writeable = False
    return mtx, mtxi


def lct_volume(scan: np.ndarray, bin_width: float, half_width: float | tuple[float, float], snr: float = 0.8,
               falloff: Literal["diffuse", "retroreflective"] = "diffuse",
               trim: float | Literal["auto"] | None = "auto", backprojection: bool = False) -> np.ndarray:
    """LCT reconstruction of a confocal scan.

    Args:
        scan: (ny, nx, M) transients (any units, ≥ 0) of a confocal grid (rows, columns), M a power of two, time
            from t = 0 in bins of ``bin_width`` seconds; half_width: the release's ``width``, half the span of the
            scan's grid, pitch·(N − 1)/2 (m), or (rows', columns') for a grid of two pitches; snr: the Wiener
            filter's signal-to-noise ratio (the paper's 0.8; its script uses 0.08 for the diffuse "S").
        falloff: "diffuse" scales the transients by t⁴, "retroreflective" by t² (:data:`FALLOFF_POWER`).
        trim: the direct light to zero first: "auto" (:func:`~datagen.analysis.confocal.direct_light_bins`), a
            duration in s (the release's script: 2.4e-9), or None / 0 for none.
        backprojection: multiply by the kernel's conjugate instead of Wiener-deconvolving (the script's
            ``isbackprop``; filtered by :func:`datagen.analysis.reconstruct.confocal_volume`'s "fbp").
    Returns:
        (ny, nx, M) float64 albedo volume ≥ 0, in the scan's orientation; index k along the last axis is depth
        (k + ½)·c·Δt/2 from the wall.
    Raises:
        ValueError: a scan that is not (ny, nx, M) with M a power of two, non-positive bin_width / half_width / snr,
            an unknown falloff, or a negative trim.
    """
    scan = np.array(scan, dtype=np.float64)
    if scan.ndim != 3:
        raise ValueError(f"LCT needs an (ny, nx, M) confocal scan, got shape {scan.shape}")
    if not (bin_width > 0 and np.all(np.asarray(half_width) > 0) and snr > 0):
        raise ValueError(f"LCT needs bin_width, half_width and snr > 0, got {bin_width}, {half_width}, {snr}")
    if falloff not in FALLOFF_POWER:
        raise ValueError(f"falloff must be one of {', '.join(FALLOFF_POWER)}, got {falloff!r}")
    ny, nx, m = scan.shape
    mtx, mtxi = resampling_operator(m)
    if trim == "auto":
        scan[..., :direct_light_bins(scan, bin_width)] = 0.0
    elif trim:
        if not trim > 0:
            raise ValueError(f"trim must be 'auto', None or a duration >= 0 s, got {trim!r}")
        scan[..., :int(np.ceil(trim / bin_width - 1e-9))] = 0.0
    data = np.moveaxis(scan, 2, 0) * np.linspace(0, 1, m)[:, None, None] ** FALLOFF_POWER[falloff]   # (M, ny, nx)
    rng = m * SPEED_OF_LIGHT * bin_width
    slope = float(half_width) / rng if np.ndim(half_width) == 0 else tuple(float(h) / rng for h in half_width)
    invpsf = inverse_kernel((ny, nx), m, slope, snr, backprojection)
    vol = padded_convolution((mtx @ data.reshape(m, -1)).reshape(m, ny, nx), invpsf)
    vol = (mtxi @ vol.reshape(m, -1)).reshape(m, ny, nx)
    return np.moveaxis(np.maximum(vol, 0.0), 0, 2)


def depth_from_volume(volume: np.ndarray, depths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel depth of the strongest voxel of an (H, W, Z) volume.

    Args:
        volume: (H, W, Z) reconstruction (its magnitude is used); depths: (Z,) metres of its last axis.
    Returns:
        ((H, W) depth in metres, (H, W) the strongest |value|).
    """
    mag = np.abs(np.asarray(volume))
    return np.asarray(depths)[np.argmax(mag, axis=-1)], mag.max(axis=-1)
