"""Hostile input, round 4 (the capture and scoring commands): tracebacks turned into one-line errors.

Each case ran into a Python traceback before; now it is a one-line ``error:`` (exit 2) naming the option or the
file and the value.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import box_before_wall
from test_hostile import cli

from datagen.io import write_result
from datagen.simulation import resolve_config, simulate


@pytest.fixture(scope="module")
def scan_store(tmp_path_factory):
    """A 4 × 4 confocal scan result store (counts (4, 4, T))."""
    room = box_before_wall(4)
    config = resolve_config(room.scene, {"estimator": {"kind": "quadrature", "edge": 0.2}})
    path = tmp_path_factory.mktemp("scan") / "result.zarr"
    write_result(simulate(room.scene, config), path)
    return path


@pytest.mark.parametrize("pixel, words", [
    ("99,99", "--pixel 99,99: outside the scan of"),
    ("4,0", "whose points run 0..3, 0..3"),
    ("a,b", "--pixel 'a,b': give the scan point as integers 'i,j'"),
])
def test_fit_detector_pixel_outside_the_scan_is_one_line(scan_store, pixel, words):
    """Before: ``--pixel 99,99`` on a 16 × 16 store raised IndexError in the histogram read, ``--pixel a,b`` a
    ValueError traceback."""
    cli(["fit-detector", scan_store, "--repetition-rate", "20MHz", "--n-cycles", "1000", "--pixel", pixel], 2, words)


def test_a_truncated_predictions_archive_is_named(tmp_path):
    """Before: ``score`` of a truncated ``.npz`` ended in zipfile.BadZipFile (the file is read before the dataset)."""
    good = tmp_path / "pred.npz"
    np.savez(good, depth=np.ones((4, 16, 16)))
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    cli(["score", cut, "--dataset", tmp_path / "no_dataset", "--split", "train"], 2,
        f"error: {cut}: not a NumPy .npz archive, or a truncated one (BadZipFile")
