"""NLOSDataset for training: normalisation fields, object slot order, transforms with index and params, float
counts, the planner's decisions in params, occupancy resolution of the default config, both codecs."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import zarr

import datagen
from datagen import spad
from datagen.dataset import build_dataset, load_dataset_config, sample_room, scene_labels
from datagen.dataset.config import SplitSpec, sample_rngs
from datagen.planner import EFFECTS
from datagen.scene import Laser

SMOKE = Path("configs/datasets/smoke.yaml")
DEFAULT = Path("configs/datasets/default.yaml")


NEAR_BOX = {"objects": {"pillar": {"count": {"min": 1, "max": 1}},
                        "box": {"count": {"min": 1, "max": 1}, "placement": {"room": {"weight": 0.0}}}}}
"""A pillar in the L-room and a box in the corridor end: the box, generated last, is nearer the relay wall."""


def build(tmp_path_factory, name, **store):
    config = load_dataset_config(SMOKE)
    splits = {"train": SplitSpec(count=6), "near_box": SplitSpec(count=3, room_overrides=NEAR_BOX)}
    config = config.model_copy(update={"splits": splits, "shard_size": 4,
                                       "store": config.store.model_copy(update=store)})
    out = tmp_path_factory.mktemp(name) / "ds"
    build_dataset(config, out, workers=0, progress=False)
    return out


@pytest.fixture(scope="module")
def lz4_path(tmp_path_factory):
    return build(tmp_path_factory, "lz4", components=True)


def test_every_item_says_how_to_normalise_it(lz4_path):
    ds = datagen.NLOSDataset(lz4_path)
    det = spad.DetectorConfig.model_validate(ds.detector)
    item = ds[2]
    assert {"cycles", "photons_per_pulse", "background"} <= set(item)
    assert item["cycles"].item() == det.cycles == 100_000        # 10 MHz × 10 ms
    width = float(ds.time_edges[1] - ds.time_edges[0])
    assert item["background"].item() == pytest.approx((0.3 * 1e4 + 100) * width * det.cycles, rel=1e-12)
    laser = Laser(**ds.params(2)["room"]["laser"])
    assert item["photons_per_pulse"].item() == pytest.approx(laser.photons, rel=1e-12)
    # at low flux the expected counts are cycles × envelope + background (pile-up changes the late bins by e^{-C})
    env = item["envelope"].numpy().astype(np.float64)
    expected = spad.expected_histogram(spad.rates_from_envelope(env, det), det)
    first = np.argmax(env > 0)
    assert expected[first] == pytest.approx(item["cycles"].item() * env[first] + item["background"].item(), rel=1e-3)
    # datasets without the stored field derive it from params: drop it from the card and compare
    meta = json.loads((lz4_path / "zarr.json").read_text())
    fields = meta["attributes"]["splits"]["train"]["fields"]
    old = {k: v for k, v in fields.items() if k != "photons_per_pulse"}
    meta["attributes"]["splits"]["train"]["fields"] = old
    copy = lz4_path.parent / "old"
    copy.mkdir(exist_ok=True)
    (copy / "zarr.json").write_text(json.dumps(meta))
    for child in lz4_path.iterdir():
        if child.name != "zarr.json" and not (copy / child.name).exists():
            (copy / child.name).symlink_to(child)
    old_ds = datagen.NLOSDataset(copy, fields=("photons_per_pulse", "cycles"))
    assert old_ds[2]["photons_per_pulse"].item() == item["photons_per_pulse"].item()


def test_objects_sorted_by_distance_to_the_relay_wall(lz4_path):
    stored = {s: datagen.NLOSDataset(lz4_path, split=s) for s in ("train", "near_box")}
    ordered = {s: datagen.NLOSDataset(lz4_path, split=s, object_order="distance") for s in ("train", "near_box")}
    relay_x = stored["train"].card["config"]["room"]["relay_x"]
    seen_reorder = 0
    for split, i in [("train", i) for i in range(6)] + [("near_box", i) for i in range(3)]:
        a, b = stored[split][i], ordered[split][i]
        n = int(a["object_count"])
        order = np.argsort(relay_x - a["object_center"][:n, 0].numpy(), kind="stable")
        seen_reorder += not np.array_equal(order, np.arange(n))
        distance = relay_x - b["object_center"][:n, 0].numpy()
        assert np.all(np.diff(distance) >= 0)
        for name in ("object_class", "object_center", "object_size", "object_yaw", "object_albedo", "object_brdf"):
            assert torch.equal(b[name][:n], a[name][:n][order]), name
            assert torch.equal(b[name][n:], a[name][n:]), name        # padding stays last
        assert torch.equal(b["components"][1:1 + n], a["components"][1:1 + n][order])
        assert torch.equal(b["components"][0], a["components"][0]) and torch.equal(b["envelope"], a["envelope"])
    assert seen_reorder >= 3       # every near_box sample is reordered
    with pytest.raises(ValueError, match="object_order"):
        datagen.NLOSDataset(lz4_path, object_order="size")


def test_transform_receives_index_and_params_when_it_asks(lz4_path):
    calls = []

    def one(item):
        calls.append("one")
        return item

    def with_index(item, index):
        return {**item, "i": index}

    def with_both(item, index, params):
        return {"i": index, "split": params["split"], "n": params["room"]["objects"].__len__()}

    def with_kwargs(item, **kw):
        return sorted(kw)

    ds = datagen.NLOSDataset(lz4_path, fields=("object_count",), transform=one)
    ds[1]
    assert calls == ["one"]
    assert datagen.NLOSDataset(lz4_path, fields=("object_count",), transform=with_index)[-1]["i"] == 5
    got = datagen.NLOSDataset(lz4_path, fields=("object_count",), transform=with_both)[3]
    assert got["i"] == 3 and got["split"] == "train"
    assert got["n"] == int(datagen.NLOSDataset(lz4_path, fields=("object_count",))[3]["object_count"])
    assert datagen.NLOSDataset(lz4_path, fields=("depth",), transform=with_kwargs)[0] == ["index", "params"]
    assert isinstance(datagen.NLOSDataset(lz4_path, fields=("depth",), transform=dict)[0], dict)


def test_float_counts_frozen_and_resampled(lz4_path):
    for noise in ("frozen", "resample"):
        raw = datagen.NLOSDataset(lz4_path, fields=("envelope", "counts"), noise=noise)[4]["counts"]
        ds = datagen.NLOSDataset(lz4_path, fields=("envelope", "counts"), noise=noise, counts_dtype=torch.float32)
        item = ds[4]
        assert item["counts"].dtype == torch.float32 and torch.equal(item["counts"], raw.float())


def test_params_record_every_planner_decision(lz4_path):
    plan = datagen.NLOSDataset(lz4_path).params(0)["plan"]
    assert set(plan) == set(EFFECTS) | {"multibounce"}             # smoke.yaml: orders unset, i.e. auto
    for decision in plan.values():
        assert set(decision) == {"on", "forced", "reason"} and isinstance(decision["reason"], str)
    assert plan["secondary"] == {**plan["secondary"], "on": True, "forced": True}   # smoke.yaml fixes effects


def test_default_config_occupancy_resolves_every_object():
    """voxels: 64 in configs/datasets/default.yaml: 0.23 m voxels, below the smallest object edge (0.3 m);
    every object of 40 sampled rooms covers at least one voxel centre (at 32 voxels, 12 of 300 built samples
    had none at all)."""
    config = load_dataset_config(DEFAULT)
    spec = config.label_spec()
    dist = config.room_distribution("train")
    smallest = min(dist.objects.pillar.size.x.min, dist.objects.box.size.x.min)
    for i in range(40):
        rngs = sample_rngs(config.seed, "train", i)
        room = sample_room(dist, {k: rngs[k] for k in ("geometry", "materials", "sensor")})
        labels = scene_labels(room, spec)
        assert float(labels["occupancy_pitch"]) < smallest
        for obj in room.objects:
            alone = room.__class__(room.scene, room.params, [obj])
            assert scene_labels(alone, spec.model_copy(update={"max_objects": 1}))["occupancy"].sum() >= 1


def test_zstd_store_reads_through_the_fast_path(tmp_path_factory):
    path = build(tmp_path_factory, "zstd", compression="zstd")
    meta = json.loads((path / "train" / "envelope" / "zarr.json").read_text())
    assert meta["codecs"][0]["configuration"]["codecs"][-1]["name"] == "zstd"
    ds = datagen.NLOSDataset(path)
    group = zarr.open_group(str(path), mode="r")["train"]
    for i in (0, 5):
        for name in ("envelope", "counts", "occupancy"):
            assert ds[i][name].numpy().tobytes() == group[name][i].tobytes()


def test_reference_is_the_same_room_without_its_objects(tmp_path_factory):
    """store.reference: the empty room of sample i equals, bit for bit, sample i of a split with the same name
    whose distribution has no objects (room, materials, capture and sampling streams are drawn identically)."""
    config = load_dataset_config(SMOKE)
    store = config.store.model_copy(update={"reference": True})
    with_ref = config.model_copy(update={"splits": {"train": SplitSpec(count=5)}, "store": store})
    empty = {"objects": {"pillar": {"count": {"min": 0, "max": 0}}, "box": {"count": {"min": 0, "max": 0}}}}
    without = config.model_copy(update={"splits": {"train": SplitSpec(count=5, room_overrides=empty)}})
    a, b = tmp_path_factory.mktemp("ref") / "a", tmp_path_factory.mktemp("ref") / "b"
    build_dataset(with_ref, a, workers=0, progress=False)
    build_dataset(without, b, workers=0, progress=False)
    ref = datagen.NLOSDataset(a, fields=("envelope", "reference", "object_count"))
    plain = datagen.NLOSDataset(b, fields=("envelope", "object_count"))
    changed = 0
    for i in range(5):
        assert int(plain[i]["object_count"]) == 0
        assert torch.equal(ref[i]["reference"], plain[i]["envelope"])
        same = torch.equal(ref[i]["reference"], ref[i]["envelope"])
        assert same or int(ref[i]["object_count"]) > 0          # an empty room is its own reference
        changed += not same           # (an object no lookin of the 4×4 smoke sampling reaches changes nothing)
    assert changed >= 1


def test_cli_build_splits_cuts_the_config_to_a_prefix(tmp_path):
    """``datagen build … --splits train=3``: only that split, 3 samples, each equal to the full build's."""
    from click.testing import CliRunner
    from datagen.cli.main import main

    out = tmp_path / "cut"
    result = CliRunner().invoke(main, ["build", str(SMOKE), "--out", str(out), "--workers", "0", "--quiet",
                                       "--splits", "train=3"])
    assert result.exit_code == 0, result.output
    ds = datagen.NLOSDataset(out, fields=("envelope", "counts"))
    assert len(ds) == 3 and set(ds.card["splits"]) == {"train"}
    config = load_dataset_config(SMOKE)
    from datagen.dataset import make_sample
    full = make_sample(config, "train", 2)
    assert ds[2]["envelope"].numpy().tobytes() == full.arrays["envelope"].tobytes()
    for bad, text in (("tran=3", "no split 'tran'"), ("train=x", "NAME=COUNT"), ("train=-1", ">= 0")):
        result = CliRunner().invoke(main, ["build", str(SMOKE), "--out", str(tmp_path / "x"), "--splits", bad])
        assert result.exit_code == 2 and text in result.output and result.output.count("\n") == 1, result.output


