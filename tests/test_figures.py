"""Tests of datagen.plot.figures: the sampling views of Scholes & Leach 2024, Figures 3 and 5, on the demo room.

Small sampling (6×6 lookins × 24×24 pixels) keeps this quick. Besides checking that both PNGs are written,
the Figure 3 data is checked against geometry and the laser-irradiance formula: the box on its shelf next
to the laser spot must cast a laser shadow on the corridor floor, exactly where a segment–box test says.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen import load_scene, resolve_config
from datagen.plot import write_sampling_figures
from datagen.plot.energy import laser_energy

DEMO = Path(__file__).resolve().parents[1] / "scene_library" / "demo_room.yaml"
SMALL = {"lookins": "6x6", "pixels": "24x24"}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MIN_PNG_BYTES = 10_000
"""A real figure with six painted panels is far above this; an empty or failed canvas is below it."""


@pytest.fixture(scope="module")
def demo():
    scene = load_scene(DEMO)
    return scene, resolve_config(scene, SMALL)


def _segment_hits_box(p: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Slab test: does segment p→q (rows of p, one q) cross the axis-aligned box [lo, hi]? (n, 3) → (n,)."""
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p) / d, (hi - p) / d
    parallel = d == 0
    inside = (p >= lo) & (p <= hi)
    t_near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
    t_far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
    return (t_far >= np.maximum(t_near, 0.0)) & (t_near <= 1.0)


def test_writes_both_figures(demo, tmp_path):
    scene, config = demo
    paths = write_sampling_figures(scene, config, tmp_path)
    assert [p.name for p in paths] == ["fig3_laser_energy.png", "fig5_lookin.png"]
    for p in paths:
        assert p.parent == tmp_path and p.is_file()
        data = p.read_bytes()
        assert data[:8] == PNG_MAGIC, p
        assert len(data) > MIN_PNG_BYTES, (p, len(data))


def test_box_casts_laser_shadow_on_corridor_floor(demo):
    scene, config = demo
    d = laser_energy(scene, config)
    box = next(o for o in scene.objects if o.name == "box")
    lo, hi = box.vertices.min(axis=0), box.vertices.max(axis=0)
    spot = np.asarray(scene.laser.spot, dtype=np.float64)
    # corridor floor (y < 1 m: only the box can stand between it and the spot) facing the spot
    floor = (d.label == "floor") & (d.points[:, 1] < 1.0) & (d.spot_emission > 0) & (d.cos_in > 0)
    assert floor.sum() > 500
    blocked = _segment_hits_box(d.points[floor], spot, lo, hi)
    # the shadow rays agree with the segment–box test (a grazing point may differ by a ray offset)
    assert np.mean(d.lit[floor] == ~blocked) > 0.995
    # on the floor beyond and below the box, seen from the spot, a good part lies in its shadow
    behind = floor & (d.points[:, 0] > 4.0) & (d.points[:, 1] > lo[1])
    shadowed = float(np.mean(~d.lit[behind]))
    assert behind.sum() > 100
    assert shadowed > 0.2, shadowed
    assert not np.any(d.irradiance[floor][~d.lit[floor]])        # shadowed points get no laser light


def test_laser_irradiance_is_lambertian_spot_over_r_squared(demo):
    """Panel (c): E = Φ·(ρ/π)·cosθ_l·cosθ_x/R² at every lit point (relay wall Lambertian, ρ = 1)."""
    scene, config = demo
    d = laser_energy(scene, config)
    spot = np.asarray(scene.laser.spot, dtype=np.float64)
    lit = d.lit
    w = (d.points[lit] - spot) / d.distance[lit, None]
    cos_l = w @ np.array([-1.0, 0.0, 0.0])                          # relay wall x = 6 faces −x
    expected = d.photons / np.pi * cos_l * d.cos_in[lit] / d.distance[lit] ** 2
    np.testing.assert_allclose(d.irradiance[lit], expected, rtol=1e-12)
    np.testing.assert_allclose(d.inv_square, 1.0 / d.distance ** 2, rtol=1e-12)
