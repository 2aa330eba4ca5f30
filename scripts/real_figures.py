"""The figures of docs/real.md: a real capture of the Stanford LCT release against its simulation by
``datagen simulate scene_library/stanford_*.yaml --like STORE``.

Usage: PYTHONPATH=. python scripts/real_figures.py REAL_STORE SIM_STORE [REAL_STORE SIM_STORE ...]

Prints per pair: the hidden counts in the window the release's README uses (bins 600–1899 of 4 ps, less the per-bin
floor of bins 1900–2047), for the real counts and the simulated expected envelope (its scale is the model's: compare
ratios between captures, not values), and the second round trip (chart → wall → chart) of each as
:func:`datagen.analysis.second_round_trip.second_round_trip` measures it (its size relative to the main return and
its median arrival, the main return's tail taken out by a baseline fitted on both sides; docs/real.md), the real one
with its counting noise from Poisson redraws.
"""
from __future__ import annotations

import sys

import numpy as np

ECHO_DRAWS = 100              # Poisson redraws of the real counts for the echo's counting noise


def hidden_counts(data: np.ndarray) -> float:
    """The release's hidden counts of a scan (..., K), scan-summed
    (:func:`datagen.analysis.hidden_ratio.release_hidden_counts`)."""
    from datagen.analysis.hidden_ratio import release_hidden_counts

    return release_hidden_counts(data.reshape(-1, data.shape[-1]).sum(axis=0))


def main(pairs: list[str]) -> None:
    from datagen.analysis.second_round_trip import second_round_trip
    from datagen.io import read_result

    for real_path, sim_path in zip(pairs[0::2], pairs[1::2]):
        real, sim = read_result(real_path), read_result(sim_path)
        r, s = np.asarray(real.counts, float), np.asarray(sim.envelope, float)
        print(f"{real_path}: hidden counts real {hidden_counts(r):.6g}, sim (expected) {hidden_counts(s):.6g}")
        for what, d, edges in (("real", r, real.time_edges), ("sim", s, sim.time_edges)):
            try:
                m = second_round_trip(d, edges, draws=ECHO_DRAWS if what == "real" else 0,
                                      rng=np.random.default_rng(0))
            except ValueError as err:
                print(f"  {what}: no second round trip measured ({err})")
                continue
            noise = (f" (counting noise {m.size_sd:.3%}, {m.time_sd * 1e12:.0f} ps; baseline chi2/dof "
                     f"{m.baseline_chi2:.2f})" if what == "real" else "")
            print(f"  {what}: main return {m.main_time * 1e9:.3f} ns; second round trip {m.size:.3%} of the main "
                  f"return, median arrival {m.time * 1e9:.3f} ns{noise}; its bump's peak {m.peak_size:.3%} at "
                  f"{m.peak_time * 1e9:.3f} ns")


if __name__ == "__main__":
    if len(sys.argv) < 3 or len(sys.argv) % 2 != 1:
        sys.exit(__doc__)
    main(sys.argv[1:])
