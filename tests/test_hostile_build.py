"""Hostile input, part 2: dataset builds, verify, the loader, and faults (issue 14).

A refused build writes nothing (the corrected command then works); ``verify`` finds truncated, deleted and
metadata-edited shards and edited cards; ``build --resume`` repairs them bit-identically to an uninterrupted
build; the loader never returns data from a store whose metadata disagrees with its card; a full disk and an
unreachable scheduler are one line; a SIGKILLed build leaves no process behind. Scenes, simulate, detect and
the detector API are tests/test_hostile.py.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
import zarr

from test_hostile import alias_bomb, cli   # the same in-process runner and checks

from datagen.dataset import (DatasetCorruptError, NLOSDataset, build_dataset, load_dataset_config, read_card,
                             verify_dataset)
from datagen.dataset.config import SplitSpec
from datagen.dataset.store import DONE_DIR, shard_file

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "datasets" / "smoke.yaml"


def tiny(train: int = 2, val: int = 1, shard_size: int = 1):
    """The smoke config cut to 3 one-sample shards (a fraction of a second of work)."""
    config = load_dataset_config(SMOKE)
    return config.model_copy(update={"splits": {"train": SplitSpec(count=train), "val": SplitSpec(count=val)},
                                     "shard_size": shard_size})


def config_file(tmp_path: Path, edit=None, config=None) -> Path:
    data = (config or tiny()).to_json()
    if edit is not None:
        edit(data)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def build_args(config: Path, out: Path, *extra) -> list:
    return ["build", config, "--out", out, "--workers", "0", "--quiet", *extra]


def arrays(path: Path) -> dict[str, bytes]:
    group = zarr.open_group(str(path), mode="r")
    return {f"{s}/{n}": repr(group[s][n][...].tolist()) if group[s][n].dtype.kind in "OT"
            else group[s][n][...].tobytes() for s in group.group_keys() for n in group[s].array_keys()}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("reference") / "ds"
    build_dataset(tiny(), out, workers=0, progress=False)
    return out


@pytest.fixture
def copy_of(reference, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    return out


def assert_same_as_reference(out: Path, reference: Path) -> None:
    """Bit-identical: every array's values and every shard file's sha256 equal the reference build's."""
    assert arrays(out) == arrays(reference)
    assert read_card(out)["shards"] == read_card(reference)["shards"]
    assert verify_dataset(out) == []


# ------------------------------------------------------------------------------------------ refused builds

