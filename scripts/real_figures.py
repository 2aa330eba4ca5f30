"""The figures of docs/real.md: a real capture of the Stanford LCT release against its simulation by
``datagen simulate scene_library/stanford_*.yaml --like STORE``.

Usage: PYTHONPATH=. python scripts/real_figures.py REAL_STORE SIM_STORE [REAL_STORE SIM_STORE ...]

Prints per pair: the hidden counts in the window the release's README uses (bins 600–1899 of 4 ps, less the per-bin
floor of bins 1900–2047), for the real counts and the simulated expected envelope (its scale is the model's: compare
ratios between captures, not values), and the second round trip (chart → wall → chart) as the largest bump of the
scan-summed transient, smoothed over 40 ps, between 1.8 and 2.3 times the main return's round trip, above the straight
line joining the window's ends, relative to the main return's peak above the floor.
"""
from __future__ import annotations

import sys

import numpy as np

HIDDEN = (600, 1900)
FLOOR = (1900, 2048)
SMOOTH_BINS = 10              # 40 ps of 4 ps bins


def hidden_counts(data: np.ndarray) -> float:
    """Σ bins 600–1899 less 1300 × the mean of bins 1900–2047 (scan-summed)."""
    s = data.reshape(-1, data.shape[-1]).sum(axis=0)
    return float(s[HIDDEN[0]:HIDDEN[1]].sum() - (HIDDEN[1] - HIDDEN[0]) * s[FLOOR[0]:FLOOR[1]].mean())


def echo(data: np.ndarray, dt: float) -> tuple[float, float, float]:
    """(main return's peak time s, echo's time s, echo's size relative to the main peak)."""
    s = data.reshape(-1, data.shape[-1]).sum(axis=0).astype(float)
    s = np.convolve(s, np.ones(SMOOTH_BINS) / SMOOTH_BINS, mode="same")
    floor = s[FLOOR[0]:FLOOR[1]].mean()
    i = HIDDEN[0] + int(np.argmax(s[HIDDEN[0]:HIDDEN[1]]))
    lo, hi = int(1.8 * i), min(int(2.3 * i), len(s) - 1)
    base = np.interp(np.arange(lo, hi + 1), [lo, hi], [s[lo], s[hi]])
    bump = s[lo:hi + 1] - base
    j = int(np.argmax(bump))
    return (i + 0.5) * dt, (lo + j + 0.5) * dt, float(bump[j] / (s[i] - floor))


def main(pairs: list[str]) -> None:
    from datagen.io import read_result

    for real_path, sim_path in zip(pairs[0::2], pairs[1::2]):
        real, sim = read_result(real_path), read_result(sim_path)
        dt = float(real.time_edges[1] - real.time_edges[0])
        r, s = np.asarray(real.counts, float), np.asarray(sim.envelope, float)
        print(f"{real_path}: hidden counts real {hidden_counts(r):.6g}, sim (expected) {hidden_counts(s):.6g}")
        for what, d in (("real", r), ("sim", s)):
            t1, t2, size = echo(d, dt)
            print(f"  {what}: main return {t1 * 1e9:.3f} ns; second round trip {t2 * 1e9:.3f} ns, "
                  f"{size:.3%} of the main return")


if __name__ == "__main__":
    if len(sys.argv) < 3 or len(sys.argv) % 2 != 1:
        sys.exit(__doc__)
    main(sys.argv[1:])
