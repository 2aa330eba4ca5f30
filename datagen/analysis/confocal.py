"""A confocal scan made ready for the reconstruction baselines: its transients on the hidden round-trip axis, and
where the direct light off the scanned points ends.

The baselines (:mod:`.lct`, :mod:`.phasor`, :mod:`.reconstruct`) assume the time axis of the LCT release and of
the f-k release's reader: bin k holds the round trips [k·Δt, (k + 1)·Δt) from the scanned point p to the hidden
scene and back, t = 2·|x − p|/c, "t = 0 when the light reaches the scan surface". :func:`align_confocal` puts any
confocal scan there, whatever its ``t_start`` and whichever wall legs its time axis counts (per-point offsets:
an LCT ``tofgrid``, or a datagen result's counted legs). :func:`direct_light_bins` finds how many leading bins the
direct light fills (its peak at t ≈ 0 and the detector's slow tail after it): the LCT release's captures keep it,
and the release's script zeroes the first 2.4 ns by hand before it reconstructs.
"""
from __future__ import annotations

import numpy as np

DIRECT_WINDOW = 0.5e-9
"""s: the direct light's peak is looked for in the first 0.5 ns of the aligned axis (7.5 cm of depth); a later peak
is the hidden scene's."""

DIRECT_SMOOTHING = 100e-12
"""s: the scan-summed transient is smoothed over 100 ps (a moving average) before its shape is read, so that
counting noise does not end the tail early."""

DIRECT_RISE = 0.5
"""The direct light's tail ends where the smoothed scan-summed transient rises 50 % above its lowest value since
the direct peak (the hidden scene's return; the release's captures hold a 15 % echo 2 ns after the direct peak,
which this does not take for the scene)."""

FLOOR_MARGIN = 0.1
"""...or where it has fallen to within 10 % of the transient's lowest value after the peak (the background
floor): the tail is gone."""


def align_confocal(envelope: np.ndarray, time_edges: np.ndarray, offsets: np.ndarray | None = None
                   ) -> tuple[np.ndarray, float]:
    """A confocal scan on the hidden round-trip axis: bin k of every transient holds round trips [k·Δt, (k+1)·Δt).

    Transient p is shifted by round((time_edges[0] − offsets[p]) / Δt) bins (the f-k release's reader shifts by
    −floor(tofgrid/Δt)); bins that fall before t = 0 are dropped, and the axis runs to the last bin any point
    keeps. A sub-bin remainder of an offset stays (at most half a bin).

    Args:
        envelope: (ny, nx, T) transients (any units); time_edges: (T+1,) s, uniform bins of Δt.
        offsets: (ny, nx) s that each transient's time axis holds beyond the hidden round trip (the counted wall
            legs, :meth:`datagen.io.lab_formats.LabCapture.time_offsets`); None: 0 everywhere.
    Returns:
        ((ny, nx, M) float64 aligned scan, Δt in s).
    Raises:
        ValueError: not an (ny, nx, T) scan, time_edges of another length or not uniform, offsets of another
            shape or not finite.
    """
    env = np.asarray(envelope, dtype=np.float64)
    edges = np.asarray(time_edges, dtype=np.float64)
    if env.ndim != 3:
        raise ValueError(f"a confocal scan is (ny, nx, T); got envelope shape {env.shape}")
    if edges.shape != (env.shape[2] + 1,):
        raise ValueError(f"time_edges has {edges.size} edges for {env.shape[2]} bins")
    widths = np.diff(edges)
    dt = float(widths[0])
    if not (dt > 0 and np.allclose(widths, dt, rtol=1e-9, atol=0)):
        raise ValueError("the time bins are not uniform (time_edges)")
    off = np.zeros(env.shape[:2]) if offsets is None else np.asarray(offsets, dtype=np.float64)
    if off.shape != env.shape[:2] or not np.isfinite(off).all():
        raise ValueError(f"offsets must be finite and of the scan's shape {env.shape[:2]}, got {off.shape}")
    shift = np.rint((edges[0] - off) / dt).astype(np.int64)               # aligned bin = stored bin + shift
    n_out = max(1, int((env.shape[2] + shift).max()))
    out = np.zeros(env.shape[:2] + (n_out,))
    for (iy, ix), s in np.ndenumerate(shift):
        lo = max(0, -s)
        if lo < env.shape[2]:
            out[iy, ix, lo + s:env.shape[2] + s] = env[iy, ix, lo:]
    return out, dt


def direct_light_bins(scan: np.ndarray, bin_width: float) -> int:
    """How many leading bins of an aligned confocal scan (:func:`align_confocal`) hold the direct light: 0 when it
    has none.

    On the scan-summed transient smoothed over :data:`DIRECT_SMOOTHING`: the direct peak is its maximum within
    :data:`DIRECT_WINDOW` of t = 0; walking on from it, the tail ends at the first bin that has either fallen to
    within :data:`FLOOR_MARGIN` of the transient's lowest value after the peak, or risen :data:`DIRECT_RISE` above
    the lowest value since the peak (a hidden return). The bins before the lowest point up to there are the direct
    light's. A hidden return that rises less than that above the floor, arriving before the tail has decayed, is
    taken for tail: give the trim explicitly then. On the LCT release's captures this ends 2.6–3.8 ns (the script
    zeroes 2.4 ns by hand).

    Args:
        scan: (ny, nx, M) aligned transients ≥ 0 (counts or expected photons); bin_width: Δt in s.
    Returns:
        the number of bins to zero, 0 ≤ n < M.
    """
    s = np.asarray(scan, dtype=np.float64).reshape(-1, np.shape(scan)[-1]).sum(axis=0)
    w = max(1, int(round(DIRECT_SMOOTHING / bin_width)))
    box = np.ones(w)
    smooth = np.convolve(s, box, mode="same") / np.convolve(np.ones_like(s), box, mode="same")
    lead = max(1, min(len(s), int(round(DIRECT_WINDOW / bin_width))))
    peak = int(np.argmax(smooth[:lead]))
    tail = smooth[peak:]
    floor = float(tail.min())
    running = np.minimum.accumulate(tail)
    stop = np.flatnonzero((tail <= floor + FLOOR_MARGIN * abs(floor)) | (tail > (1 + DIRECT_RISE) * running))
    end = int(stop[0]) if stop.size else len(tail) - 1
    return peak + int(np.argmin(tail[:end + 1]))


def grid_pitches(points: np.ndarray) -> tuple[float, float]:
    """(between rows, between columns) pitch in m of a regular confocal grid of (ny, nx, 3) scan points: rows
    spaced alike, columns spaced alike (a rectangle's two pitches may differ).

    Raises:
        ValueError: not (ny, nx, 3) with ny, nx ≥ 2, or spacings that vary along an axis by more than 1e-6
            relative (the message gives the range).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[-1] != 3 or min(pts.shape[:2]) < 2:
        raise ValueError(f"expected a grid of at least 2 x 2 points (ny, nx, 3), got shape {pts.shape}")
    out = []
    for axis, name in ((0, "rows"), (1, "columns")):
        d = np.linalg.norm(np.diff(pts, axis=axis), axis=-1)
        pitch = float(d.mean())
        if not (pitch > 0 and np.allclose(d, pitch, rtol=1e-6)):
            raise ValueError(f"the scan points are not a regular grid: the spacing between {name} runs from "
                             f"{float(d.min()):.6g} m to {float(d.max()):.6g} m")
        out.append(pitch)
    return out[0], out[1]
