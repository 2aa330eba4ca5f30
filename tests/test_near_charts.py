"""benchmarks/near_charts.py (docs/real.md, "The near-chart check") on a small build of the LCT release's kind of
set-up: the truth is the label's median depth, the reference LCT's full-exposure found points, the thinning seeded
by the sample, a network's error its median depth over the reference minus the truth; bad input is one line."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import datagen

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import near_charts  # noqa: E402
import real_low_light  # noqa: E402


@pytest.fixture(scope="module")
def charts(tmp_path_factory):
    """Two 16 × 16 samples of lct_release_smoke.yaml's test split (its cut-outs 0.3–1.3 m out)."""
    from datagen.dataset import build_dataset, load_dataset_config
    config = load_dataset_config(ROOT / "configs/datasets/lct_release_smoke.yaml")
    out = tmp_path_factory.mktemp("charts") / "d"
    build_dataset(config, out, workers=0, progress=False)
    return out


def test_errors_are_the_depth_over_lcts_found_points_minus_the_labels(charts, monkeypatch):
    """A network that answers every point with the label's depth + 2 cm errs +0.02 m on every sample in view; LCT's
    error at the full exposure is its own depth map's median over its found points minus the label's median; at 1/10
    the thinning is sample i's ``default_rng(i)`` (LCT's error recomputed from that draw)."""
    import examples.train_depth_image as tdi
    ds = datagen.NLOSDataset(charts, split="test", fields=("counts", "wall_depth", "params"))
    dt = float(ds.card["time_edges"]["bin_width"])
    items = [ds[i] for i in range(len(ds))]
    labels = [np.asarray(it["wall_depth"], np.float64).reshape(16, 16) for it in items]
    kept = [i for i, it in enumerate(items) if (labels[i] > 0).any() and not np.isnan(
        real_low_light.found(np.asarray(it["counts"], np.float64), dt, tdi.scan_pitch(it["params"]), "lct")).all()]
    assert kept, "the smoke build has no sample in view: the test would check nothing"
    truths = iter([float(np.median(labels[i][labels[i] > 0])) for i in kept] * 2)

    def deeper(net, rec, counts, dt, pitch, probability=False):
        return np.full(counts.shape[:2], next(truths) + 0.02), np.ones(counts.shape[:2], bool)

    monkeypatch.setattr(tdi, "predict_depth", deeper)
    for fraction in (1.0, 0.1):
        truth, errors = near_charts.chart_errors(charts, {"net": (None, {"input": "lct"})}, "test", fraction)
        assert truth == pytest.approx([float(np.median(labels[i][labels[i] > 0])) for i in kept], abs=0)
        assert errors["net"] == pytest.approx(0.02, abs=1e-12)
        for k, i in enumerate(kept):
            counts = np.asarray(items[i]["counts"], np.float64)
            pitch = tdi.scan_pitch(items[i]["params"])
            reference = ~np.isnan(real_low_light.found(counts, dt, pitch, "lct"))
            thinned = counts if fraction == 1 else real_low_light.thin(counts, fraction, np.random.default_rng(i))
            depth = real_low_light.found(thinned, dt, pitch, "lct")
            assert errors["lct"][k] == pytest.approx(np.nanmedian(depth[reference]) - truth[k], abs=1e-12) \
                or (np.isnan(errors["lct"][k]) and np.isnan(depth[reference]).all())


def test_bad_input_is_one_line(tmp_path):
    with pytest.raises(SystemExit, match=r"--fraction: a share of the exposure lies in \(0, 1\], got 0"):
        near_charts.main([str(tmp_path), "--fraction", "0"])
    with pytest.raises(SystemExit, match=f"{tmp_path}: not a dataset"):
        near_charts.main([str(tmp_path)])
    with pytest.raises(SystemExit, match="--network: no file at nope.pt"):
        near_charts.main([str(tmp_path), "--network", "nope.pt"])
