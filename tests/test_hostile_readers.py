"""Hostile input, part 3: the commands that read a dataset (issue 28).

Every reader (the loader, ``score``, ``inspect``, ``view``, ``export-tal``, ``detect``) refuses an incomplete build
with the same line (:func:`datagen.dataset.integrity.require_complete`: the dataset, the splits and the shard
numbers not built, and ``--resume``); ``score`` refuses repeated indices, 0-d arrays, NaN occupancy and a NaN
threshold and reads its labels through the loader; ``detect`` of a dataset folder says what to use instead;
``export-tal`` checks ``--out`` before any work and leaves no ``.partial`` behind. A hypothesis property test
throws random prediction files at ``score``: exit 0 with finite, consistent scores, or exit 2 with one line.
"""
from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from test_hostile import cli   # the in-process runner: exit code, needles, no traceback, one error line
from test_hostile_build import tiny

from datagen.cli import main
from datagen.dataset import NLOSDataset, build_dataset, read_card
from datagen.dataset.config import config_from_json
from datagen.dataset.store import marker_path, shard_file
from datagen.dataset.integrity import (DatasetIncompleteError, card_fields, number_ranges, remove_shard_files,
                                       require_complete, verify_dataset)
from datagen.dataset.store import finish_card, plan_shards, zarr_module

ROOT = Path(__file__).resolve().parents[1]
DETECTOR = ROOT / "configs" / "detectors" / "cmos_spad_array.yaml"
TRAIN = 4
"""Samples of the train split (one per shard): depth labels (16, 16) with object pixels, occupancy (16, 16, 16)."""


@pytest.fixture(scope="module")
def complete(tmp_path_factory):
    out = tmp_path_factory.mktemp("readers") / "ds"
    build_dataset(tiny(train=TRAIN, val=1), out, workers=0, progress=False)
    return out


def unbuild(root: Path, shards: dict[str, list[int]], finish: bool = True) -> None:
    """Make ``root`` what an interrupted build leaves: the shards' done markers and files gone and the card
    filled from the remaining markers (``finish``: as a build that ended with failed shards writes it), or
    left as the build's initialisation wrote it (no shard records: a build killed before its end)."""
    card = read_card(root)
    config = config_from_json(card["config"])
    for task in plan_shards(config):
        if task.shard in shards.get(task.split, []):
            marker_path(root, task.split, task.shard).unlink()
            remove_shard_files(root, task, card_fields(card))
    if finish:
        card = finish_card(root, card, config)
    else:
        for key in ("shards", "shards_done", "shards_total", "timing", "accuracy"):
            card.pop(key, None)
        card["status"] = "incomplete"
    group = zarr_module().open_group(str(root), mode="r+")
    group.attrs.clear()
    group.update_attributes(card)


@pytest.fixture(scope="module")
def interrupted(complete, tmp_path_factory):
    out = tmp_path_factory.mktemp("interrupted") / "ds"
    shutil.copytree(complete, out)
    unbuild(out, {"train": [1, 2]})
    return out


