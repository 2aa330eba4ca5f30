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


def test_compiled_primary_with_fov_shadows_equals_the_numpy_path(monkeypatch):
    """The flood's zones are FoV cells other than its laser points, so the hidden → FoV leg is shadow-tested
    (shadow_fov: the corridor's walls hide parts of the room from the zones). The compiled primary reads that leg's
    visibility from a map of one shadow ray per (FoV cell, sub-triangle), as the numpy path casts them: the two
    agree to 1e-9 (relative L2), with a ray for every lit laser leg or with the exact segment tests, while the numpy
    envelope without the FoV shadows differs by more than 1e-4."""
    import dataclasses

    from datagen.transport.quadrature import estimator as quadrature

    original = quadrature.Quadrature.__init__

    def envelope(**attrs):
        made = []

        def init(self, *args, **kwargs):
            original(self, *args, **kwargs)
            for k, v in attrs.items():
                setattr(self, k, v(self) if callable(v) else v)
            made.append(self)

        monkeypatch.setattr(quadrature.Quadrature, "__init__", init)
        result = run(small_room(), 2, 0.1, 2)
        monkeypatch.undo()
        return result.envelope, made[0]

    ref, q_ref = envelope(use_compiled=False)
    rays, q_rays = envelope(segment_tests=False)
    fast, q_fast = envelope()
    unshadowed, _ = envelope(use_compiled=False, settings=lambda q: dataclasses.replace(q.settings, shadow_fov=False))
    assert q_ref.settings.shadow_fov and q_fast.compiled_case() and q_fast.stats.shadow_rays > 0
    norm = np.linalg.norm(ref)
    assert norm > 0
    assert np.linalg.norm(rays - ref) <= 1e-9 * norm and np.linalg.norm(fast - ref) <= 1e-9 * norm
    assert np.linalg.norm(unshadowed - ref) > 1e-4 * norm


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


def grid_nodes(grid: dict, relay_x: float) -> np.ndarray:
    """(ny·nx, 3) cell centres of a stored wall grid on the relay wall x = relay_x (u = +y, v = +z)."""
    (nx, ny), (w, h), c = grid["points"], grid["size"], grid["center"]
    a = ((np.arange(nx) + 0.5) / nx - 0.5) * w
    b = ((np.arange(ny) + 0.5) / ny - 0.5) * h
    u, v = np.meshgrid(c[1] + a, c[2] + b)
    return np.stack([np.full(u.shape, relay_x), u, v], axis=-1).reshape(-1, 3)


def test_multizone_dataset_stores_the_zones_histograms(tmp_path):
    from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config
    from datagen.dataset.config import SplitSpec
    from datagen.dataset.store import read_card

    config = load_dataset_config(ROOT / "configs" / "datasets" / "multizone_smoke.yaml")
    config = config.model_copy(update={"splits": {"train": SplitSpec(count=1), "val": SplitSpec(count=2)},
                                       "store": config.store.model_copy(update={"node_envelope": True})})
    out = tmp_path / "mz"
    build_dataset(config, out, workers=0, progress=False)
    fields = read_card(out)["splits"]["val"]["fields"]
    assert fields["envelope"] == {"shape": [4, 4, 128], "dtype": "<f4", "axes": ["zone_y", "zone_x", "time"]}
    assert fields["counts"] == {"shape": [4, 4, 128], "dtype": "<i8", "axes": ["zone_y", "zone_x", "time"]}
    assert fields["node_envelope"]["axes"] == ["node_y", "node_x", "zone_y", "zone_x", "time"]
    ds = NLOSDataset(out, split="val")
    for i in range(len(ds)):
        item, params = ds[i], ds.params(i)
        env = item["envelope"].numpy().astype(np.float64)
        nodes = item["node_envelope"].numpy().astype(np.float64)
        assert nodes.shape == (4, 4, 4, 4, 128)
        room = params["room"]
        spots = grid_nodes(room["sensor"]["scan"]["laser_grid"], room["room"]["relay_x"])
        w = node_weights(spots, np.broadcast_to([-1.0, 0.0, 0.0], spots.shape), room["laser"]["emitter"],
                         FloodProfile(kind="uniform_intensity"))
        assert w.max() / w.min() > 1.1                      # 16 nodes, uneven: the cos θ / r² profile
        # the stored zones are the flood-weighted sum of the stored nodes (float32 storage)
        np.testing.assert_allclose(env, compose_zones(nodes.reshape(16, 16, 128), w).reshape(4, 4, 128),
                                   rtol=1e-5, atol=1e-7 * env.max())
        # the counts are one exposure per zone: their total is the expected one within 5 sigma
        cycles, counts = float(item["cycles"]), item["counts"].numpy()
        expected = env.sum() * cycles + float(item["background"]) * env.size
        assert counts.dtype == np.int64 and abs(counts.sum() - expected) < 5 * np.sqrt(expected) + 0.05 * expected
    net = NLOSDataset(out, split="val", layout="network", fields=("envelope", "counts"))[0]
    assert tuple(net["envelope"].shape) == tuple(net["counts"].shape) == (1, 128, 4, 4)
    # the capture files hold one laser point per transient: a flood's sample is refused with that reason (before:
    # "the regenerated capture has channels (4, 4, 4, 4) … built by another code version?")
    from datagen.dataset.export import sample_result
    from datagen.errors import DatasetError
    with pytest.raises(DatasetError, match=r"a multi-zone dataset: its samples are zones lit by a flood, with no "
                                           r"single laser point per transient"):
        sample_result(out, "val", 0)


