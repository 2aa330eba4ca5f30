"""One orientation (docs/capture_io.md, "Orientation"): an asymmetric hidden "F" simulated by datagen, exported as an
LCT .mat, reconstructed the way the Stanford LCT release's script does (its permute, its grid, its front view) and
by ``datagen reconstruct``, both agreeing with the F's wall-view label; and, when the release's captures are at hand,
``datagen reconstruct`` on them at the charts' and the diffuse "S"'s depths with the release's own front view."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.io import loadmat
from conftest import NEEDS_REAL, REAL

import datagen
from datagen.cli.main import main
from datagen.dataset.sampler import SampledRoom
from datagen.dataset.wall_view import wall_view_labels
from datagen.io import write_result
from datagen.io.lab_formats import capture_from_result, write_lab_capture
from datagen.scene import (CaptureSpec, FieldOfView, Laser, Material, RayCaster, Scene, SceneObject, Sensor, WallGrid,
                           quad)
from datagen.scene.builders import quad_mesh

ROOT = Path(__file__).resolve().parents[1]
C_RELEASE = 3e8                          # the release's script's speed of light
GRID = {"center": (2.0, 0.0, 1.0), "size": (0.8, 0.8), "points": (16, 16)}
F_DEPTH = 0.5                            # the F's distance from the wall (m)


def f_cutout() -> SceneObject:
    """A flat "F" 0.5 m × 0.7 m facing the relay wall x = 2 from x = 1.5: seen from the wall (u = +y to the right,
    v = +z up) its stem is on the left, its long bar at the top and its short bar in the middle."""
    x = 2.0 - F_DEPTH
    parts = [((-0.25, 0.65), (0.15, 0.70)),            # stem: (y0, z0), (width along y, height along z)
             ((-0.10, 1.20), (0.35, 0.15)),            # top bar
             ((-0.10, 0.95), (0.22, 0.15))]            # middle bar
    vertices, faces = [], []
    for (y0, z0), (dy, dz) in parts:
        v, f = quad_mesh(np.array([x, y0, z0]), np.array([0.0, dy, 0.0]), np.array([0.0, 0.0, dz]))  # normal +x
        faces.append(f + sum(len(p) for p in vertices))
        vertices.append(v)
    return SceneObject("F", "mesh", Material(albedo=0.8), np.concatenate(vertices), np.concatenate(faces))


def f_scene() -> Scene:
    wall = quad("relay_wall", (2.0, -1.05, -0.05), (0.0, 0.0, 2.1), (0.0, 2.1, 0.0), Material(albedo=0.8),
                label="relay_wall")
    return Scene([wall, f_cutout()], Laser(emitter=(1.5, -3.0, 1.0), spot=(2.0, 0.0, 1.0)),
                 Sensor(position=(1.5, -3.0, 1.0), aperture_radius=0.02,
                        fov=FieldOfView(center=GRID["center"], size=GRID["size"])), name="f_cutout",
                 capture=CaptureSpec(type="confocal", laser_grid=WallGrid(**GRID)))


@pytest.fixture(scope="module")
def f_capture(tmp_path_factory):
    """The F's simulated scan (its time axis counting the wall → sensor leg, so the export carries a tofgrid), its
    store, its LCT export, and its wall-view mask (16, 16) in datagen's order."""
    scene = f_scene()
    over = {"estimator": "quadrature", "quadrature_edge": 0.04, "quadrature_fov": "edge", "secondary": "none",
            "count_sensor_leg": True, "time": {"t_start": 0.0, "bin_width": 32e-12, "n_bins": 640},
            "irf": {"fwhm": 70e-12}, "effects": {"first_bounce": False, "secondary": False},
            "detector": {"model": "poisson", "pde": 0.3, "repetition_rate": 1.0e7, "exposure": "8ms"}}
    result = datagen.simulate(scene, datagen.resolve_config(scene, over))
    tmp = tmp_path_factory.mktemp("f")
    write_result(result, tmp / "sim" / "result.zarr")
    write_lab_capture(capture_from_result(result, "lct-mat"), tmp / "f.mat")
    params = {"sensor": {"scan": {"laser_grid": {k: list(v) for k, v in GRID.items()}}}}
    room = SampledRoom(scene, params, [{"name": "F", "material": {"albedo": 0.8}}])
    label = wall_view_labels(room, RayCaster(scene), GRID["points"][::-1], 1)
    return result, tmp, label["wall_mask"][0].astype(bool), label["wall_depth"]


