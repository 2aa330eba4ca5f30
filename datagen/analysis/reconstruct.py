"""Baseline reconstructions of a confocal scan, what ``datagen reconstruct`` runs: LCT, phasor fields or filtered
backprojection, and the depth map of what they find.

:func:`confocal_volume` takes a scan on the hidden round-trip axis (:func:`~datagen.analysis.confocal.align_confocal`)
and prepares it (:func:`prepare_scan`): sums pairs of bins until at most ``max_bins`` remain (the LCT release's
script sums 4 ps bins to 16 ps), subtracts each point's background floor (:func:`background_floor`: ambient light
and dark counts, which the radiometric falloff below would otherwise weigh up with t² or t⁴ until they outshine a
distant object), zeroes the direct light (:func:`~datagen.analysis.confocal.direct_light_bins`, or a given
duration), pads the time axis to a power of two; then it runs one method:

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
"""Default share of the way from the front view's pedestal to its maximum above which a scan point counts as having
found something."""

FOUND_PEDESTAL = 5.0
"""Percentile of the front view taken as its pedestal: the level a reconstruction's front view keeps where there is
no object (the maximum over depth of its noise and blur). On the Stanford release's diffuse "S" it is 0.20 of the
maximum, so a share of the maximum alone finds two thirds of the scan (docs/real.md, "Baselines at lower
exposures"); an object that covers more than 95 % of the scan loses its weakest points to it."""

FLOOR_BLOCKS = 4
"""Runs of bins after the direct light among which :func:`background_floor` takes the quietest."""

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


def background_floor(scan: np.ndarray, first: int = 0, blocks: int = FLOOR_BLOCKS) -> np.ndarray:
    """Each scan point's background floor, counts (or photons) per bin: the mean of the quietest of ``blocks``
    equal runs of its bins from ``first`` on (after the direct light).

    The quietest run rather than a fixed late window, so that a hidden return reaching the window's end (a
    simulated scan cut close behind its scene) is not taken for background: of the runs one holds no return as
    long as the scene's light fills less than (blocks − 1) / blocks of the window. On noisy counts the minimum
    of the runs' means lies below the floor λ by about √(λ / n) for runs of n bins (the expected minimum of four
    normal means is 1.03 standard errors low): the floor is under-subtracted on average, and over-subtracted at a
    point only where every run's noise is positive (1 in 2^blocks).

    Args:
        scan: (ny, nx, M) transients (counts or expected photons) on the hidden round-trip axis.
        first: the first bin after the direct light (0 ≤ first < M); blocks: runs, ≥ 1 (fewer where fewer bins
            remain).
    Returns:
        float64 (ny, nx), ≥ 0.
    Raises:
        ValueError: not an (ny, nx, M) scan, or ``first`` outside it.
    """
    s = np.asarray(scan, dtype=np.float64)
    if s.ndim != 3 or not 0 <= first < s.shape[-1]:
        raise ValueError(f"expected a scan (ny, nx, M) and 0 <= first < M, got shape {s.shape} and first {first}")
    rest = s[..., first:]
    n = max(1, min(int(blocks), rest.shape[-1]))
    size = rest.shape[-1] // n
    means = rest[..., : n * size].reshape(s.shape[:2] + (n, size)).mean(axis=-1)
    return np.maximum(means.min(axis=-1), 0.0)


def prepare_scan(scan: np.ndarray, bin_width: float, trim: float | Literal["auto"] | None = "auto",
                 max_bins: int = MAX_BINS, background: Literal["auto"] | None = "auto"
                 ) -> tuple[np.ndarray, float, int]:
    """A scan as every method of :func:`confocal_volume` takes it (module doc): summed to at most ``max_bins``
    bins (:func:`coarsen`), each point's floor subtracted (``background`` "auto": :func:`background_floor` after
    the direct light; None: kept), the direct light zeroed (``trim``: "auto", :func:`direct_light_bins`; a duration
    in s; or None), zero-padded to a power of two.

    Args:
        scan: (ny, nx, M) transients ≥ 0 on the hidden round-trip axis; bin_width: s.
    Returns:
        (data (ny, nx, 2^k) float64, a new array; its bin width s; the bins zeroed at the start).
    Raises:
        ValueError: ``background`` neither "auto" nor None.
    """
    if background not in ("auto", None):
        raise ValueError(f"background must be 'auto' or None, got {background!r}")
    data, dt = coarsen(np.array(scan, dtype=np.float64), float(bin_width), max_bins)     # a copy: trim zeroes it
    if trim == "auto":
        n_trim = direct_light_bins(data, dt)
    elif trim:
        n_trim = int(np.ceil(float(trim) / dt - 1e-9))
    else:
        n_trim = 0
    if background == "auto" and n_trim < data.shape[-1]:
        data -= background_floor(data, n_trim)[..., None]
    data[..., :n_trim] = 0.0
    m = 1 << max(1, int(np.ceil(np.log2(data.shape[-1]))))
    return np.concatenate([data, np.zeros(data.shape[:2] + (m - data.shape[-1],))], axis=-1), dt, n_trim


def confocal_volume(scan: np.ndarray, bin_width: float, pitch: float | tuple[float, float], method: str = "lct",
                    falloff: Literal["diffuse", "retroreflective"] = "retroreflective", snr: float = 0.8,
                    trim: float | Literal["auto"] | None = "auto", max_bins: int = MAX_BINS,
                    background: Literal["auto"] | None = "auto") -> tuple[np.ndarray, np.ndarray, dict]:
    """Reconstruct an aligned confocal scan with one of :data:`METHODS`.

    Args:
        scan: (ny, nx, M) transients ≥ 0 on the hidden round-trip axis from t = 0 (:func:`align_confocal`), row
            up the wall, column along u; pitch: the grid's spacing (m), or (between rows, between columns)
            (:func:`~datagen.analysis.confocal.grid_pitches`).
        bin_width: s; method: "lct", "phasor" or "fbp"; falloff, snr: :func:`~datagen.analysis.lct.lct_volume`'s
            (the release script's defaults: t², 0.8; its diffuse "S" used t⁴ and 0.08).
        trim: the direct light to zero: "auto" (:func:`direct_light_bins`), a duration in s, or None.
        max_bins: the time axis is summed to at most this many bins (:func:`coarsen`).
        background: "auto" subtracts each point's floor (:func:`background_floor`), None keeps it.
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
    if np.ndim(scan) != 3:
        raise ValueError(f"a confocal scan is (ny, nx, M); got shape {np.shape(scan)}")
    ny, nx = np.shape(scan)[:2]
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    data, dt, n_trim = prepare_scan(scan, bin_width, trim, max_bins, background)
    m = data.shape[-1]
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


def depth_map(volume: np.ndarray, depths: np.ndarray, level: float = FOUND_LEVEL,
              pedestal: float | None = FOUND_PEDESTAL) -> tuple[np.ndarray, np.ndarray]:
    """Depth of what a reconstruction found at each scan point.

    Args:
        volume: (ny, nx, Z) reconstruction (its magnitude is used); depths: (Z,) m of its last axis.
        level: a scan point has found something where its front-view value F (the maximum over depth) reaches
            P + ``level`` · (max F − P), 0 < level ≤ 1, P the front view's pedestal.
        pedestal: the percentile of F taken as P (0 < pedestal ≤ 50; :data:`FOUND_PEDESTAL`), or 0 / None for
            P = 0 (a share of the maximum, ``datagen reconstruct --pedestal 0``).
    Returns:
        ((ny, nx) float64 depth in m of the strongest voxel, NaN where nothing is found; (ny, nx) front view).
    Raises:
        ValueError: level outside (0, 1], pedestal outside [0, 50].
    """
    if not 0 < level <= 1:
        raise ValueError(f"level must be in (0, 1], got {level}")
    if pedestal is not None and not 0 <= pedestal <= 50:
        raise ValueError(f"pedestal must be a percentile in [0, 50], got {pedestal}")
    depth, front = depth_from_volume(volume, depths)
    base = float(np.percentile(front, pedestal)) if pedestal else 0.0
    top = float(front.max())
    found = front >= base + level * (top - base) if top > base else np.zeros(front.shape, bool)
    return np.where(found, depth, np.nan), front