def test_node_envelope_needs_a_flood():
    from datagen.dataset import load_dataset_config
    from datagen.dataset.config import make_sample
    from datagen.errors import ConfigError

    config = load_dataset_config(ROOT / "configs" / "datasets" / "multizone_smoke.yaml")
    config = config.model_copy(update={"room": {**config.room, "capture": {**config.room["capture"],
                                                                         "scan": {**config.room["capture"]["scan"],
                                                                                  "flood": None}}},
                                       "store": config.store.model_copy(update={"node_envelope": True})})
    with pytest.raises(ConfigError, match=r"^store\.node_envelope: true needs a multi-zone capture "
                                          r"\(room capture\.scan\.flood\); remove it$"):
        make_sample(config, "train", 0)


def test_a_flood_scan_must_be_exhaustive():
    from datagen.dataset.scan import ScanDist

    with pytest.raises(ValueError, match="flood: a flood's zones are an exhaustive scan's sensor grid with the "
                                         "aperture convention, got type 'confocal', convention 'aperture'"):
        ScanDist(type="confocal", flood={})


def test_load_scene_points_a_multizone_file_to_simulate():
    from datagen.scene import load_scene

    with pytest.raises(SceneError) as info:
        load_scene(SCENE)
    assert str(info.value) == (f"{SCENE}: this is a multi-zone scene (it has a multizone block): simulate it with "
                               "`datagen simulate SCENE.yaml --out DIR`, or load it with "
                               "datagen.scene.flood.load_multizone_scene (docs/multizone.md)")


def small_scene_file(tmp_path: Path) -> Path:
    """scene_library/multizone_room.yaml with a 2 × 2 node flood (a fast CLI run)."""
    data = yaml.safe_load(SCENE.read_text())
    data["multizone"]["flood"]["nodes"] = [2, 2]
    path = tmp_path / "mz2.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_cli_simulate_runs_a_multizone_scene_as_multizone_does(tmp_path):
    from click.testing import CliRunner
    from datagen.cli import main
    from datagen.io import read_result

    scene = small_scene_file(tmp_path)
    runner = CliRunner()
    a = runner.invoke(main, ["simulate", str(scene), "--out", str(tmp_path / "a"), "--edge", "0.3", "--seed", "3",
                             "--quiet"])
    assert a.exit_code == 0, a.output
    lines = a.output.splitlines()
    assert lines[0] == "4×4 zones, flood of 2×2 nodes over 1.4×1.4 m (uniform_intensity)"
    assert [line.split()[0] for line in lines[1:5]] == ["total", "room", "box", "secondary"]
    assert lines[-1] == (f"wrote {tmp_path / 'a' / 'result.zarr'}, {tmp_path / 'a' / 'envelope.png'}, "
                         f"{tmp_path / 'a' / 'zones.png'}")
    assert (tmp_path / "a" / "zones.png").stat().st_size > 10_000
    b = runner.invoke(main, ["multizone", str(SCENE), "--out", str(tmp_path / "b"), "--nodes", "2x2",
                             "--edge", "0.3", "--seed", "3", "--quiet"])
    assert b.exit_code == 0, b.output
    assert a.output.replace("/a/", "/b/") == b.output
    ra, rb = read_result(tmp_path / "a" / "result.zarr"), read_result(tmp_path / "b" / "result.zarr")
    assert ra.envelope.shape == ra.counts.shape == (4, 4, 128)
    np.testing.assert_array_equal(ra.envelope, rb.envelope)
    np.testing.assert_array_equal(ra.counts, rb.counts)
    assert ra.attrs["multizone"]["weights"][0][0] == pytest.approx(0.25, rel=0.05)


def test_cli_simulate_refuses_options_a_multizone_run_does_not_take(tmp_path):
    from click.testing import CliRunner
    from datagen.cli import main

    runner = CliRunner()
    for extra in (["--tolerance", "1%"], ["--figures"]):
        res = runner.invoke(main, ["simulate", str(SCENE), "--out", str(tmp_path / "a")] + extra)
        assert res.exit_code == 2
        assert res.output.strip() == (f"error: {extra[0]} does not apply to the multi-zone scene {SCENE} (a flood's "
                                      "zones are simulated in one run: docs/multizone.md)")
    res = runner.invoke(main, ["multizone", str(SCENE), "--out", str(tmp_path / "b"), "--nodes", "4x99"])
    assert res.exit_code == 2
    assert "error: --nodes: multizone.flood.nodes: at most 64 nodes per side, got [4, 99]" in res.output
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_flood_off_the_wall_names_the_multizone_field():
    data = yaml.safe_load(SCENE.read_text())
    data["multizone"]["flood"]["center"] = [2.0, 5.0, 1.0]
    scene, spec = multizone_from_dict(data, "x.yaml")
    with pytest.raises(SceneError, match=r"^x\.yaml: multizone\.flood node 0 .* is off every surface"):
        simulate_multizone(scene, spec)