def release_front_view(path: Path, crop: int = 256, bin_resolution: float | None = None, k: int = 0,
                       z_trim: int = 0) -> np.ndarray:
    """The LCT release's "Front view" of an LCT .mat, as its script computes and draws it: the f-k release's
    reader's tofgrid shift (per point, −floor(tofgrid / bin) bins) and crop, ``K`` halvings of the time axis
    (``rect_data(:,:,1:2:end) + rect_data(:,:,2:2:end)``), the first ``z_trim`` (of the unhalved) bins zeroed,
    ``permute(rect_data, [3 2 1])`` to (t, j, i), t² scaling, the light-cone Wiener deconvolution (snr 0.8),
    ``vol(:, :, end:-1:1)``, the maximum over t; returned as ``imagesc`` shows it, row 0 at the top. Written here
    from the scripts, apart from datagen.analysis."""
    from scipy import sparse

    f = loadmat(path)
    rect = np.asarray(f["rect_data"], float)
    width = float(f["width"].squeeze())
    res = bin_resolution or float(f["bin_resolution"].squeeze())
    for i, j in np.ndindex(rect.shape[:2]) if "tofgrid" in f else ():
        rect[i, j] = np.roll(rect[i, j], -int(np.floor(f["tofgrid"][i, j] / (res * 1e12))))
    rect = rect[..., :crop]
    for _ in range(k):
        rect, res = rect[..., 0::2] + rect[..., 1::2], 2 * res
    rect[..., :round(z_trim / 2 ** k)] = 0
    n, m = rect.shape[0], rect.shape[2]
    data = np.transpose(rect, (2, 1, 0)) * np.linspace(0, 1, m)[:, None, None] ** 2     # (t, j, i)
    x = np.linspace(-1, 1, 2 * n)
    gz, gy, gx = np.meshgrid(np.linspace(0, 2, 2 * m), x, x, indexing="ij")
    psf = np.abs((4 * width / (m * C_RELEASE * res)) ** 2 * (gx ** 2 + gy ** 2) - gz)
    psf = (psf == psf.min(axis=0, keepdims=True)).astype(float)
    psf = np.roll(psf / np.linalg.norm(psf), (n, n), axis=(1, 2))
    k = np.arange(1, m * m + 1)
    mtx = sparse.diags(1 / np.sqrt(k)) @ sparse.csr_matrix((np.ones(m * m), (k - 1, np.ceil(np.sqrt(k)).astype(int) - 1)),
                                                           shape=(m * m, m))
    mtxi = mtx.T.tocsr()
    for _ in range(int(np.log2(m))):
        mtx, mtxi = 0.5 * (mtx[0::2] + mtx[1::2]), 0.5 * (mtxi[:, 0::2] + mtxi[:, 1::2])
    fpsf = np.fft.fftn(psf)
    tdata = np.zeros((2 * m, 2 * n, 2 * n))
    tdata[:m, :n, :n] = (mtx @ data.reshape(m, -1)).reshape(m, n, n)
    tvol = np.fft.ifftn(np.fft.fftn(tdata) * np.conj(fpsf) / (np.abs(fpsf) ** 2 + 1 / 0.8))[:m, :n, :n]
    vol = np.maximum((mtxi @ tvol.real.reshape(m, -1)).reshape(m, n, n), 0)
    return vol[:, :, ::-1].max(axis=0)                 # (j, reversed i): imagesc's rows and columns


def best_match(found: np.ndarray, label: np.ndarray) -> tuple[str, dict]:
    """Which of the eight flips and transposes of ``label`` the mask ``found`` overlaps most (intersection over
    union), and every score."""
    views = {"as is": label, "transposed": label.T, "rows reversed": label[::-1], "columns reversed": label[:, ::-1],
             "rotated 180": label[::-1, ::-1], "anti-transposed": label[::-1, ::-1].T,
             "rotated +90": np.rot90(label), "rotated -90": np.rot90(label, -1)}
    scores = {k: float((found & v).sum() / (found | v).sum()) for k, v in views.items()}
    return max(scores, key=scores.get), scores