@pytest.fixture
def copy_of(complete, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(complete, out)
    return out


def refusal(path: Path) -> str:
    return (f"error: {path}: the dataset build is not complete (train shards 1-2 of {TRAIN} not built); finish it "
            f"with `datagen build CONFIG --out {path} --resume`")


def predictions(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


def good_depth(n: int = TRAIN) -> np.ndarray:
    return np.ones((n, 16, 16))


# ------------------------------------------------------------------------------------------ incomplete builds


@pytest.mark.parametrize("numbers, text", [([3, 5, 6, 7, 8, 9], "3, 5-9"), ([], ""), ([0], "0"), ([2, 1], "1-2"),
                                           ([0, 2, 4], "0, 2, 4"), ([7, 7, 8], "7-8")])
def test_shard_numbers_are_written_as_compact_ranges(numbers, text):
    assert number_ranges(numbers) == text


def test_require_complete_names_the_splits_the_missing_shards_and_resume(interrupted, tmp_path):
    with pytest.raises(DatasetIncompleteError) as info:
        require_complete(interrupted)
    assert f"error: {info.value}" == refusal(interrupted)
    # a build killed before its end records no shards in its card: the done markers are the truth
    killed = tmp_path / "killed"
    shutil.copytree(interrupted, killed)
    unbuild(killed, {"train": [3], "val": [0]}, finish=False)
    assert "shards" not in read_card(killed)
    with pytest.raises(DatasetIncompleteError, match=r"\(train shards 1-3 of 4; val shard 0 of 1 not built\); "
                                                     r"finish it with `datagen build CONFIG --out "):
        require_complete(killed)


def test_every_shard_built_but_the_card_not_finished(copy_of):
    """A build killed after its last shard but before it completed the card: resume only finishes the card."""
    unbuild(copy_of, {}, finish=False)
    with pytest.raises(DatasetIncompleteError, match="every shard is built but the build did not finish.*--resume"):
        require_complete(copy_of)


def test_the_loader_refuses_an_incomplete_build_with_the_shared_line(interrupted):
    """Before: '… (3 of 5 shards); resume it with `datagen build ... --resume`' (no shard numbers)."""
    with pytest.raises(DatasetIncompleteError) as info:
        NLOSDataset(interrupted, split="val")          # even a split whose shards are all built
    assert f"error: {info.value}" == refusal(interrupted)


READERS = {   # command: (arguments after the dataset path, files it would write, relative to tmp_path)
    "export-tal": (lambda ds, tmp: ["export-tal", ds, "--split", "train", "--index", "1", "--out", tmp / "s.hdf5"],
                   ["s.hdf5", "s.hdf5.partial"]),
    "score": (lambda ds, tmp: ["score", predictions(tmp / "p.npz", depth=good_depth()), "--dataset", ds, "--split",
                               "train", "--depth-field", "depth"], ["p_scores.csv", "p_scores.json"]),
    "inspect": (lambda ds, tmp: ["inspect", ds, "--no-3d", "--png", tmp / "i.png"], ["i.png"]),
    "view": (lambda ds, tmp: ["view", ds, "--split", "train", "--index", "1", "--out", tmp / "v.png"], ["v.png"]),
    "detect": (lambda ds, tmp: ["detect", ds, "--detector", DETECTOR], []),
}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("command", sorted(READERS))
def test_every_reader_refuses_an_incomplete_build_with_the_same_line(interrupted, tmp_path, command):
    """Before: export-tal wrote an H of zeros for a sample never built, score averaged the unbuilt samples' fill
    values in ('4 samples … mean over 2'), inspect and view went on, detect gave zarr's KeyError traceback."""
    args, written = READERS[command]
    before = sorted(p.relative_to(interrupted) for p in interrupted.rglob("*"))
    out = cli(args(interrupted, tmp_path), 2)
    assert refusal(interrupted) in out.splitlines()
    assert not [name for name in written if (tmp_path / name).exists()]
    assert sorted(p.relative_to(interrupted) for p in interrupted.rglob("*")) == before   # nothing written there


def test_inspect_still_summarises_an_incomplete_build_before_refusing(interrupted, tmp_path):
    out = cli(["inspect", interrupted, "--no-3d", "--png", tmp_path / "i.png"], 2)
    assert "dataset 'smoke': incomplete (3/5 shards)" in out and out.splitlines()[-1] == refusal(interrupted)


# ------------------------------------------------------------------------------------------ score


def test_score_refuses_repeated_indices(complete, tmp_path):
    """Before: one sample scored four times and reported as '4 samples'."""
    path = predictions(tmp_path / "dup.npz", depth=good_depth(), index=np.array([0, 0, 0, 0]))
    cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 2,
        f"error: {path}: index repeats 0 (4 times, at positions 0, 1, 2, 3): each sample is scored at most once")
    assert not (tmp_path / "dup_scores.json").exists()
    path = predictions(tmp_path / "dup2.npz", depth=good_depth(3), index=np.array([2, 0, 2]))
    cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 2,
        "index repeats 2 (2 times, at positions 0, 2)")


@pytest.mark.parametrize("threshold", ["nan", "inf", "-inf"])
def test_score_refuses_a_threshold_that_is_not_finite(complete, tmp_path, threshold):
    """Before: --threshold nan reported IoU 0 and exit 0."""
    path = predictions(tmp_path / "p.npz", occupancy=np.ones((TRAIN, 16, 16, 16)))
    cli(["score", path, "--dataset", complete, "--split", "train", "--threshold", threshold], 2,
        f"error: occupancy threshold (--threshold) must be a finite number, got {float(threshold)}")


