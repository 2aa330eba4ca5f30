"""The laser-leg shadow map of the quadrature's pair loop (datagen/transport/quadrature/shadow.py) is conservative.

Every (sub-triangle centroid, laser point) pair whose segment passes through a candidate triangle grown by the
kernel's margin (an independent numpy segment-triangle test) must be marked; the map must also leave most clear
pairs unmarked (else the pair loop gains nothing), and a scene run with and without the map gives the same
envelope bit for bit.
"""
from __future__ import annotations

import numpy as np
import pytest

from datagen.transport.quadrature.kernel import occluder_planes
from datagen.transport.quadrature.shadow import (INSIDE_TOL, grown_triangles, row_span, shadow_flags, spot_buckets,
                                                 spot_plane)

MARGIN = 1e-3


def _segment_hits(x, s, tri, margin):
    """(P, S) bool: segment x[p] → s[q] crosses some triangle of ``tri`` (k, 3, 3) at a point within ``margin``
    of each of its edges' lines on their inner side (the kernel's exact test, written independently)."""
    hits = np.zeros((len(x), len(s)), dtype=bool)
    for t in tri:
        n = np.cross(t[1] - t[0], t[2] - t[0])
        n /= np.linalg.norm(n)
        d0 = (x - t[0]) @ n                                  # (P,)
        d1 = (s - t[0]) @ n                                  # (S,)
        cross = (d0[:, None] * d1[None, :]) < 0
        tt = d0[:, None] / np.where(cross, d0[:, None] - d1[None, :], 1.0)
        p = x[:, None, :] + tt[..., None] * (s[None, :, :] - x[:, None, :])       # (P, S, 3)
        inside = np.ones(p.shape[:2], dtype=bool)        # within ``margin`` of every edge's line, inner side
        for i in range(3):
            a, b = t[i], t[(i + 1) % 3]
            inward = np.cross(n, b - a)
            inside &= (p - a) @ (inward / np.linalg.norm(inward)) >= -margin
        hits |= cross & inside
    return hits


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_pair_a_grown_occluder_may_block_is_marked(seed):
    rng = np.random.default_rng(seed)
    # laser points: a 24 × 24 grid on the plane x = 0 (normal +x), 2 m square
    g = np.linspace(-1, 1, 24)
    spots = np.stack(np.broadcast_arrays(0.0, g[:, None], g[None, :]), axis=-1).reshape(-1, 3)
    normals = np.tile([1.0, 0.0, 0.0], (len(spots), 1))
    # occluders: 30 random triangles 0.3–1.2 m from the wall; centroids 0.5–1.5 m, half of them "closed"
    centre = rng.uniform([0.3, -0.6, -0.6], [1.2, 0.6, 0.6], size=(30, 1, 3))
    tri = centre + rng.normal(scale=0.12, size=(30, 3, 3))
    x = rng.uniform([0.5, -0.8, -0.8], [1.5, 0.8, 0.8], size=(60, 3))
    normal = rng.normal(size=(60, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    closed = (np.arange(60) % 2).astype(np.uint8)
    plane, edges = occluder_planes(tri)
    grown = grown_triangles(tri, 2 * MARGIN)
    n, o = spot_plane(spots, normals)
    axes = np.stack([spots.mean(axis=0), [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    uv = (spots - axes[0]) @ axes[1:].T
    buckets, ptr, col = spot_buckets(uv)
    flags = np.zeros((len(spots), 60), dtype=np.uint8)
    one = np.zeros(1, dtype=np.int64)
    occ = (True, np.array([0, 1]), one, np.array([30]), np.zeros((1, 4)), np.array([0, 1]), np.array([0, 30]),
           np.zeros((1, 4)), np.arange(30), plane, edges, MARGIN, np.zeros(1, dtype=np.uint8))      # OCC: one run
    shadow_flags((x, normal, closed, np.zeros(60, dtype=np.int64)), occ, grown,
                 (np.append(n, o), axes, uv, spots.mean(axis=0),
                  float(np.linalg.norm(spots - spots.mean(0), axis=1).max()), buckets, ptr, col), flags)
    hits = _segment_hits(x, spots, tri, MARGIN)
    flags = flags.T                                                # (centroid, laser point) as hits
    front = ((spots[None] - x[:, None]) * normal[:, None]).sum(-1) > 0
    needed = hits & (front | ~closed.astype(bool)[:, None])
    assert needed.sum() > 200                                     # the scene does block legs
    assert not (needed & (flags == 0)).any(), np.argwhere(needed & (flags == 0))[:5]
    clear = ~hits & (front | ~closed.astype(bool)[:, None])
    marked_clear = (flags[clear] == 1).mean()
    assert marked_clear < 0.1, marked_clear                        # grown by 2 mm: a thin band only


def test_row_span_holds_every_point_near_the_polygon_in_its_strip():
    """Thin convex polygons (the slivers a triangle seen nearly edge-on projects to) and points within INSIDE_TOL of
    them: each point's u lies in the span row_span gives for any strip holding its v (the rows the map visits)."""
    rng = np.random.default_rng(5)
    misses = 0
    for _ in range(300):
        angle = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 7)))
        radii = rng.uniform(0.1, 2.0) * np.array([1.0, rng.choice([1e-9, 1e-4, 0.3, 1.0])])
        rot = rng.uniform(0, np.pi)
        c, s_ = np.cos(rot), np.sin(rot)
        xy = np.stack([radii[0] * np.cos(angle), radii[1] * np.sin(angle)], axis=1) @ np.array([[c, s_], [-s_, c]])
        pu, pv = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        k = len(pu)
        # points on the edges (half of them at a vertex), pushed out by 0.999 INSIDE_TOL along the edge's normal
        j = rng.integers(0, k, 200)
        w = np.where(rng.uniform(size=200) < 0.5, 0.0, rng.uniform(0, 1, 200))
        e = xy[(j + 1) % k] - xy[j]
        out = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
        out *= np.sign(np.einsum("ij,ij->i", out, xy[j] - xy.mean(axis=0)))[:, None]     # away from the centre
        q = xy[j] + w[:, None] * e + 0.999 * INSIDE_TOL * out
        for u, v in q:
            height = rng.uniform(1e-6, 0.5)
            lo_v = v - rng.choice([0.0, height, rng.uniform(0, height)])     # a strip holding v (v on its edge)
            lo, hi = row_span(pu, pv, k, lo_v, lo_v + height, 0.0)
            misses += not (lo <= u <= hi)
        assert row_span(pu, pv, k, pv.max() + 1.0, pv.max() + 2.0, 0.0)[0] == np.inf   # a strip it misses
    assert misses == 0


def test_grown_triangle_moves_every_edge_out_by_the_distance():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 0.2, 0]], [[0, 0, 0], [1, 0, 1], [0, 1, 0]]])
    plane, edges = occluder_planes(tri)
    grown = grown_triangles(tri, 0.01)
    for k in range(2):
        for j in range(3):             # the grown triangle's corners lie 0.01 m outside the two edges they join
            corner = grown[k, (j + 1) % 3]
            inner = edges[k, :, :3] @ corner - edges[k, :, 3]
            assert inner[j] == pytest.approx(-0.01, abs=1e-12)
            assert inner[(j + 1) % 3] == pytest.approx(-0.01, abs=1e-12)
        assert np.abs(grown[k] @ plane[k, :3] - plane[k, 3]).max() < 1e-12
    assert np.isnan(grown_triangles(np.zeros((1, 3, 3)), 0.01)).all()


@pytest.mark.parametrize("name", ["wall_smoke", "confocal_smoke"])
def test_a_scan_with_the_map_equals_the_scan_without(monkeypatch, name):
    from datagen.dataset import load_dataset_config, make_sample
    import datagen.transport.quadrature.primary as primary
    config = load_dataset_config(f"configs/datasets/{name}.yaml")
    calls = []
    real = primary.shadow_flags
    monkeypatch.setattr(primary, "shadow_flags", lambda *a: (calls.append(1), real(*a))[1])
    with_map = make_sample(config, "train", 1).arrays
    assert calls                                                   # the map was built and used
    monkeypatch.setattr(primary, "SHADOW_MAP", False)
    without = make_sample(config, "train", 1).arrays
    for key in ("envelope", "counts", "envelope_error"):
        assert np.array_equal(with_map[key], without[key]), key