def test_the_f_label_is_an_f_seen_from_the_wall(f_capture):
    _, _, mask, _ = f_capture
    rows, cols = np.nonzero(mask)
    assert mask[:, :5].sum() > mask[:, -5:].sum() * 3        # the stem on the left (columns grow along u)
    assert rows.mean() > 7.5 and cols.mean() < 7.5           # the bars at the top (rows grow upward)


def test_the_release_reads_datagens_export_as_datagen_sees_the_f(f_capture):
    """The release's front view (row 0 at the top) of the exported file is the wall-view label drawn
    origin="lower", i.e. the label with its rows reversed."""
    _, tmp, mask, _ = f_capture
    front = release_front_view(tmp / "f.mat")
    found = front >= 0.5 * front.max()
    view, scores = best_match(found, mask[::-1])
    assert view == "as is" and scores["as is"] > 0.5, scores


@pytest.mark.parametrize("source", ["sim", "imported"])
def test_datagen_reconstruct_finds_the_f_where_the_label_has_it(f_capture, source):
    result, tmp, mask, wall_depth = f_capture
    run = CliRunner()
    store = tmp / "sim"
    if source == "imported":
        out = run.invoke(main, ["import-capture", str(tmp / "f.mat"), "--out", str(tmp / "imported")])
        assert out.exit_code == 0, out.output
        store = tmp / "imported"
    out = run.invoke(main, ["reconstruct", str(store), "--out", str(tmp / f"rec_{source}"), "--level", "0.5"])
    assert out.exit_code == 0, out.output
    depth = np.load(tmp / f"rec_{source}" / "depth.npy")
    view, scores = best_match(np.isfinite(depth), mask)
    assert view == "as is" and scores["as is"] > 0.5, scores
    assert float(np.nanmedian(depth)) == pytest.approx(F_DEPTH, abs=0.01)
    assert f"median depth {np.nanmedian(depth):.4f} m" in out.output
    assert (tmp / f"rec_{source}" / "reconstruction.png").stat().st_size > 10_000
    assert np.load(tmp / f"rec_{source}" / "volume.npy").shape[:2] == (16, 16)


def test_the_lct_grid_holds_both_ways(f_capture):
    """Export writes width = pitch·(N − 1)/2, so the release's linspace(−width, width, N) is the simulated grid; the
    import puts the scan back on that grid (columns along +x, rows up +z)."""
    from datagen.io.lab_formats import read_lab_capture

    result, tmp, _, _ = f_capture
    cap = read_lab_capture(tmp / "f.mat")
    pts = result.laser_points                                  # the relay wall x = 2: u = +y, v = +z
    u = pts[0, :, 1] - pts[..., 1].mean()
    v = pts[:, 0, 2] - pts[..., 2].mean()
    np.testing.assert_allclose(cap.sensor_points()[0, :, 0], u, atol=1e-12)
    np.testing.assert_allclose(cap.sensor_points()[:, 0, 2], v, atol=1e-12)
    assert float(np.squeeze(cap.raw["width"])) == pytest.approx(0.8 * 15 / 16 / 2)
    np.testing.assert_array_equal(cap.data(), result.envelope)


def test_reconstruct_refuses_what_is_not_a_scan_in_one_line(tmp_path, f_capture):
    result, tmp, _, _ = f_capture
    import dataclasses

    write_result(dataclasses.replace(result, laser_points=None, sensor_points=None), tmp_path / "nogrid" / "result.zarr")
    out = CliRunner().invoke(main, ["reconstruct", str(tmp_path / "nogrid"), "--out", str(tmp_path / "r")])
    assert out.exit_code == 2 and out.output.count("\n") == 1, out.output
    assert "nogrid: laser_points: none stored" in out.output
    out = CliRunner().invoke(main, ["reconstruct", str(tmp / "sim"), "--out", str(tmp_path / "r"), "--trim", "soon"])
    assert out.exit_code == 2 and "--trim" in out.output, out.output


# ---- the release's own captures (not shipped: ../shared/real, or DATAGEN_REAL_CAPTURES) ---------------------


