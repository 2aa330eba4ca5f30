"""The lookin estimator (``estimator: {kind: lookin}``): the paper's sampler (Scholes & Leach 2024, docs/physics.md §3).

Converges to: the primary L_p (unbiased with jittered lookins) and, with ``secondary: full | exact``, the
secondary L_s; ``secondary: optimized`` (the paper's top-K) is a biased fraction of L_s and does not converge to it.
Cost: N lookins × a 180° camera of l × p pixels each; the relative L2 error falls as ≈ N^−0.57 (primary) and
≈ N^−0.66 (secondary; 1.25 % at 45 × 45 lookins in the demo room, docs/physics.md §3.4, docs/accuracy.md). Its counted
work, in nominal seconds, is what a dataset's ``cost_cap`` bounds (:meth:`LookinSampler.nominal_seconds`).
Pick it to reproduce the paper's figures and settings (lookins, pixels, top-K); for datasets the area sampler
reaches the same error sooner.

- :mod:`.estimator`: :class:`LookinSampler` (registered as ``"lookin"``), :class:`LookinSettings`, the options
  block :class:`~.estimator.LookinOptions`, the counters :class:`~.estimator.LookinStats`.
- :mod:`.secondary`: :class:`~.secondary.LookinSecondary`, the secondary paths between pairs of observed points
  (full, exact with the dark middle vertices, optimized top-K), a collaborator each :class:`LookinSampler` holds.
"""
from .estimator import LookinSampler, LookinSettings

__all__ = ["LookinSampler", "LookinSettings"]