REFUSED = {   # case: (config edit or None, extra CLI args, what the message names)
    "all split counts 0": (lambda d: d.update(splits={"train": {"count": 0}, "val": {"count": 0}}), [],
                           "splits: every split has count 0"),
    "labels.max_objects too small": (lambda d: d["labels"].update(max_objects=0), [], "labels.max_objects: 0"),
    "retries -5": (None, ["--retries", "-5"], "--retries must be an integer >= 0, got -5"),
    "tasks-per-worker 0": (None, ["--tasks-per-worker", "0"], "--tasks-per-worker must be an integer >= 1"),
    "workers -1": (None, ["--workers", "-1"], "--workers must be an integer >= 0, got -1"),
    "scheduler not an address": (None, ["--scheduler", "foo"], "--scheduler must be 'local' or an address"),
    "lookins too many": (lambda d: d["simulation"].update(estimator="lookin", lookins="100000x100000"), [],
                         "lookins 100000x100000"),
    "exposure 1e12 s": (lambda d: d["detector"].update(exposure="1e12s"), [], "detector"),
    "shard_size huge": (lambda d: d.update(shard_size=10**9), [], "shard_size 1000000000"),
    "area_samples too many": (lambda d: d["simulation"].update(area_samples=10**13), [], "area_samples"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_refused_build_writes_nothing(tmp_path, case):
    edit, extra, needle = REFUSED[case]
    out = tmp_path / "ds"
    cli(build_args(config_file(tmp_path, edit), out, *extra), 2, needle)   # a repeated option: the last counts
    assert not out.exists()


def test_refused_option_leaves_nothing_that_blocks_the_corrected_command(tmp_path):
    config, out = config_file(tmp_path), tmp_path / "ds"
    cli(["build", config, "--out", out, "--workers", "1", "--quiet", "--tasks-per-worker", "0"], 2,
        "--tasks-per-worker")
    cli(build_args(config, out), 0, "3 shards built")


def test_unreachable_scheduler_is_one_line_in_bounded_time_and_writes_nothing(tmp_path, monkeypatch):
    import datagen.dataset.dask_engine as engine
    monkeypatch.setattr(engine, "SCHEDULER_TIMEOUT_S", 1)
    out = tmp_path / "ds"
    t0 = time.monotonic()
    cli(["build", config_file(tmp_path), "--out", out, "--scheduler", "tcp://127.0.0.1:1", "--quiet"], 2,
        "--scheduler tcp://127.0.0.1:1: cannot reach the Dask scheduler within 1 s", "nothing was written")
    assert time.monotonic() - t0 < 30 and not out.exists()


def test_dataset_config_alias_bomb(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb())
    cli(build_args(path, tmp_path / "ds"), 2, str(path), "expands to more than")


@pytest.mark.parametrize("where", ["under a file", "a file"])
def test_out_under_or_at_an_existing_file(tmp_path, where):
    (tmp_path / "file").write_text("x")
    out = tmp_path / "file" / "ds" if where == "under a file" else tmp_path / "file"
    cli(build_args(config_file(tmp_path), out), 2, "--out", "is a file")


def test_existing_dataset_without_resume(tmp_path, copy_of):
    cli(build_args(config_file(tmp_path), copy_of), 2, "already holds a dataset; pass --resume")


def test_resume_with_another_config_names_the_difference(tmp_path, copy_of):
    cli(build_args(config_file(tmp_path, lambda d: d.update(seed=1)), copy_of, "--resume"), 2,
        "different config (differs in: seed)")


def test_disk_full_stops_the_build_in_one_line_and_resume_completes_it(tmp_path, reference, monkeypatch):
    import datagen.dataset.build as build_module
    real, calls = build_module.write_json_atomic, []

    def full_after_one(path, data):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, data)

    monkeypatch.setattr(build_module, "write_json_atomic", full_after_one)
    config, out = config_file(tmp_path), tmp_path / "ds"
    cli(build_args(config, out), 2, "No space left on device while writing shard train/000001", "--resume")
    assert read_card(out)["status"] == "incomplete"
    monkeypatch.setattr(build_module, "write_json_atomic", real)
    cli(build_args(config, out, "--resume"), 0, "2 shards built", "1 already done")
    assert_same_as_reference(out, reference)


# ------------------------------------------------------------------------------------------ damage

def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


DAMAGE = {   # case: (damage(ds), what verify reports)
    "truncated shard": (lambda ds: truncate(shard_file(ds, "train", "envelope", 1, 2)), "envelope: sha256 mismatch"),
    "deleted shard": (lambda ds: shard_file(ds, "val", "counts", 0, 2).unlink(), "counts: shard file missing"),
    "dtype edited": (lambda ds: edit_json(ds / "train" / "envelope" / "zarr.json",
                                          lambda d: d.update(data_type="int32")), "data_type 'int32'"),
    "shape edited": (lambda ds: edit_json(ds / "train" / "depth" / "zarr.json",
                                          lambda d: d.update(shape=[2, 8, 8])), "shape [2, 8, 8]"),
    "consolidated copy edited": (lambda ds: edit_json(ds / "zarr.json", lambda d: d["consolidated_metadata"][
        "metadata"]["val/envelope"].update(data_type="float64")), "consolidated metadata of val/envelope"),
    "card count edited": (lambda ds: edit_json(ds / "zarr.json", lambda d: d["attributes"]["splits"]["train"].update(
        count=3)), "splits.train.count is 3"),
    "array metadata deleted": (lambda ds: (ds / "val" / "object_count" / "zarr.json").unlink(),
                               "object_count/zarr.json: missing"),
    "done marker hash edited": (lambda ds: edit_json(ds / DONE_DIR / "train" / "000000.json",
                                                     lambda d: d["sha256"].update(counts="0" * 64)),
                                "done marker's hashes differ"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_verify_finds_the_damage_and_resume_repairs_it_bit_identically(tmp_path, reference, copy_of, case):
    damage, needle = DAMAGE[case]
    damage(copy_of)
    cli(["verify", copy_of], 1, needle)
    cli(build_args(config_file(tmp_path), copy_of, "--resume"), 0, "status complete", "repaired:")
    assert_same_as_reference(copy_of, reference)


def test_resume_rebuilds_a_shard_whose_marker_is_gone_over_its_old_file(tmp_path, reference, copy_of):
    """Before: removing a done marker made resume fail with 'Stored and computed checksum do not match'."""
    truncate(shard_file(copy_of, "train", "envelope", 0, 2))
    (copy_of / DONE_DIR / "train" / "000000.json").unlink()
    cli(build_args(config_file(tmp_path), copy_of, "--resume"), 0, "1 shards built")
    assert_same_as_reference(copy_of, reference)


# ------------------------------------------------------------------------------------------ loader


@pytest.mark.parametrize("index", [1.5, 1.0, "1", True, None, np.float32(1)])
def test_loader_refuses_non_integer_indices(reference, index):
    ds = NLOSDataset(reference, split="train")
    with pytest.raises(TypeError, match="sample index must be an integer"):
        ds[index]


def test_loader_takes_numpy_and_tensor_integers(reference):
    import torch
    ds = NLOSDataset(reference, split="train")
    assert torch.equal(ds[np.int64(1)]["envelope"], ds[1]["envelope"])
    assert torch.equal(ds[torch.tensor(-1)]["envelope"], ds[1]["envelope"])


@pytest.mark.parametrize("case", ["dtype edited", "shape edited", "array metadata deleted"])
def test_loader_refuses_metadata_that_disagrees_with_the_card(copy_of, case):
    """Before: a float32 → int32 edit returned 5.4e8 where 1.9e-19 was stored."""
    DAMAGE[case][0](copy_of)
    split = "val" if case == "array metadata deleted" else "train"
    with pytest.raises(DatasetCorruptError, match=r"zarr.json: (differs|missing).*datagen verify"):
        NLOSDataset(copy_of, split=split)


def test_loader_names_a_truncated_shard(copy_of):
    truncate(shard_file(copy_of, "train", "envelope", 1, 2))
    ds = NLOSDataset(copy_of, split="train")
    assert ds[0]["envelope"].sum() > 0                     # intact shards still read
    with pytest.raises(DatasetCorruptError, match=r"train/envelope/c/1/0: .*(truncated|checksum)"):
        ds[1]


def test_loader_names_a_deleted_shard(copy_of):
    shard_file(copy_of, "train", "counts", 1, 2).unlink()
    with pytest.raises(DatasetCorruptError, match=r"train/counts/c/1/0: shard file missing"):
        NLOSDataset(copy_of, split="train")[1]


def test_loader_finds_a_damaged_shard_index(copy_of):
    path = shard_file(copy_of, "train", "depth", 0, 3)
    data = bytearray(path.read_bytes())
    data[-10] ^= 0x01                                      # inside the index (offset, nbytes) table
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetCorruptError, match="shard index checksum does not match"):
        NLOSDataset(copy_of, split="train")[0]


def test_inspect_on_a_truncated_shard_is_one_line(tmp_path, copy_of):
    truncate(shard_file(copy_of, "train", "envelope", 0, 2))
    cli(["inspect", copy_of, "--png", tmp_path / "x.png", "--no-3d"], 2, "train/envelope/c/0/0")


def test_inspect_png_under_a_file(tmp_path, reference):
    (tmp_path / "file").write_text("x")
    cli(["inspect", reference, "--png", tmp_path / "file" / "x.png"], 2, "--png", "is a file")


def test_damaged_card_is_one_line_naming_it(copy_of):
    (copy_of / "zarr.json").write_bytes(b"\x00garbage")
    cli(["verify", copy_of], 2, "zarr.json: the dataset card is not a JSON object")
    cli(["inspect", copy_of], 2, "zarr.json: the dataset card is not a JSON object")


@pytest.mark.parametrize("key", ["config"])
def test_card_without_its_config_is_one_line_naming_it(copy_of, key):
    """A card edited by hand without ``config``: every reader says so in one line (inspect and the loader raised
    KeyError 'config')."""
    meta = json.loads((copy_of / "zarr.json").read_text())
    del meta["attributes"][key]
    (copy_of / "zarr.json").write_text(json.dumps(meta))
    needle = f"zarr.json: the dataset card has no {key!r} mapping"
    for command in (["verify", copy_of], ["inspect", copy_of, "--no-3d"]):
        cli(command, 2, needle)
    with pytest.raises(ValueError, match=needle):
        NLOSDataset(copy_of)


def test_verify_and_loader_on_something_that_is_not_a_dataset(tmp_path):
    cli(["verify", tmp_path], 2, "no datagen dataset")
    with pytest.raises(FileNotFoundError, match="no datagen dataset"):
        NLOSDataset(tmp_path)


# ------------------------------------------------------------------------------------------ SIGKILL


def _session_processes(sid: int) -> list[int]:
    """Live (non-zombie) processes of session ``sid``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] not in ("Z", "X"):   # fields: state ppid pgrp session
            pids.append(int(entry.name))
    return pids


def kill_and_count_survivors(args: list[str], started) -> list[int]:
    """Start ``datagen args`` in its own session, wait until ``started()`` (at most 120 s), SIGKILL the datagen
    process only, and return the processes of its session still alive 5 s later."""
    proc = subprocess.Popen([sys.executable, "-m", "datagen.cli", *args], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while not started(proc.pid):
            assert proc.poll() is None and time.monotonic() - t0 < 120, "the command made no progress"
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)                   # the command only: its children must follow
        proc.wait(timeout=10)
        deadline = time.monotonic() + 5.0
        while _session_processes(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        return _session_processes(proc.pid)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_a_build_leaves_no_process_after_5_s(tmp_path):
    """Before: the fork server, the resource tracker and both workers survived (≈ 370 MB, still writing
    shards 14 minutes later)."""
    config, out = config_file(tmp_path, config=tiny(train=40, val=0)), tmp_path / "ds"

    def started(pid):   # a shard is done, and the build, fork server, resource tracker and workers are up
        return bool(list(out.glob(f"{DONE_DIR}/*/*.json"))) and len(_session_processes(pid)) >= 4

    assert kill_and_count_survivors(["build", str(config), "--out", str(out), "--workers", "2", "--quiet"],
                                    started) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_simulate_with_workers_leaves_no_process_after_5_s(tmp_path):
    """The lookin estimator's fork workers (``simulate --workers 2``) die with the simulate process too."""
    args = ["simulate", "scene_library/demo_room.yaml", "--out", str(tmp_path / "out"), "--quiet", "--lookins",
            "40x40", "--workers", "2"]
    assert kill_and_count_survivors(args, lambda pid: len(_session_processes(pid)) >= 3) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_an_area_simulate_with_workers_leaves_no_process_after_5_s(tmp_path):
    """The area sampler's forked replicas (datagen.processes.ForkedCall) die with the simulate process too."""
    args = ["simulate", "scene_library/demo_room.yaml", "--out", str(tmp_path / "out"), "--quiet", "--estimator",
            "area", "--samples", "20000000", "--workers", "2"]
    assert kill_and_count_survivors(args, lambda pid: len(_session_processes(pid)) >= 2) == []
