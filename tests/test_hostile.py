"""Hostile input, part 1: scenes, the simulate and detect commands, and the detector API (issue 14).

Every case gives either a correct result or one ``error: …`` line with exit code 2 that names the file and the
field (or the option) and the value, in bounded time, with no traceback. The dataset, loader and fault cases
are tests/test_hostile_build.py.
"""
from __future__ import annotations

import copy
import errno
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from pydantic import ValidationError

from datagen import spad
from datagen.spad.synchronous import detection_pmf
from datagen.cli.main import main
from datagen.scene import load_scene
from datagen.errors import SceneError
from datagen.scene.load import MAX_YAML_VALUES, parse_yaml

PATCH = {   # the conftest patch scene as a file: relay wall x = 2 facing -x, a 0.4 m patch 1 m from it
    "name": "patch",
    "objects": [
        {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [2.0, -2.0, -2.0],
         "edge_u": [0.0, 4.0, 0.0], "edge_v": [0.0, 0.0, 4.0]},
        {"builder": "quad", "name": "patch", "corner": [1.0, -0.2, 0.3], "edge_u": [0.0, 0.4, 0.0],
         "edge_v": [0.0, 0.0, 0.4]},
    ],
    "laser": {"emitter": [0.0, 0.0, -0.5], "spot": [2.0, 0.0, 0.0], "photons_per_pulse": 1.0},
    "sensor": {"position": [0.0, 0.0, -0.5], "aperture_radius": 0.02,
               "fov": {"center": [2.0, 0.0, -0.6], "size": [0.8, 0.8]}},
    "simulation": {"lookins": "16x16", "pixels": "8x8", "secondary": "none",
                   "time": {"t_start": 0.0, "bin_width": "20ps", "n_bins": 1000}, "irf": {"fwhm": "100ps"},
                   "detector": {"model": "poisson", "repetition_rate": "10MHz", "n_cycles": 1000}},
}


