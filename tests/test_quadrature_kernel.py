"""The compiled quadrature primary (datagen.transport.quadrature.kernel / .primary, datagen.timing.tent_kernel)
against the numpy path it replaces (datagen.transport.quadrature, EnvelopeAccumulator.add_tents)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import njit

import datagen
from datagen.dataset import load_dataset_config, sample_setup
from datagen.scene import CaptureSpec
from datagen.timing import EnvelopeAccumulator, Irf, TimeAxis
from datagen.timing.tent_kernel import deposit_tent, sort3
from datagen.transport.quadrature import estimator as quadrature

ROOT = Path(__file__).resolve().parents[1]


@njit
def _deposit_all(coord, w, comp, n_fine, min_nodes, hist, curv, total, beyond, bound):
    for i in range(len(w)):
        c0, c1, c2 = sort3(coord[i, 0], coord[i, 1], coord[i, 2])
        deposit_tent(c0, c1, c2, w[i], comp[i], n_fine, min_nodes, hist, curv, total, beyond, bound)


@pytest.mark.parametrize("min_nodes", [4.0, np.inf])
def test_compiled_tent_deposits_equal_add_tents(min_nodes):
    """Tents of every kind (sub-node sides, zero span, hundreds of nodes, cut by either end of the grid, wholly
    outside it) deposited one by one by deposit_tent give add_tents' fine histogram, total and outside weight
    to 1e-12 (per-node form only with min_nodes = inf, curvature form for wide tents with 4); every node they write
    lies within the rows' bounds, which the fold and binning read only (the same bits as whole rows)."""
    axis, irf = TimeAxis(t_start=0.0, bin_width=100e-12, n_bins=64), Irf(fwhm=100e-12)
    ref = EnvelopeAccumulator(axis, irf, 3)
    new = ref.spawn()
    ref.curvature_min_nodes = new.curvature_min_nodes = min_nodes
    rng = np.random.default_rng(5)
    n = 4000
    mid = rng.uniform(-1e-9, 7.5e-9, n)                               # some beyond either end of the 6.4 ns axis
    span = rng.choice([0.0, 1e-15, 3e-12, 2e-11, 1e-10, 2e-9], n) * rng.uniform(0.5, 1.0, n)
    times = mid[:, None] + span[:, None] * rng.uniform(-0.5, 0.5, (n, 3))
    times[::7, 1] = times[::7, 0]                                     # a zero-width side
    w = rng.uniform(0.1, 2.0, n)
    comp = rng.integers(0, 3, n)
    ref.add_tents(times, w, comp)
    g = new.tent_grid()
    coord = (times - g.t_start) / g.fine_step + g.shift
    _deposit_all(coord, w, comp.astype(np.int64), g.n_fine, g.min_nodes, g.hist, g.curvature, g.total, g.beyond,
                 g.bound)
    written = (g.hist != 0).reshape(3, -1) | (g.curvature != 0).reshape(3, -1)
    nodes = np.arange(g.n_fine)
    assert written.any(axis=1).all()
    assert not (written & ((nodes < g.bound[:, :1]) | (nodes >= g.bound[:, 1:]))).any()
    one = ref.spawn().tent_grid()                                     # one wide tent: a narrow bound, two empty rows
    _deposit_all(np.array([[300.2, 310.7, 340.1]]), np.ones(1), np.ones(1, dtype=np.int64), one.n_fine, 4.0,
                 one.hist, one.curvature, one.total, one.beyond, one.bound)
    assert one.bound.tolist() == [[one.n_fine, 0], [299, 350], [one.n_fine, 0]]
    a, b = new.fine_histogram(), ref.fine_histogram()
    assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    np.testing.assert_allclose(new.total_weight(), ref.total_weight(), rtol=1e-13)
    np.testing.assert_allclose(new.outside(), ref.outside(), rtol=1e-10)
    assert 0 < ref.outside().sum() < w.sum()                          # the cases did reach beyond the grid


def _room(points: int = 8):
    """Confocal room sample 1 of configs/datasets/confocal.yaml (a box and a pillar that shadow hidden walls, a
    Phong mesh), on a points × points sub-scan of its pixel size."""
    config = load_dataset_config(ROOT / "configs/datasets/confocal.yaml")
    scene, sim = sample_setup(config, "train", 1)
    grid = scene.capture.laser_grid
    n = grid.points[0]
    scene.capture = CaptureSpec(**{**scene.capture.__dict__, "laser_grid": {
        "center": list(grid.center), "size": [grid.size[0] * points / n, grid.size[1] * points / grid.points[1]],
        "points": [points, points]}})
    return scene, sim


