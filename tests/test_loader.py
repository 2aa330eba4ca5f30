"""NLOSDataset: the fast shard reader returns exactly what zarr stores; DataLoader workers return the same
tensors as the main process; re-drawn SPAD noise is fresh per epoch, repeatable per epoch, and has the
detector model's mean."""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import zarr
from torch.utils.data import DataLoader

import datagen
from datagen import spad
from datagen.dataset import build_dataset
from datagen.dataset import load_dataset_config
from datagen.dataset.config import SplitSpec
from datagen.dataset import NLOSDataset
from datagen.dataset.loader import DETECTOR_FIELDS, SCALE_FIELDS

SMOKE = Path("configs/datasets/smoke.yaml")


@pytest.fixture(scope="module")
def dataset_path(tmp_path_factory):
    config = load_dataset_config(SMOKE)
    splits = {"train": SplitSpec(count=8), "val": SplitSpec(count=2)}
    config = config.model_copy(update={"splits": splits, "shard_size": 3})   # shards of 3, 3, 2 samples
    out = tmp_path_factory.mktemp("loader") / "ds"
    build_dataset(config, out, workers=0, progress=False)
    return out


def test_items_equal_the_stored_arrays(dataset_path):
    ds = datagen.NLOSDataset(dataset_path, split="train")
    group = zarr.open_group(str(dataset_path), mode="r")["train"]
    assert len(ds) == 8 and "params" not in ds.fields and {"envelope", "counts", "depth", "occupancy"} <= set(ds.fields)
    for i in (0, 2, 3, 7):      # first/last sample of a shard, and of the short last shard
        item = ds[i]
        for name in set(ds.fields) - set(SCALE_FIELDS):      # the scale fields are derived (test_loader_ergonomics)
            stored = group[name][i]
            assert isinstance(item[name], torch.Tensor), name
            assert item[name].numpy().dtype == stored.dtype and item[name].numpy().tobytes() == stored.tobytes(), name
    assert ds[-1]["counts"].equal(ds[7]["counts"])
    assert ds.params(5)["index"] == 5 and ds.params(5)["split"] == "train"
    with pytest.raises(IndexError):
        ds[8]


def test_the_loader_returns_each_samples_envelope_error(dataset_path):
    """envelope_error (the sample's estimated relative L2 error) comes back as a 0-d float32 tensor, the value
    its parameters record, and batches of it are (batch,)."""
    ds = NLOSDataset(dataset_path, split="train", fields=("envelope", "envelope_error"))
    item = ds[2]
    assert item["envelope_error"].shape == () and item["envelope_error"].dtype == torch.float32
    assert float(item["envelope_error"]) == pytest.approx(ds.params(2)["accuracy"]["envelope_error"], rel=1e-6)
    assert 0 < float(item["envelope_error"]) <= 0.05
    batch = next(iter(DataLoader(ds, batch_size=4)))
    assert batch["envelope_error"].shape == (4,)


def test_dataloader_two_workers_returns_the_same_tensors_as_zero(dataset_path):
    ds = NLOSDataset(dataset_path, split="train", fields=("envelope", "counts", "depth", "object_count"))
    ds[0]   # open shards in this process: nothing opened may travel to the workers
    state = pickle.dumps(ds)
    assert len(state) < 200_000 and pickle.loads(state)[4]["counts"].equal(ds[4]["counts"])
    batches0 = list(DataLoader(ds, batch_size=3, num_workers=0))
    batches2 = list(DataLoader(ds, batch_size=3, num_workers=2))
    assert len(batches0) == len(batches2) == 3
    for a, b in zip(batches0, batches2):
        assert a.keys() == b.keys()
        for name in a:
            assert a[name].dtype == b[name].dtype and torch.equal(a[name], b[name]), name
    assert batches0[0]["envelope"].shape == (3, 256) and batches0[0]["counts"].dtype == torch.int64


