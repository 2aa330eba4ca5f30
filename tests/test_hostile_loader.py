"""Hostile input, the loader and the torch noise (issue 28): count dtypes that cannot hold the counts, envelope
PDEs and generators SPADNoise cannot use, a ``split`` that is not a name, and a byte changed inside a stored
chunk, which only ``NLOSDataset(..., verify=True)`` (and ``datagen verify``) sees. Each case is refused with one
message naming the parameter (or the file) and the value, or gives the right result.
"""
from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

import datagen
from datagen import spad
from datagen.dataset import DatasetCorruptError, NLOSDataset, build_dataset, load_dataset_config, verify_dataset
from datagen.dataset.config import SplitSpec, config_from_json
from datagen.dataset.store import DONE_DIR, shard_file
from datagen.dataset import shard_reader
from datagen.spad.torch_noise import exact_count_limit

from test_hostile import cli

pytestmark = pytest.mark.timeout(600)      # the first test builds the datasets (numba compiles once)

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "datasets" / "smoke.yaml"
CYCLES = 100_000                           # smoke detector: 10 ms at 10 MHz


def smoke(**splits):
    config = load_dataset_config(SMOKE)
    return config.model_copy(update={"splits": {k: SplitSpec(count=v) for k, v in splits.items()},
                                     "shard_size": 2})


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Smoke samples in shards of 2: train shards 0 (samples 0, 1) and 1 (2, 3), val shard 0."""
    out = tmp_path_factory.mktemp("loader") / "ds"
    build_dataset(smoke(train=4, val=1), out, workers=0, progress=False)
    return out


@pytest.fixture
def copy_of(reference, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    return out


@pytest.fixture(scope="module")
def poisson_path(tmp_path_factory):
    """One poisson-model sample of 20 cycles with 12 ambient detections per cycle per bin: bins count ~240,
    more than the cycles (a pile-up bin never counts more than the cycles)."""
    data = smoke(train=1).to_json()
    data["detector"].update(model="poisson", ambient_rate=2e11, exposure="2us")
    data["simulation"]["effects"]["pile_up"] = False
    out = tmp_path_factory.mktemp("poisson") / "ds"
    build_dataset(config_from_json(data), out, workers=0, progress=False)
    return out


def flip_last_byte_of_chunk(path: Path, shard_size: int, k: int) -> None:
    """Flip the lowest bit of the last byte of inner chunk ``k`` of a shard file (its index at the end)."""
    raw = bytearray(path.read_bytes())
    index = np.frombuffer(bytes(raw[-(16 * shard_size + 4):-4]), dtype="<u8").reshape(shard_size, 2)
    offset, nbytes = (int(v) for v in index[k])
    raw[offset + nbytes - 1] ^= 0x01
    path.write_bytes(bytes(raw))


# ------------------------------------------------------------------------------------------ counts dtype


@pytest.mark.parametrize("dtype, limit", [(torch.uint8, 255), (torch.int8, 127), (torch.int16, 32767),
                                          (torch.float16, 2048), (torch.bfloat16, 256)])
def test_loader_refuses_a_counts_dtype_narrower_than_the_cycles(reference, dtype, limit):
    """Before: counts_dtype=torch.uint8 returned 242 where 473 was stored (wrapped), exit 0."""
    with pytest.raises(ValueError, match=rf"NLOSDataset: counts_dtype={dtype} holds counts up to {limit} exactly, "
                                         rf"but a bin can count up to {CYCLES} .*pass counts_dtype=torch.int32"):
        NLOSDataset(reference, counts_dtype=dtype)


@pytest.mark.parametrize("dtype, exc, text", [(torch.bool, ValueError, "torch.bool cannot hold counts"),
                                              (torch.complex64, ValueError, "torch.complex64 cannot hold counts"),
                                              ("float32", TypeError, "must be a torch.dtype .*got 'float32'")])
def test_loader_refuses_a_counts_dtype_that_is_not_a_count(reference, dtype, exc, text):
    with pytest.raises(exc, match=rf"NLOSDataset: counts_dtype=.*{text}"):
        NLOSDataset(reference, counts_dtype=dtype)


def test_loader_counts_dtypes_that_hold_the_counts_give_the_stored_values(reference):
    stored = NLOSDataset(reference, fields=("counts",))[2]["counts"]
    assert stored.dtype == torch.int64 and 100 < int(stored.max()) < 1000
    for dtype in (torch.int32, torch.float32, torch.float64):
        counts = NLOSDataset(reference, fields=("counts",), counts_dtype=dtype)[2]["counts"]
        assert counts.dtype == dtype and torch.equal(counts.to(torch.int64), stored)


def test_loader_counts_dtype_bound_is_the_longest_drawn_exposure(reference):
    """With detector_ranges the bound is the top of the exposure range: 10 ms at 10 MHz = 1e5 > int16's 32767,
    1 ms = 1e4 fits."""
    with pytest.raises(ValueError, match="int16 holds counts up to 32767 exactly, but a bin can count up to 100000"):
        NLOSDataset(reference, noise="resample", detector_ranges={"exposure": ("1ms", "10ms")},
                    counts_dtype=torch.int16)
    ds = NLOSDataset(reference, fields=("envelope", "counts", "cycles"), noise="resample",
                     detector_ranges={"exposure": ("0.1ms", "1ms")}, counts_dtype=torch.int16)
    item = ds[1]
    assert item["counts"].dtype == torch.int16 and 0 < int(item["counts"].max()) <= float(item["cycles"]) <= 10_000


def test_loader_checks_each_items_counts_when_bins_can_count_more_than_the_cycles(poisson_path):
    """Poisson model, 20 cycles: int8 (up to 127) passes the construction check, the read counts exceed it."""
    most = int(NLOSDataset(poisson_path, fields=("counts",))[0]["counts"].max())
    assert most > 127
    ds = NLOSDataset(poisson_path, fields=("counts",), counts_dtype=torch.int8)
    with pytest.raises(ValueError, match=rf"counts_dtype=torch.int8 holds counts up to 127 exactly, but sample 0 "
                                         rf"of 'train' counts {most} in a bin; pass a wider counts_dtype"):
        ds[0]
    assert int(NLOSDataset(poisson_path, fields=("counts",), counts_dtype=torch.int16)[0]["counts"].max()) == most


# ------------------------------------------------------------------------------------------ SPADNoise


def detector(**kw) -> spad.DetectorConfig:
    base = dict(model="pile_up", pde=0.3, dcr=100.0, ambient_rate=1e4, repetition_rate=1e7, n_cycles=10_000,
                bin_width=100e-12)
    return spad.DetectorConfig(**(base | kw))


ENVELOPE = torch.full((2, 64), 1e-2)


@pytest.mark.parametrize("dtype, limit", [(torch.int8, 127), (torch.uint8, 255), (torch.float16, 2048),
                                          (torch.bfloat16, 256)])
def test_spad_noise_refuses_a_dtype_narrower_than_the_cycles(dtype, limit):
    """Before: dtype=torch.int8 or torch.uint8 wrapped the counts, exit 0."""
    with pytest.raises(ValueError, match=rf"SPADNoise: dtype={dtype} holds counts up to {limit} exactly, but a bin "
                                         rf"can count up to 10000 .*pass dtype=torch.int32"):
        datagen.SPADNoise(detector(), dtype=dtype)


def test_spad_noise_refuses_bool_and_keeps_dtypes_that_fit():
    """Before: dtype=torch.bool saturated every count to True."""
    with pytest.raises(ValueError, match="SPADNoise: dtype=torch.bool: torch.bool cannot hold counts"):
        datagen.SPADNoise(detector(), dtype=torch.bool)
    counts = datagen.SPADNoise(detector(), dtype=torch.int16)(ENVELOPE, torch.Generator().manual_seed(1))
    wide = datagen.SPADNoise(detector(), dtype=torch.float64)(ENVELOPE, torch.Generator().manual_seed(1))
    assert counts.dtype == torch.int16 and torch.equal(counts.double(), wide) and wide.sum() > 1000
    assert exact_count_limit(torch.float32) == 2**24 and exact_count_limit(torch.int32) == 2**31 - 1


def test_spad_noise_poisson_counts_beyond_the_dtype_are_refused():
    """Poisson bins can count more than the cycles: 10 cycles at 40 detections each ≈ 400 > int8's 127."""
    noise = datagen.SPADNoise(detector(model="poisson", n_cycles=10), dtype=torch.int8)
    with pytest.raises(ValueError, match=r"SPADNoise: dtype=torch.int8 holds counts up to 127 exactly, but a bin "
                                         r"counted \d{3}; pass a wider dtype"):
        noise(torch.full((2, 8), 40.0), torch.Generator().manual_seed(0))