def _run(scene, sim, monkeypatch, **attrs):
    made = []
    original = quadrature.Quadrature.__init__

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        for k, v in attrs.items():
            setattr(self, k, v)
        made.append(self)

    monkeypatch.setattr(quadrature.Quadrature, "__init__", init)
    result = datagen.simulate(scene, sim)
    monkeypatch.undo()
    return result, made[0]


def test_compiled_primary_equals_the_numpy_path(monkeypatch):
    """A confocal room with occluders and a Phong object: the compiled primary with a shadow ray for every lit
    pair equals the numpy path to 1e-9 (relative L2 of the envelope, and the error estimate); with its exact
    segment tests it differs only where Embree's float32 rays leak through edges (≤ 1e-6) and casts a small
    fraction of the rays."""
    scene, sim = _room()
    ref, q_ref = _run(scene, sim, monkeypatch, use_compiled=False)
    rays, q_rays = _run(scene, sim, monkeypatch, segment_tests=False)
    fast, q_fast = _run(scene, sim, monkeypatch)
    assert q_ref.compiled_case() and q_ref.settings.shadow_spot
    assert (scene.materials.kind[q_ref.cell_object] == 2).any()         # a Phong hidden surface is covered
    norm = np.linalg.norm(ref.envelope)
    assert norm > 0
    assert np.linalg.norm(rays.envelope - ref.envelope) <= 1e-9 * norm
    assert abs(rays.attrs["error"]["rel_l2"] - ref.attrs["error"]["rel_l2"]) <= 1e-9 * ref.attrs["error"]["rel_l2"]
    assert np.linalg.norm(fast.envelope - ref.envelope) <= 1e-6 * norm
    assert abs(q_fast.stats.tents - q_ref.stats.tents) < 1e-3 * q_ref.stats.tents
    assert q_rays.stats.tents == q_ref.stats.tents
    assert q_fast.stats.shadow_rays < 0.05 * q_rays.stats.shadow_rays


def test_compiled_primary_with_attenuation_equals_the_numpy_path(monkeypatch):
    """The same room in a medium (μ = 0.2 /m: e^{−μ·path} ≈ 0.1–0.3 over its paths): the compiled primary with a
    shadow ray for every lit pair equals the numpy path to 1e-9, and the medium did dim the envelope."""
    scene, sim = _room()
    dump = sim.model_dump(exclude_unset=True)
    hazy = type(sim).model_validate({**dump, "attenuation": 0.2,
                                     "effects": {**dump.get("effects", {}), "attenuation": True}})
    ref, q_ref = _run(scene, hazy, monkeypatch, use_compiled=False)
    rays, q_rays = _run(scene, hazy, monkeypatch, segment_tests=False)
    clear, _ = _run(scene, sim, monkeypatch, segment_tests=False)
    assert q_ref.settings.attenuation == 0.2 and q_rays.compiled_case()
    norm = np.linalg.norm(ref.envelope)
    assert np.linalg.norm(rays.envelope - ref.envelope) <= 1e-9 * norm
    assert 0.05 < ref.envelope.sum() / clear.envelope.sum() < 0.5


def _torus_scene(n: int, faces=None):
    import trimesh

    from datagen.scene import Laser, Material, Scene, SceneObject, Sensor, quad

    torus = trimesh.creation.torus(major_radius=0.3, minor_radius=0.1, major_sections=40, minor_sections=16)
    v = np.asarray(torus.vertices)[:, [2, 0, 1]] + np.array([-1.0, 0.1, 1.05])
    f = np.asarray(torus.faces) if faces is None else faces(np.asarray(torus.faces))
    objects = [quad("relay_wall", (0.0, -1.05, 0.0), (0.0, 2.1, 0.0), (0.0, 0.0, 2.1), label="relay_wall"),
               SceneObject("torus", "mesh", Material(albedo=0.8), v, f)]
    grid = {"center": [0.0, 0.0, 1.05], "size": [2.0, 2.0], "points": [n, n]}
    return Scene(objects, Laser(emitter=(-0.4, 0.0, 0.1), spot=(0.0, 0.0, 1.05), photons_per_pulse=1e6),
                 Sensor(position=(-0.4, 0.0, 0.1)), capture=CaptureSpec(type="confocal", laser_grid=grid))


