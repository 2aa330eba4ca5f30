"""Sampling: hemisphere maps, pdfs, and the camera's per-pixel solid angles."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.sampling import square_to_hemisphere
from datagen.sampling.directions import stratified_grid
from datagen.sampling.lookins import camera_solid_angle


def pixel_solid_angle(i, j, l, p, sub=40):
    """Solid angle of camera pixel (i, j) from the map's Jacobian |∂ω/∂u × ∂ω/∂v| on a sub-grid."""
    s = (np.arange(sub) + 0.5) / sub
    t = (np.arange(sub) + 0.3) / sub        # off the map's diagonal seams, where the derivative has a kink
    u = (i + s[:, None]) / l + 0 * t[None]
    v = (j + t[None, :]) / p + 0 * s[:, None]
    h = 1e-6
    w0, _ = square_to_hemisphere(u, v, "uniform")
    du, _ = square_to_hemisphere(u + h, v, "uniform")
    dv, _ = square_to_hemisphere(u, v + h, "uniform")
    jac = np.linalg.norm(np.cross((du - w0) / h, (dv - w0) / h), axis=-1)
    return float(jac.mean() / (l * p))


def test_camera_pixels_have_equal_known_solid_angles_summing_to_2pi():
    l, p = 60, 60
    assert camera_solid_angle((l, p)) * l * p == pytest.approx(2 * np.pi, rel=1e-15)
    rng = np.random.default_rng(1)
    pixels = [(0, 0), (29, 30), (59, 59), (0, 59)] + [tuple(rng.integers(0, 60, 2)) for _ in range(6)]
    for i, j in pixels:   # corners (pole/edge of the disk map) included
        assert pixel_solid_angle(i, j, l, p) == pytest.approx(camera_solid_angle((l, p)), rel=2e-3)


@pytest.mark.parametrize("pdf", ["cosine", "uniform"])
def test_hemisphere_pdf_integrates_cosine_to_pi(pdf):
    uv = stratified_grid(200, 200, np.random.default_rng(0))[0]
    w, density = square_to_hemisphere(uv[:, 0], uv[:, 1], pdf)
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0) and np.all(w[:, 2] >= 0)
    estimate = np.mean(w[:, 2] / density)             # ∫ cos θ dω = π
    assert estimate == pytest.approx(np.pi, rel=1e-3 if pdf == "uniform" else 1e-12)


def test_stratified_grid_one_point_per_cell():
    g = stratified_grid(7, 5, np.random.default_rng(3), count=2)
    assert g.shape == (2, 35, 2)
    cells = np.floor(g * np.array([7, 5])).astype(int)
    for c in cells:
        assert len({tuple(x) for x in c}) == 35
    assert np.allclose(stratified_grid(2, 2, None)[0], [[0.25, 0.25], [0.25, 0.75], [0.75, 0.25], [0.75, 0.75]])