@pytest.mark.parametrize("value", [-0.3, math.nan, math.inf, -math.inf, 1.5])
def test_spad_noise_refuses_an_envelope_pde_outside_0_1(value):
    """Before: a negative or NaN envelope_pde silently dropped the signal (background only), exit 0."""
    with pytest.raises(ValueError, match=rf"SPADNoise: envelope_pde must be a finite number in \[0, 1\], got "
                                         rf"{value!r}"):
        datagen.SPADNoise(detector(), envelope_pde=value)


@pytest.mark.parametrize("field, value, text", [("pde", -0.1, "greater than or equal to 0"),
                                                ("pde", math.nan, "finite number"),
                                                ("ambient_rate", -5.0, "greater than or equal to 0"),
                                                ("ambient_rate", (0.0, math.inf), "finite number"),
                                                ("dcr", math.nan, "finite number"),
                                                ("exposure", -1e-3, "greater than 0")])
def test_spad_noise_other_rates_and_probabilities_are_checked_the_same_way(field, value, text):
    with pytest.raises(ValueError, match=rf"SPADNoise: {field}: .*{text}"):
        datagen.SPADNoise(detector(), **{field: value})


def test_spad_noise_takes_an_int_seed_and_refuses_a_numpy_generator():
    """Before: a numpy Generator or an int failed inside torch.rand() with a TypeError listing its overloads."""
    noise = datagen.SPADNoise(detector())
    with pytest.raises(TypeError, match=r"SPADNoise: generator must be a torch.Generator or an int seed, got "
                                        r"numpy.Generator"):
        noise(ENVELOPE, np.random.default_rng(0))
    with pytest.raises(TypeError, match="got builtins.bool"):
        noise(ENVELOPE, True)
    with pytest.raises(ValueError, match=r"generator seed must be in \[0, 2\*\*64\), got -1"):
        noise(ENVELOPE, -1)
    seeded = noise(ENVELOPE, 7)
    assert torch.equal(seeded, noise(ENVELOPE, torch.Generator().manual_seed(7)))
    assert torch.equal(seeded, noise(ENVELOPE, np.int64(7))) and seeded.sum() > 1000


