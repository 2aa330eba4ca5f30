"""Phasor-field reconstruction with Rayleigh–Sommerfeld diffraction (Liu et al. 2019): the benchmark's RSD baseline
for confocal scans.

y-tal 0.20's phasor-field solvers fail on confocal captures (``tal.reconstruct.pf`` stops with an AttributeError in
its propagator, ``tal.reconstruct.pf_dev`` refuses confocal data; docs/benchmark.md), so this is datagen's own; for a
single-sensor (non-confocal) scan it is checked against ``tal.reconstruct.pf_dev`` on the same capture.

The transients are filtered with a virtual illumination pulse, a complex wave of central wavelength λ_c under a
Gaussian envelope of standard deviation σ in path length (tal's ``pf`` filter: σ = λ_c/√2 by default), done as a sum over the wavenumbers κ its
spectrum holds. Each κ component is propagated to planes parallel to the wall by an RSD convolution, a 2-D FFT per
plane, with the kernel e^{iκ·m·r}/r (m = 2 for a confocal scan, whose path is wall → x → wall; m = 1 for a single
sensor point s, whose second leg |x − s| is then a per-voxel phase). The image is the magnitude of the sum over κ at
t = 0 (the confocal camera of the phasor-field papers).
"""
from __future__ import annotations

import numpy as np

from ..units import SPEED_OF_LIGHT

SPECTRUM_CUT = 1e-3
"""Wavenumbers whose Gaussian weight is below this fraction of the peak are left out of the sum."""


def phasor_rsd(scan: np.ndarray, bin_width: float, pitch: float | tuple[float, float], depths: np.ndarray, wavelength: float,
               sigma: float | None = None, t_start: float = 0.0, sensor_leg: np.ndarray | None = None) -> np.ndarray:
    """Phasor-field RSD volume of a scan on a regular wall grid.

    Args:
        scan: (H, W, T) transients (any units) of an H × W grid of wall points with spacing ``pitch`` (m; or
            (between rows, between columns) for a grid of two pitches), time bins of ``bin_width`` s from
            ``t_start`` s. Confocal (``sensor_leg`` None): t = 2·|x − p|/c.
            Single sensor: t = (|x − l| + |x − s|)/c and ``sensor_leg`` gives |x − s| in metres at every voxel,
            (H, W, Z).
        depths: (Z,) plane distances from the wall (m, > 0); voxel (i, j, k) is grid point (i, j) moved by
            depths[k] along the wall normal.
        wavelength: central wavelength λ_c of the virtual pulse (m); sigma: its envelope's standard deviation in
            path length (m; default λ_c/√2).
    Returns:
        (H, W, Z) float64 magnitude.
    Raises:
        ValueError: a scan that is not (H, W, T), non-positive bin_width / pitch / wavelength / depths, or a
            ``sensor_leg`` of another shape than (H, W, Z).
    """
    scan = np.asarray(scan, dtype=np.float64)
    depths = np.asarray(depths, dtype=np.float64)
    if scan.ndim != 3:
        raise ValueError(f"phasor_rsd needs an (H, W, T) scan, got shape {scan.shape}")
    pitch_y, pitch_x = (pitch, pitch) if np.ndim(pitch) == 0 else pitch
    if not (bin_width > 0 and pitch_y > 0 and pitch_x > 0 and wavelength > 0 and np.all(depths > 0)):
        raise ValueError("phasor_rsd needs bin_width, pitch, wavelength and every depth > 0")
    h, w, nt = scan.shape
    if sensor_leg is not None and np.shape(sensor_leg) != (h, w, len(depths)):
        raise ValueError(f"sensor_leg must have shape {(h, w, len(depths))}, got {np.shape(sensor_leg)}")
    dl = SPEED_OF_LIGHT * bin_width                                    # path length per bin (m)
    n_fft = nt
    kappa = 2 * np.pi * np.fft.rfftfreq(n_fft, d=dl)                  # wavenumbers (rad/m)
    sigma_l = wavelength / np.sqrt(2) if sigma is None else float(sigma)    # Gaussian envelope in path length
    weight = np.exp(-0.5 * ((kappa - 2 * np.pi / wavelength) * sigma_l) ** 2)
    keep = weight > SPECTRUM_CUT * weight.max()
    kappa, weight = kappa[keep], weight[keep]
    spectrum = np.fft.rfft(scan, n=n_fft, axis=-1)[..., keep].astype(np.complex64)         # Σ_L H(L) e^{-iκL}, L from t_start
    spectrum = spectrum * np.exp(-1j * kappa * SPEED_OF_LIGHT * t_start) * weight    # L measured from 0
    mult = 1.0 if sensor_leg is not None else 2.0
    # lateral offsets of the padded convolution grid
    oy = (np.fft.fftfreq(2 * h) * 2 * h) * pitch_y
    ox = (np.fft.fftfreq(2 * w) * 2 * w) * pitch_x
    r2 = oy[:, None] ** 2 + ox[None, :] ** 2
    f_spec = np.fft.fft2(np.moveaxis(spectrum, -1, 0), s=(2 * h, 2 * w))            # (K, 2H, 2W)
    out = np.empty((h, w, len(depths)))
    for k, z in enumerate(depths):
        r = np.sqrt(r2 + z * z)
        kernel = (np.exp(1j * mult * kappa[:, None, None] * r[None]) / r[None]).astype(np.complex64)
        # correlation: voxel q collects Σ_p S(p) K(q − p); the kernel is even, so a convolution does it
        field = np.fft.ifft2(f_spec * np.fft.fft2(kernel))[:, :h, :w]             # (K, H, W)
        if sensor_leg is not None:
            field = field * np.exp(1j * kappa[:, None, None] * sensor_leg[None, :, :, k])
        out[:, :, k] = np.abs(field.sum(axis=0))
    return out