def test_closed_outward_surfaces():
    """A closed outward torus is recognised; with a face missing, reversed, or a laser point inside its box it is
    not."""
    from datagen.scene import RayCaster
    from datagen.transport.quadrature.primary import closed_outward

    outside, inside = np.array([[0.0, 0.0, 1.05]]), np.array([[-1.0, 0.1, 1.05]])
    for faces, spots, want in ((None, outside, True), (lambda f: f[1:], outside, False),
                               (lambda f: f[:, ::-1], outside, False), (None, inside, False)):
        caster = RayCaster(_torus_scene(2, faces))
        obj = caster.face_object[np.flatnonzero(caster.face_object != caster.face_object[0])[0]]
        assert closed_outward(caster, np.array([obj]), spots)[0] == want


def test_never_lit_faces_are_left_out_without_changing_a_bit(monkeypatch):
    """The faces of a closed outward torus whose front is turned away from every laser point (dark_faces, from the
    laser points' hull) are exactly those a brute-force test over every laser point finds, and leaving their
    sub-triangles out changes no bit of the envelope or the error estimate (the kernel never lights them)."""
    from datagen.scene import RayCaster
    from datagen.transport.quadrature.primary import dark_faces, front_only

    scene = _torus_scene(6)
    sim = _torus_config(scene, 0.05)
    cut, q_cut = _run(scene, sim, monkeypatch)
    monkeypatch.setattr(quadrature, "dark_faces", lambda caster, faces, *args: np.zeros(len(faces), dtype=bool))
    whole, q_whole = _run(scene, sim, monkeypatch)
    assert q_cut.settings.shadow_spot and q_cut.front.any()
    assert 0.6 * q_whole.n_cells < q_cut.n_cells < 0.9 * q_whole.n_cells
    assert np.array_equal(cut.envelope, whole.envelope) and cut.envelope.max() > 0
    assert cut.attrs["error"]["rel_l2"] == whole.attrs["error"]["rel_l2"] > 0
    caster = RayCaster(scene)
    faces = q_cut.area.hidden_faces
    spots, normals = q_cut.capture.spots, q_cut.capture.spot_normals
    front = front_only(caster, faces, spots)
    n, p0 = caster.face_normals[faces], caster.vertices[caster.faces[faces, 0]]
    brute = front & ((spots @ n.T) - np.einsum("ij,ij->i", n, p0) < -q_cut.area.tol).all(axis=0)
    assert brute.sum() > 0 and np.array_equal(dark_faces(caster, faces, front, spots, normals, q_cut.area.tol), brute)
    assert not dark_faces(caster, faces, np.zeros(len(faces), dtype=bool), spots, normals, 0.0).any()


def test_torus_self_shadowing_without_rays_on_inner_sides(monkeypatch):
    """A self-shadowing closed mesh: the compiled primary (no rays for the inner sides of the torus) equals the
    numpy path (a ray for every lit pair) to 1e-5 (measured 1e-6: inner-side points within a ray offset of a
    convex edge, whose segment leaves the solid before Embree's pushed-off ray starts, count as lit there), with
    about half the rays."""
    scene = _torus_scene(6)
    sim = datagen.resolve_config(scene, {"estimator": "quadrature", "quadrature_fov": 1, "secondary": "none",
                                         "count_sensor_leg": False, "quadrature_edge": 0.05,
                                         "time": {"t_start": 0.0, "bin_width": 32e-12, "n_bins": 512},
                                         "irf": {"fwhm": 70e-12}, "effects": {"first_bounce": False,
                                         "secondary": False, "shadow_spot": True, "shadow_sensor": True},
                                         "detector": {"model": "poisson", "repetition_rate": 1e7, "exposure": "8ms"}})
    ref, q_ref = _run(scene, sim, monkeypatch, use_compiled=False)
    fast, q_fast = _run(scene, sim, monkeypatch)
    norm = np.linalg.norm(ref.envelope)
    assert norm > 0 and np.linalg.norm(fast.envelope - ref.envelope) <= 1e-5 * norm
    assert abs(q_fast.stats.tents - q_ref.stats.tents) <= 1e-3 * q_ref.stats.tents
    assert q_fast.stats.shadow_rays < 0.6 * q_ref.stats.shadow_rays


