"""The reconstruction baselines on any confocal scan (datagen.analysis.confocal, .lct, .reconstruct): the time axis
put on the hidden round trip, the direct light found and zeroed, each point's background floor subtracted, t² and t⁴
falloffs, and each method finding a point target where it is."""
from __future__ import annotations

import numpy as np
import pytest

from datagen.analysis.confocal import align_confocal, direct_light_bins, grid_pitches
from datagen.analysis.lct import lct_volume
from datagen.analysis.reconstruct import FLOOR_BLOCKS, background_floor, coarsen, confocal_volume, depth_map
from datagen.units import SPEED_OF_LIGHT as C

N, DT, M = 16, 32e-12, 256
HALF = 0.375                                           # the LCT grid linspace(−0.375, 0.375, 16): pitch 5 cm
PITCH = 2 * HALF / (N - 1)


def point_scan(depth: float, offset: float = 0.0, rows: np.ndarray | None = None) -> np.ndarray:
    """(N, N, M) transients of a point `depth` m before the centre of the scan (rows at ``rows`` m, default the
    columns' grid): one count at its round trip 2·|x − p|/c (+ ``offset`` s) at every scan point."""
    xs = np.linspace(-HALF, HALF, N)
    gy, gx = np.meshgrid(xs if rows is None else rows, xs, indexing="ij")
    t = 2 * np.sqrt(depth ** 2 + gx ** 2 + gy ** 2) / C + offset
    scan = np.zeros(gx.shape + (M,))
    np.put_along_axis(scan, (t // DT).astype(int)[..., None], 1.0, axis=2)
    return scan


def with_direct_light(scan: np.ndarray, rng) -> np.ndarray:
    """A capture as the LCT release's look: a direct return at t = 0 a thousand times the hidden one with a slow
    exponential tail (400 ps), on a background floor, in Poisson counts."""
    t = (np.arange(M) + 0.5) * DT
    direct = 2000.0 * np.exp(-t / 400e-12)
    return rng.poisson(50.0 * scan + direct + 0.5).astype(float)


def test_align_removes_each_points_offset_and_the_window_start():
    off = np.random.default_rng(0).uniform(1e-9, 3e-9, (N, N))
    stored = point_scan(0.5, offset=0.0)
    edges = 0.8e-9 + np.arange(M + 1) * DT                     # the window starts at 0.8 ns
    shifted = np.zeros_like(stored)
    for iy, ix in np.ndindex(N, N):                            # what the store holds: t + offset, from 0.8 ns
        s = int(np.rint((off[iy, ix] - 0.8e-9) / DT))
        shifted[iy, ix, s:] = stored[iy, ix, :M - s]
    aligned, dt = align_confocal(shifted, edges, off)
    assert dt == pytest.approx(DT, rel=1e-12)
    np.testing.assert_array_equal(aligned[..., :M - 80], stored[..., :M - 80])


def test_align_refuses_offsets_of_another_shape():
    with pytest.raises(ValueError, match=r"offsets must be finite and of the scan's shape \(16, 16\)"):
        align_confocal(point_scan(0.5), np.arange(M + 1) * DT, np.zeros((4, 4)))


def test_the_direct_light_ends_before_the_hidden_return():
    rng = np.random.default_rng(1)
    hidden = point_scan(0.5)
    first = int(np.argmax(hidden.reshape(-1, M).sum(0) > 0))   # the hidden return's first bin
    end = direct_light_bins(with_direct_light(hidden, rng), DT)
    assert 0.6 * first < end <= first, (end, first)             # the tail (down to the floor) and nothing after
    assert direct_light_bins(hidden, DT) == 0                    # no direct light: nothing to trim


def test_lct_trims_the_direct_light_itself_and_finds_the_point_with_either_falloff():
    rng = np.random.default_rng(2)
    scan = with_direct_light(point_scan(0.5), rng)
    depths = (np.arange(M) + 0.5) * C * DT / 2
    for falloff in ("retroreflective", "diffuse"):
        vol = lct_volume(scan, DT, HALF, falloff=falloff)
        assert depths[np.unravel_index(vol.argmax(), vol.shape)[2]] == pytest.approx(0.5, abs=0.015), falloff
    by_hand = scan.copy()
    by_hand[..., :direct_light_bins(scan, DT)] = 0.0
    np.testing.assert_array_equal(lct_volume(scan, DT, HALF), lct_volume(by_hand, DT, HALF, trim=None))
    by_hand = scan.copy()
    by_hand[..., :75] = 0.0                                      # the release's way: a duration, 2.4 ns = 75 bins
    np.testing.assert_array_equal(lct_volume(scan, DT, HALF, trim=2.4e-9), lct_volume(by_hand, DT, HALF, trim=None))
    with pytest.raises(ValueError, match="falloff must be one of diffuse, retroreflective"):
        lct_volume(scan, DT, HALF, falloff="specular")


@pytest.mark.parametrize("n, m, slope", [((16, 16), 256, 0.1), ((16, 16), 256, 0.5), ((16, 12), 128, (0.2, 0.15)),
                                         ((8, 8), 16, 2.0), ((32, 32), 512, 0.081)])
def test_the_light_cone_kernel_is_the_nearest_bin_of_each_column(n, m, slope):
    """light_cone_psf against the release script's construction, written out here: |cone − z| over the whole
    (2m, 2ny, 2nx) grid, 1 where it is least in its column (ties both), normalised; equal bit for bit, over square
    and rectangular grids and slopes whose cone stays inside the range or leaves it (slope 2)."""
    from datagen.analysis.lct import light_cone_psf

    ny, nx = n
    sy, sx = (slope, slope) if np.ndim(slope) == 0 else slope
    gz, gy, gx = np.meshgrid(np.linspace(0, 2, 2 * m), np.linspace(-1, 1, 2 * ny), np.linspace(-1, 1, 2 * nx),
                             indexing="ij")
    cone = (4 * sx) ** 2 * (gx ** 2 + gy ** 2) if sx == sy else (4 * sx) ** 2 * gx ** 2 + (4 * sy) ** 2 * gy ** 2
    gap = np.abs(cone - gz)
    psf = (gap == gap.min(axis=0, keepdims=True)).astype(np.float64)
    psf /= psf[:, ny, nx].sum()
    psf /= np.linalg.norm(psf)
    np.testing.assert_array_equal(light_cone_psf(n, m, slope), np.roll(psf, (ny, nx), axis=(1, 2)))


@pytest.mark.parametrize("shape", [(64, 16, 16), (32, 16, 12), (16, 4, 8)])
def test_the_padded_convolution_is_the_full_fft_of_the_padded_scan(shape):
    """padded_convolution against numpy's n-dimensional real FFT of the explicitly zero-padded data: equal bit for
    bit on square and rectangular grids (random data and a random complex filter, seeded)."""
    from datagen.analysis.lct import padded_convolution

    rng = np.random.default_rng(11)
    m, ny, nx = shape
    data = rng.random(shape)
    filt = rng.standard_normal((2 * m, 2 * ny, nx + 1)) + 1j * rng.standard_normal((2 * m, 2 * ny, nx + 1))
    padded = np.zeros((2 * m, 2 * ny, 2 * nx))
    padded[:m, :ny, :nx] = data
    full = np.fft.irfftn(np.fft.rfftn(padded) * filt, s=padded.shape, axes=(0, 1, 2))[:m, :ny, :nx]
    np.testing.assert_array_equal(padded_convolution(data, filt), full)


def test_the_kept_kernel_gives_the_volume_a_kernel_built_anew_gives(monkeypatch):
    """lct_volume keeps its two latest inverse kernels: alternating two geometries, snr and backprojection, each
    volume equals, bit for bit, the one computed with no kernel kept (KERNEL_CACHE_BYTES 0); the kept kernel is
    read-only, so no caller can change what the next call uses."""
    from datagen.analysis import lct

    rng = np.random.default_rng(5)
    scan = with_direct_light(point_scan(0.5), rng)
    calls = [dict(half_width=HALF), dict(half_width=(HALF, 0.8 * HALF)), dict(half_width=HALF, snr=0.08),
             dict(half_width=HALF, backprojection=True), dict(half_width=HALF)]
    kept = [lct_volume(scan, DT, **call) for call in calls]
    monkeypatch.setattr(lct, "KERNEL_CACHE_BYTES", 0)
    for call, volume in zip(calls, kept):
        np.testing.assert_array_equal(volume, lct_volume(scan, DT, **call))
    kernel = lct.inverse_kernel((N, N), M, 0.1, 0.8, False)
    with pytest.raises(ValueError, match="read-only"):
        kernel[0, 0, 0] = 0.0


def test_the_sparse_resampling_gives_the_volume_the_dense_matrices_give(monkeypatch):
    """The time resampling (t → t² and back) multiplies by sparse matrices kept per number of bins: the volume equals
    the one from their dense form within 1e-12 of its maximum (only the order of the sums differs); the operator
    maps a unit transient's bin k to v ≈ (k/M)²·M and is read-only, so no caller can change what the next call
    uses."""
    from datagen.analysis import lct

    rng = np.random.default_rng(5)
    scan = with_direct_light(point_scan(0.5), rng)
    sparse_volume = lct_volume(scan, DT, HALF)
    mtx, mtxi = lct.resampling_operator(M)
    assert lct.resampling_operator(M)[0] is mtx and mtx.nnz < 3 * M
    with pytest.raises(ValueError, match="power-of-two number of time bins, got 48"):
        lct.resampling_operator(48)
    monkeypatch.setattr(lct, "resampling_operator", lambda m: (mtx.toarray(), mtxi.toarray()))
    dense_volume = lct_volume(scan, DT, HALF)
    np.testing.assert_allclose(sparse_volume, dense_volume, rtol=0, atol=1e-12 * dense_volume.max())
    k = M // 2                                                    # t = T/2 lands at v = T/4
    assert abs(int(np.argmax(mtx @ np.eye(M)[k])) - M // 4) <= 1
    with pytest.raises(ValueError, match="read-only"):
        mtx.data[0] = 0.0


@pytest.mark.parametrize("method", ["lct", "fbp", "phasor"])
def test_each_method_finds_the_point_at_its_depth(method):
    scan = with_direct_light(point_scan(0.45), np.random.default_rng(3))
    given = scan.copy()
    vol, depths, info = confocal_volume(given, DT, PITCH, method)
    np.testing.assert_array_equal(given, scan)                    # the caller's scan is not trimmed
    assert 0 < info["trim_bins"] and not vol[..., depths <= C * info["trim"] / 2].any()
    vol, depths, info = confocal_volume(point_scan(0.45), DT, PITCH, method)
    assert vol.shape[:2] == (N, N) and vol.shape[2] == len(depths) and info["trim_bins"] == 0
    iy, ix, k = np.unravel_index(vol.argmax(), vol.shape)
    assert depths[k] == pytest.approx(0.45, abs=0.02) and abs(iy - 7.5) <= 1 and abs(ix - 7.5) <= 1
    depth, front = depth_map(vol, depths, 0.5)
    assert np.isfinite(depth[iy, ix]) and np.isnan(depth).any() and front.shape == (N, N)


def test_what_is_found_is_measured_from_the_front_views_pedestal():
    """A weak capture's front view sits on a pedestal (the maximum over depth of its noise): an "L" of 1.0 over a
    third of a 32 × 32 scan on a pedestal of 0.40 ± 0.02 (seeded). A share of the maximum (pedestal None) finds the
    whole scan; measured from the 5th percentile (the default) the "L" alone, none of the pedestal."""
    rng = np.random.default_rng(11)
    obj = np.zeros((32, 32), bool)
    obj[4:28, 4:14] = obj[4:12, 4:28] = True
    front = np.where(obj, 1.0, 0.40 + 0.02 * rng.standard_normal((32, 32)))
    volume = np.zeros((32, 32, 5))
    volume[..., 2] = front
    depths = np.linspace(0.3, 0.7, 5)
    old, _ = depth_map(volume, depths, 0.25, pedestal=None)
    np.testing.assert_array_equal(depth_map(volume, depths, 0.25, pedestal=0)[0], old)   # --pedestal 0
    new, fv = depth_map(volume, depths)
    assert np.isfinite(old).all()
    np.testing.assert_array_equal(np.isfinite(new), obj)
    assert np.nanmedian(new) == depths[2] and np.array_equal(fv, front)
    # the level is a share of the way from the pedestal: at 0.95 of it only the "L" reaches it still
    base = np.percentile(front, 5)
    np.testing.assert_array_equal(np.isfinite(depth_map(volume, depths, 0.95)[0]), front >= base + 0.95 * (1 - base))
    with pytest.raises(ValueError, match="pedestal must be a percentile in \\[0, 50\\], got 60"):
        depth_map(volume, depths, pedestal=60)


@pytest.mark.parametrize("method", ["lct", "phasor"])
def test_a_rectangle_of_two_pitches_puts_the_point_where_it_is(method):
    """12 rows 8 cm apart, 16 columns 5 cm apart: the kernel takes each axis's pitch (a point 10 cm up, centred)."""
    rows = np.linspace(-0.44, 0.44, 12)
    vol, depths, _ = confocal_volume(point_scan(0.45, rows=rows - 0.10), DT, (0.08, PITCH), method)
    iy, ix, k = np.unravel_index(vol.argmax(), vol.shape)
    assert vol.shape[:2] == (12, N) and depths[k] == pytest.approx(0.45, abs=0.02)
    assert rows[iy] == pytest.approx(0.10, abs=0.08) and abs(ix - 7.5) <= 1


def test_bins_are_summed_in_pairs_and_a_grid_has_one_pitch_per_axis():
    scan, dt = coarsen(np.ones((2, 2, 2048)), 4e-12, 512)
    assert scan.shape == (2, 2, 512) and dt == 16e-12 and scan.sum() == 4 * 2048
    grid = np.stack(np.meshgrid(np.arange(3) * 0.1, np.arange(4) * 0.2, [0.0]), -1)[..., 0, :]   # (4, 3, 3)
    assert grid_pitches(grid) == pytest.approx((0.2, 0.1))
    grid[0, 0, 0] = 0.03
    with pytest.raises(ValueError, match="not a regular grid: the spacing between rows runs from 0.2 m to 0.202"):
        grid_pitches(grid)


def test_the_floor_is_the_quietest_run_after_the_direct_light():
    """A Poisson floor of 3 counts per bin with a return in the window's last run: the estimate is the minimum of the
    other three runs' means, whose expectation is 0.846 standard errors below the floor (the expected minimum of
    three standard normals, -0.8463, its sd 0.748), not the late window's floor plus the return."""
    rng = np.random.default_rng(4)
    lam, first = 3.0, 32
    scan = rng.poisson(lam, (N, N, M)).astype(float)
    scan[..., -40:] += 20.0                                     # a hidden return in the last run
    floor = background_floor(scan, first)
    n = (M - first) // FLOOR_BLOCKS
    se = np.sqrt(lam / n)
    assert floor.shape == (N, N) and (floor < lam + 3 * se).all()
    assert FLOOR_BLOCKS == 4 and floor.mean() == pytest.approx(lam - 0.8463 * se, abs=4 * 0.748 * se / N)
    assert scan[..., -M // 10:].mean() > lam + 5                 # where a late-window floor would have read it
    assert not background_floor(point_scan(0.45), 0).any()      # no background: nothing subtracted
    with pytest.raises(ValueError, match="0 <= first < M"):
        background_floor(scan, M)


@pytest.mark.parametrize("method", ["lct", "phasor"])
def test_ambient_light_is_subtracted_before_the_falloff_weighs_it_up(method):
    """Sunlight on the wall (a floor of 60 counts per bin, three times the point's 20 counts): with the floor kept,
    the volume's far end outweighs the point (LCT weighs the floor up by t²); subtracted, the point is found at its
    depth. Without a floor the subtraction changes nothing."""
    rng = np.random.default_rng(5)
    scan = rng.poisson(20.0 * point_scan(0.45) + 60.0).astype(float)
    for background, near in (("auto", True), (None, False)):
        vol, depths, _ = confocal_volume(scan, DT, PITCH, method, background=background)
        found = depths[np.unravel_index(vol.argmax(), vol.shape)[2]]
        assert (abs(found - 0.45) < 0.02) == near, (background, found)
    clean = point_scan(0.45)
    np.testing.assert_array_equal(confocal_volume(clean, DT, PITCH, method)[0],
                                  confocal_volume(clean, DT, PITCH, method, background=None)[0])
    with pytest.raises(ValueError, match="background must be 'auto' or None, got 'median'"):
        confocal_volume(clean, DT, PITCH, method, background="median")
