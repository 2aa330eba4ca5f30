"""From the transport envelope to expected avalanches per laser cycle per bin: background (PDE·ambient +
dark counts), diffusion tail, gating and true (DNL) bin widths; rebinning of a fine envelope onto any bin
edges (docs/physics.md §2, §5, §6)."""
from __future__ import annotations

from typing import Any

import numpy as np

from .config import DetectorConfig
from .effects import convolve_last, exponential_kernel
from .maps import check_map_shape

__all__ = [
    "NEGATIVE_ENVELOPE_RTOL",
    "gate_fraction",
    "rebin_envelope",
    "rates_from_envelope",
]


NEGATIVE_ENVELOPE_RTOL = 1e-9
"""Envelope values down to ``-NEGATIVE_ENVELOPE_RTOL × max|envelope|`` (per pixel) are FFT round-off and are
clamped to 0; anything more negative is an error."""


def _clamp_envelope(envelope: Any) -> np.ndarray:
    e = np.array(envelope, dtype=np.float64)  # copy: we clamp in place
    if e.ndim == 0 or e.shape[-1] == 0:
        raise ValueError(f"envelope must have shape (..., bins) with bins >= 1, got shape {e.shape}")
    low = np.min(e, axis=-1, keepdims=True)             # per pixel; NaN and ±inf reach both ends
    scale = np.maximum(np.max(e, axis=-1, keepdims=True), -low)
    if not np.all(np.isfinite(scale)):
        bad = np.argwhere(~np.isfinite(e))[0]
        raise ValueError(f"envelope contains a non-finite value {e[tuple(bad)]!r} at index "
                         f"{tuple(int(b) for b in bad)}")
    if np.any(low < -NEGATIVE_ENVELOPE_RTOL * scale):   # two reductions, no full-size temporaries
        bad = np.argwhere(e < -NEGATIVE_ENVELOPE_RTOL * scale)[0]
        raise ValueError(f"envelope has a clearly negative value {e[tuple(bad)]!r} at index "
                         f"{tuple(int(b) for b in bad)} (more than {NEGATIVE_ENVELOPE_RTOL:g} of that pixel's "
                         "maximum; only FFT round-off is clamped)")
    np.maximum(e, 0.0, out=e)
    return e


def gate_fraction(edges: np.ndarray, gate: tuple[float, float] | None) -> np.ndarray:
    """Fraction of each bin ``[edges[i], edges[i+1])`` inside ``gate = (start, stop)`` (all ones if None).

    Args:
        edges: float64 (bins + 1,) increasing bin edges in s.
        gate: ``(start, stop)`` in s, or None.
    Returns:
        float64 (bins,) in [0, 1].  Used by :func:`rates_from_envelope` (docs/physics.md §6: the bright first
        bounce is gated out in NLOS systems).
    """
    edges = np.asarray(edges, dtype=np.float64)
    if gate is None:
        return np.ones(edges.size - 1)
    lo = np.clip(edges[:-1], gate[0], gate[1])
    hi = np.clip(edges[1:], gate[0], gate[1])
    width = np.diff(edges)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(width > 0, (hi - lo) / np.where(width > 0, width, 1.0), 0.0)
    return np.clip(frac, 0.0, 1.0)


def rebin_envelope(fine_envelope: Any, fine_edges: Any, edges: Any) -> np.ndarray:
    """Integrate a finely binned envelope over arbitrary (e.g. unequal, DNL) bin edges.

    The envelope is taken as piecewise constant within each fine bin, so the result is exact for that
    density: bin ``k`` holds ``∫_{edges[k]}^{edges[k+1]}`` of it (docs/physics.md §5 "bins are integrals").  Mass
    outside ``[fine_edges[0], fine_edges[-1]]`` is zero.

    Args:
        fine_envelope: (..., n_fine) photons per fine bin (any real dtype; float64 internally).
        fine_edges: (n_fine + 1,) increasing edges in s.
        edges: (n + 1,) increasing target edges in s.
    Returns:
        float64 (..., n) photons per target bin.
    Raises:
        ValueError: mismatched lengths or non-increasing edges.
    """
    f = np.asarray(fine_envelope, dtype=np.float64)
    fe = np.asarray(fine_edges, dtype=np.float64)
    ne = np.asarray(edges, dtype=np.float64)
    if fe.ndim != 1 or fe.size != f.shape[-1] + 1:
        raise ValueError(f"fine_edges must have shape ({f.shape[-1] + 1},), got {fe.shape}")
    if ne.ndim != 1 or ne.size < 2:
        raise ValueError(f"edges must be a 1-D array of at least 2 edges, got shape {ne.shape}")
    if np.any(np.diff(fe) <= 0) or np.any(np.diff(ne) <= 0):
        raise ValueError("fine_edges and edges must be strictly increasing")
    cum = np.zeros(f.shape[:-1] + (fe.size,))
    np.cumsum(f, axis=-1, out=cum[..., 1:])
    x = np.clip(ne, fe[0], fe[-1])
    k = np.clip(np.searchsorted(fe, x, side="right") - 1, 0, fe.size - 2)
    frac = (x - fe[k]) / (fe[k + 1] - fe[k])
    at = cum[..., k] + frac * f[..., k]
    out = np.diff(at, axis=-1)
    return np.maximum(out, 0.0)


def rates_from_envelope(envelope: Any, config: DetectorConfig) -> np.ndarray:
    """Expected avalanches per laser cycle per bin from a detected-photon envelope.

    ``rates = G·K_tail ⊗ envelope + B·(pde·ambient_rate + dcr)·width_i``, multiplied by the gate fraction of
    each bin; G and B are each scan point's ``gain_map`` and ``background_map`` values (1 when not set,
    docs/detector.md "Direct light, gain and background maps").  The envelope already contains the PDE (docs/physics.md §2), so only ambient light is thinned here; the
    diffusion tail (``diffusion_tail``, ``diffusion_fraction``) acts before pile-up (docs/physics.md §6).  Widths
    are ``config.bin_widths`` when given (DNL), else ``bin_width``.

    Args:
        envelope: (..., bins) detected photons per pulse per bin, any real dtype (float64 internally).
        config: detector description.
    Returns:
        float64 (..., bins) rates ≥ 0.
    Raises:
        ValueError: NaN/inf in the envelope, values more negative than FFT round-off
            (``NEGATIVE_ENVELOPE_RTOL`` × the pixel maximum; smaller ones are clamped to 0), a bin count
            different from ``len(config.bin_widths)``, or a gain / background map whose shape is not the envelope's
            leading (scan point) shape.
    """
    e = _clamp_envelope(envelope)
    n_bins = e.shape[-1]
    widths = config.widths(n_bins)
    if config.diffusion_tail > 0 and config.diffusion_fraction > 0:
        kernel, first = exponential_kernel(config.diffusion_tail, config.bin_width, config.diffusion_fraction)
        e = convolve_last(e, kernel, first)
    gain, background = (config.scan_map(f) for f in ("gain_map", "background_map"))
    if gain is not None:
        e *= check_map_shape(gain, "gain_map", e.shape[:-1])[..., None]
    if background is None:
        rates = e + config.background_rate * widths
    else:
        rates = e + config.background_rate * check_map_shape(background, "background_map", e.shape[:-1])[..., None] \
            * widths
    if config.gate is not None:
        rates *= gate_fraction(config.bin_edges(n_bins), config.gate)
    return rates