def test_score_refuses_nan_occupancy(complete, tmp_path):
    """Before: an all-NaN occupancy prediction reported IoU 0 and exit 0 (NaN depth was refused)."""
    path = predictions(tmp_path / "nan.npz", occupancy=np.full((TRAIN, 16, 16, 16), np.nan, dtype=np.float32))
    cli(["score", path, "--dataset", complete, "--split", "train"], 2,
        f"error: {path}: occupancy of sample 0 (position 0 of the file) is nan at voxel (0, 0, 0): give finite "
        "values")
    occ = np.zeros((2, 16, 16, 16))
    occ[1, 3, 4, 5] = np.inf
    path = predictions(tmp_path / "inf.npz", occupancy=occ, index=np.array([3, 1]))
    cli(["score", path, "--dataset", complete, "--split", "train"], 2,
        "occupancy of sample 1 (position 1 of the file) is inf at voxel (3, 4, 5)")


def test_score_refuses_nan_depth_on_the_mask_naming_the_pixel(complete, tmp_path):
    depth = good_depth()
    depth[2][NLOSDataset(complete, split="train", fields=["depth"]).read(2)["depth"] > 0] = np.nan
    path = predictions(tmp_path / "p.npz", depth=depth)
    cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 2,
        f"error: {path}: depth of sample 2 (position 2 of the file) is nan at pixel (")


@pytest.mark.parametrize("key, value, needle", [
    ("depth", np.float64(1.0), "depth has shape () (a single value); expected (N, H, W) real numbers (m)"),
    ("occupancy", np.array(True), "occupancy has shape () (a single value); expected (N, V, V, V)"),
    ("depth", np.zeros((0, 16, 16)), "depth holds no samples (shape (0, 16, 16)); expected (N, H, W) real numbers "
                                     "(m) with N >= 1"),
    ("depth", np.ones((TRAIN, 16, 16), dtype=np.complex64), "depth has dtype complex64; expected (N, H, W) real"),
    ("depth", np.full((TRAIN, 16, 16), "1"), "depth has dtype <U1; expected (N, H, W) real numbers"),
])
def test_score_refuses_0d_empty_and_non_numeric_arrays_in_one_line(complete, tmp_path, key, value, needle):
    """Before: a 0-d depth said 'len() of unsized object'."""
    path = predictions(tmp_path / "p.npz", **{key: value})
    cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 2,
        f"error: {path}: {needle}")


def test_score_refuses_a_0d_index(complete, tmp_path):
    path = predictions(tmp_path / "p.npz", depth=good_depth(1), index=np.int64(0))
    cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 2,
        f"error: {path}: index has shape () (a single value); expected (N,) integers")


def test_score_reads_its_labels_through_the_loader(copy_of, tmp_path):
    """A complete dataset whose label shard was deleted: before, score read zarr's fill value (depth 0: no object
    pixels) and reported 'mean over the 3 samples with object pixels'; now the loader names the file."""
    shard_file(copy_of, "train", "depth", 1, 3).unlink()
    path = predictions(tmp_path / "p.npz", depth=good_depth())
    cli(["score", path, "--dataset", copy_of, "--split", "train", "--depth-field", "depth"], 2,
        f"{copy_of}/train/depth/c/1/0/0: shard file missing")


def test_score_of_good_predictions_still_works(complete, tmp_path):
    ds = NLOSDataset(complete, split="train", fields=["depth", "occupancy"])
    depth = np.stack([ds.read(i)["depth"] for i in range(TRAIN)]).astype(np.float64)
    occ = np.stack([ds.read(i)["occupancy"] for i in range(TRAIN)])
    path = predictions(tmp_path / "p.npz", depth=depth[[3, 0]] + 0.25, occupancy=occ[[3, 0]],
                       index=np.array([3, 0]))
    out = cli(["score", path, "--dataset", complete, "--split", "train", "--depth-field", "depth"], 0,
              "train: 2 samples; depth MAE 0.25 m, RMSE 0.25 m", "occupancy IoU 1")
    assert "wrote" in out
    summary = json.loads((tmp_path / "p_scores.json").read_text())["summary"]
    assert summary["depth_pixels"] == int((depth[[3, 0]] > 0).sum()) and summary["samples"] == 2