def test_resampled_noise_differs_across_epochs_and_repeats_within_one(dataset_path):
    frozen = NLOSDataset(dataset_path, split="train", fields=("counts",))
    ds = NLOSDataset(dataset_path, split="train", fields=("envelope", "counts"), noise="resample")
    ds.set_epoch(0)
    e0 = [ds[i]["counts"] for i in range(len(ds))]
    e0_again = [ds[i]["counts"] for i in range(len(ds))]
    ds.set_epoch(1)
    e1 = [ds[i]["counts"] for i in range(len(ds))]
    for i in range(len(ds)):
        assert torch.equal(e0[i], e0_again[i])
        assert not torch.equal(e0[i], e1[i])
        assert not torch.equal(e0[i], frozen[i]["counts"])
    # workers draw exactly what the main process draws for the same epoch
    ds.set_epoch(1)
    loaded = torch.cat([b["counts"] for b in DataLoader(ds, batch_size=4, num_workers=2)])
    assert torch.equal(loaded, torch.stack(e1))


def test_resampled_counts_have_the_detector_models_mean(dataset_path):
    """Mean total counts of 40 epochs of sample 1 = the pile-up model's expected total from the stored
    envelope (within 5 standard errors), as the build's own counts are a draw of the same model."""
    ds = NLOSDataset(dataset_path, split="train", fields=("envelope", "counts"), noise="resample")
    env = ds[1]["envelope"].numpy().astype(np.float64)
    det = spad.DetectorConfig.model_validate(ds.detector)
    expected = spad.expected_histogram(spad.rates_from_envelope(env, det), det).sum()
    totals = []
    for epoch in range(40):
        ds.set_epoch(epoch)
        totals.append(int(ds[1]["counts"].sum()))
    totals = np.asarray(totals, dtype=np.float64)
    assert abs(totals.mean() - expected) < 5 * totals.std(ddof=1) / np.sqrt(len(totals)) + 1e-9 * expected
    stored = NLOSDataset(dataset_path, split="train", fields=("counts",))[1]["counts"].sum().item()
    assert abs(stored - expected) < 5 * totals.std(ddof=1)


def test_transform_fields_and_errors(dataset_path):
    ds = NLOSDataset(dataset_path, split="val", fields=("depth", "params"),
                     transform=lambda item: {**item, "depth": item["depth"] * 2})
    item = ds[1]
    assert set(item) == {"depth", "params"} and isinstance(item["params"], str)
    raw = NLOSDataset(dataset_path, split="val", fields=("depth",))[1]["depth"]
    assert torch.equal(item["depth"], raw * 2)
    with pytest.raises(ValueError, match="split 'tran'"):
        NLOSDataset(dataset_path, split="tran")
    with pytest.raises(ValueError, match="fields \\['dept'\\]"):
        NLOSDataset(dataset_path, fields=("dept",))
    with pytest.raises(ValueError, match="noise must be"):
        NLOSDataset(dataset_path, noise="fresh")
    with pytest.raises(FileNotFoundError, match="no datagen dataset"):
        NLOSDataset(dataset_path / "nope")


