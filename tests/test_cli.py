"""CLI: the main job writes its files; bad input gets one clear line and a non-zero exit code."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from datagen.cli.main import main
from datagen.io import read_result

DEMO = Path("scene_library/demo_room.yaml")


def demo_data() -> dict:
    return yaml.safe_load(DEMO.read_text())


def run(args):
    return CliRunner().invoke(main, args)


def test_simulate_writes_zarr_png_and_summary(tmp_path):
    res = run(["simulate", str(DEMO), "--out", str(tmp_path), "--lookins", "4x4", "--pixels", "16x16",
               "--secondary", "optimized", "--quiet", "--seed", "3"])
    assert res.exit_code == 0, res.output
    assert "box" in res.output and "secondary" in res.output and "wall time" in res.output
    result = read_result(tmp_path)
    assert (tmp_path / "envelope.png").stat().st_size > 20_000
    assert result.time_edges.shape == (5001,) and result.envelope.shape == (5000,)
    assert result.counts.dtype == np.int64 and result.counts.shape == (5000,)
    assert set(result.components) == {"room", "box", "pillar", "secondary", "multibounce"}   # orders unset: auto
    np.testing.assert_allclose(sum(result.components.values()), result.envelope, rtol=1e-12, atol=1e-300)
    assert result.attrs["config"]["estimator"]["lookins"] == [4, 4] and result.attrs["config"]["seed"] == 3
    assert result.attrs["effects"]["secondary"] == "optimized"
    assert result.attrs["effects"]["non_lambertian_brdfs"] == ["sin_theta"]
    assert result.attrs["versions"]["zarr"].startswith("3.")
    assert result.attrs["units"]["time_edges"] == "s"


def write_scene(tmp_path, data) -> Path:
    path = tmp_path / f"scene{len(list(tmp_path.glob('scene*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def bad_inputs(tmp_path):
    d = demo_data()
    d["objects"][1]["material"]["kind"] = "velvet"
    yield "unknown BRDF", write_scene(tmp_path, d), ["objects.1", "velvet"]
    d = demo_data()
    d["objects"][2]["material"]["albedo"] = -0.5
    yield "negative albedo", write_scene(tmp_path, d), ["objects.2", "albedo", "-0.5"]
    d = demo_data()
    d["sensor"]["fov"]["center"] = [6.0, 40.0, 1.5]
    yield "FoV sees no surface", write_scene(tmp_path, d), ["sensor.fov", "sees no surface"]
    d = demo_data()
    d["laser"]["spot"] = [6.0, 0.0, 9.0]
    yield "laser spot off every surface", write_scene(tmp_path, d), ["laser.spot", "off every surface"]
    d = demo_data()
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    d["objects"].append({"builder": "mesh", "name": "statue", "path": "nan.obj"})
    yield "NaN vertex", write_scene(tmp_path, d), ["statue", "vertex 1", "not finite"]
    yield "missing file", tmp_path / "nope.yaml", ["not found", "nope.yaml"]
    d = demo_data()
    d["laser"]["wavelength"] = "532furlongs"
    yield "bad unit", write_scene(tmp_path, d), ["laser.wavelength", "furlongs"]
    d = demo_data()
    d["simulation"]["lookins"] = "ten"
    yield "bad lookins", write_scene(tmp_path, d), ["lookins", "'ten'"]


@pytest.mark.parametrize("case", range(8))
def test_bad_input_gets_one_clear_line(tmp_path, case):
    name, path, must_contain = list(bad_inputs(tmp_path))[case]
    res = run(["simulate", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    assert res.exit_code == 2, (name, res.output)
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), (name, res.output)
    for fragment in must_contain:
        assert fragment in lines[0], (name, fragment, lines[0])
    assert "Traceback" not in res.output
    assert not (tmp_path / "out" / "result.zarr").exists()


def test_detect_redraws_counts_from_stored_envelope(tmp_path):
    assert run(["simulate", str(DEMO), "--out", str(tmp_path), "--lookins", "4x4", "--pixels", "16x16",
                "--secondary", "none", "--quiet"]).exit_code == 0
    import zarr

    draws = []
    for _ in range(2):
        res = run(["detect", str(tmp_path), "--detector", "configs/detectors/hwu_single_pixel.yaml",
                   "--exposure", "5ms", "--seed", "4"])
        assert res.exit_code == 0, res.output
        g = zarr.open_group(str(tmp_path / "result.zarr"), mode="r")
        counts = g["detections/hwu_single_pixel/counts"][...]
        draws.append(counts)
        assert counts.dtype == np.int64 and counts.sum() > 0
        assert g["detections/hwu_single_pixel"].attrs["n_cycles"] == 50_000     # 5 ms at 10 MHz
    np.testing.assert_array_equal(draws[0], draws[1])
    assert read_result(tmp_path).envelope.shape == (5000,)                         # envelope untouched
    bad = run(["detect", str(tmp_path), "--detector", "missing.yaml"])
    assert bad.exit_code == 2 and bad.output.startswith("error: ")