def _torus_config(scene, edge, **extra):
    return datagen.resolve_config(scene, {"estimator": "quadrature", "quadrature_fov": 1, "secondary": "none",
                                          "count_sensor_leg": False, "quadrature_edge": edge,
                                          "time": {"t_start": 0.0, "bin_width": 32e-12, "n_bins": 512},
                                          "irf": {"fwhm": 70e-12}, "effects": {"first_bounce": False,
                                          "secondary": False, "shadow_spot": True, "shadow_sensor": True},
                                          "detector": {"model": "poisson", "repetition_rate": 1e7,
                                                       "exposure": "8ms"}, **extra})


def test_big_mesh_occluder_candidates_replace_most_rays(monkeypatch):
    """A mesh too big for the numpy occluder test (forced here: PAIR_TEST_MAX_PAIRS = 0) gets its per-face
    candidates from the compiled hull test with the face's own plane (quadrature.kernel.face_candidates): the envelope
    equals the numpy path's (a ray for every lit pair) to 1e-5 (Embree's float32 leaks, as above) and the
    exact-test path of the numpy occluder lists to 1e-9, with under 5 % of the numpy path's rays (measured 0)."""
    from datagen.transport.quadrature import primary as quadrature_primary

    scene = _torus_scene(6)
    sim = _torus_config(scene, 0.05)
    ref, q_ref = _run(scene, sim, monkeypatch, use_compiled=False)
    listed, _ = _run(scene, sim, monkeypatch)
    monkeypatch.setattr(quadrature_primary, "PAIR_TEST_MAX_PAIRS", 0)
    big, q_big = _run(scene, sim, monkeypatch)
    norm = np.linalg.norm(ref.envelope)
    assert norm > 0 and np.linalg.norm(big.envelope - ref.envelope) <= 1e-5 * norm
    assert np.linalg.norm(big.envelope - listed.envelope) <= 1e-9 * norm
    assert q_big.stats.shadow_rays < 0.05 * q_ref.stats.shadow_rays
    assert q_big.occluder_cache[1][-1].sum() == 0                        # no face fell back to rays


@pytest.mark.parametrize("fov_cells", [1, 2])
def test_threads_give_bit_identical_envelopes(monkeypatch, fov_cells):
    """The pair kernel runs channel groups in parallel: in the calling thread only (a short run), on one of numba's
    threads and on numba's default count the envelope is the same bit for bit, with one connection per channel and
    with 2 × 2 FoV cells per pixel (4 connections per channel), and equals the numpy path to 1e-9 with a ray for
    every lit pair."""
    import numba

    from datagen.transport.quadrature import primary as quadrature_primary

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core: nothing runs in parallel")
    scene = _torus_scene(6)
    sim = _torus_config(scene, 0.05).with_estimator(fov_cells=fov_cells)
    serial, q = _run(scene, sim, monkeypatch, segment_tests=False)             # 1.4 M pairs: no threads
    default = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        monkeypatch.setattr(quadrature_primary, "PARALLEL_MIN_PAIRS", 0)
        one, _ = _run(scene, sim, monkeypatch, segment_tests=False)
    finally:
        numba.set_num_threads(default)
    monkeypatch.setattr(quadrature_primary, "PARALLEL_MIN_PAIRS", 0)
    many, _ = _run(scene, sim, monkeypatch, segment_tests=False)
    ref, _ = _run(scene, sim, monkeypatch, use_compiled=False)
    assert len(q.conn_laser) == fov_cells ** 2 * 36 and q.n_cells * len(q.targets) < quadrature_primary.PARALLEL_MIN_PAIRS
    assert np.array_equal(serial.envelope, one.envelope) and np.array_equal(one.envelope, many.envelope)
    assert np.linalg.norm(many.envelope - ref.envelope) <= 1e-9 * np.linalg.norm(ref.envelope) > 0