def test_spad_noise_envelope_shapes():
    """Before: 0 bins failed in reshape ('cannot reshape tensor of 0 elements'); a numpy envelope in .dim()."""
    noise = datagen.SPADNoise(detector())
    for call in (noise, noise.expected):
        with pytest.raises(ValueError, match=r"envelope must be \(batch, \.\.\., bins\) with at least one bin, got "
                                             r"shape \(2, 0\)"):
            call(torch.zeros(2, 0))
    with pytest.raises(TypeError, match="SPADNoise: envelope must be a torch.Tensor, got ndarray"):
        noise(np.zeros((2, 64)))
    counts, params = noise.sample(torch.zeros(0, 64), 1)          # an empty batch: empty counts
    assert counts.shape == (0, 64) and params["cycles"].shape == (0,)


# ------------------------------------------------------------------------------------------ split


@pytest.mark.parametrize("split", [["train"], ("train",), 0, None])
def test_loader_split_that_is_not_a_name(reference, split):
    """Before: split=["train"] raised TypeError: unhashable type: 'list'."""
    with pytest.raises(TypeError, match=rf"split must be one split name \(a str\), got {re.escape(repr(split))} "
                                        rf"\({type(split).__name__}\); splits: \['train', 'val'\]"):
        NLOSDataset(reference, split=split)
    with pytest.raises(ValueError, match=r"split 'test' not in .*\(splits: \['train', 'val'\]\)"):
        NLOSDataset(reference, split="test")


