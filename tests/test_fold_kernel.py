"""The accumulator's compiled row kernels (datagen/timing/fold_kernel.py) against numpy, the same bits on one
thread and on two (their rows run on numba's threads for large grids), and datagen.threads' thread rule and
OpenMP wait policy, and numpy's BLAS on one thread in the pipeline."""
from __future__ import annotations

import numba
import numpy as np
import pytest

from datagen.timing.fold_kernel import bin_rows, bin_weights, fold_rows, full_bounds, nonzero_rows, rows_dot

ROWS, NODES, OVERSAMPLE = 300, 640, 5


def sparse_rows(seed: int) -> np.ndarray:
    """(ROWS, NODES) float64: a third of the rows empty, the others non-zero on a random span of ≤ 120 nodes."""
    rng = np.random.default_rng(seed)
    a = np.zeros((ROWS, NODES))
    for r in rng.choice(ROWS, 2 * ROWS // 3, replace=False):
        lo = int(rng.integers(0, NODES - 120))
        n = int(rng.integers(1, 120))
        a[r, lo:lo + n] = rng.random(n)
    return a


FULL = full_bounds(ROWS, NODES)


def on_threads(n: int, fn, *args):
    threads = numba.get_num_threads()
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(threads)


def test_nonzero_rows_and_rows_dot_match_numpy():
    a = sparse_rows(1)
    v = np.random.default_rng(2).random(NODES)
    for n in (1, 2):
        assert np.array_equal(on_threads(n, nonzero_rows, a, FULL), np.flatnonzero(a.any(axis=1)))
        assert on_threads(n, rows_dot, a, v, FULL) == pytest.approx(a @ v, rel=1e-12, abs=0.0)
    assert np.array_equal(on_threads(1, rows_dot, a, v, FULL), on_threads(2, rows_dot, a, v, FULL))
    assert len(nonzero_rows(np.zeros((4, 7)), full_bounds(4, 7))) == 0


def test_rows_dot_over_the_non_zero_weights_is_the_in_order_sum():
    """Window fractions non-zero only near both ends (the sparse path) and everywhere (the span path): each row's
    result equals the plain sum over every node in node order, to the bit."""
    a = sparse_rows(3)
    a[5, :] = np.random.default_rng(4).random(NODES)           # a full row reaches both ends
    a[7, 3] = -1e-300                                          # round-off below zero: ±0.0 products where v is 0
    for v in (np.concatenate([np.linspace(1.0, 1e-9, 90), np.zeros(NODES - 150), np.linspace(1e-9, 1.0, 60)]),
              np.random.default_rng(5).random(NODES)):
        expect = np.zeros(ROWS)
        for i in range(ROWS):
            total = 0.0
            for j in range(NODES):
                total += float(a[i, j]) * float(v[j])
            expect[i] = total
        for n in (1, 2):
            assert np.array_equal(on_threads(n, rows_dot, a, v, FULL), expect)


def test_fold_rows_is_the_double_running_sum():
    """Curvature rows that are second differences of a compact profile fold back to that profile (the double
    running sum, numpy.cumsum twice, vanishes beyond each row's span), on one thread and on two alike."""
    profile = sparse_rows(3)
    padded = np.pad(profile, ((0, 0), (2, 2)))
    curvature = np.diff(padded, n=2, axis=1)[:, :NODES]          # second differences, stored at the node they end on
    base = np.random.default_rng(4).random((ROWS, NODES))
    out = {}
    for n in (1, 2):
        hist = base.copy()
        on_threads(n, fold_rows, hist, curvature, FULL)
        out[n] = hist
    assert np.array_equal(out[1], out[2])
    expected = base + np.cumsum(np.cumsum(curvature, axis=1), axis=1)
    assert np.abs(out[1] - expected).max() < 1e-12
    assert np.abs(out[1] - base - profile).max() < 1e-12


def test_bin_rows_is_the_valid_convolution_summed_per_bin():
    hist = sparse_rows(5)
    kernel = np.exp(-0.5 * ((np.arange(23) - 11) / 3.0) ** 2)
    kernel /= kernel.sum()
    table = bin_weights(kernel, OVERSAMPLE)
    n_bins = (NODES - len(kernel) + 1) // OVERSAMPLE
    rows = np.flatnonzero(hist.any(axis=1)).astype(np.int64)
    got = {}
    for n in (1, 2):
        out, peak = np.empty((len(rows), n_bins)), np.empty(len(rows))
        on_threads(n, bin_rows, hist, rows, table, out, peak, FULL)
        got[n] = (out, peak)
    assert np.array_equal(got[1][0], got[2][0]) and np.array_equal(got[1][1], got[2][1])
    valid = np.array([np.convolve(hist[r], kernel, "valid")[:n_bins * OVERSAMPLE] for r in rows])
    expected = valid.reshape(len(rows), n_bins, OVERSAMPLE).sum(axis=2)
    assert np.abs(got[1][0] - expected).max() < 1e-12
    assert np.array_equal(got[1][1], np.abs(hist[rows]).max(axis=1))
    weights = table.T.ravel()                        # node order: weights[q · oversample + p] = table[p, q]
    for i in range(0, len(rows), 7):                 # each bin, bit for bit: its window's terms in node order
        for b in range(n_bins):
            start, total = b * OVERSAMPLE, 0.0
            for j in range(start, min(start + len(weights), NODES)):
                total += float(hist[rows[i], j]) * float(weights[j - start])
            assert got[1][0][i, b] == total, (i, b)


def test_bounds_give_the_same_bits_and_nothing_outside_them_is_read():
    """Per-row bounds (each row's non-zero span widened by a few nodes, empty rows [0, 0)) give every kernel the
    results of whole rows, to the bit; NaN put outside the bounds (the binning: outside its windows' reach beyond
    them) is never read (it would spread into every sum)."""
    hist, curvature = sparse_rows(6), sparse_rows(7)
    nz = (hist != 0) | (curvature != 0)
    bound = np.zeros((ROWS, 2), dtype=np.int64)
    for r in np.flatnonzero(nz.any(axis=1)):
        cols = np.flatnonzero(nz[r])
        bound[r] = max(cols[0] - 3, 0), min(cols[-1] + 4, NODES)
    poisoned = [a.copy() for a in (hist, curvature)]
    for a in poisoned:
        for r in range(ROWS):
            a[r, :bound[r, 0]] = np.nan
            a[r, bound[r, 1]:] = np.nan
    v = np.concatenate([np.linspace(1.0, 1e-9, 90), np.zeros(NODES - 150), np.linspace(1e-9, 1.0, 60)])
    assert np.array_equal(nonzero_rows(poisoned[0], bound), nonzero_rows(hist, FULL))
    assert np.array_equal(rows_dot(poisoned[0], v, bound), rows_dot(hist, v, FULL))
    folded, expect = poisoned[0].copy(), hist.copy()
    fold_rows(folded, poisoned[1], bound)
    fold_rows(expect, curvature, FULL)
    inside = np.isfinite(folded)
    assert np.array_equal(folded[inside], expect[inside]) and (expect[~inside] == 0).all()
    kernel = np.exp(-0.5 * ((np.arange(23) - 11) / 3.0) ** 2)
    table = bin_weights(kernel / kernel.sum(), OVERSAMPLE)
    n_bins = (NODES - len(kernel) + 1) // OVERSAMPLE
    rows = np.flatnonzero(hist.any(axis=1)).astype(np.int64)
    got = [(np.empty((len(rows), n_bins)), np.empty(len(rows))) for _ in range(2)]
    windows = hist.copy()                            # the binning reads whole windows of the bins a span reaches
    for r in range(ROWS):
        windows[r, :max(bound[r, 0] - table.size, 0)] = np.nan
        windows[r, bound[r, 1] + table.size:] = np.nan
    bin_rows(windows, rows, table, *got[0], bound)
    bin_rows(hist, rows, table, *got[1], FULL)
    assert np.array_equal(got[0][0], got[1][0]) and np.array_equal(got[0][1], got[1][1])


def test_threads_for_runs_short_work_on_one_thread_and_restores_the_count():
    from datagen.threads import threads_for

    before = numba.get_num_threads()
    with threads_for(10, 100):
        assert numba.get_num_threads() == 1
    with threads_for(100, 100):
        assert numba.get_num_threads() == before
    assert numba.get_num_threads() == before


def test_idle_openmp_threads_sleep_unless_the_user_says_otherwise():
    import os
    import subprocess
    import sys

    code = "import datagen.threads, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "PASSIVE"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ACTIVE"


def test_the_pipeline_runs_numpys_blas_on_one_thread_and_restores_the_count(monkeypatch):
    """make_sample (and the simulate_to_tolerance / simulate it calls) runs with numpy's BLAS on one thread
    (datagen.threads.one_blas_thread), and gives the caller's thread count back."""
    import threadpoolctl

    import datagen.simulation.tolerance as tolerance
    from datagen.dataset import load_dataset_config, make_sample
    from datagen.threads import one_blas_thread
    from conftest import ROOT

    def blas_threads():
        return [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]

    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        if not before or max(before) < 2:
            pytest.skip(f"numpy's BLAS runs {before} threads here: nothing to limit")
        with one_blas_thread():
            assert blas_threads() == [1] * len(before)
        assert blas_threads() == before
        seen, make_result = [], tolerance.make_result

        def recording(*args, **kwargs):                  # the BLAS threads while the result is made
            seen.append(blas_threads())
            return make_result(*args, **kwargs)

        monkeypatch.setattr(tolerance, "make_result", recording)
        make_sample(load_dataset_config(ROOT / "configs" / "datasets" / "wall_smoke.yaml"), "train", 0)
        assert seen and all(threads == [1] * len(before) for threads in seen)
        assert blas_threads() == before
