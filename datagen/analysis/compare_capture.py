"""Sim-to-real distance: a measured capture against its simulation, on one time axis.

Both captures are brought to the *hidden* time axis (each scan point's own offset removed: the LCT / f-k
``tofgrid`` or the counted wall legs, :mod:`datagen.io.lab_formats`) and rebinned onto the real capture's bin
width (:func:`datagen.spad.rates.rebin_envelope`, exact for binned data). The transients are normalised to
unit sum (the simulation's absolute scale is the model's, the measurement's the exposure's), then compared:

* ``rel_l2``: ‖ŝ − r̂‖₂ / ‖r̂‖₂ of the normalised scan-summed transients (and per scan point, ``rel_l2_points``,
  when both grids have the same shape);
* ``chi2_per_bin``: Σ (r − N·ŝ)² / max(N·ŝ, 1) over the bins where N·ŝ ≥ 1 or r > 0, divided by their number,
  with r the measured counts and N their total (the per-bin χ² of the measurement against the simulation scaled
  to its counts; ≈ 1 when they agree to counting noise — meaningful when the measurement holds counts);
* ``peak_time_diff``: simulated − measured peak time (s, parabolic interpolation of the peak bin);
* ``width_diff``: simulated − measured full width at half maximum (s, linear interpolation).
"""
from __future__ import annotations

import numpy as np

from ..spad.rates import rebin_envelope

__all__ = ["hidden_time_transients", "peak_time", "fwhm", "compare_transients", "compare_captures"]


def hidden_time_transients(data: np.ndarray, time_edges: np.ndarray, offsets: np.ndarray | None,
                           edges: np.ndarray) -> np.ndarray:
    """Each scan point's transient with its time offset removed, rebinned onto ``edges``.

    Args:
        data: (..., T) transients; time_edges: (T+1,) s; offsets: (...) s per scan point or None (no shift);
        edges: (K+1,) target edges in s (hidden time).
    Returns:
        float64 (P, K) with P the scan points (leading axes flattened).
    """
    d = np.asarray(data, dtype=np.float64)
    flat = d.reshape(-1, d.shape[-1])
    off = np.zeros(flat.shape[0]) if offsets is None else np.asarray(offsets, float).reshape(-1)
    out = np.empty((flat.shape[0], len(edges) - 1))
    values, inverse = np.unique(off, return_inverse=True)
    for k, o in enumerate(values):                       # one rebin per distinct offset
        rows = inverse == k
        out[rows] = rebin_envelope(flat[rows], np.asarray(time_edges, float) - o, edges)
    return out


def peak_time(t: np.ndarray, y: np.ndarray) -> float:
    """Peak time (s) of ``y`` on bin centres ``t``: the maximum bin refined by a parabola through its neighbours."""
    i = int(np.argmax(y))
    if 0 < i < len(y) - 1:
        a, b, c = y[i - 1], y[i], y[i + 1]
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return float(t[i] + shift * (t[1] - t[0]))
    return float(t[i])


def fwhm(t: np.ndarray, y: np.ndarray) -> float:
    """Full width at half maximum (s) of the peak of ``y`` on bin centres ``t`` (linear interpolation of the
    half-maximum crossings on each side of the peak)."""
    i = int(np.argmax(y))
    half = 0.5 * y[i]
    lo = i
    while lo > 0 and y[lo - 1] > half:
        lo -= 1
    hi = i
    while hi < len(y) - 1 and y[hi + 1] > half:
        hi += 1
    dt = t[1] - t[0]
    left = t[lo] - dt * ((y[lo] - half) / (y[lo] - y[lo - 1]) if lo > 0 and y[lo] != y[lo - 1] else 0.5)
    right = t[hi] + dt * ((y[hi] - half) / (y[hi] - y[hi + 1]) if hi < len(y) - 1 and y[hi] != y[hi + 1] else 0.5)
    return float(right - left)


