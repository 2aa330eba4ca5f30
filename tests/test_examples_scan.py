"""The scan baselines of examples/ (train_depth_image.py, backprojection_baseline.py) write predictions that
``datagen score`` reads, on a tiny build of configs/datasets/wall_smoke.yaml (16 × 16 × 128 bins)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config
from datagen.dataset.config import SplitSpec
from datagen.dataset.score import score_predictions
from datagen.units import parse_duration
from examples import backprojection_baseline, train_depth_image

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "datasets"


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    config = load_dataset_config(CONFIGS / "wall_smoke.yaml")
    config = config.model_copy(update={"splits": {"train": SplitSpec(count=3), "test": SplitSpec(count=2)}})
    out = tmp_path_factory.mktemp("examples") / "wall"
    build_dataset(config, out, workers=0, progress=False)
    return out


def test_backprojection_depth_images_are_scored(wall, tmp_path):
    """Filtered backprojection of the noise-free envelope puts every test object within 10 cm of its labelled
    depth on average (a 0.5–1.5 m range; the constant mid-range guess 1.0 m is off by up to 0.5 m); the file
    holds (N, H, W) depths and indices as `datagen score` reads them."""
    pred = backprojection_baseline.predict(wall, "test", "envelope")
    assert pred["depth"].shape == (2, 16, 16) and pred["depth"].dtype == np.float32
    assert pred["index"].tolist() == [0, 1]
    assert ((pred["depth"] > backprojection_baseline.NEAR) & (pred["depth"] < backprojection_baseline.FAR)).all()
    path = tmp_path / "bp.npz"
    backprojection_baseline.main([str(wall), "--split", "test", "--input", "envelope", "--out", str(path)])
    rows = score_predictions(path, wall, "test")["rows"]
    assert all(r["depth_pixels"] > 0 for r in rows)
    assert max(r["depth_mae"] for r in rows) < 0.10, rows


def test_depth_network_predictions_and_trivial_baseline(wall, tmp_path):
    """Two epochs give finite (N, H, W) depths the scorer accepts; the trivial file is the training mean depth
    over the object pixels, computed here independently from the stored labels."""
    torch.set_num_threads(1)
    out = tmp_path / "net.npz"
    train_depth_image.main([str(wall), "--val", "test", "--epochs", "2", "--batch", "2", "--threads", "1",
                            "--out", str(out)])
    with np.load(out) as f:
        depth, index = f["depth"], f["index"]
    assert depth.shape == (2, 16, 16) and np.isfinite(depth).all() and index.tolist() == [0, 1]
    labels = np.stack([NLOSDataset(wall, split="train", fields=("wall_depth",)).read(i)["wall_depth"]
                       for i in range(3)])
    with np.load(tmp_path / "net_trivial.npz") as f:
        np.testing.assert_allclose(f["depth"], labels[labels > 0].mean(), rtol=1e-6)
    summary = score_predictions(out, wall, "test")["summary"]
    assert summary["samples"] == 2 and np.isfinite(summary["mean_depth_rmse"])



@pytest.mark.parametrize("small, shipped", [("wall_baseline", "wall"), ("confocal_baseline", "confocal")])
def test_baseline_configs_draw_from_the_shipped_distribution(small, shipped):
    """The baselines' small sets (benchmarks/bench_baselines.py) are their shipped config's distribution: the same
    room file with only the scan's point count overridden, the same detector, estimator and object count, and the
    same time window (so the targets they teach are the shipped config's targets)."""
    a, b = (load_dataset_config(CONFIGS / f"{name}.yaml") for name in (small, shipped))
    assert a.room == b.room
    shipped = b.room_overrides.get("capture", {}).get("scan", {})       # confocal.yaml: height: width (a square)
    assert a.room_overrides == {"capture": {"scan": {"points": [16, 16], **shipped}}}
    assert a.detector == b.detector
    assert a.simulation["estimator"]["kind"] == b.simulation["estimator"]["kind"] == "quadrature"
    assert a.labels["max_objects"] == b.labels["max_objects"]
    ta, tb = a.simulation["time"], b.simulation["time"]
    assert parse_duration(ta["t_start"]) == parse_duration(tb["t_start"]) == 0.0
    window = [parse_duration(t["bin_width"]) * t["n_bins"] for t in (ta, tb)]
    assert window[0] == pytest.approx(window[1], rel=1e-12), window


def test_backprojection_refuses_an_empty_depth_range(wall, capsys):
    """--far at or below --near: a one-line usage error (exit 2) naming both values, not a numpy traceback."""
    with pytest.raises(SystemExit) as exc:
        backprojection_baseline.main([str(wall), "--far", "0.2"])
    assert exc.value.code == 2
    assert "--near 0.3 and --far 0.2: need 0 <= near < far - 0.02 m" in capsys.readouterr().err


def test_depth_network_on_the_lct_volume_saves_what_it_was_trained_on(wall, tmp_path):
    """``--input lct --mask --save``: the record names the data set by its card's config_sha256 and split counts, the
    command and the input; the trivial file is still the training mean depth (not the mean of the depth correction);
    the saved network predicts a finite depth and a mask from a stored scan's counts, bin width and pitch."""
    torch.set_num_threads(1)
    out, net_file = tmp_path / "lct.npz", tmp_path / "lct.pt"
    argv = [str(wall), "--val", "test", "--epochs", "2", "--batch", "2", "--threads", "1", "--input", "lct", "--mask",
            "--out", str(out), "--save", str(net_file)]
    train_depth_image.main(argv)
    labels = np.stack([NLOSDataset(wall, split="train", fields=("wall_depth",)).read(i)["wall_depth"]
                       for i in range(3)])
    with np.load(tmp_path / "lct_trivial.npz") as f:
        np.testing.assert_allclose(f["depth"], labels[labels > 0].mean(), rtol=1e-6)
    net, record = train_depth_image.load_model(net_file)
    card = NLOSDataset(wall, split="train", fields=("counts",)).card
    assert record["config_sha256"] == card["config_sha256"] and record["splits"] == {"train": 3, "test": 2}
    assert record["input"] == "lct" and net.mask and record["mask_threshold"] in train_depth_image.MASK_THRESHOLDS
    assert record["command"] == "python -m examples.train_depth_image " + " ".join(argv)
    item = NLOSDataset(wall, split="test", fields=("counts", "params")).read(0)
    depth, seen = train_depth_image.predict_depth(net, record, np.asarray(item["counts"], np.float64),
                                                  card["time_edges"]["bin_width"],
                                                  train_depth_image.scan_pitch(item["params"]))
    assert depth.shape == seen.shape == (16, 16) and np.isfinite(depth).all() and seen.dtype == bool
    with pytest.raises(ValueError, match="needs the scan's bin_width and pitch"):
        train_depth_image.predict_depth(net, record, np.asarray(item["counts"], np.float64))


def test_the_unet_with_augmentation_saves_its_architecture_and_predicts(wall, tmp_path):
    """``--arch unet --augment --mask-label lct --outline-head``: the record names the architecture, the mask label
    and each head's threshold, load_model rebuilds a DepthUNet with both mask heads and the same weights (the same
    output to the bit), and it predicts a finite depth and a mask on the 16 × 16 grid (pooled 2 × 2 to 8 × 8, two
    2 × 2 pooling levels). An outline head beside the outline mask label, or on the CNN, is refused."""
    torch.set_num_threads(1)
    net_file = tmp_path / "unet.pt"
    train_depth_image.main([str(wall), "--val", "test", "--epochs", "2", "--batch", "2", "--threads", "1", "--input",
                            "lct", "--pool", "2", "--arch", "unet", "--augment", "--mask-label", "lct",
                            "--depth-over", "mask", "--outline-head", "--out", str(tmp_path / "u.npz"),
                            "--save", str(net_file)])
    net, record = train_depth_image.load_model(net_file)
    assert record["arch"] == "unet" and isinstance(net, train_depth_image.DepthUNet) and net.mask
    assert record["mask_label"] == "lct" and record["depth_over"] == "mask" and net.mask_heads == 2
    thresholds = record["mask_thresholds"]
    assert len(thresholds) == 2 and set(thresholds) <= set(train_depth_image.MASK_THRESHOLDS)
    assert record["mask_thresholds"][0] == record["mask_threshold"] and record["outline_head"] == "mean"
    assert record["mask_thresholds"][1] == record["outline_threshold"]
    assert {"outline_iou", "both_iou", "both_outline_iou"} <= set(record["val"])
    again, _ = train_depth_image.load_model(net_file)
    x = torch.randn(1, 1, net.bins, 8, 8, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(net(x, (16, 16)), again(x, (16, 16)), rtol=0, atol=0)
        assert net(x).shape == (1, 3, 8, 8)
    for refused in (["--arch", "unet", "--mask-label", "outline"], ["--arch", "cnn", "--mask-label", "lct"]):
        with pytest.raises(SystemExit, match=f"an outline head needs --arch unet .* got {' '.join(refused)}"):
            train_depth_image.main([str(wall), "--val", "test", "--input", "lct", "--outline-head", *refused])
    with pytest.raises(ValueError, match="outline_head must be one of mean, auxiliary, got 'both'"):
        train_depth_image.train(wall, arch="unet", mask_label="lct", outline_head="both")
    card = NLOSDataset(wall, split="train", fields=("counts",)).card
    item = NLOSDataset(wall, split="test", fields=("counts", "params")).read(0)
    depth, seen = train_depth_image.predict_depth(net, record, np.asarray(item["counts"], np.float64),
                                                  card["time_edges"]["bin_width"],
                                                  train_depth_image.scan_pitch(item["params"]))
    assert depth.shape == seen.shape == (16, 16) and np.isfinite(depth).all() and seen.dtype == bool


def test_the_augmentation_is_the_eight_symmetries_of_the_square_applied_alike():
    """dihedral(k): k = 0 the identity, 1 a quarter turn (numpy's rot90 over the last two axes), 4 the transpose; the
    eight images of an asymmetric array are all different, and every array of the batch is turned alike."""
    a = torch.arange(12.0).reshape(1, 3, 4) ** 2
    images = [train_depth_image.dihedral((a, a + 1), k) for k in range(8)]
    for x, y in images:
        torch.testing.assert_close(y, x + 1)
    torch.testing.assert_close(images[0][0], a)
    np.testing.assert_array_equal(images[1][0].numpy(), np.rot90(a.numpy(), 1, (-2, -1)))
    np.testing.assert_array_equal(images[4][0].numpy(), a.numpy().transpose(0, 2, 1))
    assert len({tuple(x.flatten().tolist()) + tuple(x.shape) for x, _ in images}) == 8


def point_scan(n: int, pitch: float, dt: float, z: float, i0: int, j0: int):
    """The noise-free confocal scan (512, n, n) of one point ``z`` m out in front of scan point (i0, j0): each
    transient a unit pulse at its round trip 2·√(z² + r²)/c, split linearly between two bins; and the grid's row
    and column indices (n, n)."""
    c = 299792458.0
    x = (np.arange(n) - (n - 1) / 2) * pitch
    k = 2 * np.hypot(z, np.hypot(*np.meshgrid(x - x[i0], x - x[j0], indexing="ij"))) / c / dt
    envelope = np.zeros((512, n, n))
    rows, cols = np.indices((n, n))
    np.add.at(envelope, (k.astype(int), rows, cols), 1 - k % 1)
    np.add.at(envelope, (k.astype(int) + 1, rows, cols), k % 1)
    return envelope, rows, cols


def test_the_lct_mask_label_finds_a_point_where_it_is_and_nothing_without_an_object():
    """lct_seen on the noise-free confocal scan of one point 0.3 m out (16 × 16 points at 12.5 mm, 512 bins of
    16 ps, each transient a unit pulse at its round trip 2·√(z² + r²)/c): LCT focuses it back to the point, so the
    found points hold the point's own (4, 11) with their centroid within 1.5 points of it, and all lie within the
    resolution bound c·γ·√(w² + z²)/(2w) = 2.8 cm of it (γ 60 ps, w 0.1 m; unclipped, LCT's blur at 0.25 of its
    peak reaches 4.5 cm here); with an empty outline (no object in view) nothing is
    found, whatever the scan holds; an unknown mask label is refused in one line."""
    c, n, pitch, dt, z, (i0, j0) = 299792458.0, 16, 0.0125, 16e-12, 0.3, (4, 11)
    envelope, rows, cols = point_scan(n, pitch, dt, z, i0, j0)
    depth = torch.zeros(n, n)
    depth[i0, j0] = z
    seen = train_depth_image.lct_seen(envelope, dt, pitch, depth).numpy()
    assert seen[i0, j0] and 5 <= seen.sum() < 0.15 * n * n, seen.sum()
    assert np.hypot(rows[seen].mean() - i0, cols[seen].mean() - j0) < 1.5
    reach = c * 60e-12 * np.hypot(n * pitch / 2, z) / (n * pitch)
    assert np.hypot(rows[seen] - i0, cols[seen] - j0).max() * pitch <= reach
    assert not train_depth_image.lct_seen(envelope, dt, pitch, torch.zeros(n, n)).any()
    with pytest.raises(ValueError, match="mask_label must be one of outline, lct, counts, got 'edges'"):
        train_depth_image.load_split("nowhere", "train", mask_label="edges")


def test_the_measured_mask_label_finds_the_point_in_a_noisy_capture_and_no_wider_than_the_noise_free_one():
    """lct_seen with ``measured`` on a capture of the same point (the unit-pulse scan of the test above scaled to 50
    photons per point, a floor of 0.02 photons per bin, Poisson counts drawn with seed 3): the floor subtracted, the
    found points hold the point (4, 11), their centroid within 1.5 points of it, all within the resolution bound;
    the noise lifts the front view's pedestal, so they are no more than the noise-free label's (the reference's
    rule on a measured capture finds less than on a noise-free one); nothing with an empty outline."""
    c, n, pitch, dt, z, (i0, j0) = 299792458.0, 16, 0.0125, 16e-12, 0.3, (4, 11)
    envelope, rows, cols = point_scan(n, pitch, dt, z, i0, j0)
    counts = np.random.default_rng(3).poisson(50 * envelope + 0.02).astype(np.float32)
    depth = torch.zeros(n, n)
    depth[i0, j0] = z
    seen = train_depth_image.lct_seen(counts, dt, pitch, depth, measured=True).numpy()
    clean = train_depth_image.lct_seen(envelope, dt, pitch, depth).numpy()
    assert seen[i0, j0] and np.hypot(rows[seen].mean() - i0, cols[seen].mean() - j0) < 1.5
    reach = c * 60e-12 * np.hypot(n * pitch / 2, z) / (n * pitch)
    assert np.hypot(rows[seen] - i0, cols[seen] - j0).max() * pitch <= reach
    assert 1 <= seen.sum() <= clean.sum(), (seen.sum(), clean.sum())
    assert not train_depth_image.lct_seen(counts, dt, pitch, torch.zeros(n, n), measured=True).any()


def test_the_depth_is_extended_over_the_mask_from_the_nearest_outline_point():
    """extend_depth: an outline of two points (row 2, columns 2 and 3, at 0.5 and 0.7 m) and a mask over row 2's
    columns 0–5 and the point (4, 3): the outline keeps its depths, columns 0–1 take 0.5 m and 4–5 take 0.7 m
    (their nearest outline points), (4, 3) takes 0.7 m (2 points below column 3); every point outside both stays 0,
    and a sample without an outline stays 0 whatever its mask; an unknown ``depth_over`` is refused in one line."""
    depth = torch.zeros(2, 6, 6)
    depth[0, 2, 2], depth[0, 2, 3] = 0.5, 0.7
    over = torch.zeros(2, 6, 6, dtype=torch.bool)
    over[:, 2, :] = True
    over[:, 4, 3] = True
    out = train_depth_image.extend_depth(depth, over)
    np.testing.assert_allclose(out[0, 2].numpy(), [0.5, 0.5, 0.5, 0.7, 0.7, 0.7], rtol=1e-6)
    assert out[0, 4, 3] == pytest.approx(0.7)
    assert (out[0] > 0).sum() == 7 and not out[1].any() and out.dtype == torch.float32
    with pytest.raises(ValueError, match="depth_over must be one of outline, mask, got 'rim'"):
        train_depth_image.train("nowhere", depth_over="rim")


def test_the_lct_mask_label_loads_beside_either_input(wall):
    """load_split with mask_label "lct" gives the "seen" masks (N, H, W) bool on the label's grid beside the counts
    as beside the LCT volume (the pitch read from the params either way), the same masks for both, and none where
    the label has no object pixels."""
    counts = train_depth_image.load_split(wall, "test", mask_label="lct")
    volume = train_depth_image.load_split(wall, "test", lct=True, mask_label="lct")
    assert counts["seen"].shape == counts["depth"].shape == (2, 16, 16) and counts["seen"].dtype == torch.bool
    torch.testing.assert_close(counts["seen"], volume["seen"])
    assert counts["seen"].any()
    for seen, depth in zip(counts["seen"], counts["depth"]):
        assert (depth > 0).any() or not seen.any()


def test_the_counts_mask_label_loads_the_same_in_worker_processes(wall):
    """load_split with mask_label "counts" (what the LCT of each sample's stored counts finds): "seen" (N, H, W) bool
    within the object's reach, none without object pixels; prepared in 2 worker processes, every block is equal
    to the one prepared in this process."""
    here = train_depth_image.load_split(wall, "test", lct=True, mask_label="counts")
    workers = train_depth_image.load_split(wall, "test", lct=True, mask_label="counts", workers=2)
    assert set(here) == set(workers) == {"lct", "strongest", "depth", "seen"}
    for key in here:
        torch.testing.assert_close(here[key], workers[key], rtol=0, atol=0)
    assert here["seen"].shape == (2, 16, 16) and here["seen"].dtype == torch.bool and here["seen"].any()
    for seen, depth in zip(here["seen"], here["depth"]):
        assert (depth > 0).any() or not seen.any()


def test_training_on_a_split_the_data_lack_is_one_line(wall):
    """A split that is not in the dataset: one line naming it and the splits there are, no traceback."""
    expected = r"train_depth_image: split 'nosuch' not in .*\(splits: \['test', 'train'\]\)"
    with pytest.raises(SystemExit, match=expected):
        train_depth_image.main([str(wall), "--train", "nosuch", "--epochs", "1", "--threads", "1"])


def test_training_on_a_path_without_a_dataset_is_one_line(tmp_path):
    """A data path that holds no dataset: one line naming it, no traceback."""
    with pytest.raises(SystemExit, match=f"train_depth_image: no datagen dataset at {tmp_path / 'none'}"):
        train_depth_image.main([str(tmp_path / "none"), "--epochs", "1", "--threads", "1"])


def test_the_fine_base_reads_a_point_closer_than_the_input_voxels_do():
    """lct_input's strongest-voxel depth (the base the network's depth corrects) at a point's own scan position in
    the noise-free confocal scan of that point (:func:`point_scan`: 16 × 16 points at 12.5 mm, 512 bins of 16 ps),
    z from 0.380 to 0.420 m in 2 mm steps: with ``base_bins=512`` it lies within 1.5 16 ps voxels, 1.5·c·16 ps/2 =
    3.6 mm (+ 0.2 mm; a voxel, and LCT's resampling of t² moves the peak by up to half of one), of z at every z, and
    its errors spread over at most that (+ 0.1 mm; measured 0.1 to 3.7 mm); in the input's own 256 bins (4.8 mm
    voxels) they spread wider (measured −1.9 to +5.7 mm); 384 bins are refused in one line."""
    c, n, pitch, dt = 299792458.0, 16, 0.0125, 16e-12
    errors = {256: [], 512: []}
    for z in np.arange(0.380, 0.4201, 0.002):
        scan = np.moveaxis(point_scan(n, pitch, dt, z, 8, 8)[0], 0, -1)
        for bins, err in errors.items():
            err.append(float(train_depth_image.lct_input(scan, dt, pitch, 1, bins)[1][8, 8]) - z)
    reach = 1.5 * c * dt / 2
    assert np.abs(errors[512]).max() <= reach + 2e-4, errors[512]
    assert np.ptp(errors[512]) <= reach + 1e-4 < np.ptp(errors[256]), errors
    with pytest.raises(ValueError, match="base_bins must be one of 256, 512, got 384"):
        train_depth_image.lct_input(scan, dt, pitch, 1, 384)


def test_the_fine_base_is_kept_in_the_record_and_read_back(wall, tmp_path, monkeypatch):
    """``--input lct --base-bins 512``: the record keeps base_bins 512 and predict_depth asks lct_input for that base
    (the shipped records, without the key, get the input's own LCT_BINS); without ``--input lct`` it is one line."""
    torch.set_num_threads(1)
    with pytest.raises(SystemExit, match="train_depth_image: --base-bins 512 is the base of a network on the LCT "
                                         "volume: it needs --input lct"):
        train_depth_image.main([str(wall), "--val", "test", "--base-bins", "512"])
    net_file = tmp_path / "fine.pt"
    train_depth_image.main([str(wall), "--val", "test", "--epochs", "1", "--batch", "2", "--threads", "1", "--input",
                            "lct", "--base-bins", "512", "--out", str(tmp_path / "fine.npz"), "--save", str(net_file)])
    net, record = train_depth_image.load_model(net_file)
    assert record["base_bins"] == 512
    asked = []
    real_input = train_depth_image.lct_input

    def spy(*args):
        asked.append(args[4])
        return real_input(*args)

    monkeypatch.setattr("examples.depth_nets.lct_input", spy)
    item = NLOSDataset(wall, split="test", fields=("counts", "params")).read(0)
    dt = NLOSDataset(wall, split="test", fields=("counts",)).card["time_edges"]["bin_width"]
    pitch = train_depth_image.scan_pitch(item["params"])
    depth, _ = train_depth_image.predict_depth(net, record, np.asarray(item["counts"], np.float64), dt, pitch)
    record.pop("base_bins")
    train_depth_image.predict_depth(net, record, np.asarray(item["counts"], np.float64), dt, pitch)
    assert asked == [512, train_depth_image.LCT_BINS] and np.isfinite(depth).all()
