"""Flood-illuminated multi-zone captures (docs/multizone.md): the point limit, convergence to a reference, the
flood's radiometry, the scene block's errors, the view's drawables and the dataset config."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from datagen.errors import SceneError
from datagen.scene import scene_from_dict
from datagen.scene.flood import FloodProfile, load_multizone_scene, multizone_from_dict, node_weights
from datagen.simulation import resolve_config, simulate
from datagen.simulation.multizone import compose_zones, simulate_multizone

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scene_library" / "multizone_room.yaml"


def small_room() -> dict:
    """A 1.2 m wide L-room (relay wall x = 1.2) with a hidden box, the module 0.8 m out, a 0.8 m flood and
    4 × 4 zones, 128 bins of 100 ps: scene_library/multizone_room.yaml shrunk so a reference runs in a test."""
    data = yaml.safe_load(SCENE.read_text())
    data["objects"] = [dict(builder="l_room", relay_x=1.2, corridor_start=0.3, corridor_width=1.2, room_depth=0.6,
                            room_length=0.8, height=1.2),
                       dict(builder="box", name="box", center=[0.9, 0.9, 0.3], size=[0.25, 0.25, 0.25])]
    data["laser"]["emitter"] = data["sensor"]["position"] = [0.4, 0.0, 0.6]
    for key in ("flood", "zones"):
        data["multizone"][key].update(center=[1.2, 0.0, 0.6], size=[0.8, 0.8])
    data["simulation"]["time"] = {"t_start": "0ns", "bin_width": "100ps", "n_bins": 128}
    data["simulation"]["irf"] = {"fwhm": "300ps"}
    return data


def run(data: dict, nodes: int, edge: float, fov_cells: int):
    data = yaml.safe_load(yaml.safe_dump(data))
    data["multizone"]["flood"]["nodes"] = [nodes, nodes]
    scene, spec = multizone_from_dict(data)
    config = resolve_config(scene, {"estimator": {"kind": "quadrature", "edge": edge, "fov_cells": fov_cells}})
    return simulate_multizone(scene, spec, config)


def test_point_flood_equals_the_single_spot_simulation():
    # a flood of zero size is one laser point: bit for bit today's single-spot capture of the same zones
    data = small_room()
    data["multizone"]["flood"].update(size=[0, 0], nodes=[1, 1], center=[1.2, 0.15, 0.75])
    flood = run(data, 1, 0.1, 2)
    single = {k: v for k, v in data.items() if k != "multizone"}
    single["laser"] = {**data["laser"], "spot": [1.2, 0.15, 0.75]}
    zones = data["multizone"]["zones"]
    single["capture"] = {"type": "single", "sensor_grid": {"center": zones["center"], "size": zones["size"],
                                                           "points": zones["zones"]}}
    scene = scene_from_dict(single)
    spot = simulate(scene, resolve_config(scene, {"estimator": {"kind": "quadrature", "edge": 0.1, "fov_cells": 2}}))
    assert flood.envelope.shape == spot.envelope.shape == (4, 4, 128)
    assert flood.envelope.sum() > 0
    np.testing.assert_array_equal(flood.envelope, spot.envelope)
    np.testing.assert_array_equal(flood.counts, spot.counts)
    assert flood.attrs["multizone"]["weights"] == [[1.0]]


@pytest.mark.slow
def test_flood_agrees_with_a_converged_reference():
    # 6 × 6 nodes at edge 0.1 m (2 × 2 FoV cells per zone) against 12 × 12 nodes at edge 0.07 m and 3 × 3 FoV cells
    # per zone (itself within 0.07 % of 10 × 10 nodes): measured 0.82 % (docs/multizone.md, "Convergence")
    data = small_room()
    test = run(data, 6, 0.1, 2).envelope
    ref = run(data, 12, 0.07, 3).envelope
    err = np.linalg.norm(test - ref) / np.linalg.norm(ref)
    assert err <= 0.01, err
    assert err > 1e-4           # a real comparison: the two differ
    # the patch quadrature matters: a single node at the patch centre is far off
    one = run({**data, "multizone": {**data["multizone"],
                                     "flood": {**data["multizone"]["flood"], "size": [0.0, 0.0]}}}, 1, 0.1, 2)
    assert np.linalg.norm(one.envelope - ref) / np.linalg.norm(ref) > 0.1


def test_uniform_intensity_weights_are_the_patch_solid_angle():
    # emitter on the axis of a 2a × 2b patch at distance d: the share of the central a × b rectangle is the ratio
    # of the solid angles Ω(a, b) = 4·asin(ab / √((a² + d²)(b² + d²))) (half sides a/2, b/2 against a, b)
    a, b, d, n = 0.6, 0.4, 0.5, 64
    u = ((np.arange(n) + 0.5) / n - 0.5) * 2 * a
    v = ((np.arange(n) + 0.5) / n - 0.5) * 2 * b
    uu, vv = np.meshgrid(u, v)
    spots = np.stack([np.full(uu.size, d), uu.ravel(), vv.ravel()], axis=1)
    w = node_weights(spots, np.broadcast_to([-1.0, 0.0, 0.0], spots.shape), np.zeros(3),
                     FloodProfile(kind="uniform_intensity"))
    inner = (np.abs(spots[:, 1]) < a / 2) & (np.abs(spots[:, 2]) < b / 2)

    def omega(p, q):
        return 4 * np.arcsin(p * q / np.sqrt((p * p + d * d) * (q * q + d * d)))

    assert w.sum() == pytest.approx(1.0)
    assert w[inner].sum() == pytest.approx(omega(a / 2, b / 2) / omega(a, b), rel=1e-4)
    uniform = node_weights(spots, np.broadcast_to([-1.0, 0.0, 0.0], spots.shape), np.zeros(3),
                           FloodProfile(kind="uniform_irradiance"))
    assert uniform[inner].sum() == pytest.approx(0.25)


def test_compose_zones_is_the_weighted_sum_over_nodes():
    rng = np.random.default_rng(1)
    per_node = rng.random((3, 5, 7))
    w = np.array([0.5, 0.3, 0.2])
    np.testing.assert_allclose(compose_zones(per_node, w), 0.5 * per_node[0] + 0.3 * per_node[1] + 0.2 * per_node[2])
    with pytest.raises(ValueError, match=r"weights of shape \(2,\) do not match the node axis"):
        compose_zones(per_node, w[:2])


def test_scene_block_errors_name_the_field():
    data = yaml.safe_load(SCENE.read_text())
    bad = yaml.safe_load(yaml.safe_dump(data))
    bad["multizone"]["zones"]["zones"] = [4, 40]
    with pytest.raises(SceneError, match=r"^x\.yaml: multizone\.zones\.zones: .*at most 16 zones per side"):
        multizone_from_dict(bad, "x.yaml")
    bad = yaml.safe_load(yaml.safe_dump(data))
    bad["capture"] = {"type": "single"}
    with pytest.raises(SceneError, match=r"^x\.yaml: capture: a multi-zone scene takes its capture from multizone"):
        multizone_from_dict(bad, "x.yaml")
    bad = yaml.safe_load(yaml.safe_dump(data))
    bad["multizone"]["flood"]["profile"] = {"kind": "cone"}
    with pytest.raises(SceneError, match=r"multizone\.flood\.profile\.kind"):
        multizone_from_dict(bad, "x.yaml")


def test_view_draws_the_lit_patch_and_the_zones():
    from datagen.cli.view import load_view_input
    from datagen.plot.view_flood import flood_drawables

    scene, info = load_view_input(SCENE)
    assert info["kind"] == "multizone"
    d = flood_drawables(scene, info["multizone"])
    lines = dict((name, seg) for name, seg, _, _ in d.lines)
    assert lines["lit patch"].shape == (4, 2, 3)
    np.testing.assert_allclose(lines["lit patch"][:, 0, 0], 2.0)                       # on the relay wall
    np.testing.assert_allclose(np.sort(np.unique(lines["lit patch"][:, 0, 1].round(9))), [-0.7, 0.7])
    assert lines["zones"].shape == (16 * 4, 2, 3)
    texts = [t for t, _, _ in d.legend]
    assert texts[0].startswith("lit patch (flood) 1.4×1.4 m, uniform_intensity profile, 8×8 quadrature nodes")
    assert texts[1].startswith("4×4 zones, one histogram each")


def test_example_scene_loads_with_the_preset_numbers():
    scene, spec = load_multizone_scene(SCENE)
    assert scene.capture.type == "exhaustive" and scene.capture.laser_grid.points == (8, 8)
    config = resolve_config(scene)
    preset = yaml.safe_load((ROOT / "configs" / "detectors" / "tmf8828.yaml").read_text())
    assert config.time.n_bins == 128 and config.time.bin_width == pytest.approx(260e-12)
    assert preset["bin_width"] == "260ps" and config.detector["pde"] == preset["pde"]


def test_multizone_dataset_smoke_builds(tmp_path):
    from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config

    out = tmp_path / "mz"
    build_dataset(load_dataset_config(ROOT / "configs" / "datasets" / "multizone_smoke.yaml"), out, workers=0,
                  progress=False)
    ds = NLOSDataset(out, split="val")
    assert len(ds) == 4
    env = ds.read(0)["envelope"]
    assert env.shape == (4, 4, 4, 4, 128)
    from examples.multizone_baseline import zone_envelope
    zones, params = zone_envelope(ds, 0, FloodProfile())
    assert zones.shape == (4, 4, 128) and zones.sum() > 0
    # the composition is a convex combination of the nodes' envelopes
    per_node = np.asarray(env, dtype=np.float64).reshape(16, 4, 4, 128).sum(axis=(1, 2, 3))
    assert per_node.min() <= zones.sum() <= per_node.max()


def test_cli_simulate_points_to_multizone_and_multizone_checks_nodes(tmp_path):
    from click.testing import CliRunner
    from datagen.cli import main

    runner = CliRunner()
    res = runner.invoke(main, ["simulate", str(SCENE), "--out", str(tmp_path / "a")])
    assert res.exit_code == 2
    assert res.output.strip().endswith("this is a multi-zone scene (it has a multizone block): simulate it with "
                                       "`datagen multizone SCENE.yaml --out DIR` (docs/multizone.md)")
    res = runner.invoke(main, ["multizone", str(SCENE), "--out", str(tmp_path / "b"), "--nodes", "4x99"])
    assert res.exit_code == 2
    assert "error: --nodes: multizone.flood.nodes: at most 64 nodes per side, got [4, 99]" in res.output
    assert not (tmp_path / "b").exists()


def test_cli_multizone_writes_the_zone_result(tmp_path):
    from click.testing import CliRunner
    from datagen.cli import main
    from datagen.io import read_result

    res = CliRunner().invoke(main, ["multizone", str(SCENE), "--out", str(tmp_path), "--nodes", "2x2",
                                    "--edge", "0.3"])
    assert res.exit_code == 0, res.output
    assert res.output.startswith("4×4 zones, flood of 2×2 nodes over 1.4×1.4 m (uniform_intensity)")
    result = read_result(tmp_path / "result.zarr")
    assert result.envelope.shape == result.counts.shape == (4, 4, 128)
    assert result.attrs["multizone"]["weights"][0][0] == pytest.approx(0.25, rel=0.05)


def test_a_flood_off_the_wall_names_the_multizone_field():
    data = yaml.safe_load(SCENE.read_text())
    data["multizone"]["flood"]["center"] = [2.0, 5.0, 1.0]
    scene, spec = multizone_from_dict(data, "x.yaml")
    with pytest.raises(SceneError, match=r"^x\.yaml: multizone\.flood node 0 .* is off every surface"):
        simulate_multizone(scene, spec)