# ------------------------------------------------------------------------------------------ detect, export-tal


def test_detect_of_a_dataset_folder_says_what_to_do_instead(complete):
    """Before: a traceback (zarr KeyError 'components' not found in consolidated metadata)."""
    cli(["detect", complete, "--detector", DETECTOR], 2,
        f"error: {complete} is a datagen dataset, not a result store; detect re-draws the counts of one `datagen "
        "simulate` result", "NLOSDataset(PATH, noise='resample', detector_ranges={...})")
    cli(["detect", complete / "train", "--detector", DETECTOR], 2,
        f"{complete / 'train'} is a split folder of the datagen dataset {complete}, not a result store")
    assert verify_dataset(complete) == []          # nothing was added to it


def test_export_tal_of_a_dataset_without_split_and_index(complete, tmp_path):
    cli(["export-tal", complete, "--out", tmp_path / "s.hdf5"], 2,
        f"error: {complete} is a datagen dataset, not a result store; give --split and --index to export one of "
        "its samples")


def test_export_tal_of_a_deleted_shard_of_a_complete_build_names_the_file(copy_of, tmp_path):
    """A complete dataset whose envelope shard was deleted afterwards: export-tal reads through the loader, which
    names the missing file (zarr's reader returned its fill value: an H of zeros) and writes nothing."""
    shard_file(copy_of, "train", "envelope", 1, 2).unlink()
    out = tmp_path / "h.hdf5"
    cli(["export-tal", copy_of, "--split", "train", "--index", "1", "--out", out], 2,
        f"{copy_of}/train/envelope/c/1/0: shard file missing")
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


def test_export_tal_out_an_existing_folder_is_refused_before_any_work(complete, tmp_path, monkeypatch):
    """Before: '[Errno 21] Is a directory' after the work, and OUT.partial left behind."""
    import datagen.dataset.export as export
    calls = []
    monkeypatch.setattr(export, "sample_result", lambda *a, **k: calls.append(a))
    folder = tmp_path / "out"
    folder.mkdir()
    cli(["export-tal", complete, "--split", "train", "--index", "0", "--out", folder], 2,
        f"error: --out {folder} is a directory; give the .hdf5 file to write, e.g. {folder / 'capture.hdf5'}")
    assert calls == [] and sorted(tmp_path.iterdir()) == [folder] and list(folder.iterdir()) == []


def test_export_tal_out_under_a_file_is_refused(complete, tmp_path):
    (tmp_path / "file").write_text("x")
    cli(["export-tal", complete, "--split", "train", "--index", "0", "--out", tmp_path / "file" / "s.hdf5"], 2,
        "--out", "is a file")


def test_a_failed_tal_write_leaves_no_partial_file(complete, tmp_path, monkeypatch):
    import errno

    import datagen.io.tal_hdf5 as tal_hdf5
    from datagen.dataset.export import sample_result

    result = sample_result(complete, "train", 0)
    with pytest.raises(IsADirectoryError, match="is a directory"):
        tal_hdf5.write_tal_hdf5(result, tmp_path)
    assert list(tmp_path.iterdir()) == []

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tal_hdf5.yaml, "safe_dump", disk_full)   # fails midway through the file
    with pytest.raises(OSError, match="No space left"):
        tal_hdf5.write_tal_hdf5(result, tmp_path / "s.hdf5")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------ property test

DTYPES = [np.float64] * 5 + [np.float32] * 3 + [np.float16, np.int32, np.uint8, np.bool_, np.complex64]
"""Mostly valid dtypes (so that many examples get through to the scores), the others refused."""
VALUES = [0.0, 0.5, 1.0, 2.0, 3.0, -1.0, np.nan, np.inf, -np.inf, 1e300]
THRESHOLDS = ["0.5"] * 10 + ["0", "-1", "0.25", "1e300", "nan", "inf", "-inf"]