def compare_transients(t: np.ndarray, real: np.ndarray, sim: np.ndarray) -> dict:
    """Distances between two transients on the same bin centres ``t`` (s); see the module docstring."""
    r = np.asarray(real, float)
    s = np.asarray(sim, float)
    n = r.sum()
    rn, sn = r / n, s / s.sum()
    mu = n * sn
    used = (mu >= 1.0) | (r > 0)          # bins where either capture has something (empty tails would dilute χ²)
    return {"rel_l2": float(np.linalg.norm(sn - rn) / np.linalg.norm(rn)),
            "chi2_per_bin": float(((r - mu)[used] ** 2 / np.maximum(mu[used], 1.0)).sum() / max(used.sum(), 1)),
            "peak_time_real": peak_time(t, r), "peak_time_sim": peak_time(t, s),
            "peak_time_diff": peak_time(t, s) - peak_time(t, r),
            "fwhm_real": fwhm(t, r), "fwhm_sim": fwhm(t, s), "width_diff": fwhm(t, s) - fwhm(t, r),
            "counts_real": float(n)}


def _window(edges: np.ndarray, offsets: np.ndarray) -> str:
    """A capture's window on the hidden time axis, in ns, for messages."""
    lo, hi = float(edges[0]) - float(offsets.max()), float(edges[-1]) - float(offsets.min())
    return f"{lo * 1e9:.4g}..{hi * 1e9:.4g} ns"


def compare_captures(real: np.ndarray, real_edges: np.ndarray, real_offsets: np.ndarray | None,
                     sim: np.ndarray, sim_edges: np.ndarray, sim_offsets: np.ndarray | None) -> dict:
    """Sim-to-real distance of two captures (module docstring).

    Args:
        real, sim: (..., T) transients (leading axes: scan points); *_edges: (T+1,) s, uniform;
        *_offsets: per scan point time offsets in s (shape of the leading axes) or None.
    Returns:
        dict of the metrics of :func:`compare_transients` on the scan-summed transients, ``rel_l2_points`` (mean
        per-point relative L2 when both grids have the same shape, else None), and for drawing: ``t`` (K,) bin
        centres (hidden time, s), ``real_sum`` / ``sim_sum`` (K,) the summed transients, ``real_image`` /
        ``sim_image`` the time-integrated intensity per scan point (leading shape).
    Raises:
        ValueError: no overlap of the two time windows, or a capture without counts in the window.
    """
    real = np.asarray(real, float)
    sim = np.asarray(sim, float)
    dt = float(real_edges[1] - real_edges[0])
    ro = np.zeros(real.shape[:-1]) if real_offsets is None else np.asarray(real_offsets, float)
    so = np.zeros(sim.shape[:-1]) if sim_offsets is None else np.asarray(sim_offsets, float)
    lo = max(float(real_edges[0]) - float(ro.max()), float(sim_edges[0]) - float(so.max()))
    hi = min(float(real_edges[-1]) - float(ro.min()), float(sim_edges[-1]) - float(so.min()))
    if hi <= lo + dt:
        raise ValueError(f"the two captures' time windows do not overlap on the hidden time axis (real "
                         f"{_window(real_edges, ro)}, sim {_window(sim_edges, so)})")
    edges = lo + np.arange(int((hi - lo) // dt) + 1) * dt
    r = hidden_time_transients(real, real_edges, ro, edges)
    s = hidden_time_transients(sim, sim_edges, so, edges)
    empty = [name for name, x in (("real", r), ("sim", s)) if not x.sum() > 0]
    if empty:
        raise ValueError(f"{' and '.join(empty)}: no signal in the common time window {lo * 1e9:.4g}..{hi * 1e9:.4g} "
                         f"ns of hidden time (real {_window(real_edges, ro)}, sim {_window(sim_edges, so)})")
    t = 0.5 * (edges[1:] + edges[:-1])
    out = compare_transients(t, r.sum(0), s.sum(0))
    out["rel_l2_points"] = None
    if real.shape[:-1] == sim.shape[:-1]:
        rn = r / np.maximum(r.sum(1, keepdims=True), 1e-300)
        sn = s / np.maximum(s.sum(1, keepdims=True), 1e-300)
        ok = np.linalg.norm(rn, axis=1) > 0
        out["rel_l2_points"] = float(np.mean(np.linalg.norm(sn - rn, axis=1)[ok] / np.linalg.norm(rn, axis=1)[ok]))
    out.update({"t": t, "real_sum": r.sum(0), "sim_sum": s.sum(0), "bins": len(t),
                "real_image": real.sum(-1), "sim_image": sim.sum(-1)})
    return out
