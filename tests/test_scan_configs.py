"""The network-resolution scan configs (wall128, confocal64): their smoke variants build, verify and load in the
network layout; the store's codec and counts-dtype options (Blosc zstd, bitshuffle, uint16 / uint32 counts)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from datagen.cli import main
from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config, read_card
from datagen.dataset.dtypes import stored_counts
from datagen.dataset.store import numeric_codecs
from datagen.errors import DatasetError

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "datasets"


@pytest.fixture(scope="module", params=[("wall128_smoke", "byte", (1, 512, 32, 32)),
                                        ("confocal64_smoke", "byte", (1, 512, 16, 16)),
                                        ("confocal64_smoke", "bit", (1, 512, 16, 16))],
                ids=["wall128_smoke", "confocal64_smoke", "confocal64_smoke-bitshuffle"])
def smoke(request, tmp_path_factory):
    name, shuffle, shape = request.param
    config = load_dataset_config(CONFIGS / f"{name}.yaml")
    if shuffle != config.store.shuffle:
        config = config.model_copy(update={"store": config.store.model_copy(update={"shuffle": shuffle})})
    out = tmp_path_factory.mktemp("configs") / name
    build_dataset(config, out, workers=0, progress=False)
    return out, shuffle, shape


def test_smoke_builds_verifies_and_loads_in_the_network_layout(smoke):
    path, shuffle, shape = smoke
    result = CliRunner().invoke(main, ["verify", str(path)])
    assert result.exit_code == 0, result.output
    assert "match the card's sha256" in result.output
    card = read_card(path)
    fields = card["splits"]["train"]["fields"]
    assert fields["counts"]["dtype"] == "<u2"                   # store.counts_dtype: uint16
    assert fields["envelope"]["dtype"] == "<f4"
    meta = json.loads((path / "train" / "envelope" / "zarr.json").read_text())
    blosc = meta["codecs"][0]["configuration"]["codecs"][-1]
    assert blosc["name"] == "blosc" and blosc["configuration"]["cname"] == "zstd"
    assert blosc["configuration"]["shuffle"] == {"byte": "shuffle", "bit": "bitshuffle"}[shuffle]

    net = NLOSDataset(path, split="test", layout="network")
    stored = NLOSDataset(path, split="test")
    for i in range(len(net)):
        a, b = stored[i], net[i]
        assert b["envelope"].shape == shape and b["envelope"].dtype == torch.float32
        assert b["counts"].shape == shape and b["counts"].dtype == torch.float32
        assert b["wall_depth"].shape == (1,) + shape[2:] and b["wall_depth"].dtype == torch.float32
        assert a["counts"].dtype == torch.int64                  # uint16 on disk, int64 to the user
        np.testing.assert_array_equal(b["counts"][0].numpy(), np.moveaxis(a["counts"].numpy(), -1, 0))
        assert int(a["counts"].sum()) > 0 and float(a["envelope"].max()) > 0
    f32 = NLOSDataset(path, split="test", fields=("counts",), layout="network", counts_dtype=torch.float32)[0]
    assert f32["counts"].dtype == torch.float32


def test_counts_dtype_refuses_counts_it_cannot_hold():
    counts = np.array([[0, 3, 65535]], dtype=np.int64)
    out = stored_counts(counts, "uint16", "sample (train, 0)")
    assert out.dtype == np.uint16 and out.tolist() == [[0, 3, 65535]]
    assert stored_counts(counts + 1, "uint32", "x").dtype == np.uint32
    with pytest.raises(DatasetError, match=r"^sample \(train, 7\): counts reach 65536 in a bin, more than "
                                           r"store.counts_dtype uint16 holds \(65535\); set store.counts_dtype"):
        stored_counts(counts + 1, "uint16", "sample (train, 7)")


def test_store_codecs_and_their_fingerprints():
    (lz4,) = numeric_codecs("lz4", 5)
    assert (lz4.cname.value, lz4.shuffle.value, lz4.clevel) == ("lz4", "shuffle", 5)
    (bz,) = numeric_codecs("blosc-zstd", 12, "bit")
    assert (bz.cname.value, bz.shuffle.value, bz.clevel) == ("zstd", "bitshuffle", 9)
    assert numeric_codecs("none", 5) is None
    # the new store keys at their defaults leave the config JSON (and so every older fingerprint) unchanged
    wall = load_dataset_config(CONFIGS / "wall.yaml")
    assert "counts_dtype" not in wall.to_json()["store"] and "shuffle" not in wall.to_json()["store"]
    smoke = load_dataset_config(CONFIGS / "wall128_smoke.yaml").to_json()["store"]
    assert smoke["counts_dtype"] == "uint16" and smoke["compression"] == "blosc-zstd" and "shuffle" not in smoke


def test_a_bad_counts_dtype_is_one_line(tmp_path):
    text = (CONFIGS / "wall128_smoke.yaml").read_text().replace("counts_dtype: uint16", "counts_dtype: uint8")
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace("room: ../rooms/wall.yaml", f"room: {CONFIGS.parent / 'rooms' / 'wall.yaml'}"))
    result = CliRunner().invoke(main, ["build", str(path), "--out", str(tmp_path / "out"), "--workers", "0"])
    assert result.exit_code == 2
    assert result.output.startswith("error: ") and "store.counts_dtype" in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize("name, points, bin_ps", [("wall128", [128, 128], 32), ("confocal64", [64, 64], 100)])
def test_full_configs_load_at_the_network_resolution(name, points, bin_ps):
    config = load_dataset_config(CONFIGS / f"{name}.yaml")
    room = config.to_json()
    assert room["room_overrides"]["capture"]["scan"]["points"] == points
    time = config.simulation_config("train").time
    assert time.n_bins == 512 and round(time.bin_width * 1e12) == bin_ps
    assert config.store.compression == "blosc-zstd" and config.store.counts_dtype == "uint16"


def test_depth_network_pools_a_network_resolution_scan(smoke, tmp_path):
    """examples/train_depth_image.py --pool 2 sums 2 × 2 scan points on loading and predicts on the label's grid."""
    path, shuffle, shape = smoke
    if shuffle != "byte" or shape[2] != 32:
        pytest.skip("once, on wall128_smoke")
    from examples import train_depth_image
    scan = torch.arange(2 * 4 * 4, dtype=torch.float32).reshape(1, 2, 4, 4)
    pooled = train_depth_image.pool_scan(scan, 2)
    assert pooled.shape == (1, 2, 2, 2) and pooled[0, 0, 0, 0].item() == 0 + 1 + 4 + 5
    torch.set_num_threads(1)
    out = tmp_path / "net.npz"
    train_depth_image.main([str(path), "--val", "test", "--epochs", "1", "--batch", "2", "--threads", "1",
                            "--pool", "2", "--out", str(out)])
    with np.load(out) as f:
        assert f["depth"].shape == (2, 32, 32) and np.isfinite(f["depth"]).all()
    with pytest.raises(ValueError, match=r"--pool 3 does not divide the 32 × 32 scan"):
        train_depth_image.load_split(path, "test", 3)