@st.composite
def prediction_arrays(draw, key: str, n: int):
    """A prediction array for ``key`` with ``n`` samples: most often the labels' shape, else a wrong, 0-d or empty
    one; any dtype; a few entries set to NaN, ±inf, huge or ordinary values."""
    grid = (16, 16) if key == "depth" else (16, 16, 16)
    right = [(n,) + grid] * 6 + ([(n, 1) + grid] if key == "depth" else [])
    shape = draw(st.sampled_from(right + [(), (n,), (n, 16, 8), (0,) + grid, (n + 1,) + grid]))
    dtype = np.dtype(draw(st.sampled_from(DTYPES)))
    with np.errstate(all="ignore"):
        array = np.full(shape, draw(st.sampled_from(VALUES[:6]))).astype(dtype)
        flat = array.reshape(-1)
        if flat.size:
            spots = draw(st.lists(st.tuples(st.integers(0, flat.size - 1), st.sampled_from(VALUES)), max_size=4))
            for at, value in spots:
                flat[at] = np.asarray(value).astype(dtype)
    return flat.reshape(shape)


@st.composite
def score_inputs(draw):
    n = draw(st.integers(1, TRAIN + 1))
    keys = draw(st.sampled_from([("depth",), ("occupancy",), ("depth", "occupancy")]))
    arrays = {key: draw(prediction_arrays(key, n)) for key in keys}
    if draw(st.booleans()):
        if draw(st.booleans()):     # distinct valid indices, or random ones (repeated, negative, out of range)
            values = draw(st.permutations(range(TRAIN)))[:n]
        else:
            values = draw(st.lists(st.integers(-2, TRAIN + 1), min_size=n - 1, max_size=n + 1))
        dtype = draw(st.sampled_from([np.int64, np.int64, np.uint8, np.int8, np.float64]))
        arrays["index"] = np.asarray(values, dtype=np.int64).astype(dtype)
    return arrays, draw(st.sampled_from(THRESHOLDS))


@pytest.mark.timeout(600)
@settings(max_examples=50, deadline=None, suppress_health_check=list(HealthCheck))
@given(inputs=score_inputs())
def test_score_property_exit_0_with_finite_consistent_scores_or_exit_2_with_one_line(complete, inputs):
    arrays, threshold = inputs
    with tempfile.TemporaryDirectory() as tmp:
        pred = Path(tmp) / "pred.npz"
        np.savez(pred, **arrays)
        res = CliRunner().invoke(main, ["score", str(pred), "--dataset", str(complete), "--split", "train",
                                        "--depth-field", "depth", "--threshold", threshold])
        assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
        lines = res.output.splitlines()
        event(f"exit {res.exit_code}" + (f": {lines[0].split(': ', 2)[-1][:40]}" if res.exit_code == 2 else ""))
        written = sorted(p.name for p in Path(tmp).iterdir())
        if res.exit_code == 2:
            assert len(lines) == 1 and lines[0].startswith("error: "), res.output
            assert written == ["pred.npz"]
            return
        assert res.exit_code == 0, res.output
        scores = json.loads((Path(tmp) / "pred_scores.json").read_text())
    rows, summary = scores["rows"], scores["summary"]
    n = len(next(v for k, v in arrays.items() if k != "index"))
    index = [int(i) for i in arrays.get("index", np.arange(n))]
    assert summary["samples"] == len(rows) == n >= 1
    assert [r["index"] for r in rows] == index and len(set(index)) == n and all(0 <= i < TRAIN for i in index)
    assert np.isfinite(float(threshold))
    for key in ("depth_mae", "depth_rmse", "occupancy_iou"):
        values = [r[key] for r in rows if r.get(key) is not None]
        assert all(np.isfinite(v) and v >= 0 for v in values)
        mean = summary.get(f"mean_{key}")
        if not values:
            assert mean is None
        else:
            assert mean == pytest.approx(np.mean(values), rel=1e-12)
        if key == "occupancy_iou":
            assert all(v <= 1 for v in values)
    if "depth" in arrays:
        assert summary["depth_pixels"] == sum(r["depth_pixels"] for r in rows)
        assert all(r["depth_mae"] <= r["depth_rmse"] * (1 + 1e-12) for r in rows if r["depth_mae"] is not None)
        assert np.isfinite(summary["pooled_depth_mae"]) and np.isfinite(summary["pooled_depth_rmse"])
