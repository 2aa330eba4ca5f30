"""Benchmark of datagen.spad (issue 3).  Plain script: ``python benchmarks/bench_spad.py``.

Prints a table of wall-clock times (best of ``REPEATS``) for
* a 64×64-pixel × 1024-bin synchronous (pile-up) exposure of 10^6 cycles, drawn by the default sampler
  (exact sequential conditional binomials, fixed pixel chunks in threads) and by the alternatives
  (single-thread sequential, binary-tree conditional binomials, numpy's ``Generator.multinomial``);
* the free-running event simulation, as detections per second;
* the expected histogram of the free-running Markov chain.
"""
from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's datagen, not whichever one is installed

from datagen.spad import DetectorConfig, expected_histogram, rates_from_envelope, sample_histogram  # noqa: E402
from datagen.spad.synchronous import detection_pmf, first_photon_sequential, first_photon_tree  # noqa: E402

REPEATS = 3
PIXELS = (64, 64)
BINS = 1024
CYCLES = 10**6


def best_of(func, repeats=REPEATS):
    best, result = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = func()
        best = min(best, time.perf_counter() - t0)
    return best, result


def nlos_envelope(shape, bins, rng):
    """A weak Gaussian return (σ = 4 bins) at a random bin per pixel, 0.02–0.1 detected photons per pulse."""
    t = np.arange(bins)
    centre = rng.uniform(200, 800, size=shape + (1,))
    amplitude = rng.uniform(0.02, 0.1, size=shape + (1,))
    g = np.exp(-0.5 * ((t - centre) / 4.0) ** 2)
    return amplitude * g / g.sum(axis=-1, keepdims=True)


def main():
    rng = np.random.default_rng(2024)
    rows = []
    cfg = DetectorConfig(repetition_rate="20MHz", n_cycles=CYCLES, bin_width="50ps", pde=0.3,
                         ambient_rate="1MHz", dcr="100cps")
    rates = rates_from_envelope(nlos_envelope(PIXELS, BINS, rng), cfg)
    lam = rates.sum(-1)
    label = f"pile-up {PIXELS[0]}x{PIXELS[1]}x{BINS}, 1e6 cycles"
    t, counts = best_of(lambda: sample_histogram(rates, cfg, np.random.default_rng(1)))
    rows.append((label, "sample_histogram (default: threaded sequential binomials)", t,
                 f"{counts.sum() / t:.3g} counts/s"))
    r2 = rates.reshape(-1, BINS)
    t, _ = best_of(lambda: first_photon_sequential(np.random.default_rng(1), r2, CYCLES))
    rows.append((label, "sequential binomials, 1 thread", t, ""))
    t, _ = best_of(lambda: first_photon_tree(np.random.default_rng(1), r2, CYCLES))
    rows.append((label, "binary-tree binomials, 1 thread", t, ""))
    pmf = detection_pmf(r2)
    t, _ = best_of(lambda: np.random.default_rng(1).multinomial(CYCLES, pmf))
    rows.append((label, "numpy Generator.multinomial(pmf), 1 thread", t, "(+ pmf time, inexact tail)"))
    t, _ = best_of(lambda: expected_histogram(rates, cfg))
    rows.append((label, "expected_histogram", t, ""))

    # free-running event simulation: same pixels, 1000 bins = one 50 ns period, dead time 50 ns
    fr = DetectorConfig(repetition_rate="20MHz", n_cycles=20_000, bin_width="50ps", pde=0.3,
                        ambient_rate="1MHz", dcr="100cps", model="free_running", dead_time="50ns")
    fr_rates = rates_from_envelope(nlos_envelope(PIXELS, 1000, rng) * 10, fr)
    t, counts = best_of(lambda: sample_histogram(fr_rates, fr, np.random.default_rng(2)), repeats=1)
    rows.append((f"free-running {PIXELS[0]}x{PIXELS[1]}x1000, 2e4 cycles", "batched event simulation", t,
                 f"{counts.sum() / t:.3g} detections/s ({counts.sum():,} det.)"))
    few = fr_rates[:2, :2]
    fr_long = DetectorConfig(**{**fr.model_dump(), "n_cycles": 2_000_000})
    t, counts = best_of(lambda: sample_histogram(few, fr_long, np.random.default_rng(3)), repeats=1)
    rows.append(("free-running 2x2x1000, 2e6 cycles", "batched event simulation", t,
                 f"{counts.sum() / t:.3g} detections/s ({counts.sum():,} det.)"))
    fr_ap = DetectorConfig(**{**fr.model_dump(), "afterpulse_probability": 0.01, "afterpulse_time_constant": 50e-9})
    t, counts = best_of(lambda: sample_histogram(fr_rates, fr_ap, np.random.default_rng(4)), repeats=1)
    rows.append((f"free-running {PIXELS[0]}x{PIXELS[1]}x1000, 2e4 cycles, P_ap=1%",
                 "round-based event simulation", t, f"{counts.sum() / t:.3g} detections/s"))
    t, _ = best_of(lambda: expected_histogram(fr_rates[0, :16], fr), repeats=1)
    rows.append(("free-running 16 pixels x 1000 bins", "expected_histogram (Markov chain)", t,
                 f"{t / 16 * 1e3:.1f} ms/pixel"))

    print(f"datagen.spad benchmark — python {platform.python_version()}, numpy {np.__version__}, "
          f"{len(os.sched_getaffinity(0))} cores")
    print(f"mean Λ per pixel per cycle (pile-up case): {lam.mean():.3f}")
    width = max(len(r[0]) for r in rows)
    mwidth = max(len(r[1]) for r in rows)
    print(f"{'case':<{width}}  {'method':<{mwidth}}  {'time [s]':>9}  note")
    for case, method, seconds, note in rows:
        print(f"{case:<{width}}  {method:<{mwidth}}  {seconds:9.3f}  {note}")


if __name__ == "__main__":
    main()
