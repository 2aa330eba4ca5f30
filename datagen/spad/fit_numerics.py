"""Numerical optimisation and covariances of datagen/spad/fit.py's detector fit: Newton polishing with
central-difference derivatives, the inverse observed information and the sandwich covariance of a
quasi-likelihood (its score's variance from simulated histograms), and the likelihood-ratio interval of a scan."""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["NEWTON_STEPS", "NEWTON_DECREMENT", "REJECTED", "newton", "gradient", "hessian", "inverse_covariance",
           "sandwich_covariance", "profile_interval", "with_coordinate", "PROFILE_REFIT_STEPS", "PROFILE_STOP_POINTS",
           "profile_walk"]


REJECTED = 1e300
"""The −log L of a parameter point the fit rejects (outside the searched dead times, or a model that fails there)."""

NEWTON_STEPS = 20
"""Newton iterations (numerical gradient and Hessian) polishing the Nelder–Mead optimum."""

NEWTON_DECREMENT = 1e-4
"""Converged when the Newton decrement gᵀH⁻¹g/2 (the −log L still to gain) is below this: a parameter change of
√(2·1e-4) ≈ 0.014 standard deviations at most."""


PROFILE_REFIT_STEPS = 6
"""Newton steps (the optimum's Hessian held, the gradient recomputed) refitting the other parameters at each point of
:func:`profile_walk`."""

PROFILE_STOP_POINTS = 3
""":func:`profile_walk` stops on a side after this many consecutive points above its stop level (the free-running
dead time's profile has bumps of 1-2 in −log L a few bins wide, which one point above the level would stop at)."""


def newton(f, x: np.ndarray, steps: list[float]) -> tuple[np.ndarray, np.ndarray, bool]:
    """Newton's method with step halving from ``x``: (optimum, Hessian there, converged); see NEWTON_DECREMENT.

    ``f`` maps float64 (k,) to a float; ``steps`` (k,) are the central-difference steps of :func:`gradient` and
    :func:`hessian`. Returns float64 (k,), float64 (k, k), bool."""
    fx = f(x)
    for _ in range(NEWTON_STEPS):
        g = gradient(f, x, steps)
        hess = hessian(f, x, steps, fx)
        w, v = _descent_eigh(hess)
        dx = -(v @ ((v.T @ g) / w))
        decrement = float(-(g @ dx)) / 2
        if decrement < NEWTON_DECREMENT:
            return x, hess, True
        x, fx, moved = _halving_step(f, x, fx, dx, 1e-4)
        if not moved:              # no decrease along the Newton step: the noise floor of −log L
            return x, hess, decrement < 100 * NEWTON_DECREMENT
    return x, hessian(f, x, steps, fx), False