def test_batch_noise_in_the_workers_repeats_and_keeps_the_mean(lz4_path):
    from datagen.dataset import BatchNoise

    ds = datagen.NLOSDataset(lz4_path, fields=("envelope", "object_count"))

    def epoch(seed):
        loader = torch.utils.data.DataLoader(ds, batch_size=3, num_workers=2,
                                             collate_fn=BatchNoise(ds.spad_noise(), seed=seed))
        return list(loader)

    a, b, c = epoch(1), epoch(1), epoch(2)
    assert a[0]["counts"].shape == (3, 256) and a[0]["counts"].dtype == torch.float32
    assert a[0]["cycles"].tolist() == [100_000.0] * 3 and a[0]["object_count"].shape == (3,)
    assert all(torch.equal(x["counts"], y["counts"]) for x, y in zip(a, b))
    assert not torch.equal(a[0]["counts"], c[0]["counts"]) and not torch.equal(a[0]["counts"], a[1]["counts"][:3])
    expected = ds.spad_noise().expected(torch.cat([x["envelope"] for x in a])).sum(-1)
    drawn = torch.cat([x["counts"] for x in a + c]).sum(-1).double().view(2, -1)
    z = (drawn.mean(0) - expected) / torch.sqrt(expected / 2)      # totals: variance at most the mean (pile-up)
    assert z.abs().max() < 4