def test_plot_returns_a_figure(dataset_path, tmp_path):
    ds = NLOSDataset(dataset_path, split="train")
    fig = ds.plot(2)
    titles = [ax.get_title() for ax in fig.axes]
    assert "envelope and counts" in titles and "depth from the FoV centre" in titles
    assert any(t.startswith("occupancy") for t in titles)
    fig.savefig(tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 10_000
    assert ds.plot(ds[2]) is not None


RANGES = {"exposure": (1e-3, 1e-2), "ambient_rate": (0.0, 1e5), "pde": (0.2, 0.4)}


def test_detector_ranges_are_drawn_per_sample_and_epoch_and_recorded(dataset_path):
    """Each item's drawn detector lies in its ranges (dcr, not given, stays the split's), is the same for the same
    epoch and index (in workers too) and differs across epochs and samples; cycles and background are the drawn
    detector's (round(exposure·f_rep), (pde·ambient + dcr)·bin width·cycles)."""
    ds = NLOSDataset(dataset_path, split="train", fields=("counts", "cycles", "background") + DETECTOR_FIELDS,
                     noise="resample", detector_ranges=RANGES)
    det = spad.DetectorConfig.model_validate(ds.detector)
    width = float(ds.time_edges[1] - ds.time_edges[0])
    ds.set_epoch(3)
    items = [ds[i] for i in range(len(ds))]
    for item in items:
        drawn = {f: float(item[f]) for f in DETECTOR_FIELDS}
        for f, (lo, hi) in RANGES.items():
            assert lo <= drawn[f] <= hi, (f, drawn[f])
        assert drawn["dcr"] == det.dcr and item["pde"].dtype == torch.float64 and item["pde"].shape == ()
        assert float(item["cycles"]) == round(drawn["exposure"] * det.repetition_rate)
        assert float(item["background"]) == pytest.approx(
            (drawn["pde"] * drawn["ambient_rate"] + det.dcr) * width * float(item["cycles"]), rel=1e-12)
    assert len({float(item["exposure"]) for item in items}) == len(items)          # a draw per sample
    again = [ds[i] for i in (0, 5)]
    assert all(torch.equal(again[k][f], items[i][f]) for k, i in enumerate((0, 5)) for f in again[k])
    loaded = next(iter(DataLoader(ds, batch_size=len(ds), num_workers=2)))
    assert torch.equal(loaded["pde"], torch.stack([item["pde"] for item in items]))
    assert torch.equal(loaded["counts"], torch.stack([item["counts"] for item in items]))
    ds.set_epoch(4)
    assert float(ds[0]["exposure"]) != float(items[0]["exposure"]) and float(ds[0]["pde"]) != float(items[0]["pde"])
    with pytest.raises(ValueError, match="detector_ranges needs noise='resample'"):
        NLOSDataset(dataset_path, split="train", detector_ranges=RANGES)
    with pytest.raises(ValueError, match="unknown detector field.*'gain'"):
        NLOSDataset(dataset_path, split="train", noise="resample", detector_ranges={"gain": (1, 2)})
    with pytest.raises(ValueError, match="pde range must have low <= high"):
        NLOSDataset(dataset_path, split="train", noise="resample", detector_ranges={"pde": (0.4, 0.2)})
    with pytest.raises(ValueError, match="detector_ranges: pde: "):
        NLOSDataset(dataset_path, split="train", noise="resample", detector_ranges={"pde": (0.2, 1.5)})


def test_randomised_counts_have_the_drawn_detectors_mean(dataset_path):
    """Over 60 epochs of sample 1, each epoch's total counts against the pile-up expectation of ITS drawn detector
    (the stored envelope × pde / 0.3, the drawn exposure, ambient rate and PDE; built here from the recorded
    draw): the standardised residuals z = (N − E)/√(E(1 − E/n)) have mean within 5/√60 of 0 and a standard
    deviation in [0.6, 1.5]. The expected totals span a factor > 3 across the draws, so counts drawn with the
    split's own detector fail."""
    ds = NLOSDataset(dataset_path, split="train", fields=("envelope", "counts") + DETECTOR_FIELDS,
                     noise="resample", detector_ranges=RANGES)
    base = spad.DetectorConfig.model_validate(ds.detector)
    z, expected = [], []
    for epoch in range(60):
        ds.set_epoch(epoch)
        item = ds[1]
        drawn = {f: float(item[f]) for f in DETECTOR_FIELDS}
        det = base.model_copy(update={"exposure": drawn["exposure"], "ambient_rate": drawn["ambient_rate"],
                                      "pde": drawn["pde"]})
        env = item["envelope"].numpy().astype(np.float64) * drawn["pde"] / base.pde
        e = spad.expected_histogram(spad.rates_from_envelope(env, det), det).sum()
        n = det.cycles
        z.append((int(item["counts"].sum()) - e) / np.sqrt(e * (1 - e / n)))
        expected.append(e)
    z = np.asarray(z)
    assert max(expected) > 3 * min(expected)
    assert abs(z.mean()) < 5 / np.sqrt(len(z)), z.mean()
    assert 0.6 < z.std(ddof=1) < 1.5, z.std(ddof=1)