def _descent_eigh(hess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (clipped to ≥ 1e-8 × the largest |eigenvalue|, so a step with them is a descent direction) and
    eigenvectors of the symmetrised (k, k) Hessian: float64 (k,), (k, k)."""
    w, v = np.linalg.eigh(0.5 * (hess + hess.T))
    return np.maximum(w, 1e-8 * max(float(np.abs(w).max()), 1e-300)), v


def _halving_step(f, x: np.ndarray, fx: float, dx: np.ndarray, floor: float) -> tuple[np.ndarray, float, bool]:
    """The first of x + dx, x + dx/2, … (step factor above ``floor``) that lowers f below fx: (point, f there,
    moved); (x, fx, False) when none does."""
    t = 1.0
    while t > floor:
        fn = f(x + t * dx)
        if fn < fx:
            return x + t * dx, fn, True
        t *= 0.5
    return x, fx, False


def gradient(f, x: np.ndarray, steps: list[float]) -> np.ndarray:
    """Central-difference derivatives of ``f`` at ``x`` (k,) with per-coordinate ``steps``: float64 (k,) for a
    scalar ``f`` (its gradient), (n, k) for an ``f`` with (n,) values (its Jacobian)."""
    columns = []
    for i, h in enumerate(steps):
        e = np.zeros(x.size)
        e[i] = h
        columns.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(columns, axis=-1).astype(np.float64, copy=False)


def hessian(f, x: np.ndarray, steps: list[float], f0: float | None = None) -> np.ndarray:
    """Central-difference Hessian of ``f`` at ``x`` (k,): float64 (k, k); datagen/spad/fit.py steps 1e-3 in log/logit
    coordinates and 1e-2 bins for positions. ``f0`` = f(x) when known."""
    k = x.size
    hs = np.asarray(steps, dtype=np.float64)
    f0 = f(x) if f0 is None else f0
    out = np.zeros((k, k))
    for i in range(k):
        ei = np.zeros(k)
        ei[i] = hs[i]
        out[i, i] = (f(x + ei) - 2 * f0 + f(x - ei)) / hs[i] ** 2
        for j in range(i + 1, k):
            ej = np.zeros(k)
            ej[j] = hs[j]
            v = (f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej)) / (4 * hs[i] * hs[j])
            out[i, j] = out[j, i] = v
    return out


def inverse_covariance(hess: np.ndarray) -> tuple[np.ndarray, set[int]]:
    """Covariance = H⁻¹ on the well-determined subspace of the (k, k) Hessian: float64 (k, k), and the indices
    whose variance is unbounded (H singular or not positive along them)."""
    w, v = np.linalg.eigh(0.5 * (hess + hess.T))
    scale = max(float(np.abs(w).max()), 1e-300)
    good = w > 1e-10 * scale
    inv_w = np.where(good, 1.0 / np.where(good, w, 1.0), 0.0)
    cov = (v * inv_w) @ v.T
    singular = {i for i in range(hess.shape[0]) if np.any((~good) & (np.abs(v[i]) > 0.1))}
    return cov, singular


def sandwich_covariance(h_inv: np.ndarray, x: np.ndarray, steps: list[float], mean: Callable[[np.ndarray], np.ndarray],
                        replicates: np.ndarray, n: int, m: int) -> np.ndarray:
    """Sandwich covariance H⁻¹VH⁻¹ of a Poisson quasi-likelihood fit whose bins are not independent Poisson.

    The quasi-score of −log L = Σ(μ − h log μ) is U = Jᵀ(1 − h/μ), J = ∂μ/∂x, so V = Var(U) =
    Jᵀdiag(1/μ)·Cov(h)·diag(1/μ)J. Cov(h) comes from simulated histograms of m cycles and is scaled to the data's n
    cycles (the covariance of a stationary count grows linearly in cycles; the start-up transient of each
    replicate adds O(1/m)).

    Args:
        h_inv: float64 (k, k) inverse Hessian of −log L at the optimum (:func:`inverse_covariance`).
        x: float64 (k,) the optimum in the fit coordinates; steps: (k,) central-difference steps for J.
        mean: x → float64 (bins,) expected histogram of n cycles.
        replicates: (R, bins) counts of R independent histograms of m cycles drawn from the fitted model (R > k).
        n, m: cycles of the data and of each replicate.
    Returns:
        float64 (k, k) covariance of x̂ in the fit coordinates.
    """
    mu = np.maximum(mean(x), 1e-300)
    jac = gradient(mean, x, steps)                      # (bins, k)
    score = (replicates / mu) @ jac                     # (R, k); the constant Jᵀ1 drops out of the covariance
    v = np.atleast_2d(np.cov(score, rowvar=False)) * (n / m)
    return h_inv @ v @ h_inv


def profile_interval(grid: np.ndarray, delta: np.ndarray, z: float) -> tuple[float, float]:
    """(low, high) fit coordinates: the hull of the likelihood-ratio set {delta ≤ z²/2} on the evenly spaced
    ``grid`` (``delta``: the scaled profile, −log L above its optimum, 0 at the middle; the set may have several
    pieces where the profile has several dips), each end linear between the grid points around its crossing;
    the grid's end where the profile stays below (the caller reports the span)."""
    level = 0.5 * z * z
    inside = np.flatnonzero(delta <= level)
    lo_k, hi_k = int(inside[0]), int(inside[-1])
    step = grid[1] - grid[0]
    lo = grid[lo_k] if lo_k == 0 else grid[lo_k] - step * (level - delta[lo_k]) / (delta[lo_k - 1] - delta[lo_k])
    hi = (grid[hi_k] if hi_k == grid.size - 1
          else grid[hi_k] + step * (level - delta[hi_k]) / (delta[hi_k + 1] - delta[hi_k]))
    return float(lo), float(hi)


def with_coordinate(x: np.ndarray, i: int, value: float) -> np.ndarray:
    """A copy of the fit coordinates ``x`` (k,) float64 with coordinate ``i`` set to ``value``."""
    y = np.array(x, dtype=np.float64)
    y[i] = value
    return y


def _refit(f, y: np.ndarray, fy: float, others: np.ndarray, h_inv: np.ndarray, steps: np.ndarray
           ) -> tuple[np.ndarray, float]:
    """Minimise f over the coordinates ``others`` from y: Newton steps with the fixed inverse Hessian ``h_inv``
    (the optimum's), the gradient recomputed, step halving; at most PROFILE_REFIT_STEPS steps."""
    def sub(z):
        w = y.copy()
        w[others] = z
        return f(w)

    for _ in range(PROFILE_REFIT_STEPS):
        g = gradient(sub, y[others], list(steps))
        dx = np.zeros(y.size)
        dx[others] = -(h_inv @ g)
        if float(g @ dx[others]) / -2 < NEWTON_DECREMENT:
            break
        y, fy, moved = _halving_step(f, y, fy, dx, 1e-3)
        if not moved:
            break
    return y, fy


def profile_walk(f, x: np.ndarray, i: int, hess: np.ndarray, steps: list[float], step: float, stop: float,
                 bounds: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, tuple[bool, bool]]:
    """Profile of f (−log L) along coordinate ``i``: the other coordinates refitted at each point.

    From the optimum ``x`` (k,) the walk steps ``step`` at a time each way; each point starts from the previous
    one moved along the ridge direction of the Hessian (−H_oo⁻¹H_oi per unit of coordinate i: the profile to
    second order) and is refitted by :func:`_refit`. A side ends after PROFILE_STOP_POINTS consecutive points
    more than ``stop`` above f(x), or at ``bounds`` (the coordinate's searched range).

    Args:
        f: float64 (k,) → float; x: float64 (k,) the optimum; hess: float64 (k, k) its Hessian; steps: (k,)
            central-difference steps; step: > 0, grid spacing in coordinate i; stop: −log L rise that ends a side;
            bounds: (low, high) of coordinate i.
    Returns:
        (grid, delta, (low_open, high_open)): float64 (n,) evenly spaced coordinate values including x[i], the
        profile's rise above f(x) there (may dip below 0 where the walk finds a better point), and whether each
        side ended at its bound without rising above ``stop``.
    """
    k = x.size
    others = np.array([j for j in range(k) if j != i], dtype=np.int64)
    w, v = _descent_eigh(hess[np.ix_(others, others)])
    h_inv = (v / w) @ v.T
    ridge = -(h_inv @ hess[others, i])
    sub_steps = np.asarray(steps, dtype=np.float64)[others]
    f0 = f(x)
    points = {0: f0}
    open_ends = []
    for direction in (-1, 1):
        y, above, n = x.copy(), 0, 0
        while above < PROFILE_STOP_POINTS:
            n += 1
            t = x[i] + direction * n * step
            if not bounds[0] <= t <= bounds[1]:
                break
            y = y.copy()
            y[i] = t
            y[others] += ridge * direction * step
            y, points[direction * n] = _refit(f, y, f(y), others, h_inv, sub_steps)
            above = above + 1 if points[direction * n] - f0 > stop else 0
        open_ends.append(above < PROFILE_STOP_POINTS)
    keys = sorted(points)
    grid = x[i] + step * np.array(keys, dtype=np.float64)
    return grid, np.array([points[j] for j in keys]) - f0, (open_ends[0], open_ends[1])
