"""Figure for docs/detector.md: one envelope under low flux, pile-up and dead time.

``python benchmarks/plot_detector_regimes.py`` writes ``docs/detector_regimes.png``.  Everything is an exact
expected histogram (no noise), so the differences are the detector models, not sampling.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from datagen.spad import DetectorConfig, coates, expected_histogram, rates_from_envelope  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "docs" / "detector_regimes.png"
BINS, BIN_WIDTH = 500, 100e-12          # 50 ns window = one 20 MHz period
N_CYCLES = 200_000


def envelope(photons_per_pulse: float) -> np.ndarray:
    """Gaussian return (σ = 0.6 ns) at 20 ns carrying ``photons_per_pulse`` detected photons per pulse."""
    t = (np.arange(BINS) + 0.5) * BIN_WIDTH
    g = np.exp(-0.5 * ((t - 20e-9) / 0.6e-9) ** 2)
    return photons_per_pulse * g / g.sum()


def config(model: str, **kw) -> DetectorConfig:
    return DetectorConfig(repetition_rate="20MHz", n_cycles=N_CYCLES, bin_width=BIN_WIDTH, pde=0.3,
                          ambient_rate="2MHz", dcr="100cps", model=model, **kw)


def main() -> None:
    t_ns = (np.arange(BINS) + 0.5) * BIN_WIDTH * 1e9
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), constrained_layout=True)
    cases = [("low flux: 0.02 photons/pulse", 0.02), ("pile-up: 3 photons/pulse", 3.0),
             ("dead time: 3 photons/pulse", 3.0)]
    for ax, (title, photons) in zip(axes, cases):
        env = envelope(photons)
        poisson_cfg = config("poisson")
        rates = rates_from_envelope(env, poisson_cfg)
        ideal = expected_histogram(rates, poisson_cfg)
        ax.plot(t_ns, ideal, color="0.6", lw=3, label="poisson (ideal, no pile-up)")
        if title.startswith("dead"):
            for model, kw, colour in [("pile_up", {}, "C0"),
                                      ("multi_stop", dict(dead_time=10e-9), "C2"),
                                      ("free_running", dict(dead_time=77e-9), "C3")]:
                c = config(model, **kw)
                label = model + (f", τ = {kw['dead_time'] * 1e9:.0f} ns" if kw else "")
                ax.plot(t_ns, expected_histogram(rates, c), color=colour, lw=1.4, label=label)
        else:
            pile_cfg = config("pile_up")
            piled = expected_histogram(rates, pile_cfg)
            ax.plot(t_ns, piled, color="C0", lw=1.4, label="pile_up (first photon)")
            est, valid = coates(piled, N_CYCLES)
            ax.plot(t_ns[valid], N_CYCLES * est[valid], "k--", lw=1, label="Coates-corrected pile_up")
            if photons < 0.1:  # at low flux every model agrees
                fr = config("free_running", dead_time=77e-9)
                ax.plot(t_ns, expected_histogram(rates, fr), color="C3", lw=1, label="free_running, τ = 77 ns")
        ax.set_title(title)
        ax.set_xlabel("time in cycle [ns]")
        ax.set_ylabel(f"expected counts in {N_CYCLES:,} cycles")
        ax.set_yscale("log")
        ax.set_xlim(0, 50)
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle("Same Gaussian return on a constant background (20 MHz, 100 ps bins, PDE·ambient = 0.6 Mcps)")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