# ------------------------------------------------------------------------------------------ verify=True


def test_a_byte_changed_inside_a_chunk_is_data_to_the_plain_loader_and_an_error_with_verify(reference, copy_of):
    """The limit of the per-read checks, and the checked read: the plain loader returns the damaged chunk's
    values (a count gains 2**56), verify=True names the shard file, `datagen verify` finds it too."""
    good = NLOSDataset(reference, fields=("counts",))[1]["counts"]
    path = shard_file(copy_of, "train", "counts", 0, 2)
    flip_last_byte_of_chunk(path, 2, 1)                          # sample 1 = shard 0, inner chunk 1
    bad = NLOSDataset(copy_of, fields=("counts",))[1]["counts"]
    changed = (bad != good).nonzero().flatten()
    assert changed.numel() == 1 and int(bad[changed]) - int(good[changed]) == 2**56
    ds = NLOSDataset(copy_of, fields=("counts", "depth"), verify=True)
    assert torch.equal(ds[3]["counts"], NLOSDataset(reference, fields=("counts",))[3]["counts"])  # shard 1 intact
    for index in (0, 1):                                         # every sample of the damaged shard
        with pytest.raises(DatasetCorruptError, match=rf"{re.escape(str(path))}: sha256 [0-9a-f]{{16}}… differs "
                                                      r"from the recorded [0-9a-f]{16}….*datagen verify"):
            ds[index]
    assert any(f"sha256 mismatch (corrupted: {path})" in line for line in verify_dataset(copy_of))
    cli(["verify", copy_of], 1, str(path))


def test_verify_in_two_dataloader_workers_raises_naming_the_shard(copy_of):
    path = shard_file(copy_of, "train", "envelope", 1, 2)
    flip_last_byte_of_chunk(path, 2, 0)
    ds = NLOSDataset(copy_of, fields=("envelope", "counts"), verify=True)
    with pytest.raises(DatasetCorruptError, match=rf"{re.escape(str(path))}: sha256 .* differs"):
        list(DataLoader(ds, batch_size=1, num_workers=2))


def test_verify_hashes_each_shard_once_per_process_and_returns_the_same_items(reference, monkeypatch):
    plain = NLOSDataset(reference, fields=("envelope", "counts", "depth"))
    checked = NLOSDataset(reference, fields=("envelope", "counts", "depth"), verify=True)
    batches = list(DataLoader(checked, batch_size=2, num_workers=2))
    assert [torch.equal(b["envelope"], p["envelope"]) and torch.equal(b["counts"], p["counts"])
            for b, p in zip(batches, DataLoader(plain, batch_size=2))] == [True, True]
    hashed = []
    real = shard_reader.file_sha256
    monkeypatch.setattr(shard_reader, "file_sha256", lambda p: hashed.append(Path(p)) or real(p))
    for _ in range(2):                                           # two passes: the second hashes nothing
        for i in range(len(checked)):
            checked[i]
    assert len(hashed) == 2 * 3 and len(set(hashed)) == 6        # 2 train shards × 3 fields, once each
    assert len(list(DataLoader(checked, batch_size=2, num_workers=2))) == 2   # workers hash again, no error


def test_verify_without_a_recorded_hash_says_so(copy_of):
    card_path = copy_of / "zarr.json"
    card = json.loads(card_path.read_text())
    del card["attributes"]["shards"]["val"]["000000"]["sha256"]["depth"]
    card_path.write_text(json.dumps(card))
    marker = copy_of / DONE_DIR / "val" / "000000.json"
    data = json.loads(marker.read_text())
    del data["sha256"]["depth"]
    marker.write_text(json.dumps(data))
    path = shard_file(copy_of, "val", "depth", 0, 3)
    with pytest.raises(DatasetCorruptError, match=rf"{re.escape(str(path))}: no sha256 recorded in the dataset "
                                                  r"card or the done marker, so verify=True cannot check it"):
        NLOSDataset(copy_of, split="val", fields=("depth",), verify=True)[0]
