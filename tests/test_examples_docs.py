"""The examples/ scripts the docs run (docs/training.md, "First hour") still run, on small datasets.

Each script is run as the docs run it (``python -m examples.<name> DATA …``, from the repository root) with
fewer epochs, on a prefix of configs/datasets/smoke.yaml (single-pixel) and on configs/datasets/wall_smoke.yaml
(confocal wall scans); its predictions are then scored with ``datagen score`` as docs/training.md does.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from datagen.cli import main

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def run_example(name: str, *args: str) -> str:
    """stdout of ``python -m examples.<name> ARGS`` run from the repository root (fails with its stderr)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    r = subprocess.run([sys.executable, "-m", f"examples.{name}", *args], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


def build(config: str, out: Path, *extra: str) -> Path:
    r = CliRunner().invoke(main, ["build", str(ROOT / "configs" / "datasets" / config), "--out", str(out),
                                  "--workers", "0", "--quiet", *extra])
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    return build("smoke.yaml", tmp_path_factory.mktemp("examples") / "smoke", "--splits", "train=8,val=8")


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    return build("wall_smoke.yaml", tmp_path_factory.mktemp("examples") / "wall")


def test_train_single_pixel_scores_each_target_against_its_baseline(smoke, tmp_path):
    results = tmp_path / "results.json"
    out = run_example("train_single_pixel", str(smoke), "--epochs", "1", "--batch", "4",
                      "--targets", "fov_distance,object_count", "--json", str(results))
    rows = {r["target"]: r for r in json.loads(results.read_text())}
    assert set(rows) == {"fov_distance", "object_count"}, out
    assert all(np.isfinite(float(v)) for r in rows.values() for k, v in r.items()
               if isinstance(v, float)), rows
    assert "fov_distance" in out and "object_count" in out


def test_train_depth_image_writes_scored_depth_predictions(wall):
    out = run_example("train_depth_image", str(wall), "--epochs", "1", "--batch", "4", "--val", "test")
    pred = np.load(f"{wall}_net_test.npz")
    assert pred["depth"].shape == (4, 16, 16) and pred["index"].tolist() == [0, 1, 2, 3]
    assert "network: val depth MAE" in out and "trivial: val depth MAE" in out
    r = CliRunner().invoke(main, ["score", f"{wall}_net_test.npz", "--dataset", str(wall), "--split", "test"])
    assert r.exit_code == 0, r.output


def test_backprojection_baseline_writes_scored_depth_predictions(wall, tmp_path):
    out = run_example("backprojection_baseline", str(wall), "--split", "test")
    pred = np.load(f"{wall}_bp_test.npz")
    assert pred["depth"].shape == (4, 16, 16) and "4 depth images" in out
    scores = tmp_path / "bp_scores"
    r = CliRunner().invoke(main, ["score", f"{wall}_bp_test.npz", "--dataset", str(wall), "--split", "test",
                                  "--out", str(scores)])
    assert r.exit_code == 0, r.output