def scene_file(tmp_path: Path, edit=None, name: str = "scene.yaml") -> Path:
    data = copy.deepcopy(PATCH)
    if edit is not None:
        edit(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def cli(args, code: int = 2, *needles: str) -> str:
    """Run ``datagen args`` in process: the exit code is ``code``, the output holds every needle, no traceback,
    and an error is one line."""
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output
    for needle in needles:
        assert needle in res.output, (needle, res.output)
    if code == 2:
        errors = [line for line in res.output.splitlines() if line.startswith("error:") or "Error:" in line]
        assert len(errors) == 1, res.output
    return res.output


def simulate_args(path: Path, out: Path, *extra) -> list:
    return ["simulate", path, "--out", out, "--quiet", *extra]


def set_path(data: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    node = data
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node[key]
    node[int(keys[-1]) if isinstance(node, list) else keys[-1]] = value


# ------------------------------------------------------------------------------------------ scene fields

INVALID_FIELDS = {   # case: (dotted field, value, what the message must name)
    "name room": ("objects.1.name", "room", "objects.1: object name 'room' is reserved"),
    "name secondary": ("objects.1.name", "secondary", "'secondary' is reserved"),
    "name first_bounce": ("objects.1.name", "first_bounce", "'first_bounce' is reserved"),
    "name Total": ("objects.1.name", "Total", "'Total' is reserved"),
    "name zarr.json": ("objects.1.name", "zarr.json", "'zarr.json' is reserved"),
    "name path traversal": ("objects.1.name", "../../etc/passwd", "'../../etc/passwd' is not allowed"),
    "name with slash": ("objects.1.name", "a/b", "'a/b' is not allowed"),
    "name empty": ("objects.1.name", "", "objects.1: object name '' is not allowed"),
    "name with space": ("objects.1.name", "my box", "'my box' is not allowed"),
    "name dunder": ("objects.1.name", "__x", "'__x' is not allowed"),
    "quad edge 1e308": ("objects.1.edge_u", [0.0, 1e308, 0.0], "lies beyond ±1e+07 m"),
    "corner inf": ("objects.1.corner", [1.0, math.inf, 0.3], "is not finite"),
    "aperture 1e308": ("sensor.aperture_radius", 1e308, "sensor.aperture_radius"),
    "aperture inf": ("sensor.aperture_radius", math.inf, "sensor.aperture_radius: Input should be a finite"),
    "aperture text": ("sensor.aperture_radius", ".inf", "sensor.aperture_radius"),
    "wavelength inf": ("laser.wavelength", math.inf, "laser.wavelength"),
    "wavelength 1e308": ("laser.wavelength", 1e308, "laser.wavelength"),
    "photons nan": ("laser.photons_per_pulse", math.nan, "laser.photons_per_pulse"),
    "emitter 1e308": ("laser.emitter", [1e308, 0.0, 0.0], "laser.emitter"),
    "fov size 1e308": ("sensor.fov.size", [1e308, 0.8], "sensor.fov.size"),
    "attenuation inf": ("simulation.attenuation", math.inf, "attenuation: Input should be a finite"),
    "exposure inf": ("simulation.detector", {"model": "poisson", "repetition_rate": "10MHz", "exposure": math.inf},
                     "detector.exposure"),
    "exposure 1e12 s": ("simulation.detector", {"model": "pile_up", "repetition_rate": "10MHz",
                                                "exposure": "1e12s"}, "is 1e+19 laser cycles"),
    "n_cycles 1e19": ("simulation.detector", {"model": "poisson", "repetition_rate": "10MHz", "n_cycles": 10**19},
                      "detector.n_cycles"),
}


@pytest.mark.parametrize("case", sorted(INVALID_FIELDS))
def test_invalid_scene_field_is_one_line_naming_file_and_field(tmp_path, case):
    field, value, needle = INVALID_FIELDS[case]
    path = scene_file(tmp_path, lambda d: set_path(d, field, value))
    out = cli(simulate_args(path, tmp_path / "out"), 2, str(path), needle)
    assert not (tmp_path / "out").exists()                 # nothing is written for a refused input
    assert len(out) < 600


def test_the_reserved_name_no_longer_gives_components_that_miss_the_envelope(tmp_path):
    """Before: a box named 'room' merged into the room component; components summed to 0.13 of a 0.33
    envelope, exit 0. The API refuses the name as well."""
    path = scene_file(tmp_path, lambda d: set_path(d, "objects.1.name", "room"))
    with pytest.raises(SceneError, match=r"scene.yaml: objects.1: object name 'room' is reserved"):
        load_scene(path)


def test_names_differing_only_in_case_are_refused(tmp_path):
    def twin(d):
        d["objects"].append({**d["objects"][1], "name": "PATCH", "corner": [1.0, -0.2, -0.3]})
    cli(simulate_args(scene_file(tmp_path, twin), tmp_path / "out"), 2, "unique (ignoring case)", "PATCH")


def test_pillar_of_size_zero_or_negative_is_refused_like_a_box(tmp_path):
    for size in ([0.0, 0.5], [-1.0, 0.5]):
        def pillar(d, size=size):
            d["objects"].append({"builder": "pillar", "name": "p", "center": [1.0, 1.0], "size": size,
                                 "height": 2.0})
        cli(simulate_args(scene_file(tmp_path, pillar), tmp_path / "out"), 2, "objects.2: pillar 'p'",
            str(size[0]))


def test_box_of_1e308_names_the_box_not_the_laser_spot(tmp_path):
    def huge(d):
        d["objects"].append({"builder": "box", "name": "b", "center": [1.0, 1.0, 0.0], "size": [1e308] * 3})
    out = cli(simulate_args(scene_file(tmp_path, huge), tmp_path / "out"), 2, "objects.2: box 'b': size")
    assert "laser.spot" not in out


def test_room_of_1e308_names_the_field(tmp_path):
    def room(d):
        d["objects"] = [{"builder": "l_room", "room_length": 1e308}]
        d["laser"]["spot"], d["sensor"]["fov"]["center"] = [6.0, 0.0, 2.0], [6.0, 0.0, 1.5]
    out = cli(simulate_args(scene_file(tmp_path, room), tmp_path / "out"), 2, "objects.0.l_room.room_length",
              "1e+308")
    assert "laser.spot" not in out


def test_emitter_behind_the_relay_wall_is_blamed_on_the_emitter(tmp_path):
    path = scene_file(tmp_path, lambda d: set_path(d, "laser.emitter", [3.0, 0.0, -0.5]))
    out = cli(simulate_args(path, tmp_path / "out"), 2, "laser.emitter [3.0, 0.0, -0.5] is behind the relay wall")
    assert "sensor.position [0.0, 0.0, -0.5] is behind" not in out


def test_sensor_behind_the_relay_wall_is_blamed_on_the_sensor(tmp_path):
    path = scene_file(tmp_path, lambda d: set_path(d, "sensor.position", [3.0, 0.0, -0.5]))
    cli(simulate_args(path, tmp_path / "out"), 2, "sensor.position [3.0, 0.0, -0.5] is behind the relay wall")


# ------------------------------------------------------------------------------------------ mesh files


def mesh_scene(tmp_path: Path, mesh: Path) -> Path:
    return scene_file(tmp_path, lambda d: d["objects"].append(
        {"builder": "mesh", "name": "m", "path": str(mesh)}))


def test_binary_obj_names_the_file(tmp_path):
    mesh = tmp_path / "garbage.obj"
    mesh.write_bytes(np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    cli(simulate_args(mesh_scene(tmp_path, mesh), tmp_path / "out"), 2, "objects.2", str(mesh))


def test_truncated_stl_names_the_file(tmp_path):
    import trimesh
    data = trimesh.creation.box(extents=[0.2, 0.2, 0.2]).export(file_type="stl")
    mesh = tmp_path / "cut.stl"
    mesh.write_bytes(data[:len(data) // 2 + 7])
    cli(simulate_args(mesh_scene(tmp_path, mesh), tmp_path / "out"), 2, "objects.2", str(mesh))


def test_all_degenerate_mesh_and_zero_area_quad_are_invisible_and_reported(tmp_path):
    """A correct result (zero-area surfaces reflect nothing: their components are exactly 0) with a warning
    naming each object."""
    mesh = tmp_path / "flat.obj"
    mesh.write_text("v 1 0 0\nv 1 0 0\nv 1 0 0\nf 1 2 3\n")

    def add(d):
        d["objects"].append({"builder": "mesh", "name": "m", "path": str(mesh)})
        d["objects"].append({"builder": "quad", "name": "q", "corner": [1.5, 0.0, -0.4], "edge_u": [0.0, 0.0, 0.0],
                             "edge_v": [0.0, 0.0, 0.8]})
    out = cli(simulate_args(scene_file(tmp_path, add), tmp_path / "out"), 0,
              "warning: object 'm' has zero area", "warning: object 'q' has zero area")
    from datagen.io import read_result
    result = read_result(tmp_path / "out")
    assert result.components["m"].sum() == 0 and result.components["q"].sum() == 0
    assert result.components["patch"].sum() > 0 and not any(line.startswith("error") for line in out.splitlines())


# ------------------------------------------------------------------------------------------ YAML itself


def alias_bomb(levels: int = 9) -> str:
    lines = ['a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels)]
    return "\n".join(lines + [f"objects: *a{levels - 1}"]) + "\n"


def test_yaml_alias_bomb_is_refused_in_one_short_line(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb())
    out = cli(simulate_args(path, tmp_path / "out"), 2, str(path), f"more than {MAX_YAML_VALUES} values")
    assert len(out) < 300


def test_recursive_yaml_alias_is_refused():
    with pytest.raises(SceneError, match="r.yaml: the YAML expands to more than"):
        parse_yaml("a: &a [*a, *a]\n", "r.yaml")


def test_alias_bomb_in_a_detector_preset_is_refused(tmp_path):
    path = tmp_path / "det.yaml"
    path.write_text(alias_bomb())
    with pytest.raises(ValueError, match="det.yaml: the YAML expands"):
        spad.DetectorConfig.from_yaml(path)


def test_binary_scene_file_names_the_file(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_bytes(b"\xff\xfe\x00binary" * 100)
    cli(simulate_args(path, tmp_path / "out"), 2, str(path), "not a UTF-8 text file")


def test_oversized_scene_file_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text("# " + "x" * (9 << 20))
    cli(simulate_args(path, tmp_path / "out"), 2, str(path), "too large")


def test_a_directory_as_scene_file(tmp_path):
    cli(simulate_args(tmp_path, tmp_path / "out"), 2, "scene file not found", str(tmp_path))


def test_a_huge_list_value_is_shown_cut_to_one_short_line(tmp_path):
    path = scene_file(tmp_path, lambda d: set_path(d, "sensor.aperture_radius", list(range(20_000))))
    out = cli(simulate_args(path, tmp_path / "out"), 2, "sensor.aperture_radius")
    assert len(out) < 600


# ------------------------------------------------------------------------------------------ sizes and time


@pytest.mark.parametrize("option, value, field", [("--lookins", "100000x100000", "lookins 100000x100000"),
                                                 ("--pixels", "100000x100000", "pixels 100000x100000")])
def test_huge_sampling_grids_are_refused_with_a_memory_estimate(tmp_path, option, value, field):
    out = cli(simulate_args(scene_file(tmp_path), tmp_path / "out", option, value), 2, field, "GiB", "scene.yaml")
    assert "available" in out


def test_huge_fov_pixel_grid_is_refused(tmp_path):
    path = scene_file(tmp_path, lambda d: set_path(d, "sensor.fov.pixels", [100000, 100000]))
    cli(simulate_args(path, tmp_path / "out"), 2, "sensor.fov.pixels 100000x100000", "GiB")


def test_huge_confocal_scan_is_refused(tmp_path):
    def confocal(d):
        d["capture"] = {"type": "confocal", "laser_grid": {"center": [2.0, 0.0, -0.6], "size": [0.8, 0.8],
                                                           "points": [100000, 100000]}}
    cli(simulate_args(scene_file(tmp_path, confocal), tmp_path / "out"), 2, "capture.laser_grid.points 100000x100000")


def test_tiny_quadrature_edge_is_refused(tmp_path):
    cli(simulate_args(scene_file(tmp_path), tmp_path / "out", "--estimator", "quadrature", "--edge", "1e-9"), 2,
        "estimator.edge 1e-09 m", "raise estimator.edge")


def test_a_billion_time_bins_are_refused(tmp_path):
    path = scene_file(tmp_path, lambda d: set_path(d, "simulation.time.n_bins", 10**9))
    cli(simulate_args(path, tmp_path / "out"), 2, "time.n_bins 1000000000", "GiB")


def test_unreachable_tolerance_is_refused_after_the_first_round(tmp_path):
    # issue 28: projected far beyond the cap, refused (tests/test_hostile_config.py: the cap and its warning)
    cli(simulate_args(scene_file(tmp_path), tmp_path / "out", "--tolerance", "1e-9", "--time-cap", "1s"), 2,
        "--tolerance 1e-9: the first round", "beyond --time-cap 1 s")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("cap", ["0s", "-1", "inf", "soon"])
def test_bad_time_cap_is_refused(tmp_path, cap):
    cli(simulate_args(scene_file(tmp_path), tmp_path / "out", "--tolerance", "1%", "--time-cap", cap), 2, "--time-cap")


# ------------------------------------------------------------------------------------------ output paths


def test_out_under_an_existing_file(tmp_path):
    (tmp_path / "file").write_text("x")
    cli(simulate_args(scene_file(tmp_path), tmp_path / "file" / "sub"), 2, "--out", "is a file")


def test_out_that_is_a_file(tmp_path):
    (tmp_path / "file").write_text("x")
    cli(simulate_args(scene_file(tmp_path), tmp_path / "file"), 2, "--out", "is a file")


def test_disk_full_while_writing_the_result_leaves_nothing_behind(tmp_path, monkeypatch):
    import zarr

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(zarr.Group, "create_array", full)
    cli(simulate_args(scene_file(tmp_path), tmp_path / "out"), 2, "No space left on device", "result.zarr")
    assert not list((tmp_path / "out").glob("*.partial"))


# ------------------------------------------------------------------------------------------ detect


@pytest.fixture(scope="module")
def stored_result(tmp_path_factory):
    out = tmp_path_factory.mktemp("result")
    cli(simulate_args(scene_file(out), out / "sim"), 0)
    return out / "sim"


@pytest.mark.parametrize("text, needle", [("model: [\n", "not valid YAML"), ("- 1\n- 2\n", "expected a mapping"),
                                          ("model: pile_up\n", "repetition_rate"),
                                          ("repetition_rate: 10MHz\nn_cycles: 10\npde: 7\n", "pde")])
def test_detect_with_a_bad_detector_file_names_it(tmp_path, stored_result, text, needle):
    det = tmp_path / "det.yaml"
    det.write_text(text)
    cli(["detect", stored_result, "--detector", det], 2, str(det), needle)


def test_detect_with_a_missing_detector_file(tmp_path, stored_result):
    cli(["detect", stored_result, "--detector", tmp_path / "none.yaml"], 2, "none.yaml", "not found")


def test_detect_exposure_1e12_s_is_refused(tmp_path, stored_result):
    det = tmp_path / "det.yaml"
    det.write_text("model: pile_up\nrepetition_rate: 10MHz\nn_cycles: 100\n")
    cli(["detect", stored_result, "--detector", det, "--exposure", "1e12s"], 2, "exposure", "1e+19 laser cycles")


def test_detect_free_running_1e5_s_is_refused_in_bounded_time(tmp_path, stored_result):
    det = tmp_path / "det.yaml"
    det.write_text("model: free_running\nrepetition_rate: 10MHz\nn_cycles: 100\ndead_time: 50ns\ndcr: 1e5\n")
    cli(["detect", stored_result, "--detector", det, "--exposure", "1e5s"], 2, "free_running event simulation",
        "MAX_SIMULATED_EVENTS")


# ------------------------------------------------------------------------------------------ detector API

FREE_RUNNING = dict(model="free_running", repetition_rate=1e7, bin_width=1e-9, dead_time=50e-9)


def test_detection_pmf_of_huge_rates_is_finite_and_sums_to_one():
    pmf = detection_pmf([1e308, 1e308])
    np.testing.assert_array_equal(pmf, [1.0, 0.0, 0.0])
    batch = detection_pmf([[1e308, 1e308, 3.0], [1.0, 1.0, 1.0]])
    assert np.all(np.isfinite(batch)) and np.allclose(batch.sum(axis=1), 1.0, rtol=0, atol=1e-13)
    # the second row is unaffected by the first's overflow: e^{-C_i}(1 - e^{-r_i}) with C = 0, 1, 2
    np.testing.assert_allclose(batch[1, :3], np.exp(-np.arange(3.0)) * -np.expm1(-1.0), rtol=1e-15)


def test_sample_histogram_free_running_1e6_s_is_refused():
    config = spad.DetectorConfig(**FREE_RUNNING, exposure=1e6)
    with pytest.raises(ValueError, match=r"free_running event simulation: .* ~6.4e\+12 expected avalanches .*"
                                         r"MAX_SIMULATED_EVENTS"):
        spad.sample_histogram(np.full(64, 0.01), config, np.random.default_rng(0))
    # the expected histogram of the same exposure is exact and cheap
    assert np.isfinite(spad.expected_histogram(np.full(64, 0.01), config)).all()


def test_afterpulsing_simulation_refuses_a_long_exposure():
    config = spad.DetectorConfig(**FREE_RUNNING, n_cycles=10**9, afterpulse_probability=0.01,
                                 afterpulse_time_constant=1e-8)
    with pytest.raises(ValueError, match="afterpulsing"):
        spad.sample_histogram(np.full(64, 0.01), config, np.random.default_rng(0))


def test_crosstalk_simulation_refuses_a_long_exposure():
    config = spad.DetectorConfig(model="pile_up", repetition_rate=1e7, bin_width=1e-9, n_cycles=10**15,
                                 crosstalk_probability=0.1)
    with pytest.raises(ValueError, match="crosstalk"):
        spad.sample_histogram(np.full((4, 4, 16), 0.01), config, np.random.default_rng(0))


def test_sample_counter_refuses_a_window_of_1e6_s_at_1_mhz():
    with pytest.raises(ValueError, match="sample_counter"):
        spad.sample_counter(1e6, 50e-9, 1e6, np.random.default_rng(0))
    with pytest.raises(ValueError, match="window must be finite"):
        spad.sample_counter(1e6, 50e-9, math.inf, np.random.default_rng(0))


@pytest.mark.parametrize("field, value", [("exposure", math.inf), ("exposure", math.nan), ("dcr", math.inf),
                                          ("n_cycles", 2**63), ("repetition_rate", math.inf)])
def test_detector_config_refuses_non_finite_and_overflowing_values(field, value):
    kwargs = dict(model="pile_up", repetition_rate=1e7, bin_width=1e-9, n_cycles=10)
    kwargs.pop("n_cycles" if field == "exposure" else "", None)
    with pytest.raises(ValidationError, match=field):
        spad.DetectorConfig(**{**kwargs, field: value})


def test_rates_with_nan_name_the_index():
    with pytest.raises(ValueError, match=r"rates contains a non-finite value nan at index \(1,\)"):
        spad.sample_histogram([0.1, math.nan], spad.DetectorConfig(repetition_rate=1e7, bin_width=1e-9, n_cycles=5),
                              np.random.default_rng(0))
