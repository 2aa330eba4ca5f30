"""Capture sequences in datasets: the tracking set builds, verifies and loads clips through NLOSDataset, and the
tracking baseline's backprojection finds a point from its round trips (datagen/dataset/sequences.py,
examples/track_backprojection.py; docs/motion.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import datagen
from datagen.dataset.build import build_dataset
from datagen.dataset.integrity import verify_dataset
from datagen.units import SPEED_OF_LIGHT

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tracking(tmp_path_factory):
    out = tmp_path_factory.mktemp("tracking") / "data"
    build_dataset(ROOT / "configs/datasets/tracking_smoke.yaml", out, workers=1, progress=False)
    return out


def test_tracking_set_builds_verifies_and_stores_frames(tracking):
    assert verify_dataset(tracking) == []
    ds = datagen.NLOSDataset(tracking, split="train")
    assert len(ds) == 4
    item = ds[1]
    assert item["envelope"].shape == (6, 4, 4, 768) and item["counts"].shape == (6, 4, 4, 768)
    assert item["depth"].shape == (6, 16, 16) and item["occupancy"].shape == (16, 16, 16)
    pos, box = item["track_position"].numpy(), item["track_box"].numpy()
    assert pos.shape == (6, 1, 3) and np.all(box[:, :, 0] <= pos) and np.all(pos <= box[:, :, 1])
    np.testing.assert_allclose(item["frame_times"].numpy(), np.arange(6) / 10.0)
    params = ds.params(1)
    walker = params["room"]["motion"]["walkers"][0]
    speed = np.linalg.norm(item["track_velocity"].numpy()[:, 0, :2], axis=1)
    np.testing.assert_allclose(speed, walker["speed"], rtol=1e-5)     # back and forth, never standing
    assert float(item["envelope_error"]) == pytest.approx(float(item["frame_error"].max()))
    assert params["accuracy"]["sequence"]["change_split"] == 8


def test_clips_cut_the_per_frame_fields_and_keep_the_rest(tracking):
    whole = datagen.NLOSDataset(tracking, split="train")
    clips = datagen.NLOSDataset(tracking, split="train", clip=3)
    assert len(clips) == 8
    item = clips[5]                                   # sequence 2, frames 3..5
    assert int(item["sequence"]) == 2 and int(item["first_frame"]) == 3
    full = whole[2]
    for name in ("envelope", "counts", "track_position", "depth", "frame_times"):
        np.testing.assert_array_equal(item[name].numpy(), full[name].numpy()[3:6])
    np.testing.assert_array_equal(item["object_center"].numpy(), full["object_center"].numpy())
    batch = next(iter(__import__("torch").utils.data.DataLoader(clips, batch_size=4)))
    assert tuple(batch["counts"].shape) == (4, 3, 4, 4, 768)
    with pytest.raises(IndexError):
        clips[8]
    for bad in (0, 7, 2.5):
        with pytest.raises(ValueError, match="clip must be an integer from 1 to the sequences' 6 frames"):
            datagen.NLOSDataset(tracking, split="train", clip=bad)


def test_backprojection_finds_a_point_from_its_round_trips():
    """Frames whose one change is an impulse at the round trip spot → p → y_k → sensor of a known floor point p, for
    each of 16 pixels: the tracker returns p to within 4 grid pitches (0.2 m: 128 ps bins are 3.8 cm of path, and a
    1.2 m square of pixels seen from 2–4 m draws ellipsoids that cross at a shallow angle)."""
    from examples.track_backprojection import GRID_STEP, track

    room = {"relay_x": 6.0, "room_depth": 3.0, "room_length": 4.0, "corridor_width": 2.1, "bend_side": 1}
    spot, sensor = np.array([6.0, 0.0, 1.2]), np.array([0.5, 0.0, 1.2])
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, 4), np.linspace(0.9, 2.1, 4), indexing="xy")
    pixels = np.stack([np.full(16, 6.0), u.ravel(), v.ravel()], axis=1)
    edges = np.arange(0, 769) * 128e-12
    truth = [np.array([4.2, 3.1, 1.0]), np.array([5.1, 4.4, 1.0]), np.array([3.6, 2.0, 1.0])]
    frames = np.zeros((len(truth) + 2, 4, 4, 768))
    for f, p in enumerate(truth):
        path = (np.linalg.norm(p - spot) + np.linalg.norm(pixels - p, axis=1) + np.linalg.norm(pixels - sensor, axis=1))
        bins = np.floor(path / SPEED_OF_LIGHT / 128e-12).astype(int)
        frames[f].reshape(16, 768)[np.arange(16), bins] = 1.0
    est = track(frames, edges, (spot, pixels, sensor, 0.0, True, room), 1.0, 128e-12)
    for p, e in zip(truth, est):
        assert np.linalg.norm(e - p[:2]) <= 4 * GRID_STEP, (p, e)
