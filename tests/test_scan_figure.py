"""The scan-sample figure of ``datagen inspect`` (datagen/dataset/figures.py) labels its axes with the right units."""
import numpy as np
from matplotlib.figure import Figure

from datagen.dataset.figures import plot_scan_sample


def _sample(depth: np.ndarray) -> dict:
    rng = np.random.default_rng(0)
    return {"envelope": rng.random((4, 5, 16)) * 1e-4, "wall_depth": depth.astype(np.float32)}


def _panel(fig: Figure, title: str):
    return next(ax for ax in fig.axes if ax.get_title() == title)


def test_scan_sum_panel_is_in_photons_per_pulse_per_bin():
    edges = np.linspace(0.0, 16e-9, 17)
    fig = plot_scan_sample(_sample(np.full((4, 5), 0.3)), edges, fig=Figure())
    ax = _panel(fig, "envelope, scan sum")
    assert ax.get_ylabel() == "photons / pulse / bin" and ax.get_xlabel() == "time (ns)"
    assert ax.get_yscale() == "log"


def test_empty_wall_depth_is_a_blank_panel_with_a_fixed_colour_bar():
    edges = np.linspace(0.0, 16e-9, 17)
    fig = plot_scan_sample(_sample(np.zeros((4, 5))), edges, fig=Figure())
    image = _panel(fig, "label: wall_depth").images[0]
    assert image.get_clim() == (-0.1, 0.1)
    assert np.all(np.ma.getmaskarray(image.get_array()) | np.isnan(image.get_array().filled(np.nan)))
    colorbars = [ax for ax in fig.axes if ax.get_ylabel() == "m"]
    assert len(colorbars) == 1 and colorbars[0].get_ylim() == (-0.1, 0.1)