def test_plain_split_and_its_sub_scan_estimate_against_a_converged_reference(monkeypatch):
    """A 64 × 64 scan of a 1 280-triangle torus at h = 8 cm (longer than every edge, ≤ 7.3 cm): the even split
    would hold 4× the sub-triangles, so the mesh's own triangles are used (quadrature.split's plain split; not those
    turned away from every laser point) and the error
    estimate is (4/3)‖P(h) − P(h/2)‖ on every 8th laser point per axis. Against the same 8 × 8 block of laser
    points scanned at h/4 (16× closer to the integral) the measured error lies below the estimate and within 3× of
    it (measured 0.34 % against an estimate of 0.53 %)."""
    from datagen.scene import RayCaster, resolve_capture

    scene = _torus_scene(64)
    result, q = _run(scene, _torus_config(scene, 0.08), monkeypatch)
    assert q.refine_lasers is not None and len(q.refine_lasers) == 64 and q.coarse_ratio == 0.5
    faces = len(scene.objects[1].faces)          # each sub-triangle one whole face; those turned away left out
    assert q.n_cells == len(np.unique(q.cell_face)) and 0.6 * faces < q.n_cells < faces
    assert len(q.coarse_channels) == 64
    assert "E(h/2)" in result.attrs["error"]["method"]
    spots = resolve_capture(scene, RayCaster(scene)).spots.reshape(64, 64, 3)
    block = _torus_scene(8)
    block.capture = CaptureSpec(type="confocal", laser_grid={
        "center": spots[24:32, 28:36].reshape(-1, 3).mean(axis=0).tolist(), "size": [0.25, 0.25], "points": [8, 8]})
    ref = datagen.simulate(block, _torus_config(block, 0.02)).envelope
    measured = np.linalg.norm(result.envelope[24:32, 28:36] - ref) / np.linalg.norm(ref)
    estimate = result.attrs["error"]["rel_l2"]
    assert estimate / 3 <= measured <= estimate


def test_forced_plain_split_compiled_equals_numpy():
    """``split="plain"`` on an 8 × 8 scan (sub-scan: the one point (4, 4)): the compiled and numpy primaries agree
    to 1e-9 on the envelope and on the rule at h/2 of the estimate, which holds that point's channel only; the
    plain split keeps the torus's triangles (but those turned away from every laser point), the rule at h/2 cuts
    each into 4."""
    from datagen.transport.quadrature.estimator import Quadrature, QuadratureSettings

    scene = _torus_scene(8)
    out = []
    for compiled in (True, False):
        q = Quadrature(scene, QuadratureSettings(edge=0.08, split="plain", fov_cells=1, shadow_spot=True, secondary="none",
                                                 first_bounce=False))
        q.use_compiled = q.segment_tests = compiled
        acc = EnvelopeAccumulator(TimeAxis(t_start=0.0, bin_width=32e-12, n_bins=512), Irf(fwhm=70e-12),
                                  len(q.component_names) * q.capture.n_channels)
        q.run(acc)
        out.append((acc.binned().reshape(-1, 64, 512).sum(axis=0), q.coarse.binned_total(64)))   # per channel
        assert q.n_cells == len(np.unique(q.cell_face)) < 1280            # whole faces, less those turned away
        assert list(q.refine_lasers) == [4 * 8 + 4] and q.coarse_ratio == 0.5
    (a, ca), (b, cb) = out
    assert np.linalg.norm(a - b) <= 1e-9 * np.linalg.norm(b) and np.linalg.norm(b) > 0
    assert np.linalg.norm(ca - cb) <= 1e-9 * np.linalg.norm(cb)
    rows = np.flatnonzero(np.abs(cb).sum(axis=1) > 0)
    assert list(rows) == [36]
    assert 0 < np.linalg.norm(cb[36] - b[36]) < 0.1 * np.linalg.norm(b[36])      # h/2 differs from h, a little


def test_run_spheres_bound_each_run():
    """The occluder runs' bounding spheres: centred on each run's bounding box, radius its farthest point (a
    per-run loop as the reference), runs of one to eight triangles."""
    from datagen.transport.quadrature.primary import run_spheres

    rng = np.random.default_rng(0)
    tri = rng.normal(size=(500, 3, 3))
    lens = rng.integers(1, 9, 80)
    lo = np.append(0, np.cumsum(lens)[:-1])
    occ_of = rng.integers(0, 500, lens.sum())
    got = run_spheres(tri[occ_of].reshape(-1, 3), 3 * lo)
    for r, (a, n) in enumerate(zip(lo, lens)):
        pts = tri[occ_of[a:a + n]].reshape(-1, 3)
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        assert np.array_equal(got[r], [*centre, np.sqrt(((pts - centre) ** 2).sum(axis=1).max())])
    assert run_spheres(np.zeros((0, 3)), np.zeros(0, dtype=np.int64)).shape == (0, 4)