@NEEDS_REAL
@pytest.mark.parametrize("name, depth, tol", [("dot_chart_40cm", 0.40, 0.01), ("dot_chart_65cm", 0.65, 0.01),
                                              ("diffuse_s", 0.50, 0.02)])
def test_reconstruct_finds_the_release_scenes_at_their_depths(tmp_path, name, depth, tol):
    """``datagen reconstruct --method lct`` as shipped (no hand zeroing, the default falloff and SNR) on the
    imported capture: the median depth within 1 cm of the charts' 40 / 65 cm, within 2 cm of the diffuse "S"'s
    50 cm (what the release's own settings give)."""
    run = CliRunner()
    out = run.invoke(main, ["import-capture", str(REAL / f"data_{name}.mat"), "--bin-resolution", "4ps",
                            "--out", str(tmp_path / "imp")])
    assert out.exit_code == 0, out.output
    out = run.invoke(main, ["reconstruct", str(tmp_path / "imp"), "--method", "lct", "--out", str(tmp_path / "rec")])
    assert out.exit_code == 0, out.output
    assert float(np.nanmedian(np.load(tmp_path / "rec" / "depth.npy"))) == pytest.approx(depth, abs=tol)


@NEEDS_REAL
def test_reconstruct_draws_the_s_u_letters_as_the_release_does(tmp_path):
    """The release's script's front view of ``data_s_u.mat`` (16 ps, first 2.4 ns zeroed, t², snr 0.8; written in
    this test) is ``datagen reconstruct``'s front view drawn origin="lower" (its rows reversed), and not any flip or
    transpose of it: the letters read the same way."""
    run = CliRunner()
    out = run.invoke(main, ["import-capture", str(REAL / "data_s_u.mat"), "--bin-resolution", "4ps",
                            "--out", str(tmp_path / "imp")])
    assert out.exit_code == 0, out.output
    out = run.invoke(main, ["reconstruct", str(tmp_path / "imp"), "--out", str(tmp_path / "rec")])
    assert out.exit_code == 0, out.output
    ours = np.load(tmp_path / "rec" / "volume.npy").max(axis=-1)[::-1]          # as drawn, row 0 at the top
    release = release_front_view(REAL / "data_s_u.mat", crop=2048, bin_resolution=4e-12, k=2, z_trim=600)
    views = {"as is": ours, "transposed": ours.T, "rows reversed": ours[::-1], "columns reversed": ours[:, ::-1]}
    corr = {name: float(np.corrcoef(v.ravel(), release.ravel())[0, 1]) for name, v in views.items()}
    assert corr["as is"] > 0.9 and max(v for k, v in corr.items() if k != "as is") < corr["as is"] - 0.2, corr


def test_reconstruct_a_dataset_sample_in_its_labels_orientation(tmp_path):
    """A wall_smoke sample (a 16 × 16 scan of a hidden mesh): ``reconstruct DATASET --split --index`` finds it
    where its wall-view depth label has it."""
    import yaml

    cfg = yaml.safe_load((ROOT / "configs" / "datasets" / "wall_smoke.yaml").read_text())
    cfg.update(room=str(ROOT / "configs" / "rooms" / "wall.yaml"), splits={"test": {"count": 1}})
    (tmp_path / "ds.yaml").write_text(yaml.safe_dump(cfg))
    run = CliRunner()
    out = run.invoke(main, ["build", str(tmp_path / "ds.yaml"), "--out", str(tmp_path / "ds"), "--workers", "1"])
    assert out.exit_code == 0, out.output
    out = run.invoke(main, ["reconstruct", str(tmp_path / "ds"), "--split", "test", "--index", "0",
                            "--out", str(tmp_path / "rec")])
    assert out.exit_code == 0 and "sample (test, 0) of dataset" in out.output, out.output
    label = np.asarray(datagen.NLOSDataset(tmp_path / "ds", split="test", fields=("wall_depth",)).read(0)["wall_depth"])
    view, scores = best_match(np.isfinite(np.load(tmp_path / "rec" / "depth.npy")), label.reshape(16, 16) > 0)
    assert view == "as is" and scores["as is"] > 0.3, scores
    out = run.invoke(main, ["reconstruct", str(tmp_path / "ds"), "--out", str(tmp_path / "rec2")])
    assert out.exit_code == 2 and "give --split and --index" in out.output