def test_run_chunks_tile_each_run_and_hold_its_grown_triangles():
    """run_chunks: each run's entries are only reordered within the run (not at all in a run of at most
    RUN_CHUNKED, which stays one chunk); its chunks tile it in order, at most RUN_CHUNK each; each chunk's sphere holds
    every vertex of its triangles grown by 2δ (and a degenerate triangle's own vertices), so the kernel's sphere test
    can skip only triangles that could not block."""
    from datagen.transport.quadrature.primary import RUN_CHUNK, RUN_CHUNKED, run_chunks
    from datagen.transport.quadrature.shadow import grown_triangles

    rng = np.random.default_rng(1)
    tri = rng.normal(size=(300, 3, 3))
    tri[7, 2] = tri[7, 0]                                              # a degenerate triangle: grown is NaN
    grown = grown_triangles(tri, 2e-3)
    lens = rng.integers(1, 40, 50)
    lo = np.append(0, np.cumsum(lens)[:-1])
    hi = lo + lens
    occ_of = rng.integers(0, 300, lens.sum())
    occ_of[0] = 7
    order, run_chunk, chunk_ptr, spheres = run_chunks(tri, grown, occ_of, lo, hi)
    assert len(run_chunk) == len(lo) + 1 and chunk_ptr[-1] == len(occ_of) and len(spheres) == len(chunk_ptr) - 1
    for r in range(len(lo)):
        assert sorted(order[lo[r]:hi[r]]) == sorted(occ_of[lo[r]:hi[r]])
        starts = chunk_ptr[run_chunk[r]:run_chunk[r + 1] + 1]
        assert starts[0] == lo[r] and starts[-1] == hi[r] and (np.diff(starts) >= 1).all()
        if lens[r] <= RUN_CHUNKED:
            assert len(starts) == 2 and np.array_equal(order[lo[r]:hi[r]], occ_of[lo[r]:hi[r]])
        else:
            assert (np.diff(starts) <= RUN_CHUNK).all()
    for c in range(len(spheres)):
        k = order[chunk_ptr[c]:chunk_ptr[c + 1]]
        pts = np.where(np.isnan(grown[k]), tri[k], grown[k]).reshape(-1, 3)
        assert (np.linalg.norm(pts - spheres[c, :3], axis=1) <= spheres[c, 3] * (1 + 1e-12)).all()
    assert (lens > RUN_CHUNKED).any() and (lens <= RUN_CHUNKED).any() and np.isnan(grown[7]).all()
    none = run_chunks(tri, grown, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
                      np.zeros(0, dtype=np.int64))
    assert none[1].tolist() == [0] and none[2].tolist() == [0] and none[3].shape == (0, 4)


def test_chunked_segment_tests_change_no_bit(monkeypatch):
    """The self-shadowing torus (faces with dozens of candidate occluders from their own object): the kernel's
    segment tests with chunk spheres (RUN_CHUNK) give the same envelope, error estimate, tents and shadow rays, bit
    for bit, as with one chunk per run (every candidate of a run whose sphere the segment meets is tested)."""
    from datagen.transport.quadrature import primary as quadrature_primary
    from datagen.transport.quadrature.kernel import OCC

    scene = _torus_scene(6)
    sim = _torus_config(scene, 0.05)
    chunked, q_chunked = _run(scene, sim, monkeypatch)
    monkeypatch.setattr(quadrature_primary, "RUN_CHUNK", 1 << 30)
    whole, q_whole = _run(scene, sim, monkeypatch)
    occ = dict(zip(OCC, q_chunked.occluder_cache[1]))
    assert (np.diff(occ["run_chunk"]) > 1).any()                        # runs of several chunks were tested
    assert (np.diff(dict(zip(OCC, q_whole.occluder_cache[1]))["run_chunk"]) == 1).all()
    assert np.array_equal(chunked.envelope, whole.envelope) and chunked.envelope.max() > 0
    assert chunked.attrs["error"]["rel_l2"] == whole.attrs["error"]["rel_l2"] > 0
    assert (q_chunked.stats.tents, q_chunked.stats.shadow_rays) == (q_whole.stats.tents, q_whole.stats.shadow_rays)
